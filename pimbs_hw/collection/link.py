"""The little the collection routine needs from an arm, as one narrow interface.

Keeping the routine behind ``ArmLink`` (and not the driver's full API) lets it run against the
real driver, the mock bus and a plain in-process stand-in in unit tests alike.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from pimbs_recording.approach import ApproachTracker


@dataclass(frozen=True)
class Reading:
    """One snapshot of the arm in SI units; ``theta`` is None without joint encoders."""

    length: np.ndarray       # (M,) m
    tension: np.ndarray      # (M,) N
    temperature: np.ndarray  # (M,) °C
    theta: np.ndarray | None = None  # (N,) rad


class ArmLink(Protocol):
    """An arm the routine can command and read (the driver raises ``SafetyStop``)."""

    def command(self, mode: tuple[str, ...] | str, values: np.ndarray) -> None:
        """Per-muscle "length" (m) or "tension" (N) commands; also feeds the watchdog."""

    def read(self) -> Reading:
        """The latest readings of every muscle (and joint encoder)."""

    def relax(self) -> None:
        """Every muscle to its low holding tension (never slack)."""

    def begin_sample(self, index: int) -> None:
        """Told before each sample (the mock uses it to trigger ``@SAMPLE`` faults)."""


class DriverLink:
    """``ArmLink`` over ``pimbs_hw.ArmDriver`` (and the ``MockArm`` behind it, if simulated)."""

    def __init__(self, driver: Any, mock: Any = None) -> None:
        self.driver, self.mock = driver, mock

    def command(self, mode: tuple[str, ...] | str, values: np.ndarray) -> None:
        self.driver.command(mode, values)

    def read(self) -> Reading:
        s = self.driver.read_state()
        return Reading(s.length, s.tension, s.temperature, s.theta)

    def relax(self) -> None:
        self.driver.relax()

    def begin_sample(self, index: int) -> None:
        if self.mock is not None:
            self.mock.set_sample(index)


class ApproachLink:
    """An ``ArmLink`` that follows every length it reads, to know each muscle's approach.

    The direction recorded with a sample is that of the last real motion into the pose
    (see :mod:`pimbs_recording.approach`), not the difference between two samples: the slack
    removal after a move often reverses a muscle, and friction follows the reversal.
    """

    def __init__(self, link: ArmLink, n_muscles: int) -> None:
        self.link = link
        self.tracker = ApproachTracker(n_muscles)

    @property
    def approach(self) -> np.ndarray:
        return self.tracker.direction.copy()

    def command(self, mode: tuple[str, ...] | str, values: np.ndarray) -> None:
        self.link.command(mode, values)

    def read(self) -> Reading:
        reading = self.link.read()
        self.tracker.update(reading.length)
        return reading

    def relax(self) -> None:
        self.link.relax()

    def begin_sample(self, index: int) -> None:
        self.link.begin_sample(index)
