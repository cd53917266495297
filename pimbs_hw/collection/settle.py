"""Waiting until a commanded pose has settled, judged from the readings themselves.

A fixed wait is either too long (wasted hours over a 500-sample collection) or too short for
the slow samples (a muscle still creeping corrupts the row). Instead we keep commanding (each
command feeds the boards' watchdogs) and read until, over a rolling time window,

* nothing drifts: the mean of the window's second half differs from the first half's by less
  than the tolerance, for every length, tension and joint angle (means, so sensor noise does
  not count as motion; joint encoders report only every 20 ms, so the window must span
  several of their frames), and
* the commands are reached: length-controlled muscles at their length, tension-controlled
  ones at their tension (so the pause before the arm starts to move is not taken for rest).

The recorded reading is the mean over that window (less noise than one frame). A sample that
does not settle before the timeout is recorded anyway, flagged, and reported as a warning:
one slow pose must not end a collection.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace

import numpy as np

from pimbs_hw.collection.link import ArmLink, Reading


@dataclass(frozen=True)
class SettleConfig:
    """Settling thresholds; ``fixed_wait`` (s) replaces detection with a plain wait."""

    tension_tol: float = 1.0     # N: allowed drift and distance from a tension command
    length_tol: float = 3e-5     # m: the same for lengths (~3 encoder counts)
    theta_tol: float = 5e-4      # rad: allowed drift of the joint encoders (when present)
    window: float = 0.1          # s of readings judged together (>= 5 status periods)
    min_readings: int = 4        # readings needed inside the window
    timeout: float = 5.0         # s; then warn and record anyway
    poll: float = 0.005          # s between command/read cycles
    fixed_wait: float | None = None

    def meta(self) -> dict:
        return {k: v for k, v in asdict(self).items() if k != "poll"}

    def reached(self, length_tol: float = 1e-3, swings: bool = True) -> SettleConfig:
        """End of a move: motors within ``length_tol`` of their commands and, on an arm that
        ``swings``, the joints at rest (the usual joint tolerance and window).

        The slack removal that follows must not start while the arm still swings: under real
        dynamics (a MuJoCo plant, a real arm) a swinging arm runs into a held antagonist and
        its tension spikes past the ceiling. Tensions may still be far from their holding.
        An arm without inertia (the quasi-static simulated arm) cannot swing: its joints only
        creep toward the commands' equilibrium, which the slack removal ramps from and the
        final settle waits for, so only the motors are waited for, with no quiet window.
        """
        if swings:
            return replace(self, length_tol=length_tol, tension_tol=np.inf, fixed_wait=None)
        return replace(self, length_tol=length_tol, tension_tol=np.inf, theta_tol=np.inf,
                       window=0.0, min_readings=2, fixed_wait=None)

    def overshot(self, length_tol: float, tension_tol: np.ndarray, swings: bool = True
                 ) -> SettleConfig:
        """At the overshoot before the final approach: lengths and tensions both reached.

        The final ramp must start (nearly) from the overshoot itself, or the last motion into
        the pose is shorter than planned and may not reverse the friction. ``tension_tol``
        may be per muscle (N; e.g. the tension error that stretches a wire ``length_tol``).
        """
        return replace(self.reached(length_tol, swings), tension_tol=tension_tol)


@dataclass
class Settled:
    """The (window-averaged) reading after settling, and how it went."""

    reading: Reading
    settled: bool
    elapsed: float  # s
    readings: int
    worst: str = ""  # for an unsettled sample: which muscle was furthest off, and how


class SettleDetector:
    """Rolling window of timed readings for one command; ``push`` says when it is quiet."""

    def __init__(self, config: SettleConfig, is_length: np.ndarray, command: np.ndarray,
                 muscles: tuple[str, ...] = ()) -> None:
        self.config, self.is_length, self.command = config, is_length, command
        self.muscles = muscles
        self._buf: collections.deque[tuple[float, Reading]] = collections.deque()

    def push(self, t: float, reading: Reading) -> bool:
        """Add a reading taken at time ``t`` (s); True when the window is settled."""
        cfg, buf = self.config, self._buf
        buf.append((t, reading))
        while len(buf) > cfg.min_readings and t - buf[1][0] >= cfg.window:
            buf.popleft()  # keep one reading at or before the window start
        if t - buf[0][0] < cfg.window or len(buf) < cfg.min_readings:
            return False
        return self.offness().max() <= 1.0

    def offness(self) -> np.ndarray:
        """Per muscle: worst of drift and command error, in units of its tolerance."""
        cfg = self.config
        readings = [r for _, r in self._buf]
        half = len(readings) // 2
        scale = np.where(self.is_length, cfg.length_tol, cfg.tension_tol)

        def values(rs: list[Reading]) -> np.ndarray:
            return np.stack([np.where(self.is_length, r.length, r.tension) for r in rs])

        own = values(readings)
        drift = np.abs(own[half:].mean(0) - own[:half].mean(0))
        error = np.abs(own.mean(0) - self.command)
        other = np.stack([np.where(self.is_length, r.tension, r.length) for r in readings])
        other_drift = np.abs(other[half:].mean(0) - other[:half].mean(0))
        other_scale = np.where(self.is_length, cfg.tension_tol, cfg.length_tol)
        off = np.maximum(np.maximum(drift, error) / scale, other_drift / other_scale)
        if readings[-1].theta is not None:  # the pose itself must be still too
            theta = np.stack([r.theta for r in readings])
            theta_drift = np.abs(theta[half:].mean(0) - theta[:half].mean(0)).max()
            off = np.maximum(off, theta_drift / cfg.theta_tol)
        return off

    def mean(self) -> Reading:
        """The window's readings averaged (theta too, when there are joint encoders)."""
        rs = [r for _, r in self._buf]
        theta = None if rs[-1].theta is None else np.mean([r.theta for r in rs], axis=0)
        return Reading(np.mean([r.length for r in rs], axis=0),
                       np.mean([r.tension for r in rs], axis=0),
                       np.mean([r.temperature for r in rs], axis=0), theta)

    def worst(self) -> str:
        off = self.offness()
        i = int(np.argmax(off))
        name = self.muscles[i] if self.muscles else f"muscle {i}"
        return f"{name} {off[i]:.1f}x its tolerance"


def hold_until_settled(arm: ArmLink, mode: tuple[str, ...] | str, command: np.ndarray,
                       config: SettleConfig, muscles: tuple[str, ...] = (),
                       clock: Callable[[], float] = time.monotonic,
                       sleep: Callable[[float], None] = time.sleep) -> Settled:
    """Command ``(mode, command)`` repeatedly until the readings settle (or time out)."""
    command = np.asarray(command, float)
    modes = (mode,) * len(command) if isinstance(mode, str) else tuple(mode)
    detector = SettleDetector(config, np.array([m == "length" for m in modes]), command,
                              muscles)
    start = clock()
    n = 0
    while True:
        arm.command(mode, command)
        reading = arm.read()
        n += 1
        now = clock()
        elapsed = now - start
        quiet = detector.push(now, reading)
        if config.fixed_wait is not None:
            if elapsed >= config.fixed_wait:
                return Settled(detector.mean(), True, elapsed, n)
        elif quiet:
            return Settled(detector.mean(), True, elapsed, n)
        elif elapsed >= config.timeout:
            return Settled(detector.mean(), False, elapsed, n, detector.worst())
        sleep(config.poll)
