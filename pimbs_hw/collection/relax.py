"""Whether relaxing the muscles lets the arm fall out of the range its wires are routed for.

Relaxed means every muscle tension-controlled at its holding floor (``f_floor``): the boards
do it when the driver connects, after a safety stop and when a collection ends. An arm that
hangs settles near its lowest pose, but floors do not balance every arm: an upright arm
(a pybullet KUKA with one muscle pair per joint) falls to its hard stop, and MuJoCo's
``arm26.xml``, whose joints lie in a horizontal plane, turns until a stop, where its
extensor tendons have flipped sides of their wrapping cylinders (the reason its description
narrows the routed range). From there the wires cannot pull the arm back into its range, and
the commands of the first pose, computed for the routed range, pull the wires against each
other and the stop.

So the relaxed rest is predicted with the description's statics before the arm is touched,
from the simulated arm's power-up pose (θ = 0, within the joint limits) and from the middle
of the routed range; where it leaves the routed range, the collection holds the arm at its
motors' lengths instead of relaxing it.
"""

from __future__ import annotations

import numpy as np

from pimbs_arm.model import ArmModel

# a relaxed joint may rest this far beyond its routed range, in rad or as a share of the
# range (a hanging elbow rests on its stop a degree or two short of a range that starts there)
RANGE_TOLERANCE = (0.05, 0.15)


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
    return None
