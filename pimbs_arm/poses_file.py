"""A pose plan read from (or written to) a CSV: chosen poses instead of the seeded draws.

`pimbs diagnose` writes the poses that would tell two explanations apart; `pimbs collect
--poses-file` and `pimbs simulate --poses-file` take them. One row per sample, one column
per driven joint (rad, named by the joint), and optionally one column per muscle named
``floor_<muscle>``: the tension floor (N) that muscle is held with at that pose (the ATL-Map's
co-contraction; below the muscle's own ``f_floor`` it is raised to it). Without floor columns
the map decides, as for the seeded plan: ATL floors drawn from the seed, AL each muscle's
``f_floor``. A collection must know every column it is given: one that names neither a joint
nor a muscle's floor is refused, since a misspelt floor would otherwise be silently replaced.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from pimbs_arm.geometry_table import PoseFileError, read_poses_csv
from pimbs_arm.model import ArmModel
from pimbs_arm.poses import PLAN_CEILING, PosePlan, atl_floor_range, feasible

FLOOR_PREFIX = "floor_"


def floor_column(muscle: str) -> str:
    return f"{FLOOR_PREFIX}{muscle}"


def read_pose_plan(path: Path, arm: ArmModel, seed: int = 0, map_kind: str = "atl"
                   ) -> PosePlan:
    """The plan of the poses in ``path`` for ``arm``; raises ``PoseFileError`` (one line that
    names the file, the column or row, and what to do) when it does not fit the robot."""
    path = Path(path)
    poses, other = read_poses_csv(path, tuple(arm.joints))
    known = {floor_column(m): j for j, m in enumerate(arm.muscles)}
    unknown = [c for c in other if c not in known]
    if unknown:
        raise PoseFileError(
            f"{path}: column {unknown[0]!r} names no driven joint of {arm.robot.name} "
            f"({', '.join(arm.joints)}) and no muscle floor (floor_<muscle>, muscles "
            f"{', '.join(arm.muscles)}); rename or remove it")
    lo, hi = arm.joint_range[:, 0], arm.joint_range[:, 1]
    outside = np.flatnonzero(((poses < lo - 1e-9) | (poses > hi + 1e-9)).any(axis=1))
    if len(outside):
        i = int(outside[0])
        k = int(np.flatnonzero((poses[i] < lo - 1e-9) | (poses[i] > hi + 1e-9))[0])
        raise PoseFileError(
            f"{path}: row {i + 1}, {arm.joints[k]} = {poses[i, k]:g} rad lies outside its "
            f"range [{lo[k]:g}, {hi[k]:g}] of {arm.robot.name}; keep every pose in range")
    f_floor = np.array([m.f_floor for m in arm.robot.muscles])
    n = len(poses)
    drawn = _floors(path, arm, [c for c in other if c in known], known, n)
    if drawn is None:
        if map_kind == "atl":
            low, high = atl_floor_range(arm)
            drawn = np.random.default_rng([seed, 1]).uniform(low, high, (n, arm.n_muscles))
        else:
            drawn = np.zeros((n, arm.n_muscles))
    floors = np.maximum(drawn, f_floor)
    for i in range(n):
        if not feasible(arm, poses[i], floors[i]):
            raise PoseFileError(
                f"{path}: row {i + 1}: the muscles of {arm.robot.name} cannot hold this pose "
                f"with floors {np.round(floors[i], 1).tolist()} N within {PLAN_CEILING:g}*f_max"
                " (or the arm would not stay there); lower its floors or drop the row")
    return PosePlan(poses=poses, floors=floors, drawn_floors=drawn, replaced=())


def _floors(path: Path, arm: ArmModel, columns: list[str], known: dict[str, int], n: int
            ) -> np.ndarray | None:
    """(n, M) floors from the file's floor columns (all muscles or none), or None."""
    if not columns:
        return None
    missing = [m for m in arm.muscles if floor_column(m) not in columns]
    if missing:
        raise PoseFileError(f"{path}: floor columns for some muscles but not for "
                            f"{', '.join(missing)}; give floor_<muscle> for every muscle or "
                            "for none")
    with open(path, newline="", encoding="utf-8-sig") as fh:
        rows = [r for r in csv.reader(fh) if any(cell.strip() for cell in r)]
    header = [h.strip() for h in rows[0]]
    out = np.zeros((n, arm.n_muscles))
    for name in columns:
        c, j = header.index(name), known[name]
        for i, row in enumerate(rows[1:], start=1):
            cell = row[c].strip() if c < len(row) else ""
            try:
                value = float(cell)
            except ValueError:
                value = math.nan
            if not math.isfinite(value) or value < 0:
                raise PoseFileError(f"{path}: row {i}, column {name!r}: {cell!r} is not a "
                                    "tension floor; give a number of newtons ≥ 0")
            out[i - 1, j] = value
    return out


def pose_plan_csv(arm: ArmModel, poses: np.ndarray, floors: np.ndarray | None = None) -> str:
    """The CSV text ``read_pose_plan`` reads: joints, then (if given) each muscle's floor."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow([*arm.joints, *([floor_column(m) for m in arm.muscles]
                                    if floors is not None else [])])
    for i, theta in enumerate(np.asarray(poses, float)):
        row = [f"{t:.6f}" for t in theta]
        if floors is not None:
            row += [f"{f:.1f}" for f in floors[i]]
        writer.writerow(row)
    return buf.getvalue()
