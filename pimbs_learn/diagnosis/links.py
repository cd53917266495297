"""The links a mass change can sit on, and the gravity torque each one's mass carries.

A robot file gives every link's mass and centre of mass. A link that weighs more or less
than the file says (a heavier forearm, a motor fitted inside it, a hand not in the file)
changes the gravity torque by that link's own share, scaled: ``τ_i(θ)·(scale − 1)``, with
``τ_i`` the torque the link's mass alone asks at each joint. One parameter per link, and
it names the link. Without the file only the whole gravity torque is known, and the
diagnosis falls back to scaling the potential beyond a joint (``model.units_of``).
"""

from __future__ import annotations

import numpy as np

from pimbs_arm.model import ArmModel
from pimbs_sim.effects import Effect, EffectSpecError


def carried_link(arm: ArmModel, k: int) -> str | None:
    """The link joint ``k`` carries (the first body on it; links fixed to it move with it),
    or None where the description has no body on that joint."""
    if arm.backend.kind == "mjcf":
        from pimbs_calibration.mjcf import joint_names

        m = arm.backend.mj_model
        return m.body(int(m.jnt_bodyid[joint_names(m).index(arm.joints[k])])).name or None
    import pinocchio as pin

    model = arm._model
    jid = model.getJointId(arm.joints[k])
    for frame in model.frames:
        if frame.type == pin.FrameType.BODY and frame.parentJoint == jid:
            return frame.name
    return None


def link_torques(arm: ArmModel, theta: np.ndarray) -> tuple[list[str], np.ndarray]:
    """The links the joints carry that have a mass, and (L, B, N) the gravity torque each
    one's mass asks at the poses ``theta``: the change a link twice as heavy makes (gravity
    is linear in a link's mass at a fixed centre of mass, so the step is exact)."""
    base = arm.gravity_torque(theta)
    names, torques = [], []
    for k in range(arm.n_joints):
        link = carried_link(arm, k)
        if link is None or link in names:
            continue
        try:
            heavier = Effect("link_mass", 2.0, link=link).physics(arm)
        except EffectSpecError:  # a joint that carries no mass of its own
            continue
        names.append(link)
        torques.append(heavier.gravity_torque(theta) - base)
    return names, np.array(torques).reshape(len(names), *np.shape(base))
