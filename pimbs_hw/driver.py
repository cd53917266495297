"""Arm driver: every muscle board of one arm, in SI units, behind one transport.

    driver = ArmDriver(transport, load_robot("two-link-4-muscle"))
    with driver:
        driver.command("length", lengths_m)       # or "tension" in N, or per-muscle modes
        state = driver.read_state()               # ArmState: length m, tension N, °C, faults
        state = driver.dwell(0.5)                 # wait while feeding the board watchdogs
    # leaving the block (normally, by exception or Ctrl-C) relaxes the arm

The boards' watchdogs are fed only by ``command``, ``hold``, ``relax`` and ``dwell``: a host
that hangs stops feeding them and the arm relaxes within ``limits.watchdog_s``. Any limit
violation raises a ``SafetyStop`` naming the muscle and board, after the driver has relaxed
every board it can reach; later commands raise the same stop again.

The driver speaks to the boards only through the ``BoardProtocol`` seam
(``pimbs_hw.protocol.board``): per muscle, the protocol its description names (PIMBS v1 by
default, a CAN profile from a ``.dbc`` and a mapping, or CiA 402 drives from their EDS).
Safety lives here, above the seam, the same for every protocol.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pimbs_hw.host_lag import host_lag
from pimbs_hw.protocol.board import (
    BoardLimits,
    BoardProtocol,
    CorruptFrame,
    Update,
)
from pimbs_hw.protocol.codec import Fault
from pimbs_hw.safety import (
    BoardFault,
    BoardSilent,
    CorruptFrames,
    FramesDropped,
    LoadcellSaturated,
    Overheat,
    SafetyLimits,
    SafetyStop,
    TensionLimit,
    fault_stop,
)
from pimbs_hw.transport.base import Frame, Transport

_MODES = {"length": "length", "position": "length", "tension": "tension", "relax": "relax"}
_NEEDED = ("position_m", "tension_n")  # a muscle's reading is fresh when both are new
_JUDGED = 8  # frames a loss ratio must rest on before it can stop the arm
# A silence this many times the limit is a board's, however long this program stalled
# meanwhile: a stalled host delays the verdict, it never cancels it.
SILENT_WHATEVER_THE_LOAD = 10.0


@dataclass(frozen=True)
class ArmState:
    """One reading of every board. Arrays are (M,) in the robot description's muscle order."""

    time: float  # time.monotonic() when assembled
    muscles: tuple[str, ...]
    length: np.ndarray  # m, relative to the zero pose
    tension: np.ndarray  # N
    temperature: np.ndarray  # °C (NaN where the protocol reports none)
    faults: tuple[Fault, ...]
    seq: np.ndarray  # the status frame's 4-bit counter (-1 where the protocol has none)
    age: np.ndarray  # s since the older of the position and tension readings arrived
    fresh: np.ndarray  # bool: new position and tension since the previous read_state
    theta: np.ndarray | None = None  # rad, joint encoders (robots with joint_encoders)

    def muscle(self, name: str) -> dict[str, object]:
        i = self.muscles.index(name)
        return {"length": self.length[i], "tension": self.tension[i],
                "temperature": self.temperature[i], "faults": self.faults[i],
                "seq": int(self.seq[i]), "age": self.age[i], "fresh": bool(self.fresh[i])}


class _Rx:
    """Receive bookkeeping of one board (or joint encoder): latest values, freshness, loss."""

    def __init__(self, period_s: float, counted: bool) -> None:
        self.values = {"position_m": np.nan, "tension_n": np.nan, "temperature_c": np.nan,
                       "angle_rad": np.nan}
        self.times = {name: -np.inf for name in self.values}
        self.news: set[str] = set()
        self.faults = Fault(0)
        self.saturated = False
        self.counter: int | None = None
        self.version: str | None = None
        self.state: int | None = None  # the board's own state, as last reported
        self.error_code: int | None = None  # its raw error word, as last reported
        self.stop: tuple[type[SafetyStop], str] | None = None  # named by the protocol
        self.period_s, self.counted = period_s, counted
        self.gaps: collections.deque[tuple[float, int]] = collections.deque()  # (time, lost)
        self.lost = 0  # sum of the gaps in ``gaps``
        self.arrivals: collections.deque[float] = collections.deque()  # uncounted protocols
        self.first = np.inf
        self.corrupt: collections.deque[float] = collections.deque()

    def update(self, u: Update, now: float) -> None:
        if u.counter is not None:
            if self.counter is not None:
                gap = (u.counter - self.counter - 1) & 0xF
                if gap == 15:  # same counter again: a repeated frame, not news
                    return
                self.gaps.append((now, gap))
                self.lost += gap
            self.counter = u.counter
        elif not self.counted and u.position_m is not None:
            self.arrivals.append(now)
            self.first = min(self.first, now)
        for name in self.values:
            value = getattr(u, name)
            if value is not None:
                self.values[name], self.times[name] = value, now
                self.news.add(name)
        if u.tension_n is not None:
            self.saturated = u.saturated
        if u.faults is not None:
            self.faults = u.faults
        if u.version is not None:
            self.version = u.version
        if u.state is not None:
            self.state = u.state
        if u.error_code is not None:
            self.error_code = u.error_code
        if u.stop is not None and self.stop is None:
            self.stop = (u.stop, u.note or "")

    def seen(self, fields: Sequence[str] = _NEEDED) -> bool:
        return all(np.isfinite(self.times[f]) for f in fields)

    def fresh(self, fields: Sequence[str] = _NEEDED) -> bool:
        return all(f in self.news for f in fields)

    def age(self, now: float, fields: Sequence[str] = _NEEDED) -> tuple[float, str]:
        """Age of the oldest of ``fields`` and its name."""
        name = min(fields, key=lambda f: self.times[f])
        return now - self.times[name], name

    def loss(self, now: float, window_s: float, starved_s: float = 0.0) -> tuple[float, int]:
        """(fraction of frames lost, frames the judgement rests on) over the last
        ``window_s``.

        By counter gaps where the protocol counts its frames (the frames the board sent in
        the window: those received and those their counters say were lost; counting only
        those received would leave a lossy board too few to judge, e.g. 3 of a 20 ms
        stream in 0.25 s at 75 % loss), else by the arrival rate
        against the status period over ``rate_window`` (judged only once a whole window has
        been watched, and not during a silence, which is ``BoardSilent``'s to call), less
        the ``starved_s`` of that window in which the host could hear nothing.

        Why the rate, like the silence watchdog, leaves out the host's stalls (``HostLag``)
        and nothing more: while this process cannot run, a board's frames wait in the
        adapter's or the kernel's buffer and arrive late in a burst (counted then), and
        simulated boards, which run in this process, send none at all; neither is the bus
        losing frames, and the verdict is only delayed (a whole window of stall leaves too
        few frames to judge). A host that runs but reads more slowly than the bus sends is
        not discounted: a real adapter's buffer then overflows and the frames are gone, so
        the arm would be steered on readings older than the board's cycle. That is a loss
        to stop for, and its remedy is a faster reader (python-can's SLCAN interface took a
        system call per byte; ``pimbs_hw.transport.slcan`` reads in bulk). Counter gaps
        need no discount: a counter says what was sent, whenever it is read.
        """
        if self.counted:
            while self.gaps and now - self.gaps[0][0] > window_s:
                self.lost -= self.gaps.popleft()[1]
            n = len(self.gaps)
            return (self.lost / (self.lost + n) if n else 0.0), n + self.lost
        window_s = self.rate_window(window_s)
        while self.arrivals and now - self.arrivals[0] > window_s:
            self.arrivals.popleft()
        if now - self.first < window_s or not self.arrivals or (
                now - self.arrivals[-1] > 10 * self.period_s):
            return 0.0, len(self.arrivals)  # too early to judge, or silence: not loss
        expected = max(window_s - starved_s, self.period_s) / self.period_s
        return max(0.0, 1.0 - len(self.arrivals) / expected), int(expected)

    def rate_window(self, window_s: float) -> float:
        """Window for a rate judgement: long enough that a host which reads late (frames
        queued, then read in a burst) is not mistaken for a lossy bus; a 75 % loss is
        still seen within it."""
        return window_s if self.counted else max(window_s, 2.0, 100 * self.period_s)

    def corrupt_in_last_second(self, now: float) -> int:
        while self.corrupt and now - self.corrupt[0] > 1.0:
            self.corrupt.popleft()
        return len(self.corrupt)


class ArmDriver:
    """See the module docstring. ``robot``: a ``pimbs_calibration.description.RobotDescription``.

    ``protocols``: the ``BoardProtocol``s that together cover every muscle; by default
    the ones the description names (``pimbs_hw.protocol.profiles.protocols_for``).
    """

    def __init__(self, transport: Transport, robot, limits: SafetyLimits | None = None, *,
                 connect_timeout_s: float = 1.0,
                 protocols: Sequence[BoardProtocol] | None = None,
                 hold_at_start: bool = False) -> None:
        from pimbs_hw.protocol.profiles import protocols_for

        self.transport, self.robot = transport, robot
        self.limits = limits or SafetyLimits()
        specs = robot.muscles
        self.muscles = tuple(s.name for s in specs)
        self.board_ids = tuple(s.board_id for s in specs)
        if len(set(self.board_ids)) != len(specs):
            raise ValueError(f"{robot.name}: two muscles share a board_id: {self.board_ids}")
        for s in specs:
            if s.loadcell_n_per_count <= 0 or s.counts_per_m <= 0:
                raise ValueError(f"muscle {s.name}: counts_per_m and loadcell_n_per_count must "
                                 "be positive (the protocol assumes more counts = more)")
        self.protocols = tuple(protocols if protocols is not None else protocols_for(robot))
        self._proto: list[BoardProtocol | None] = [None] * len(specs)
        for proto in self.protocols:
            for i in proto.indices:
                self._proto[i] = proto
        if None in self._proto:
            raise ValueError(f"{robot.name}: no board protocol for muscle "
                             f"{self.muscles[self._proto.index(None)]}")
        self.f_floor = np.array([s.f_floor for s in specs], float)
        self.f_max = self.limits.ceilings(np.array([s.f_max for s in specs], float))
        self.zero_m = np.zeros(len(specs))  # encoder reading at the zero pose (``zero``)
        self._rx = [_Rx(p.status_period_s, p.capabilities.counter) for p in self._proto]
        self._joint_rx = ([_Rx(0.02, True) for _ in robot.joints] if robot.joint_encoders
                          else [])
        self._last: list[tuple[str, float]] | None = None
        self.tripped: SafetyStop | None = None
        self.closed = False
        self.host_lag = host_lag()  # when this process could not run (see ``_silence``)
        self._configure(connect_timeout_s, hold_at_start)

    def protocol_of(self, i: int) -> BoardProtocol:
        return self._proto[i]  # type: ignore[return-value]

    def _where(self, i: int) -> dict[str, object]:
        return {"muscle": self.muscles[i], "board_id": self.board_ids[i],
                "port": self.transport.port}

    # -- set-up ----------------------------------------------------------------------------
    def _board_limits(self, i: int) -> BoardLimits:
        lim = self.limits
        return BoardLimits(lim.watchdog_s, lim.tension_margin * self.f_max[i],  # commands
                           float(lim.relax_targets(self.f_floor)[i]),  # stop at f_max
                           lim.board_thermal_limit_c)

    def _ready(self, i: int) -> bool:
        """Readings seen, configured, and (boards with a state machine) armed as reported."""
        rx, proto = self._rx[i], self._proto[i]
        return rx.seen() and proto.armed(rx.state) and (  # type: ignore[union-attr]
            not proto.capabilities.configure  # type: ignore[union-attr]
            or proto.configured(rx.faults))  # type: ignore[union-attr]

    def _reported(self, i: int) -> str:
        """Muscle ``i``'s board state in the device's own words ('' if it has none)."""
        rx = self._rx[i]
        return self._proto[i].state_text(rx.state, rx.error_code)  # type: ignore[union-attr]

    def _configure(self, timeout_s: float, hold: bool = False) -> None:
        """Send limits, wait for every board to answer configured, then relax (safe start),
        or with ``hold`` let every motor hold its length (an arm that relaxed would fall out
        of the range its wires are routed for)."""
        for proto in self.protocols:
            try:
                proto.connect(self.transport, [self._board_limits(i) for i in proto.indices])
            except SafetyStop as stop:
                self._trip(stop)
        setup = [frame for i, p in enumerate(self._proto)
                 for frame in p.setup(i, self._board_limits(i))]  # type: ignore[union-attr]
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            self._send(setup)  # repeated: a lost setup frame costs one round
            self._pump(min(left, 0.2))
            if all(self._ready(i) for i in range(len(self._rx))) and all(
                    rx.seen(("angle_rad",)) for rx in self._joint_rx):
                break
            for rx in self._rx:
                rx.news.clear()  # wait for frames sent after this round's setup
        missing = [i for i in range(len(self._rx)) if not self._ready(i)]
        if missing:
            names = ", ".join(f"{self.muscles[i]} (board {self.board_ids[i]}"
                              + ("" if self._proto[i].name == "pimbs-v1"  # type: ignore
                                 else f", {self._proto[i].describe()}")  # type: ignore
                              + (f", reports {self._reported(i)}" if self._rx[i].seen()
                                 and self._reported(i) else "") + ")"
                              for i in missing)
            hint = ("is the arm powered and the port right? for the simulated arm use "
                    "--port virtual" if len(missing) == len(self._rx) else "check that board")
            unarmed = [i for i in missing if self._rx[i].seen()
                       and self._proto[i].has_state]  # type: ignore[union-attr]
            if unarmed == missing:  # they answer, but their own state machine refuses
                stop = BoardFault(f"not armed within {timeout_s:.1f} s: {names}; clear the "
                                  "error on the board (or power-cycle it) and check its "
                                  "calibration", **self._where(missing[0]))
            else:
                stop = BoardSilent(f"no configured status within {timeout_s:.1f} s from "
                                   f"{names}; {hint}", **self._where(missing[0]))
            self._trip(stop)
        if hold:
            self.stop()
        else:
            self.relax()
        # wait for the answers to that relax: faults latched in an earlier session (a host
        # that crashed) are cleared by it, and must not be read back from older frames
        for rx in self._rx:
            rx.news.clear()
        self._pump(max(0.05, deadline - time.monotonic()))

    # -- receive ---------------------------------------------------------------------------
    def _on_frame(self, frame: Frame) -> None:
        for proto in self.protocols:
            try:
                updates = proto.decode(frame.arbitration_id, frame.data)
            except CorruptFrame as bad:
                self._rx[bad.muscle].corrupt.append(frame.timestamp)
                return
            for u in updates:
                if u.joint:
                    if u.muscle < len(self._joint_rx):
                        self._joint_rx[u.muscle].update(u, frame.timestamp)
                else:
                    self._rx[u.muscle].update(u, frame.timestamp)
            if updates:
                return

    def _pump(self, timeout: float) -> None:
        """Process received frames; wait up to ``timeout`` until every board has news."""
        deadline = time.monotonic() + timeout
        try:
            while True:
                frame = self.transport.recv(0.0)
                if frame is None:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0 or all(rx.fresh() for rx in self._rx):
                        return
                    frame = self.transport.recv(remaining)
                    if frame is None:
                        return
                self._on_frame(frame)
        except SafetyStop as stop:
            self._trip(stop)

    def _silence(self, heard: float, now: float) -> tuple[float, str]:
        """How long a board last heard at ``heard`` has been silent while this host could
        have heard it, and the words for a stop.

        Wall time since its last frame, less the time this process could not run meanwhile
        (``HostLag``: other work had every core, or a call held the GIL). A stalled host reads
        frames late, and simulated boards in this process stall with it, so that time is the
        host's, not the board's; a silence a real board makes while the host runs counts in
        full. Past ``SILENT_WHATEVER_THE_LOAD`` times the limit the wall time
        counts alone, so a dead board is named however loaded the machine is.
        """
        age = now - heard
        lim = self.limits.silent_after_s
        if age <= lim or age > SILENT_WHATEVER_THE_LOAD * lim:
            return age, f"{age:.2f} s"
        waited = self.host_lag.starved(heard, now)
        if waited < 0.005:
            return age, f"{age:.2f} s"
        return age - waited, (f"{age - waited:.2f} s (and {waited:.2f} s more while this "
                              "program could not run)")

    def _check(self, now: float) -> None:
        """Raise (after relaxing) the first limit any board breaks."""
        lim = self.limits
        for i, rx in enumerate(self._rx):
            where = self._where(i)
            age, name = rx.age(now)
            silent, said = self._silence(now - age, now)
            if silent > lim.silent_after_s:
                what = "status" if self._proto[i].name == "pimbs-v1" else (  # type: ignore
                    f"{name.split('_')[0]} reading")
                self._trip(BoardSilent(f"no {what} for {said} (limit "
                                       f"{lim.silent_after_s} s)", **where))
            if (n := rx.corrupt_in_last_second(now)) > lim.corrupt_per_s:
                self._trip(CorruptFrames(f"{n} status frames failed their CRC in 1 s", **where))
            loss, n = rx.loss(now, lim.loss_window_s)
            if n >= _JUDGED and loss > lim.max_loss and not rx.counted:  # counters: no clock
                window = rx.rate_window(lim.loss_window_s)
                loss, n = rx.loss(now, lim.loss_window_s,
                                  self.host_lag.starved(now - window, now))
            if n >= _JUDGED and loss > lim.max_loss:
                how = "counter gaps" if rx.counted else "arrival rate"
                self._trip(FramesDropped(f"{loss:.0%} of status frames lost in the last "
                                         f"{rx.rate_window(lim.loss_window_s):g} s ({how})",
                                         **where))
            if rx.stop is not None:
                self._trip(rx.stop[0](rx.stop[1], **where))
            found = fault_stop(rx.faults)
            proto = self._proto[i]
            if proto.has_state and (found or not proto.armed(rx.state)):  # type: ignore
                # the device's own state machine: say what it reported, never a guess
                self._trip((found[0] if found else BoardFault)(
                    f"the board reports {self._reported(i)}", **where))
            if found is not None:
                self._trip(found[0](found[1], **where))
            if rx.saturated:
                self._trip(LoadcellSaturated("loadcell reading at its rail: the tension is "
                                             "unknown", **where))
            temperature = rx.values["temperature_c"]
            if temperature >= lim.fault_c:
                self._trip(Overheat(f"{temperature:.1f} °C >= {lim.fault_c} °C", **where))
            tension = rx.values["tension_n"]
            if tension > lim.tension_margin * self.f_max[i]:
                self._trip(TensionLimit(f"{tension:.1f} N > {lim.tension_margin:g} x ceiling "
                                        f"{self.f_max[i]:.1f} N", **where))
        for j, rx in enumerate(self._joint_rx):
            silent, said = self._silence(rx.times["angle_rad"], now)
            if silent > lim.silent_after_s:
                self._trip(BoardSilent(f"joint encoder {self.robot.joints[j]} (frame id "
                                       f"0x{0x240 + j:03X}) silent for {said} (limit "
                                       f"{lim.silent_after_s} s)", port=self.transport.port))

    def read_state(self, timeout: float = 0.05) -> ArmState:
        """Latest reading of every board, waiting up to ``timeout`` s for fresh frames."""
        self._refuse_if_tripped()
        self._pump(timeout)
        now = time.monotonic()
        self._check(now)
        rxs = self._rx
        state = ArmState(
            time=now, muscles=self.muscles,
            length=np.array([rx.values["position_m"] for rx in rxs]) - self.zero_m,
            tension=np.array([rx.values["tension_n"] for rx in rxs]),
            temperature=np.array([rx.values["temperature_c"] for rx in rxs]),
            faults=tuple(rx.faults for rx in rxs),
            seq=np.array([-1 if rx.counter is None else rx.counter for rx in rxs]),
            age=np.array([rx.age(now)[0] for rx in rxs]),
            fresh=np.array([rx.fresh() for rx in rxs]),
            theta=(np.array([rx.values["angle_rad"] for rx in self._joint_rx])
                   if self._joint_rx else None))
        for rx in (*rxs, *self._joint_rx):
            rx.news.clear()
        self._state = state
        return state

    # -- send ------------------------------------------------------------------------------
    def _send(self, frames: list[tuple[int, bytes]]) -> None:
        try:
            for frame in frames:
                self.transport.send(*frame)
        except SafetyStop as stop:
            self._trip(stop)

    def _send_commands(self, commands: list[tuple[str, float]]) -> None:
        frames = [frame for i, (kind, value) in enumerate(commands)
                  for frame in self._proto[i].command(i, kind, value)]  # type: ignore
        self._send(frames)
        self._last = commands

    def _refuse_if_tripped(self) -> None:
        if self.tripped is not None:
            raise self.tripped
        if self.closed:
            raise RuntimeError("ArmDriver is closed")

    def _modes(self, mode: str | Sequence[str]) -> list[str]:
        names = [mode] * len(self.muscles) if isinstance(mode, str) else list(mode)
        if len(names) != len(self.muscles) or any(n not in _MODES for n in names):
            raise ValueError(f"mode must be one of {sorted(_MODES)} or a list of "
                             f"{len(self.muscles)} of them, got {mode!r}")
        return [_MODES[n] for n in names]

    def command(self, mode: str | Sequence[str], values=None) -> None:
        """Command every muscle: "length" (m), "tension" (N, clamped) or "relax" (ignored).

        Feeds the board watchdogs. Tension commands are held between ``f_floor`` and the
        temperature-derated ceiling; a length outside the encoder range is a ValueError.
        """
        self._refuse_if_tripped()
        self._pump(0.0)
        self._check(time.monotonic())
        kinds = self._modes(mode)
        values = np.broadcast_to(np.asarray(np.nan if values is None else values, float),
                                 (len(self.muscles),))
        # no temperature reported: derate from the ambient (the host cannot see heat)
        temperature = np.nan_to_num([rx.values["temperature_c"] for rx in self._rx], nan=25.0)
        tension = self.limits.clamp_tension(np.nan_to_num(values, nan=0.0), self.f_floor,
                                            self.f_max, temperature)
        commands: list[tuple[str, float]] = []
        for i, kind in enumerate(kinds):
            if kind == "relax":
                commands.append(("relax", 0.0))
                continue
            if not np.isfinite(values[i]):
                raise ValueError(f"muscle {self.muscles[i]}: command {values[i]} is not finite")
            if kind == "tension":
                commands.append(("tension", float(tension[i])))
                continue
            position = float(values[i] + self.zero_m[i])
            lo, hi = self._proto[i].position_range_m(i)  # type: ignore[union-attr]
            if not lo <= position <= hi:
                raise ValueError(f"muscle {self.muscles[i]}: length {values[i]:.4f} m is "
                                 f"outside the encoder range of the protocol")
            commands.append(("length", position))
        self._send_commands(commands)

    def hold(self) -> None:
        """Repeat the last command (feeds the watchdogs while waiting in a pose)."""
        self._refuse_if_tripped()
        if self._last is None:
            self.relax()
        else:
            self._send_commands(self._last)

    def dwell(self, seconds: float, period: float = 0.02) -> ArmState:
        """Hold the pose for ``seconds``, feeding the watchdogs and checking limits."""
        tick = time.monotonic()
        end = tick + seconds
        while True:
            self.hold()
            state = self.read_state()
            tick += period
            if tick >= end:
                return state
            time.sleep(max(0.0, tick - time.monotonic()))

    def relax(self) -> None:
        """Every muscle to its low pre-tension (tension control at f_floor), never slack."""
        self._send_commands([("relax", 0.0)] * len(self.muscles))

    def stop(self) -> None:
        """Every motor holds its current length (emergency; prefer ``relax``)."""
        self._send_commands([("stop", 0.0)] * len(self.muscles))

    def zero(self, lengths=None) -> None:
        """Declare the current encoder positions to be ``lengths`` (default 0 m)."""
        self.read_state()
        position = np.array([rx.values["position_m"] for rx in self._rx])
        target = np.zeros(len(position)) if lengths is None else np.asarray(lengths, float)
        self.zero_m = position - target

    def set_zero(self, zero_m) -> None:
        """Use encoder zeros measured earlier (``pimbs zero``): reading at the zero pose, m."""
        zero_m = np.asarray(zero_m, float)
        if zero_m.shape != (len(self.muscles),) or not np.isfinite(zero_m).all():
            raise ValueError(f"zero positions must be {len(self.muscles)} finite numbers")
        self.zero_m = zero_m.copy()

    # -- stop and close --------------------------------------------------------------------
    def _trip(self, stop: SafetyStop) -> None:
        """Relax every board we can still reach, remember the stop, raise it.

        ``stop.end_state`` names the state the arm is left in: relaxed by the driver, or,
        when the boards cannot be reached, what each protocol's boards do by themselves.
        """
        if self.tripped is None:
            self.tripped = stop
            if not self._relax_quietly():
                stop.end_state = "; ".join(p.unreachable(self.limits.watchdog_s)
                                           for p in self.protocols if p.indices)
            else:
                stop.end_state = self._rearm_report(
                    [note for p in self.protocols for note in p.not_relaxed()])
        raise stop

    def _rearm_report(self, not_relaxed: list[str]) -> str:
        """After the relax: re-arm every board whose state machine left its armed state
        (ODrive: an axis in IDLE has its motor off, and a relax does not reach it), confirm
        by its own report, and say truthfully which boards stayed disarmed."""
        down = [i for i, p in enumerate(self._proto)
                if p.has_state and not p.armed(self._rx[i].state)]  # type: ignore[union-attr]
        # as long as the host waits for any late frame: 1 s on a bus, more in simulation
        idle = self._rearm(down, max(1.0, 2 * self.limits.silent_after_s)) if down else []
        rearmed = [self.muscles[i] for i in down if i not in idle]
        text = ("relaxed: every board at its holding floor" if not not_relaxed else
                "relaxed where the boards took it; " + "; ".join(not_relaxed))
        if idle:
            text = ("; ".join(f"{self.muscles[i]} (board {self.board_ids[i]}): motor off, its "
                              f"wire may be slack; after a re-arm the board still reports "
                              f"{self._reported(i)}" for i in idle)
                    + ("; the others relaxed at their holding floor"
                       if len(idle) < len(self.muscles) else ""))
        elif rearmed:
            text += f" ({', '.join(rearmed)} re-armed, confirmed by their own state report)"
        idlers = [p.unreachable(self.limits.watchdog_s) for p in self.protocols
                  if p.has_state and p.indices and p.capabilities.board_watchdog]
        if idlers:  # their watchdog does not wait for the host to come back
            text += "; once the host stops sending: " + "; ".join(idlers)
        return text

    def _rearm(self, down: list[int], timeout_s: float = 1.0) -> list[int]:
        """Send ``down``'s arming frames and a relax; the ones still not armed after
        ``timeout_s`` (a few state reports) as their boards report them."""
        send = getattr(self.transport, "send_despite_fault", self.transport.send)
        arm = [f for i in down
               for f in self._proto[i].setup(i, self._board_limits(i))]  # type: ignore
        relax = [f for i, p in enumerate(self._proto)
                 for f in p.command(i, "relax")]  # type: ignore[union-attr]
        deadline = time.monotonic() + timeout_s
        try:
            for frame in arm + relax:
                send(*frame)
            while time.monotonic() < deadline:
                self._pump(0.05)
                if all(self._proto[i].armed(self._rx[i].state) for i in down):  # type: ignore
                    break
                for frame in relax:  # keep every board fed (and relaxed) while waiting
                    send(*frame)
        except Exception:  # noqa: BLE001 - the link failed now: report the states as seen
            pass
        return [i for i in down if not self._proto[i].armed(self._rx[i].state)]  # type: ignore

    def _relax_quietly(self) -> bool:
        """Send every board its relax; False when the link refused (bus-off, unplugged)."""
        send = self.transport.send
        if hasattr(self.transport, "usable"):
            if not self.transport.usable():
                return False  # bus-off or a lost link: nothing we send arrives
            send = self.transport.send_despite_fault
        try:
            for i, proto in enumerate(self._proto):
                for frame in proto.command(i, "relax"):  # type: ignore[union-attr]
                    send(*frame)
        except Exception:  # noqa: BLE001 - bus-off/unplugged: the board watchdogs relax
            return False
        return True

    def close(self) -> None:
        """Relax the arm and release the transport (idempotent)."""
        if self.closed:
            return
        self._relax_quietly()
        self.closed = True
        for proto in self.protocols:
            proto.close()
        self.transport.close()

    def __enter__(self) -> ArmDriver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
