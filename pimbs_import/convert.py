"""A log -> a format-1 recording: one row per held pose, ``source: import``.

Each row is the mean over the held stretch; ``theta_command`` is that mean pose too (a log
has no commands); ``approach`` is the direction of each muscle's motion into the pose;
``tau_gravity`` comes from the robot's model at the measured pose, as for a collection. The
metadata says what the log was, how it was mapped, and what the recording holds where the
log had nothing (temperatures).
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pimbs_arm.model import ArmModel
from pimbs_import.bagread import LogError, read_series
from pimbs_import.checks import check_readings, check_rows
from pimbs_import.held import align, held_poses
from pimbs_import.mapping import LogMapping
from pimbs_recording.format import make_meta


def import_log(log: Path, arm: ArmModel, mapping: LogMapping,
               progress: Callable[[int, int], None] | None = None, *,
               keep_out_of_range: bool = False, msg_dirs: Sequence[Path] = ()
               ) -> tuple[dict[str, Any], dict[str, Any]]:
    """(columns, metadata) of the recording made from ``log``; readings and rows the robot
    cannot have are refused unless ``keep_out_of_range`` (:mod:`pimbs_import.checks`)."""
    series = read_series(log, mapping, arm.joints, arm.muscles, progress, msg_dirs)
    flags = check_readings(log, series, keep_out_of_range)
    aligned = align(series, str(log))
    poses = held_poses(aligned, mapping.settle)
    if not poses:
        span = (aligned.time[-1] - aligned.time[0]) * 1e-9
        raise LogError(
            f"{log}: no held pose in {span:.1f} s of readings: the arm never rested for "
            f"{mapping.settle.min_hold:g} s within the settle tolerances (theta "
            f"{mapping.settle.theta_tol:g} rad, length {mapping.settle.length_tol:g} m, tension "
            f"{mapping.settle.tension_tol:g} N over {mapping.settle.window:g} s). If it did, "
            "check the mapping's scales (units) or loosen 'settle' in --map")

    def mean(values: np.ndarray) -> np.ndarray:
        return np.stack([values[p.start:p.stop + 1].mean(axis=0) for p in poses])

    theta = mean(aligned.theta)
    tension = mean(aligned.tension)
    flags.update(check_rows(log, arm.joints, arm.muscles, arm.joint_limits, theta, tension,
                            keep_out_of_range))
    temperature_note = "from the log"
    if aligned.temperature is not None:
        temperature = mean(aligned.temperature)
    else:
        temperature = np.full((len(poses), arm.n_muscles), mapping.temperature_fill)
        temperature_note = (f"absent from the log: every value is {mapping.temperature_fill:g} "
                            "(temperature_fill), so thermal effects cannot be diagnosed")
    ns = np.array([aligned.time[p.stop] for p in poses], dtype=np.int64)
    data = {"sample": np.arange(len(poses)), "time": ns.astype("datetime64[ns]").astype(
                "datetime64[us]"),
            "theta": theta, "theta_command": theta.copy(), "tension": tension,
            "length": mean(aligned.length), "temperature": temperature,
            "approach": np.stack([p.approach for p in poses]).astype(np.int8),
            "tau_gravity": arm.gravity_torque(theta),
            # extra column: how long each pose was held (s)
            "held_s": np.array([(aligned.time[p.stop] - aligned.time[p.start]) * 1e-9
                                + mapping.settle.window for p in poses])}
    meta = make_meta(arm.joints, arm.muscles, "import", robot=arm.robot.name,
                     generator="pimbs import", log=Path(log).name,
                     log_path=str(Path(log).resolve()), mapping=mapping.meta(),
                     temperature=temperature_note,
                     theta_source="log", theta_command="the held pose's measured mean "
                     "(a log has no commands)",
                     log_span_s=float((aligned.time[-1] - aligned.time[0]) * 1e-9),
                     imported=dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
                     joint_range=arm.joint_range.tolist(), K=arm.K.tolist(),
                     **({"import_flags": flags} if flags else {}))
    return data, meta
