"""Muscle lengths and Jacobians of a robot at poses given in a CSV, as one JSON document.

For a paper's moment-arm table, or to check a description against another tool (MuJoCo,
OpenSim, a CAD model): the poses come from a CSV with one row per pose and one column per
driven joint (named by the joint; other columns are ignored), the answer is what the arm model
itself uses, from whichever backend the description has (MuJoCo's ``ten_length``/``ten_J``
for an MJCF, via points through pinocchio for a URDF).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np

from pimbs_arm.model import ArmModel


class PoseFileError(ValueError):
    """The poses CSV is unusable; the message names the file, the column or row, the fix."""


def read_poses_csv(path: Path, joints: tuple[str, ...]) -> tuple[np.ndarray, list[str]]:
    """Poses (P, N) in the order of ``joints`` from a CSV whose header names them, and the
    header's columns that are not driven joints (ignored). Raises ``PoseFileError``."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise PoseFileError(f"{path}: cannot read the poses CSV ({exc}); give a text file "
                            "with a header row of joint names") from exc
    rows = [r for r in rows if any(cell.strip() for cell in r)]
    if not rows:
        raise PoseFileError(f"{path}: empty; write a header row naming the joints "
                            f"({', '.join(joints)}) and one pose (rad) per row")
    header = [h.strip() for h in rows[0]]
    missing = [j for j in joints if j not in header]
    if missing:
        raise PoseFileError(f"{path}: no column for joint(s) {', '.join(missing)} (header: "
                            f"{', '.join(header)}); name one column per driven joint: "
                            f"{', '.join(joints)}")
    twice = sorted({h for h in header if header.count(h) > 1 and h in joints})
    if twice:
        raise PoseFileError(f"{path}: column {twice[0]!r} appears twice; keep one")
    cols = [header.index(j) for j in joints]
    if len(rows) == 1:
        raise PoseFileError(f"{path}: a header but no poses; add one row per pose (rad)")
    poses = np.empty((len(rows) - 1, len(joints)))
    for i, row in enumerate(rows[1:], start=1):
        for k, (c, joint) in enumerate(zip(cols, joints, strict=True)):
            cell = row[c].strip() if c < len(row) else ""
            try:
                value = float(cell)
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                raise PoseFileError(f"{path}: row {i}, column {joint!r}: {cell!r} is not a "
                                    "finite number; give the joint angle in rad")
            poses[i - 1, k] = value
    return poses, [h for h in header if h not in joints]


def geometry_table(arm: ArmModel, theta: np.ndarray) -> dict[str, Any]:
    """Lengths and Jacobians at poses (P, N) as plain lists ready for JSON.

    ``length`` is the absolute path length (m) as the backend measures it (MuJoCo's
    ``ten_length`` for an MJCF), ``h_geom`` the same relative to theta = 0 (PIMBS's
    convention), ``jacobian`` d length / d theta [pose][muscle][joint] (m/rad); the moment
    arm is its negative.
    """
    theta = np.asarray(theta, dtype=np.float64)
    kin = [arm.backend.kinematics(t) for t in theta]
    length = np.array([k.length for k in kin]).reshape(len(theta), arm.n_muscles)
    jac = np.array([k.jacobian for k in kin]).reshape(len(theta), arm.n_muscles, arm.n_joints)
    return {
        "robot": arm.robot.name,
        "description": str(arm.robot.muscle_path),
        "geometry": ("MuJoCo spatial tendons (ten_length, ten_J)" if arm.backend.kind == "mjcf"
                     else "URDF + via points (pinocchio)"),
        "units": {"theta": "rad", "length": "m", "h_geom": "m", "jacobian": "m/rad"},
        "joints": list(arm.joints),
        "muscles": list(arm.muscles),
        "theta": theta.tolist(),
        "length": length.tolist(),
        "h_geom": (length - arm._h0).tolist(),
        "jacobian": jac.tolist(),
    }
