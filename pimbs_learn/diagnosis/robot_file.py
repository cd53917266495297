"""What the robot file tells the diagnosis beyond the recording: each link's own gravity and
each muscle's routing.

**Links.** A robot file gives every link's mass and centre of mass. A link that weighs more
or less than the file says (a heavier forearm, a motor fitted inside it, a hand not in the
file) changes the gravity torque by that link's own share, scaled: ``τ_i(θ)·(scale − 1)``,
with ``τ_i`` the torque the link's mass alone asks at each joint. One parameter per link,
and it names the link. Without the file only the whole gravity torque is known, and the
diagnosis falls back to scaling the potential beyond a joint (``model.units_of``).

**Routing.** The file's muscle lengths ``h_file(θ)`` follow every via point and wrap: where
a wire crosses a joint's axis its moment arm turns over within a few degrees, which no
polynomial of the degree a recording's rows allow can follow (31 µm of error on a
four-joint arm's two muscles at degree 3, against 3–4 µm of length noise). Learned as
``h_file + correction``, the schema's polynomial only has to follow how the real arm
differs from its file, which is smooth and small; ``inputs.build_physics`` keeps the file's
routing only where it predicts held-out rows better.
"""

from __future__ import annotations

import numpy as np

from pimbs_arm.model import ArmModel
from pimbs_learn.diagnosis.bases import at_poses
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


class FileRouting:
    """The file's muscle lengths ``h_file(θ)`` (B, M) and their Jacobian (B, M, N) at a set of
    poses, memoised per pose set: the fits revisit the same poses many times (joint
    offsets move them, and each move is new)."""

    def __init__(self, arm: ArmModel) -> None:
        self.arm = arm
        self._cache: dict = {}

    def at(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return at_poses(self._cache, theta,
                        lambda t: (self.arm.h_geom(t), self.arm.muscle_jacobian(t)), 64)
