"""The collection loop: per sample, move to the pose, remove slack, settle, read, write.

Order of events for sample i (see ``plan.Target``): every muscle length-controlled, ramped
to the geometric length of a low pretension (the arm moves there; ``move.py``) until the
motors are near those lengths; then the load-bearing muscles held in length and the others
tension-controlled, ramped to the QP tensions (slack removed, pose kept), settle (the one
full wait: the arm's creep from the move ends during the slack removal), read, and append
one row. The slack removal overshoots the holding and comes back (``plan.Target.approach``),
so each muscle's last motion, and with it the capstan friction, has a known direction. The
row is on disk (atomically) before the next pose is commanded, so an interruption of any kind
loses at most the sample in progress.
"""

from __future__ import annotations

import concurrent.futures
import datetime as dt
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from pimbs_arm.model import ArmModel, InfeasiblePoseError
from pimbs_hw.collection.estimate import estimate_theta
from pimbs_hw.collection.link import ApproachLink, ArmLink, Reading
from pimbs_hw.collection.move import MoveConfig, move, release, run_ramp, take_up_slack
from pimbs_hw.collection.plan import CollectionPlan, Target
from pimbs_hw.collection.settle import SettleConfig, Settled, hold_until_settled
from pimbs_hw.collection.temperature import filled
from pimbs_recording.format import RecordingWriter

# m: how far short of the overshoot the final approach may start; its last motion is then still
# APPROACH_TRAVEL - OVERSHOOT_TOL = 1.1 mm, beyond a full friction reversal (2 bands, 1 mm)
OVERSHOOT_TOL = 3e-4


@dataclass
class Summary:
    """What a collection did so far; kept current so an interrupted run can still report."""

    path: str
    total: int                 # samples planned
    start: int                 # first sample index of this run (> 0 when resumed)
    next_sample: int = 0       # first index not yet collected
    written: int = 0           # rows written by this run
    already: int = 0           # rows that were in the file before (resume)
    unsettled: int = 0
    skipped: list[int] = field(default_factory=list)  # infeasible poses
    warnings: list[str] = field(default_factory=list)
    stopped: str | None = None  # why the run ended early (None: completed)
    started_at: float = field(default_factory=time.monotonic)
    settle_time: float = 0.0    # s spent settling, summed over samples
    tension_range: tuple[float, float] = (np.inf, -np.inf)
    temperature_max: float = -np.inf

    @property
    def elapsed(self) -> float:
        return time.monotonic() - self.started_at

    @property
    def rows(self) -> int:
        return self.already + self.written

    @property
    def rate_per_min(self) -> float:
        return 60.0 * self.written / self.elapsed if self.elapsed > 0 else 0.0

    @property
    def eta(self) -> float | None:
        """Seconds left at the current rate (None before the first sample)."""
        if not self.written:
            return None
        return (self.total - self.next_sample) * self.elapsed / self.written

    @property
    def complete(self) -> bool:
        return self.next_sample >= self.total and self.stopped is None


class Reporter(Protocol):
    """Receives progress (the rich display, or nothing in tests)."""

    def sample(self, summary: Summary, row: dict[str, Any]) -> None: ...

    def warn(self, summary: Summary, message: str) -> None: ...


class NullReporter:
    def sample(self, summary: Summary, row: dict[str, Any]) -> None:
        pass

    def warn(self, summary: Summary, message: str) -> None:
        pass


class Collector:
    """Runs one collection (or the rest of a resumed one) on an ``ArmLink``."""

    def __init__(self, link: ArmLink, model: ArmModel, plan: CollectionPlan,
                 writer: RecordingWriter, start: int, settle: SettleConfig,
                 reporter: Reporter | None = None, move: MoveConfig | None = None,
                 now: Callable[[], dt.datetime] = lambda: dt.datetime.now(dt.UTC)) -> None:
        self.link = ApproachLink(link, model.n_muscles)
        self.model, self.plan, self.writer = model, plan, writer
        self.settle, self.reporter, self.now = settle, reporter or NullReporter(), now
        self.move = move or MoveConfig()
        self.summary = Summary(path=str(writer.path), total=plan.n_samples, start=start,
                               next_sample=start, already=writer.n_rows)

    def run(self) -> Summary:
        """Collect samples ``start .. total-1``; exceptions propagate with the file intact."""
        reading = self.link.read()  # the first pose is approached from where the arm is
        theta = self._theta(reading, np.zeros(self.model.n_joints))
        previous = None  # target the arm is loaded at (None: relaxed)
        for i in range(self.summary.start, self.plan.n_samples):
            self.link.begin_sample(i)
            try:
                target = self._next_target(i, previous)
            except InfeasiblePoseError as exc:
                self.summary.skipped.append(i)
                self._warn(f"sample {i} skipped: {exc}")
                self.summary.next_sample = i + 1
                continue
            if target.note:
                self._warn(f"sample {i}: {target.note}")
            model, muscles, cfg = self.model, self.model.muscles, self.move
            if previous is not None:
                reading = run_ramp(self.link, release(model, reading, previous, cfg))
            run_ramp(self.link, move(model, reading, theta, target, cfg))
            moved = hold_until_settled(self.link, "length", target.approach_length,
                                       self.settle.reached(), muscles)
            previous = target
            run_ramp(self.link, take_up_slack(moved.reading, target, cfg,
                                              target.overshoot_command))
            over = hold_until_settled(self.link, target.hold_mode, target.overshoot_command,
                                      self._overshot(target), muscles)
            run_ramp(self.link, take_up_slack(over.reading, target, cfg))
            held = hold_until_settled(self.link, target.hold_mode, target.hold_command,
                                      self.settle, muscles)
            row = self._row(i, target.theta, held)
            if target.commanded_by:
                row["commanded_by"] = target.commanded_by
            self._append_holding(row, target)
            reading, theta = held.reading, row["theta"]
            self._account(i, held, row)
        return self.summary

    def _overshot(self, target: Target) -> SettleConfig:
        """Reached the overshoot: every motor within ``OVERSHOOT_TOL`` of it (in length, or
        in the tension error that stretches the wire by as much)."""
        tension = np.where(target.held, target.tension, target.overshoot_command)
        tension_tol = (1.0 + np.abs(tension)) * np.expm1(self.model.K * OVERSHOOT_TOL)
        return self.settle.overshot(OVERSHOOT_TOL, np.maximum(tension_tol, 1.0))

    def _row(self, i: int, theta_command: np.ndarray, held: Settled) -> dict[str, Any]:
        r = held.reading
        theta = self._theta(r, theta_command)
        return {"sample": i, "time": np.datetime64(self.now().replace(tzinfo=None), "us"),
                "theta": theta, "theta_command": theta_command, "tension": r.tension,
                "length": r.length, "temperature": filled(r.temperature),
                "approach": self.link.approach,
                "tau_gravity": self.model.gravity_torque(theta),
                # extra columns: how the sample settled (data quality, kept by all tools)
                "settled": bool(held.settled), "settle_s": float(held.elapsed)}

    def _append_holding(self, row: dict[str, Any], target: Target) -> None:
        """Write the row while still holding the pose (commands feed the board watchdogs).

        Each append rewrites the file with fsync: tens of ms at 500 rows here, longer on a
        slow disk, which must not starve the 0.25 s watchdog. The next pose is commanded only
        once the row is on disk; a stop while writing still waits for the write to finish.
        """
        self._holding(target, lambda: self.writer.append(row))  # RecordingWriteError raises

    def _next_target(self, i: int, previous: Target | None) -> Target:
        """Plan sample ``i`` while the arm still holds ``previous`` (or, relaxed, is read): a
        plan takes several equilibrium solves (more with a learned schema), longer than a
        watchdog period."""
        return self._holding(previous, lambda: self.plan.target(i))

    def _holding(self, target: Target | None, work: Callable[[], Any]) -> Any:
        """``work()`` in a worker thread while ``target``'s holding is commanded (None: the
        arm is only read); its result."""
        with concurrent.futures.ThreadPoolExecutor(1, "collection-worker") as pool:
            done = pool.submit(work)
            try:
                while not done.done():
                    if target is not None:
                        self.link.command(target.hold_mode, target.hold_command)
                    self.link.read()
                    concurrent.futures.wait([done], timeout=self.settle.poll)
            finally:
                concurrent.futures.wait([done])
            return done.result()

    def _theta(self, r: Reading, guess: np.ndarray) -> np.ndarray:
        """Joint encoders where the robot has them, else the model's estimate."""
        if r.theta is not None:
            return r.theta
        return estimate_theta(self.model, r.length, r.tension, guess)

    def _account(self, i: int, held: Settled, row: dict[str, Any]) -> None:
        s = self.summary
        s.written += 1
        s.next_sample = i + 1
        s.settle_time += held.elapsed
        lo, hi = s.tension_range
        s.tension_range = (min(lo, float(row["tension"].min())),
                           max(hi, float(row["tension"].max())))
        measured = held.reading.temperature[np.isfinite(held.reading.temperature)]
        if measured.size:  # the fill of boards that report none is no measurement
            s.temperature_max = max(s.temperature_max, float(measured.max()))
        if not held.settled:
            s.unsettled += 1
            self._warn(f"sample {i} did not settle within {self.settle.timeout:g} s "
                       f"({held.worst}); recorded anyway, flagged settled=false. Check that "
                       f"wire, or raise --settle-tol / --settle-timeout")
        self.reporter.sample(s, row)

    def _warn(self, message: str) -> None:
        self.summary.warnings.append(message)
        self.reporter.warn(self.summary, message)
