"""What a muscle routing means: which muscle pulls which joint which way, and where it cannot.

A muscle only pulls. A joint the muscles can turn one way only cannot be held against a load
the other way, so every driven joint needs, at every pose in its range, some muscle with a
positive and some with a negative moment arm. Moment arms here are ``r = -G = -dl/dθ``
(m, N·m per N): the torque a tension ``f`` gives is ``r·f`` (the sign convention of
``τ = -Gᵀf``), so ``r > 0`` turns the joint towards positive angles.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from pimbs_arm.model import ArmModel

MIN_MOMENT_ARM = 1e-3  # m: a muscle with less does not usefully pull a joint


@dataclass(frozen=True)
class RoutingReport:
    """Moment arms of every muscle about every driven joint over a set of poses."""

    poses: np.ndarray  # (P, N)
    moment_arm: np.ndarray  # (P, M, N) r = -G

    def crosses(self) -> np.ndarray:
        """(M, N) bool: the muscle has a moment arm about the joint somewhere."""
        return (np.abs(self.moment_arm) >= MIN_MOMENT_ARM).any(axis=0)

    def one_sided(self) -> np.ndarray:
        """(P, N) bool: at this pose no muscle turns the joint positive, or none negative."""
        r = self.moment_arm
        return ~((r >= MIN_MOMENT_ARM).any(axis=1) & (r <= -MIN_MOMENT_ARM).any(axis=1))

    def missing_side(self, pose: int, joint: int) -> str:
        """'positive', 'negative' or 'either': the direction no muscle turns the joint."""
        r = self.moment_arm[pose, :, joint]
        pos, neg = (r >= MIN_MOMENT_ARM).any(), (r <= -MIN_MOMENT_ARM).any()
        return "either" if not (pos or neg) else ("positive" if not pos else "negative")


def check_poses(arm: ArmModel, n_random: int = 200, seed: int = 0) -> np.ndarray:
    """The centre of the joint ranges, their corners (up to 8 joints) and seeded random
    poses inside them: where a routing is checked."""
    lo, hi = arm.joint_range[:, 0], arm.joint_range[:, 1]
    poses = [0.5 * (lo + hi)]
    if arm.n_joints <= 8:
        corners = np.array(np.meshgrid(*[[0, 1]] * arm.n_joints, indexing="ij"))
        corners = corners.reshape(arm.n_joints, -1).T
        poses.extend(lo + c * (hi - lo) for c in corners)
    rng = np.random.default_rng(seed)
    poses.extend(rng.uniform(lo, hi, (n_random, arm.n_joints)))
    return np.array(poses)


def routing_report(arm: ArmModel, poses: np.ndarray) -> RoutingReport:
    """Moment arms at ``poses`` (P, N)."""
    return RoutingReport(poses=np.asarray(poses, float), moment_arm=-arm.muscle_jacobian(poses))


def check_both_ways(arm: ArmModel) -> None:
    """At load: at the centre of the ranges every driven joint must have a muscle turning it
    each way. Raises ``DescriptionError`` naming the muscle file and the joint."""
    from pimbs_calibration.description import DescriptionError

    report = routing_report(arm, arm.joint_range.mean(axis=1)[None])
    for j in np.flatnonzero(report.one_sided()[0]):
        side = report.missing_side(0, j)
        r = report.moment_arm[0, :, j]
        arms = ", ".join(f"{m} {1e3 * v:+.1f} mm" for m, v in zip(arm.muscles, r, strict=True)
                         if abs(v) >= MIN_MOMENT_ARM) or "none"
        what = ("no muscle crosses it" if side == "either"
                else f"no muscle turns it towards {side} angles")
        raise DescriptionError(
            arm.robot.muscle_path, f"joints[{j}]",
            f"joint '{arm.joints[j]}': {what} at the middle of its range (moment arms: "
            f"{arms}), so it cannot be held against a load that way",
            "Route a muscle across it on the other side (via points on both links, offset "
            "from the joint axis), or lock the joint by removing it from 'joints'; "
            "`pimbs robot` shows the moment arms")


def both_ways_problem(arm: ArmModel, report: RoutingReport) -> str | None:
    """Which driven joints the routing cannot turn which way, at how many of the checked
    poses, in one phrase (None when every joint turns both ways everywhere). Joints no
    muscle crosses anywhere are named together, first.

    `pimbs robot`, `pimbs simulate` and `pimbs collect` refuse a routing with the same words
    (``usable_problem``), so a user meets one diagnosis whichever command they ran first.
    """
    bad = report.one_sided()
    uncrossed = [j for j in range(arm.n_joints) if not report.crosses()[:, j].any()]
    parts = [f"no muscle crosses {', '.join(arm.joints[j] for j in uncrossed)}"] \
        if uncrossed else []
    for j in np.flatnonzero(bad.any(axis=0)):
        if j in uncrossed:
            continue
        where = np.flatnonzero(bad[:, j])
        sides = {report.missing_side(p, j) for p in where}
        turns = sorted(sides - {"either"})
        words = ([f"towards {' or '.join(turns)} angles"] if turns else []) + (
            ["at all"] if "either" in sides else [])
        parts.append(f"{arm.joints[j]} not {' or '.join(words)} at {len(where)} of "
                     f"{len(report.poses)} checked poses")
    return "; ".join(parts) or None


#: what to do about a joint that cannot be turned both ways
BOTH_WAYS_FIX = "route a muscle on the missing side or narrow that joint's range"


def usable_problem(arm: ArmModel, report: RoutingReport | None = None) -> str | None:
    """What keeps a description from being simulated or collected, in one phrase with what
    to do (None: nothing). `pimbs simulate` and `pimbs collect` refuse with it and `pimbs
    robot` marks it in its explanation, so no command accepts what another refuses.

    The check: every driven joint turned both ways at the centre of the ranges, their
    corners and seeded random poses (``check_poses``; ``report`` if already measured there).
    """
    report = routing_report(arm, check_poses(arm)) if report is None else report
    problem = both_ways_problem(arm, report)
    if problem is None:
        return None
    fix = BOTH_WAYS_FIX
    if not report.crosses().any(axis=0).all():
        fix += ("; a joint no muscle crosses is left out of 'joints' in a muscle file (then "
                "held at 'lock' or its reference pose)")
    return f"some driven joints cannot be turned both ways ({problem}); {fix}"
