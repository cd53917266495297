"""Whether relaxing the muscles lets the arm fall where the collection cannot start from.

Relaxed means every muscle tension-controlled at its holding floor (``f_floor``): the boards
do it when the driver connects, after a safety stop and when a collection ends. An arm that
hangs settles near its lowest pose, but floors do not balance every arm: an upright arm
(a pybullet KUKA with one muscle pair per joint) falls to its hard stop, and MuJoCo's
``arm26.xml``, whose joints lie in a horizontal plane, turns until a stop, where its
extensor tendons have flipped sides of their wrapping cylinders (the reason its description
narrows the routed range). From there the wires cannot pull the arm back into its range, and
the commands of the first pose, computed for the routed range, pull the wires against each
other and the stop.

An arm may also fall, within its range, onto a stop where its own weight rests on the stop
and its muscles can barely lift it, or not at all: MyoSuite's abdomen torso, relaxed, leans
onto its extension and bending stops, where lifting it takes 84 % of an oblique's f_max, and
MyoSuite's motor finger hangs on its knuckle's stop where no tensions within the motors' f_max
hold it. Every move from there starts with the wires pulling the full weight off the stop, at
the edge of what they carry (the first pose of both stopped at the boards' ceiling).

So the relaxed rest is predicted with the description's statics before the arm is touched,
from the simulated arm's power-up pose (θ = 0, within the joint limits) and from the middle
of the routed range; where it leaves the routed range, or where the muscles would need more
than ``LIFT_SHARE`` of a muscle's f_max (within their floors) to hold it there, the
collection holds the arm at its motors' lengths instead of relaxing it.
"""

from __future__ import annotations

import numpy as np

from pimbs_arm.model import ArmModel, InfeasiblePoseError

# a relaxed joint may rest this far beyond its routed range, in rad or as a share of the
# range (a hanging elbow rests on its stop a degree or two short of a range that starts there)
RANGE_TOLERANCE = (0.05, 0.15)
# share of a muscle's f_max above which lifting the relaxed arm off its rest is too close to
# what the wire carries for a move to start from there (the plans hold poses at <= 0.9)
LIFT_SHARE = 0.5


def relax_fall(model: ArmModel) -> str | None:
    """One line naming the joint the relaxed arm would leave its routed range with, where it
    would rest and the range; None when relaxing keeps every joint in range."""
    lo, hi = model.joint_range[:, 0], model.joint_range[:, 1]
    limits = model.joint_limits
    starts = [np.clip(np.zeros(model.n_joints), limits[:, 0], limits[:, 1]), (lo + hi) / 2]
    floor = np.array([m.f_floor for m in model.robot.muscles])
    for start in starts:
        try:
            rest = model.equilibrium("tension", floor, theta0=start)
        except (ValueError, ArithmeticError):  # no prediction: nothing to name
            continue
        tol = np.maximum(RANGE_TOLERANCE[0], RANGE_TOLERANCE[1] * (hi - lo))
        out = (rest.theta < lo - tol) | (rest.theta > hi + tol)
        if out.any():
            j = int(np.argmax(np.maximum(lo - rest.theta, rest.theta - hi)))
            at_stop = (abs(rest.theta[j] - limits[j, 0]) < 1e-6
                       or abs(rest.theta[j] - limits[j, 1]) < 1e-6)
            return (f"relaxed (every muscle at its floor f_floor), {model.joints[j]} would "
                    f"turn to {rest.theta[j]:.3f} rad{' (its hard stop)' if at_stop else ''}, "
                    f"outside the range its wires are routed for [{lo[j]:g}, {hi[j]:g}] rad")
        heavy = _hard_to_lift(model, rest.theta, floor)
        if heavy is not None:
            return heavy
    return None


def _hard_to_lift(model: ArmModel, theta: np.ndarray, floor: np.ndarray) -> str | None:
    """The line saying why the relaxed rest ``theta`` is no place to start a move from (the
    muscles cannot hold it, or only above ``LIFT_SHARE`` of a muscle's f_max); None if not."""
    pose = ", ".join(f"{j}={t:.3f}" for j, t in zip(model.joints, theta, strict=True))
    f_max = np.asarray(model.f_max, float)
    where = f"relaxed (every muscle at its floor f_floor), the arm would come to rest at {pose} rad"
    try:
        tension = model.tension_distribution(theta, floor)
    except InfeasiblePoseError:
        return f"{where}, a pose its muscles cannot hold: only its stops carry it there"
    share = tension / f_max
    k = int(np.argmax(share))
    if share[k] <= LIFT_SHARE:
        return None
    if share[k] > 1.0:
        return (f"{where}, where holding it takes {tension[k]:.0f} N of {model.muscles[k]}, "
                f"more than its f_max ({f_max[k]:g} N): only its stops carry it there")
    return (f"{where}, where holding it takes {tension[k]:.0f} N of {model.muscles[k]} "
            f"({share[k]:.0%} of its f_max): a move from there would start at the edge of "
            "what that wire carries")
