"""Getting from one sample to the next without jerks: ramps instead of step commands.

Each board gets its new command a moment after the previous one, and each muscle's elastic
element is exponentially stiff, so a step in one muscle's length while its antagonists are
still held at the old pose stretches a wire by millimetres: hundreds of newtons (the mock bus
reproduces this as a saturated loadcell). So we never step. Modes are switched only where the
new command equals what the muscle is doing now, and then commands are ramped in small
increments along a path the model says is consistent:

* ``move_commands`` (all muscles in length control): the geometric lengths along the straight
  joint-space path from the current pose to the target, with the tension interpolated from
  the current readings to the low pretension; the model's error at the start (measured minus
  modelled lengths) is blended out along the way, so the first command is where the arm is.
* ``slack_commands``: the held muscles ramp from the pretension length to the QP length, the
  others from their current tension to the QP tension.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from calibration.arm_model import ArmModel
from pimbs_hw.collection.link import ArmLink, Reading
from pimbs_hw.collection.plan import Target


@dataclass(frozen=True)
class MoveConfig:
    """Largest change of one command per control cycle."""

    length_step: float = 5e-4  # m (0.5 mm: about 0.5 N·(f+1) of elastic tension at K = 1000)
    tension_step: float = 20.0  # N
    poll: float = 0.005        # s per cycle


def _steps(delta: np.ndarray, is_length: np.ndarray, cfg: MoveConfig) -> int:
    scale = np.where(is_length, cfg.length_step, cfg.tension_step)
    return max(1, int(np.ceil(np.max(np.abs(delta) / scale))))


def move_commands(model: ArmModel, now: Reading, theta_now: np.ndarray, target: Target,
                  cfg: MoveConfig) -> Iterator[np.ndarray]:
    """Length commands (M,) from where the arm is to ``target.approach_length``."""
    f_now = np.maximum(now.tension, 0.0)
    f_end = model.tension_from_stretch(model.h_geom(target.theta) - target.approach_length)
    start_error = now.length - model.length(theta_now, f_now)
    n = _steps(target.approach_length - now.length, np.ones(model.n_muscles, bool), cfg)
    for s in np.linspace(0.0, 1.0, n + 1):
        theta = theta_now + s * (target.theta - theta_now)
        f = f_now + s * (f_end - f_now)
        yield model.length(theta, f) + (1.0 - s) * start_error
    yield target.approach_length  # exactly, whatever rounding did


def slack_commands(now: Reading, target: Target, cfg: MoveConfig) -> Iterator[np.ndarray]:
    """Mixed commands (M,) in ``target.hold_mode`` from the current readings to the holding."""
    start = np.where(target.held, now.length, now.tension)
    n = _steps(target.hold_command - start, target.held, cfg)
    for s in np.linspace(0.0, 1.0, n + 1):
        yield start + s * (target.hold_command - start)


def ramp(link: ArmLink, mode: tuple[str, ...] | str, commands: Iterator[np.ndarray],
         poll: float) -> Reading:
    """Send each command for one control cycle (reading, so limits are checked each time)."""
    reading = None
    for command in commands:
        link.command(mode, command)
        reading = link.read()
        time.sleep(poll)
    assert reading is not None
    return reading
