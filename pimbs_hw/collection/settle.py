"""Waiting until a commanded pose has settled, judged from the readings themselves.

A fixed wait is either too long (wasted hours over a 500-sample collection) or too short for
the slow samples (a muscle still creeping corrupts the row). Instead we keep commanding (each
command feeds the boards' watchdog) and read until every length and tension has stayed within
a tolerance over a rolling time window. A sample that does not settle before the timeout is
still recorded, flagged, and reported as a warning: one slow pose must not end a collection.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from pimbs_hw.collection.link import ArmLink, Reading


@dataclass(frozen=True)
class SettleConfig:
    """Settling thresholds; ``fixed_wait`` (s) replaces detection with a plain wait."""

    tension_tol: float = 1.0     # N, peak-to-peak over the window (4 loadcell counts)
    length_tol: float = 3e-5     # m, peak-to-peak over the window (~3 encoder counts)
    window: float = 0.1          # s of readings that must stay within the tolerances
    min_readings: int = 3        # distinct readings needed inside the window
    timeout: float = 5.0         # s; then warn and record anyway
    poll: float = 0.01           # s between command/read cycles
    fixed_wait: float | None = None

    def meta(self) -> dict:
        return {k: v for k, v in asdict(self).items() if k != "poll"}


@dataclass
class Settled:
    """The last reading after settling, and how it went."""

    reading: Reading
    settled: bool
    elapsed: float  # s
    readings: int


class SettleDetector:
    """Rolling window over (time, lengths, tensions); ``settled`` once it is quiet."""

    def __init__(self, config: SettleConfig) -> None:
        self.config = config
        self._buf: collections.deque[tuple[float, np.ndarray, np.ndarray]] = collections.deque()

    def push(self, t: float, length: np.ndarray, tension: np.ndarray) -> bool:
        """Add a reading taken at time ``t`` (s); True when the window is settled."""
        cfg, buf = self.config, self._buf
        buf.append((t, np.asarray(length, float), np.asarray(tension, float)))
        while len(buf) > cfg.min_readings and t - buf[1][0] >= cfg.window:
            buf.popleft()  # keep one reading at or before the window start
        if t - buf[0][0] < cfg.window or len(buf) < cfg.min_readings:
            return False
        lengths = np.stack([b[1] for b in buf])
        tensions = np.stack([b[2] for b in buf])
        return bool(np.ptp(lengths, axis=0).max() <= cfg.length_tol
                    and np.ptp(tensions, axis=0).max() <= cfg.tension_tol)


def hold_until_settled(arm: ArmLink, mode: tuple[str, ...] | str, command: np.ndarray,
                       config: SettleConfig,
                       clock: Callable[[], float] = time.monotonic,
                       sleep: Callable[[float], None] = time.sleep) -> Settled:
    """Command ``(mode, command)`` repeatedly until the readings settle (or time out)."""
    detector = SettleDetector(config)
    start = clock()
    n = 0
    while True:
        arm.command(mode, command)
        reading = arm.read()
        n += 1
        now = clock()
        elapsed = now - start
        if config.fixed_wait is not None:
            if elapsed >= config.fixed_wait:
                return Settled(reading, True, elapsed, n)
        elif detector.push(now, reading.length, reading.tension):
            return Settled(reading, True, elapsed, n)
        elif elapsed >= config.timeout:
            return Settled(reading, False, elapsed, n)
        sleep(config.poll)
