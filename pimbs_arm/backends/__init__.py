"""Arm backends behind ``pimbs_arm.backend.ArmBackend``: one module per way of describing
an arm's geometry and gravity."""
