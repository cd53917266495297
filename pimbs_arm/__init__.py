"""The arm model: muscle geometry, gravity, elasticity, the tension QP and the static
equilibrium solver, one implementation shared by simulation, the mock bus, collection and
learning. Built from a robot description (``pimbs_calibration``); imports nothing above it.

Where things are: ``model.py`` (ArmModel), ``backend.py`` (the seam: what a geometry and
gravity backend provides), ``backends/`` (pinocchio + via points today; MuJoCo's tendons go
here), ``equilibrium.py`` (the pose an arm settles into), ``routing.py`` (every joint turned
both ways), ``poses.py`` (feasible pose plans), ``explain.py`` and ``picture.py`` (what
``pimbs robot`` prints and draws; ``label_layout.py`` keeps the picture's labels apart).
"""
