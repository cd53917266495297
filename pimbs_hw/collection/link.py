"""The little the collection routine needs from an arm, as one narrow interface.

Keeping the routine behind ``ArmLink`` (and not the driver's full API) lets it run against the
real driver, the mock bus and a plain in-process stand-in in unit tests alike.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from pimbs_hw.safety import SafetyStop
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


class SimulatedArmFailed(SafetyStop):
    """The simulated arm itself failed (a MuJoCo step blew up, a static solve found no rest
    position): nothing on a real arm, its wiring or its boards is to blame."""


class DriverLink:
    """``ArmLink`` over ``pimbs_hw.ArmDriver`` (and the ``MockArm`` behind it, if simulated)."""

    def __init__(self, driver: Any, mock: Any = None) -> None:
        self.driver, self.mock = driver, mock

    def command(self, mode: tuple[str, ...] | str, values: np.ndarray) -> None:
        self.driver.command(mode, values)

    def read(self) -> Reading:
        """The boards' readings; ``SimulatedArmFailed`` once the simulated arm has failed
        (its readings then describe no arm)."""
        self.check_simulation()
        s = self.driver.read_state()
        return Reading(s.length, s.tension, s.temperature, s.theta)

    def check_simulation(self) -> None:
        """Raise ``SimulatedArmFailed`` if the simulated arm behind the boards failed."""
        failure = None if self.mock is None else self.mock.failure()
        if failure is not None:
            raise SimulatedArmFailed(failure, port=self.driver.transport.port)

    def at_rest(self) -> bool | None:
        """Whether the arm is at rest where the simulated arm knows it (None: judge it from
        the readings, as on a real arm)."""
        return None if self.mock is None else self.mock.at_rest()

    @property
    def quasi_static(self) -> bool:
        """The arm is the built-in quasi-static simulated one: it has no inertia to ring."""
        return self.mock is not None and self.mock.quasi_static

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

    def at_rest(self) -> bool | None:
        return getattr(self.link, "at_rest", lambda: None)()

    @property
    def quasi_static(self) -> bool:
        return getattr(self.link, "quasi_static", False)


class Overload(Exception):
    """The arm did what no command for this sample asked: a muscle pulled past the load
    limit, or the joints ran away from the pose. ``reading`` is the one that showed it."""

    def __init__(self, what: str, reading: Reading, muscle: int | None = None) -> None:
        self.what, self.reading, self.muscle = what, reading, muscle
        self.unheld: np.ndarray | None = None  # a pose on the way no tensions hold, if any
        super().__init__(what)


class LoadGuard:
    """An ``ArmLink`` that raises ``Overload`` while armed (``watching``): a reading above
    ``limit`` (N per muscle), or, once a pose is given, joint encoders further than
    ``excursion`` (rad, per joint or one for all) from it.

    The boards' own ceiling stops the whole collection and relaxes the arm. A description
    that underestimates a load (a heavier link, a bigger pulley) reaches it on the poses where
    the plan is already high, and moment arms it gets wrong can leave a joint whose muscles
    are all tension-controlled out of balance, so the arm runs off and slams a held wire;
    every other pose is fine. Watching below the boards' ceiling lets the routine unload that
    one pose and go on.
    """

    def __init__(self, link: Any, limit: np.ndarray, excursion: np.ndarray | float,
                 muscles: tuple[str, ...]) -> None:
        self.link, self.limit = link, np.asarray(limit, float)
        self.excursion = np.asarray(excursion, float)
        self.muscles, self.armed = muscles, False
        self.pose: np.ndarray | None = None

    def __getattr__(self, name: str) -> Any:  # approach, relax, begin_sample: the link's
        return getattr(self.link, name)

    @contextmanager
    def watching(self) -> Iterator[None]:
        """Armed inside the block only (unloading a pose must not raise again)."""
        self.armed, self.pose = True, None
        try:
            yield
        finally:
            self.armed, self.pose = False, None

    def command(self, mode: tuple[str, ...] | str, values: np.ndarray) -> None:
        self.link.command(mode, values)

    def read(self) -> Reading:
        reading = self.link.read()
        if not self.armed:
            return reading
        over = np.flatnonzero(reading.tension > self.limit)
        if over.size:
            k = int(over[np.argmax(reading.tension[over] - self.limit[over])])
            raise Overload(f"{self.muscles[k]} pulled {reading.tension[k]:.0f} N (load limit "
                           f"{self.limit[k]:.0f} N)", reading, k)
        if self.pose is not None:
            self.check_pose(reading, self.pose)
        return reading

    def check_pose(self, reading: Reading, pose: np.ndarray) -> None:
        """``Overload`` if the joints at ``reading`` are further than ``excursion`` from
        ``pose`` (nothing to check without joint encoders)."""
        if reading.theta is None:
            return
        off = np.abs(reading.theta - pose)
        limit = np.broadcast_to(self.excursion, off.shape)
        if (off > limit).any():
            j = int(np.argmax(off / limit))
            raise Overload(f"the joints ran {off[j]:.2f} rad off the pose (limit "
                           f"{limit[j]:.2g} rad)", reading)
