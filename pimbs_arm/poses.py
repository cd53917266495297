"""The seeded pose sequence shared by ``pimbs simulate`` and ``pimbs collect``: only poses the
muscles can hold.

A pose drawn uniformly in the joint ranges may need more tension than a wire may carry (an
ATL floor of 300 N on an antagonist, a long lever against gravity). Simulation would record
it silently, a collection would stop at the board's tension ceiling on every ``--resume``,
for ever. So each pose is checked with the tension QP bounded above (``f_floor``/ATL floor
≤ f ≤ ``PLAN_CEILING``·f_max, the rest being headroom for the transients of slack removal);
an infeasible pose is replaced by the first feasible one drawn from its own stream
``[seed, 3, i]``. Feasible poses stay exactly the draws of ``[seed, 0]``, so recordings of
robots whose poses were all feasible do not change, and a replacement depends only on the
seed and the sample index (``simulate`` and ``collect`` pair by ``sample``; ``--resume``
continues the same sequence).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pimbs_arm.model import ArmModel, InfeasiblePoseError, sample_poses

ATL_F_MIN = (10.0, 300.0)  # N, the paper's range of the ATL-Map tension floors
# Floors stop at this share of the weakest muscle's f_max: a floor above it leaves that muscle
# less than 0.15 f_max under the plan ceiling for the load (and, on a balanced antagonist
# pair, the antagonist's floor is load), so most draws would be replaced; an arm with a muscle
# weaker than 300 / PLAN_CEILING N could hold none. Arms whose muscles all hold 400 N or more
# keep the paper's range.
ATL_F_MAX_SHARE = 0.75
MAPS = ("al", "atl")
PLAN_CEILING = 0.9  # a planned pose holds with every tension <= this fraction of f_max
REPLACEMENT_TRIES = 1000  # draws per infeasible pose before the robot is declared unable


@dataclass(frozen=True)
class PosePlan:
    """Poses (n, N), the tension floors a collection holds them with (n, M), and which
    sample indices were replaced because the first draw could not be held."""

    poses: np.ndarray
    floors: np.ndarray
    drawn_floors: np.ndarray  # the ATL draws before the f_floor clamp (zeros for AL)
    replaced: tuple[int, ...]


def hold_ceiling(arm: ArmModel) -> np.ndarray:
    """(M,) the highest tension a plan may ask of each muscle."""
    return PLAN_CEILING * arm.f_max


def atl_floor_range(arm: ArmModel) -> tuple[float, float]:
    """The ATL-Map floors' draw, uniform in [low, high] N for every muscle: the paper's
    [10, 300] N, its top lowered to ``ATL_F_MAX_SHARE`` of the weakest muscle's f_max."""
    low, high = ATL_F_MIN
    return low, max(low, min(high, ATL_F_MAX_SHARE * float(arm.f_max.min())))


def feasible(arm: ArmModel, theta: np.ndarray, floor: np.ndarray) -> bool:
    """Whether the muscles hold ``theta`` with ``floor <= f <= hold_ceiling``."""
    try:
        arm.tension_distribution(theta, floor, f_max=hold_ceiling(arm))
    except InfeasiblePoseError:
        return False
    return True


def plan_poses(arm: ArmModel, n: int, seed: int, map_kind: str = "atl") -> PosePlan:
    """The first ``n`` poses of the seeded sequence, every one within the muscles' reach.

    Raises ``InfeasiblePoseError`` when no draw for some sample can be held: the description
    itself (ranges, routing, f_max) is then the problem, and the message says so.
    """
    if map_kind not in MAPS:
        raise ValueError(f"map must be one of {', '.join(MAPS)}, not {map_kind!r}")
    poses = sample_poses(arm.joint_range, n, np.random.default_rng([seed, 0]))
    f_floor = np.array([m.f_floor for m in arm.robot.muscles])
    if map_kind == "atl":
        low, high = atl_floor_range(arm)
        drawn = np.random.default_rng([seed, 1]).uniform(low, high, (n, arm.n_muscles))
        floors = np.maximum(drawn, f_floor)
    else:
        drawn = np.zeros((n, arm.n_muscles))
        floors = np.broadcast_to(f_floor, (n, arm.n_muscles)).copy()
    replaced = []
    for i in range(n):
        if feasible(arm, poses[i], floors[i]):
            continue
        poses[i] = _replacement(arm, floors[i], np.random.default_rng([seed, 3, i]), i)
        replaced.append(i)
    return PosePlan(poses=poses, floors=floors, drawn_floors=drawn, replaced=tuple(replaced))


def _replacement(arm: ArmModel, floor: np.ndarray, rng: np.random.Generator, i: int
                 ) -> np.ndarray:
    for _ in range(REPLACEMENT_TRIES):
        theta = sample_poses(arm.joint_range, 1, rng)[0]
        if feasible(arm, theta, floor):
            return theta
    raise InfeasiblePoseError(
        f"{arm.robot.muscle_path}: none of {REPLACEMENT_TRIES} poses drawn in the joint ranges "
        f"for sample {i} can be held with tensions between {np.round(floor, 1).tolist()} N and "
        f"{PLAN_CEILING:g}*f_max; check the routing with `pimbs robot "
        f"{arm.robot.muscle_path}`, narrow the joint ranges or raise f_max")


def replaced_note(replaced: Sequence[int], n: int, seed: int) -> str:
    """One line for the user about replaced poses ('' when none were)."""
    if not replaced:
        return ""
    shown = ", ".join(str(i) for i in replaced[:10]) + (", ..." if len(replaced) > 10 else "")
    return (f"{len(replaced)} of {n} drawn poses need tensions beyond {PLAN_CEILING:g}*f_max "
            f"and were replaced by feasible draws from seed {seed} (samples {shown}; "
            "simulate and collect replace the same ones)")
