"""What an import refuses unless told to keep it: readings and rows the robot cannot have.

A mapping with the wrong field, unit or sign still produces numbers; they must not become a
recording silently. Refused (with counts) unless ``--keep-out-of-range`` is given:

* readings: NaN or infinite values of the robot's elements; messages whose time runs
  backwards on their topic (``clock: header`` with a publisher whose clock jumped);
* rows (held poses): a joint angle outside its URDF limits (beyond ``LIMIT_TOL_RAD``, an
  encoder's noise at a hard stop), a negative mean tension (a tendon cannot push).

With the option the import goes on: non-finite readings are dropped (interpolated over like
elements a message did not carry), readings are put in time order, and the rows are kept; the
counts are stored in the recording's metadata (``import_flags``) so nobody mistakes them for
clean data.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pimbs_import.bagopen import LogError

LIMIT_TOL_RAD = 0.01
KEEP = ("pass --keep-out-of-range to import anyway (the counts are kept in the recording's "
        "metadata, key import_flags)")


def check_readings(log: Path, series: dict[str, Any], keep: bool) -> dict[str, Any]:
    """Counts of non-finite values and backward times per quantity; refuses them unless
    ``keep`` (then non-finite values become NaN, i.e. not carried)."""
    flags: dict[str, Any] = {}
    problems = []
    for q, s in series.items():
        n = len(s.time)
        if s.nonfinite:
            flags.setdefault("nonfinite_values", {})[q] = s.nonfinite
            problems.append(f"{s.nonfinite} NaN or infinite value(s) for {q} in {n} "
                            f"message(s) on {s.topic}")
            s.values[~np.isfinite(s.values)] = np.nan
        if s.backwards:
            flags.setdefault("time_backwards", {})[q] = s.backwards
            problems.append(f"{s.backwards} of {n} message(s) on {s.topic} ({q}) stamped "
                            "earlier than the message before (with clock: header, try clock: "
                            "log)")
    if problems and not keep:
        raise LogError(f"{log}: " + "; ".join(problems) + f"; nothing was imported. {KEEP}")
    return flags


def check_rows(log: Path, joints: Sequence[str], muscles: Sequence[str],
               limits: np.ndarray, theta: np.ndarray, tension: np.ndarray,
               keep: bool) -> dict[str, Any]:
    """Counts of held poses with a joint outside its limits or a negative tension; refuses
    them unless ``keep``."""
    n = len(theta)
    lo, hi = limits[:, 0] - LIMIT_TOL_RAD, limits[:, 1] + LIMIT_TOL_RAD
    outside = (theta < lo) | (theta > hi)
    negative = tension < 0
    flags: dict[str, Any] = {}
    problems = []
    if outside.any():
        per = {j: int(c) for j, c in zip(joints, outside.sum(axis=0), strict=True) if c}
        flags["outside_joint_limits"] = per
        worst = ", ".join(
            f"{j}: {per[j]}, [{theta[:, k].min():.3g}, {theta[:, k].max():.3g}] rad against "
            f"[{limits[k, 0]:g}, {limits[k, 1]:g}]"
            for k, j in enumerate(joints) if j in per)
        problems.append(f"{int(outside.any(axis=1).sum())} of {n} held pose(s) with a joint "
                        f"outside its URDF limits ({worst})")
    if negative.any():
        per = {m: int(c) for m, c in zip(muscles, negative.sum(axis=0), strict=True) if c}
        flags["negative_tension"] = per
        worst = ", ".join(f"{m}: {per[m]}, down to {tension[:, k].min():.3g} N"
                          for k, m in enumerate(muscles) if m in per)
        problems.append(f"{int(negative.any(axis=1).sum())} of {n} held pose(s) with a "
                        f"negative tension ({worst})")
    if problems and not keep:
        raise LogError(f"{log}: " + "; ".join(problems) + "; the mapping is probably wrong "
                       "(names, units: scale and offset, sign); check it with --map, or "
                       + KEEP)
    return flags
