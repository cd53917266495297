"""The seeded pose sequence shared by ``pimbs simulate`` and ``pimbs collect``: only poses the
muscles can hold.

A pose drawn uniformly in the joint ranges may need more tension than a wire may carry (an
ATL floor of 300 N on an antagonist, a long lever against gravity). Simulation would record
it silently, a collection would stop at the board's tension ceiling on every ``--resume``,
for ever. So each pose is checked with the tension QP bounded above (``f_floor``/ATL floor
≤ f ≤ ``PLAN_CEILING``·f_max, the rest being headroom for the transients of slack removal),
and for a holding that keeps the arm there (``pimbs_arm.holding``: at some tensions a
balanced pose is a saddle the arm runs off); an infeasible pose is replaced by the first
feasible one drawn from its own stream ``[seed, 3, i]``. Feasible poses stay exactly the
draws of ``[seed, 0]``, so recordings of robots whose poses were all feasible do not change,
and a replacement depends only on the seed and the sample index (``simulate`` and
``collect`` pair by ``sample``; ``--resume`` continues the same sequence).

ATL floors an arm cannot hold anywhere (a 234 N floor on an elbow flexor with a 64 mm lever,
whose extensor pulls on 25 mm: no pose balances it below the extensor's ceiling) are scaled
instead: when ``SCALE_AFTER`` replacement poses fail, the sample keeps its drawn pose and its
drawn floors are multiplied by the largest of ``FLOOR_SCALES`` that the arm holds there (by
0, the AL-Map's floors, at worst). Where even those fail at the drawn pose, the first pose of
stream ``[seed, 4, i]`` that holds some scale is taken. Everything stays a function of the
seed and the sample index; the scaled samples are listed (``PosePlan.scaled``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pimbs_arm.holding import holdable
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
# ATL samples whose first SCALE_AFTER replacement poses all fail have floors no pose holds
# (replacements of an arm that works are found within a few tens of draws: at most 37 over
# 1800 samples of fixtures/foreign_arm); their floors are scaled instead of drawing on
FLOOR_SCALES = (7 / 8, 3 / 4, 5 / 8, 1 / 2, 3 / 8, 1 / 4, 1 / 8, 0.0)
SCALE_AFTER = 100


@dataclass(frozen=True)
class PosePlan:
    """Poses (n, N), the tension floors a collection holds them with (n, M), and which
    sample indices were replaced because the first draw could not be held."""

    poses: np.ndarray
    floors: np.ndarray
    drawn_floors: np.ndarray  # the ATL draws before the f_floor clamp (zeros for AL), scaled
    replaced: tuple[int, ...]
    scaled: tuple[int, ...] = ()  # samples whose ATL floors were scaled to be held


def hold_ceiling(arm: ArmModel) -> np.ndarray:
    """(M,) the highest tension a plan may ask of each muscle."""
    return PLAN_CEILING * arm.f_max


def atl_floor_range(arm: ArmModel) -> tuple[float, float]:
    """The ATL-Map floors' draw, uniform in [low, high] N for every muscle: the paper's
    [10, 300] N, its top lowered to ``ATL_F_MAX_SHARE`` of the weakest muscle's f_max."""
    low, high = ATL_F_MIN
    return low, max(low, min(high, ATL_F_MAX_SHARE * float(arm.f_max.min())))


def feasible(arm: ArmModel, theta: np.ndarray, floor: np.ndarray) -> bool:
    """Whether the muscles hold ``theta`` with ``floor <= f <= hold_ceiling`` and the arm
    stays there (``pimbs_arm.holding.holdable``)."""
    kin = arm.backend.kinematics(np.asarray(theta, dtype=np.float64))
    try:
        tension = arm.tensions_for(theta, kin.jacobian, floor, f_max=hold_ceiling(arm))
    except InfeasiblePoseError:
        return False
    return holdable(arm, theta, tension, kin)


def _f_floor(arm: ArmModel) -> np.ndarray:
    return np.array([m.f_floor for m in arm.robot.muscles], dtype=np.float64)


def plan_poses(arm: ArmModel, n: int, seed: int, map_kind: str = "atl") -> PosePlan:
    """The first ``n`` poses of the seeded sequence, every one within the muscles' reach.

    Raises ``InfeasiblePoseError`` when no draw for some sample can be held: the description
    itself (ranges, routing, f_max) is then the problem, and the message says so.
    """
    if map_kind not in MAPS:
        raise ValueError(f"map must be one of {', '.join(MAPS)}, not {map_kind!r}")
    poses = sample_poses(arm.joint_range, n, np.random.default_rng([seed, 0]))
    f_floor = _f_floor(arm)
    if map_kind == "atl":
        low, high = atl_floor_range(arm)
        drawn = np.random.default_rng([seed, 1]).uniform(low, high, (n, arm.n_muscles))
        floors = np.maximum(drawn, f_floor)
    else:
        drawn = np.zeros((n, arm.n_muscles))
        floors = np.broadcast_to(f_floor, (n, arm.n_muscles)).copy()
    replaced, scaled = [], []
    for i in range(n):
        if feasible(arm, poses[i], floors[i]):
            continue
        tries = SCALE_AFTER if map_kind == "atl" else REPLACEMENT_TRIES
        theta = _replacement(arm, floors[i], np.random.default_rng([seed, 3, i]), tries)
        if theta is not None:
            poses[i] = theta
            replaced.append(i)
            continue
        if map_kind != "atl":
            raise _unable(arm, i, floors[i])
        theta, scale = _scaled(arm, poses[i], drawn[i], f_floor,
                               np.random.default_rng([seed, 4, i]))
        if theta is None:
            raise _unable(arm, i, floors[i])
        if not np.array_equal(theta, poses[i]):
            poses[i] = theta
            replaced.append(i)
        drawn[i] *= scale
        floors[i] = np.maximum(drawn[i], f_floor)
        scaled.append(i)
    return PosePlan(poses=poses, floors=floors, drawn_floors=drawn, replaced=tuple(replaced),
                    scaled=tuple(scaled))


def _replacement(arm: ArmModel, floor: np.ndarray, rng: np.random.Generator, tries: int
                 ) -> np.ndarray | None:
    """The first of ``tries`` draws the muscles hold at ``floor`` (None: none of them)."""
    for _ in range(tries):
        theta = sample_poses(arm.joint_range, 1, rng)[0]
        if feasible(arm, theta, floor):
            return theta
    return None


def _scaled(arm: ArmModel, theta: np.ndarray, drawn: np.ndarray, f_floor: np.ndarray,
            rng: np.random.Generator) -> tuple[np.ndarray | None, float]:
    """The drawn pose (else the first draw of ``rng``) with the largest of ``FLOOR_SCALES``
    whose floors the muscles hold there: (pose, scale), or (None, 0) for none."""
    for k in range(REPLACEMENT_TRIES):
        if k:
            theta = sample_poses(arm.joint_range, 1, rng)[0]
        if not feasible(arm, theta, f_floor):
            continue  # not even the AL-Map's floors hold this pose
        for scale in FLOOR_SCALES:
            if scale == 0.0 or feasible(arm, theta, np.maximum(scale * drawn, f_floor)):
                return theta, scale
    return None, 0.0


def _unable(arm: ArmModel, i: int, floor: np.ndarray) -> InfeasiblePoseError:
    return InfeasiblePoseError(
        f"{arm.robot.muscle_path}: none of {REPLACEMENT_TRIES} poses drawn in the joint ranges "
        f"for sample {i} can be held with tensions between {np.round(floor, 1).tolist()} N and "
        f"{PLAN_CEILING:g}*f_max; check the routing with `pimbs robot "
        f"{arm.robot.muscle_path}`, narrow the joint ranges or raise f_max")


def unstable_message(arm: ArmModel, theta: np.ndarray) -> str:
    """Why a pose whose torques balance is not held: the arm would run off it."""
    pose = dict(zip(arm.joints, np.round(theta, 4).tolist(), strict=True))
    return (f"{arm.robot.muscle_path}: at {pose} the tensions balance but the arm would not "
            "stay there (the wires' path curvature outweighs their stiffness for every choice "
            "of length-held muscles); run `pimbs robot "
            f"{arm.robot.muscle_path}` to see its moment arms, or narrow the joint ranges")


def replaced_note(replaced: Sequence[int], n: int, seed: int) -> str:
    """One line for the user about replaced poses ('' when none were)."""
    if not replaced:
        return ""
    shown = ", ".join(str(i) for i in replaced[:10]) + (", ..." if len(replaced) > 10 else "")
    return (f"{len(replaced)} of {n} drawn poses need tensions beyond {PLAN_CEILING:g}*f_max "
            f"(or the arm would not stay there) and were replaced by feasible draws from seed "
            f"{seed} (samples {shown}; "
            "simulate and collect replace the same ones)")


def scaled_note(scaled: Sequence[int], n: int) -> str:
    """One line for the user about samples whose ATL floors were scaled ('' when none)."""
    if not scaled:
        return ""
    shown = ", ".join(str(i) for i in scaled[:10]) + (", ..." if len(scaled) > 10 else "")
    return (f"{len(scaled)} of {n} drawn sets of ATL tension floors cannot be held at any "
            f"pose tried and were scaled down until they can (samples {shown}; simulate and "
            "collect scale the same ones)")
