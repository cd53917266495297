"""Encoder zeroing results: the robot's calibration file (``pimbs zero`` writes it,
``pimbs collect`` applies it). The measurement itself is ``pimbs_hw.zeroing``.

Incremental encoders power up anywhere; the recording format needs lengths relative to the
zero pose, ``l(θ = 0, f = 0) = 0``. ``pimbs zero`` measures each motor encoder while the arm
is held at θ = 0 with the wires at their low holding tension, and removes what that tension
stretches the elastic element (``Δn(f) = log1p(f) / K``, the arm model's own law), so the
zero is the slack-wire length without ever letting a wire go slack. The result is a small
YAML file (like LeRobot's calibration files) that ``pimbs collect`` applies:

    # pimbs calibration: encoder readings at the zero pose
    robot: two-link-4-muscle
    zero_position_m: {m0: 0.01234, m1: -0.5, ...}   # encoder reading, m, at theta = 0, f = 0
    measured: {time: 2026-11-23T07:50:00Z, port: can0, tension_n: {m0: 10.1, ...}}
"""

from __future__ import annotations

import datetime as dt
import math
import os
import tempfile
from pathlib import Path

import numpy as np
import yaml

SUFFIX = ".calibration.yaml"


class CalibrationError(ValueError):
    """A calibration file that does not fit the robot; names the file and the field."""


def default_path(robot) -> Path:
    """``<robot>.calibration.yaml`` beside a user's robot file; in the current directory
    for a built-in robot (its file lives inside the installed package)."""
    from pimbs_calibration.description import builtin_robots

    name = f"{robot.name}{SUFFIX}"
    builtin = robot.muscle_path.parent == Path(__file__).parent / "robots"
    if robot.name in builtin_robots() or builtin:
        return Path(name)
    return robot.muscle_path.parent / name


def save(path: Path, robot, zero_m: np.ndarray, tension: np.ndarray, port: str) -> None:
    """Write the calibration atomically (a crash never leaves half a file)."""
    names = [m.name for m in robot.muscles]
    data = {
        "robot": robot.name,
        "zero_position_m": {n: float(z) for n, z in zip(names, zero_m, strict=True)},
        "measured": {"time": dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
                     "port": port, "pose": "home (all joints 0 rad)",
                     "tension_n": {n: round(float(f), 3)
                                   for n, f in zip(names, tension, strict=True)}},
    }
    text = ("# pimbs calibration: motor encoder readings at the zero pose (theta = 0, slack "
            "wire), written by `pimbs zero`\n" + yaml.safe_dump(data, sort_keys=False))
    fd, tmp = tempfile.mkstemp(dir=path.parent if str(path.parent) else ".", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load(path: Path, robot) -> np.ndarray:
    """Zero positions (m) in the robot's muscle order; ``CalibrationError`` names the field."""
    path = Path(path)
    try:
        raw = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise CalibrationError(f"{path}: cannot read the calibration ({exc.strerror}); run "
                               f"`pimbs zero` first or check --calibration") from exc
    except yaml.YAMLError as exc:
        raise CalibrationError(f"{path}: not valid YAML ({exc}); rerun `pimbs zero`") from exc
    if not isinstance(raw, dict):
        raise CalibrationError(f"{path}: expected a mapping with robot and zero_position_m")
    if raw.get("robot") != robot.name:
        raise CalibrationError(f"{path}: field 'robot': calibration is for "
                               f"{raw.get('robot')!r}, not {robot.name!r}; use the right file "
                               f"or rerun `pimbs zero --robot {robot.name}`")
    zeros = raw.get("zero_position_m")
    names = [m.name for m in robot.muscles]
    if not isinstance(zeros, dict) or sorted(zeros) != sorted(names):
        have = sorted(zeros) if isinstance(zeros, dict) else zeros
        raise CalibrationError(f"{path}: field 'zero_position_m': has {have}, the robot has "
                               f"muscles {names}; rerun `pimbs zero`")
    values = []
    for n in names:
        v = zeros[n]
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise CalibrationError(f"{path}: field 'zero_position_m.{n}': {v!r} is not a "
                                   "finite number; rerun `pimbs zero`")
        values.append(float(v))
    return np.array(values)
