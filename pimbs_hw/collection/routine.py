"""The collection loop: per sample, move to the pose, remove slack, settle, read, write.

Order of events for sample i (see ``plan.Target``): every muscle length-controlled, ramped
to the geometric length of the approach tensions, the lowest that hold the pose stiffly (the
arm moves there; ``move.py``) until the motors are near those lengths; then the load-bearing
muscles held in length and the others tension-controlled, ramped to the QP tensions (slack
removed, pose kept), settle (the one full wait: the arm's creep from the move ends during
the slack removal), read, and append one row. The slack removal overshoots the holding and
comes back (``plan.Target.approach``), so each muscle's last motion, and with it the capstan
friction, has a known direction. The row is on disk (atomically) before the next pose is
commanded, so an interruption of any kind loses at most the sample in progress.

Between poses the slack removal is undone and the joints come to rest before the next move
starts: under real dynamics an arm released at low tension swings, and a move commanded
from a snapshot of a swinging arm runs it into a length-held wire. The first move starts
from the relaxed arm at rest (or, where relaxing would let it fall out of its routed range,
``relax.py``, from the arm held at its motors' lengths). The quasi-static simulated arm says
itself when it rests (``ArmLink.at_rest``); every other arm is judged from its readings.

From the move on, the routine watches below the boards' ceiling (``link.LoadGuard``): a wire
past ``LOAD_LIMIT``·f_max, or joints further than ``pose_excursion`` from the pose once
the slack removal starts (on the quasi-static arm, whose joints still creep toward the pose
while its wires load: where it settles), gives that pose up: it is unloaded from where the
arm is, recorded as skipped with a warning naming what happened, the arm goes back to the
last pose recorded (or, before the first or where that fails, starts over relaxed where that
is safe), and the collection goes on. A run that keeps fewer than half
of the poses it tried is reported as failed (``Summary.failed``), not complete. A description
that gets a load or a moment arm wrong fails on a few poses, not the whole collection; the
boards' ceiling still stops everything that the guard cannot see coming.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import datetime as dt
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from pimbs_arm.model import ArmModel, InfeasiblePoseError
from pimbs_hw.collection.estimate import estimate_theta
from pimbs_hw.collection.link import ApproachLink, ArmLink, LoadGuard, Overload, Reading
from pimbs_hw.collection.move import (
    LOAD_LIMIT,
    MoveConfig,
    Ramp,
    move,
    release,
    run_ramp,
    take_up_slack,
)
from pimbs_hw.collection.plan import CollectionPlan, Target, pose_excursion
from pimbs_hw.collection.settle import SettleConfig, Settled, hold_until_settled
from pimbs_hw.collection.temperature import filled
from pimbs_recording.format import RecordingWriter

# m: how far short of the overshoot the final approach may start; its last motion is then still
# APPROACH_TRAVEL - OVERSHOOT_TOL = 1.1 mm, beyond a full friction reversal (2 bands, 1 mm)
OVERSHOOT_TOL = 3e-4
# a run that gives up more than this share of the poses it tried is no complete collection
GIVE_UP_SHARE = 0.5
# a tension-controlled muscle counts as at rest within this share of its command (or the
# settle tolerance): far enough from a relax not yet followed (0 N read against 10 N)
REST_TENSION_SHARE = 0.25

Holding = tuple[tuple[str, ...] | str, np.ndarray]  # (mode, command) sent while holding


@contextlib.contextmanager
def _way_there(way: Ramp) -> Iterator[None]:
    """An ``Overload`` on the way to a pose learns whether that way passed poses no tensions
    hold (``Ramp.unheld``): then that, not the wire, is why the pose was given up."""
    try:
        yield
    except Overload as over:
        over.unheld = way.unheld
        raise


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
    unheld_ways: int = 0        # poses given up on a way that passes poses no tensions hold
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
        """Every planned pose was tried, nothing stopped the run, and it kept most of them."""
        return (self.next_sample >= self.total and self.stopped is None
                and self.failed is None)

    @property
    def failed(self) -> str | None:
        """What went wrong with a run that tried its poses but kept too few of them (None:
        nothing did): it recorded nothing, or gave up more than ``GIVE_UP_SHARE`` of them."""
        tried = self.next_sample - self.start
        if self.stopped is not None or tried <= 0:
            return None
        if self.rows == 0:
            what = f"no pose was recorded: all {tried} tried were given up"
        elif len(self.skipped) > GIVE_UP_SHARE * tried:
            what = (f"{len(self.skipped)} of the {tried} poses tried were given up, "
                    f"{self.written} recorded")
        else:
            return None
        if self.unheld_ways > len(self.skipped) / 2:
            what += (f", {self.unheld_ways} of them on ways that pass poses the description's "
                     "muscles cannot hold")
        return what


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
                 now: Callable[[], dt.datetime] = lambda: dt.datetime.now(dt.UTC),
                 relax_safe: bool = True) -> None:
        f_max = np.array([m.f_max for m in model.robot.muscles])
        self.link = LoadGuard(ApproachLink(link, model.n_muscles), LOAD_LIMIT * f_max,
                              pose_excursion(model), model.muscles)
        self.model, self.plan, self.writer = model, plan, writer
        self.settle, self.reporter, self.now = settle, reporter or NullReporter(), now
        self.move = move or MoveConfig()
        if getattr(link, "quasi_static", False):  # nothing swings: no gentle loading needed
            self.move = dataclasses.replace(self.move, quasi_static=True)
        self._swings = not self.move.quasi_static  # wait for joints at rest before loading
        self.floor = np.array([m.f_floor for m in model.robot.muscles])
        # relaxing keeps the arm in its routed range (``relax.relax_fall``): it then starts,
        # and after a pose given up starts over, from the relaxed rest; else it is held
        self.relax_safe = relax_safe
        self.summary = Summary(path=str(writer.path), total=plan.n_samples, start=start,
                               next_sample=start, already=writer.n_rows)

    def run(self) -> Summary:
        """Collect samples ``start .. total-1``; exceptions propagate with the file intact."""
        # the first pose is approached from where the arm is, once it rests: the driver has
        # just relaxed it (or holds it), and a move from a snapshot of a falling arm starts
        # from nowhere
        reading = self._start_over()
        theta = self._theta(reading, np.zeros(self.model.n_joints))
        previous = None  # target the arm is loaded at (None: relaxed)
        recorded = None  # the last pose recorded: the arm held it, so it can go back there
        holding: Holding | None = None  # what the arm holds between samples (None: read only)
        for i in range(self.summary.start, self.plan.n_samples):
            self.link.begin_sample(i)
            try:
                target = self._next_target(i, holding)
            except InfeasiblePoseError as exc:
                self.summary.skipped.append(i)
                self._warn(f"sample {i} skipped: {exc}")
                self.summary.next_sample = i + 1
                continue
            if target.note:
                self._warn(f"sample {i}: {target.note}")
            if previous is not None:
                reading, _ = self._unload(previous, reading, theta)
            try:
                held = self._load(target, reading, theta)
            except Overload as over:
                reading, holding, previous = self._give_up(i, target, over, recorded)
                theta = self._theta(reading, target.theta if previous is None
                                    else previous.theta)
                continue
            previous, holding = target, (target.hold_mode, target.hold_command)
            recorded = target
            row = self._row(i, target.theta, held)
            if target.commanded_by:
                row["commanded_by"] = target.commanded_by
            self._append_holding(row, holding)
            reading, theta = held.reading, row["theta"]
            self._account(i, held, row)
        return self.summary

    def _load(self, target: Target, reading: Reading, theta: np.ndarray) -> Settled:
        """Move to the pose at low tension, remove the slack past the holding and back, and
        settle (``Overload`` if a muscle pulls past the load limit on the way, or the joints
        end up off the pose).

        The joints are watched from the end of the move on an arm that swings, where running
        off the pose slams a held wire. The quasi-static arm cannot swing and is not waited
        for before loading, so its joints still creep toward the pose while the slack is taken
        up: it is judged at the settled pose."""
        model, muscles, cfg = self.model, self.model.muscles, self.move
        way = move(model, reading, theta, target, cfg, self.plan.balance)
        with self.link.watching(), _way_there(way):
            moved = run_ramp(self.link, way)
            if self._swings:
                moved = hold_until_settled(self.link, "length", target.approach_length,
                                           self.settle.reached(), muscles).reading
                self.link.pose = target.theta  # from here on the arm stays near the pose
            run_ramp(self.link, take_up_slack(model, moved, target, cfg,
                                              target.overshoot_command))
            over = hold_until_settled(self.link, target.hold_mode, target.overshoot_command,
                                      self._overshot(target), muscles)
            run_ramp(self.link, take_up_slack(model, over.reading, target, cfg))
            held = hold_until_settled(self.link, target.hold_mode, target.hold_command,
                                      self.settle, muscles)
            self.link.check_pose(held.reading, target.theta)
            return held

    def _start_over(self) -> Reading:
        """The arm relaxed and at rest, where relaxing keeps it in its routed range, else held
        at its motors' lengths: where the next pose is approached from."""
        if self.relax_safe:
            return self._rest("relax", self.floor).reading
        reading = self.link.read()
        return self._rest("length", reading.length).reading

    def _give_up(self, i: int, target: Target, over: Overload, recorded: Target | None
                 ) -> tuple[Reading, Holding, Target | None]:
        """Unload the pose the arm ran off or overloaded, record it as skipped and warn; the
        arm then goes back to the last pose recorded (``recorded``), loaded as it was held
        there, and the next move starts from it. Where there is none, or the arm cannot be
        held there again, it starts over relaxed (where that is safe), else it holds the
        low-tension approach of that pose. Returns the reading, what the arm holds, and the
        pose it is loaded at (None: unloaded).

        A pose is given up because the arm went somewhere else: another rest position of the
        same lengths (MyoSuite's finger with a joint on its limit and the neighbouring joint
        bent instead), or a snagged or overloaded wire. Unloaded in place, the next move would
        start from there, and on the finger the next pose failed the same way. Relaxed, the
        finger falls onto its stops, and the straight way from there to the next pose passes
        poses its muscles cannot hold; the last pose recorded is one they held."""
        reading, holding = self._unload(target, over.reading,
                                        self._theta(over.reading, target.theta))
        back = None if recorded is None else self._go_back(recorded, reading, target.theta)
        if back is not None:
            reading, holding = back.reading, (recorded.hold_mode, recorded.hold_command)
        elif self.relax_safe:
            reading, holding = self._start_over(), ("relax", self.floor)
        s = self.summary
        s.skipped.append(i)
        s.next_sample = i + 1
        if over.unheld is not None:
            s.unheld_ways += 1
            pose = ", ".join(f"{j}={t:.3f}" for j, t in
                             zip(self.model.joints, over.unheld, strict=True))
            why = ("the straight way there passes poses the description's muscles cannot hold "
                   f"within the plan's ceiling (the first at {pose} rad), so the arm leaned "
                   "on its stops or left the way: narrow the joint ranges in the muscle file "
                   "to where the muscles hold the arm, or give them a higher f_max")
        elif over.muscle is None:
            why = ("the muscles the plan holds it with do not balance this pose on the arm "
                   "(moment arms or loads other than the description's)")
        else:
            why = (f"the plan holds it at {target.tension[over.muscle]:.0f} N: the arm needs "
                   "more there than its description says (a heavier link, a longer moment "
                   "arm), or the wire snagged")
        self._warn(f"sample {i} given up: {over}; {why}. The pose was unloaded and the "
                   "collection goes on")
        return reading, holding, (recorded if back is not None else None)

    def _go_back(self, recorded: Target, reading: Reading, guess: np.ndarray
                 ) -> Settled | None:
        """The arm loaded at ``recorded`` again, from ``reading`` (None, the pose unloaded
        again, where that fails too)."""
        theta = self._theta(reading, guess)
        try:
            return self._load(recorded, reading, theta)
        except Overload as over:
            self._unload(recorded, over.reading, self._theta(over.reading, recorded.theta))
            return None

    def _unload(self, target: Target, reading: Reading, theta: np.ndarray
                ) -> tuple[Reading, Holding]:
        """The slack removal of ``target`` undone from where the arm is (bumpless in every
        phase: each muscle starts at its reading; ``theta``: the joints at ``reading``, as
        the row or the give-up already has them), then wait for the joints to rest: the
        next move starts from where the arm is, and a swinging arm is not there for long."""
        ramp = release(self.model, reading, target, self.move, theta)
        run_ramp(self.link, ramp)
        holding = (ramp.mode, ramp.commands[-1])
        return self._rest(*holding).reading, holding

    def _rest(self, mode: tuple[str, ...] | str, command: np.ndarray) -> Settled:
        """Hold ``(mode, command)`` until no swing is to come before the next move: as the
        arm itself says where it knows (the quasi-static simulated arm, once its equilibrium
        is solved: it then only closes in on it), else judged from the readings (motors at
        their commands, joints still; see ``SettleConfig.reached``)."""
        if self.link.at_rest() is None:
            return hold_until_settled(self.link, mode, command, self._rest_config(mode, command),
                                      self.model.muscles)
        start = time.monotonic()
        while True:
            self.link.command(mode, command)
            reading = self.link.read()
            elapsed = time.monotonic() - start
            if self.link.at_rest() or elapsed >= self.settle.timeout:
                return Settled(reading, True, elapsed, 1)
            time.sleep(self.settle.poll)

    def _rest_config(self, mode: tuple[str, ...] | str, command: np.ndarray) -> SettleConfig:
        """Rest judged from the readings: the end of a move (``SettleConfig.reached``), and
        the tension-controlled muscles at their tensions (within ``REST_TENSION_SHARE`` of
        them, at least the settle tolerance). An arm that has not yet begun to follow a new
        tension command (a relax at the start: boards or a simulated arm running behind, as
        on a loaded machine) reads as still as one at rest; the move planned from there
        started from where the arm was about to leave."""
        modes = (mode,) * len(command) if isinstance(mode, str) else tuple(mode)
        is_tension = np.array([m != "length" for m in modes])
        tol = np.maximum(self.settle.tension_tol, REST_TENSION_SHARE * np.abs(command))
        return dataclasses.replace(self.settle.reached(),
                                   tension_tol=np.where(is_tension, tol, np.inf))

    def _overshot(self, target: Target) -> SettleConfig:
        """Reached the overshoot: every motor within ``OVERSHOOT_TOL`` of it (in length, or
        in the tension error that stretches the wire by as much)."""
        tension = np.where(target.held, target.tension, target.overshoot_command)
        tension_tol = (1.0 + np.abs(tension)) * np.expm1(self.model.K * OVERSHOOT_TOL)
        return self.settle.overshot(OVERSHOOT_TOL, np.maximum(tension_tol, 1.0), self._swings)

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

    def _append_holding(self, row: dict[str, Any], holding: Holding) -> None:
        """Write the row while still holding the pose (commands feed the board watchdogs).

        Each append rewrites the file with fsync: tens of ms at 500 rows here, longer on a
        slow disk, which must not starve the 0.25 s watchdog. The next pose is commanded only
        once the row is on disk; a stop while writing still waits for the write to finish.
        """
        self._holding(holding, lambda: self.writer.append(row))  # RecordingWriteError raises

    def _next_target(self, i: int, holding: Holding | None) -> Target:
        """Plan sample ``i`` while the arm still holds the last pose (or, relaxed, is read): a
        plan takes several equilibrium solves (more with a learned schema), longer than a
        watchdog period."""
        return self._holding(holding, lambda: self.plan.target(i))

    def _holding(self, holding: Holding | None, work: Callable[[], Any]) -> Any:
        """``work()`` in a worker thread while ``holding`` (mode, command) is commanded (None:
        the arm is only read); its result."""
        with concurrent.futures.ThreadPoolExecutor(1, "collection-worker") as pool:
            done = pool.submit(work)
            try:
                while not done.done():
                    if holding is not None:
                        self.link.command(*holding)
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
