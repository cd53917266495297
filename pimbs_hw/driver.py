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
"""

from __future__ import annotations

import collections
import dataclasses
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pimbs_hw.protocol.codec import (
    CodecError,
    Fault,
    JointStatus,
    Message,
    PositionCommand,
    Relax,
    SetLimits,
    Status,
    Stop,
    TensionCommand,
    board_of,
    decode,
    encode,
    frame_id,
    signal_range,
)
from pimbs_hw.safety import (
    BoardSilent,
    CorruptFrames,
    FramesDropped,
    Overheat,
    SafetyLimits,
    SafetyStop,
    TensionLimit,
    fault_stop,
)
from pimbs_hw.transport.base import Frame, Transport

POSITION_RANGE = signal_range(PositionCommand, "position_counts")
RAW_RANGE = signal_range(TensionCommand, "loadcell_raw")
_MODES = {"length": PositionCommand, "position": PositionCommand, "tension": TensionCommand,
          "relax": Relax}


@dataclass(frozen=True)
class ArmState:
    """One reading of every board. Arrays are (M,) in the robot description's muscle order."""

    time: float  # time.monotonic() when assembled
    muscles: tuple[str, ...]
    length: np.ndarray  # m, relative to the zero pose
    tension: np.ndarray  # N
    temperature: np.ndarray  # °C
    faults: tuple[Fault, ...]
    seq: np.ndarray  # the status frame's 4-bit counter
    age: np.ndarray  # s since that status frame arrived
    fresh: np.ndarray  # bool: a new status frame arrived since the previous read_state
    theta: np.ndarray | None = None  # rad, joint encoders (robots with joint_encoders)

    def muscle(self, name: str) -> dict[str, object]:
        i = self.muscles.index(name)
        return {"length": self.length[i], "tension": self.tension[i],
                "temperature": self.temperature[i], "faults": self.faults[i],
                "seq": int(self.seq[i]), "age": self.age[i], "fresh": bool(self.fresh[i])}


class _Rx:
    """Receive bookkeeping of one board: latest frame, freshness, loss and CRC failures."""

    def __init__(self) -> None:
        self.msg: Status | JointStatus | None = None
        self.time = -np.inf
        self.fresh = False
        self.gaps: collections.deque[tuple[float, int]] = collections.deque()  # (time, lost)
        self.lost = 0  # sum of the gaps in ``gaps``
        self.corrupt: collections.deque[float] = collections.deque()

    def update(self, msg: Status | JointStatus, now: float) -> None:
        if self.msg is not None:
            gap = (msg.counter - self.msg.counter - 1) & 0xF
            if gap == 15:  # same counter again: a repeated frame, not news
                return
            self.gaps.append((now, gap))
            self.lost += gap
        self.msg, self.time, self.fresh = msg, now, True

    def loss(self, now: float, window_s: float) -> tuple[float, int]:
        """(fraction of frames lost, frames received) over the last ``window_s``."""
        while self.gaps and now - self.gaps[0][0] > window_s:
            self.lost -= self.gaps.popleft()[1]
        n = len(self.gaps)
        return (self.lost / (self.lost + n) if n else 0.0), n

    def corrupt_in_last_second(self, now: float) -> int:
        while self.corrupt and now - self.corrupt[0] > 1.0:
            self.corrupt.popleft()
        return len(self.corrupt)


class ArmDriver:
    """See the module docstring. ``robot``: a ``pimbs_calibration.description.RobotDescription``."""

    def __init__(self, transport: Transport, robot, limits: SafetyLimits | None = None, *,
                 connect_timeout_s: float = 1.0) -> None:
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
        self._index = {b: i for i, b in enumerate(self.board_ids)}
        self.counts_per_m = np.array([s.counts_per_m for s in specs], float)
        self.n_per_count = np.array([s.loadcell_n_per_count for s in specs], float)
        self.offset_counts = np.array([s.loadcell_offset_counts for s in specs], float)
        self.f_floor = np.array([s.f_floor for s in specs], float)
        self.f_max = self.limits.ceilings(np.array([s.f_max for s in specs], float))
        self.zero_counts = np.zeros(len(specs))
        self._rx = [_Rx() for _ in specs]
        self._joint_rx = [_Rx() for _ in robot.joints] if robot.joint_encoders else []
        self._tx_counter = 0
        self._last: list[Message] | None = None
        self.tripped: SafetyStop | None = None
        self.closed = False
        self._configure(connect_timeout_s)

    # -- conversions -----------------------------------------------------------------------
    def _raw(self, tension: np.ndarray) -> np.ndarray:
        raw = np.rint(self.offset_counts + tension / self.n_per_count)
        return np.clip(raw, RAW_RANGE[0] + 1, RAW_RANGE[1] - 1).astype(int)  # rails = saturated

    def _where(self, i: int) -> dict[str, object]:
        return {"muscle": self.muscles[i], "board_id": self.board_ids[i],
                "port": self.transport.port}

    # -- set-up ----------------------------------------------------------------------------
    def _configure(self, timeout_s: float) -> None:
        """Send limits, wait for every board to answer configured, then relax (safe start)."""
        lim = self.limits
        ceiling = self._raw(lim.tension_margin * self.f_max)  # commands stop at f_max
        relax = self._raw(lim.relax_targets(self.f_floor))
        limits = [SetLimits(b, 0, lim.watchdog_s, int(ceiling[i]), int(relax[i]),
                            lim.board_thermal_limit_c) for i, b in enumerate(self.board_ids)]
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            self._send_all(limits)  # repeated: a lost SET_LIMITS frame costs one round
            self._pump(min(left, 0.2))
            if all(rx.msg is not None and not rx.msg.faults & Fault.UNCONFIGURED
                   for rx in self._rx) and all(rx.msg is not None for rx in self._joint_rx):
                break
            for rx in self._rx:
                rx.fresh = False  # wait for frames sent after this round's SET_LIMITS
        missing = [i for i, rx in enumerate(self._rx)
                   if rx.msg is None or rx.msg.faults & Fault.UNCONFIGURED]
        if missing:
            names = ", ".join(f"{self.muscles[i]} (board {self.board_ids[i]})" for i in missing)
            hint = ("is the arm powered and the port right? for the simulated arm use "
                    "--port virtual" if len(missing) == len(self._rx) else "check that board")
            stop = BoardSilent(f"no configured status within {timeout_s:.1f} s from {names}; "
                               f"{hint}", **self._where(missing[0]))
            self._trip(stop)
        self.relax()
        # wait for the answers to that relax: faults latched in an earlier session (a host
        # that crashed) are cleared by it, and must not be read back from older frames
        for rx in self._rx:
            rx.fresh = False
        self._pump(max(0.05, deadline - time.monotonic()))

    # -- receive ---------------------------------------------------------------------------
    def _on_frame(self, frame: Frame) -> None:
        try:
            msg = decode(frame.arbitration_id, frame.data)
        except CodecError:
            board = board_of(frame.arbitration_id)
            if board in self._index and frame.arbitration_id == frame_id(Status, board):
                self._rx[self._index[board]].corrupt.append(frame.timestamp)
            return
        if isinstance(msg, Status) and msg.board_id in self._index:
            self._rx[self._index[msg.board_id]].update(msg, frame.timestamp)
        elif isinstance(msg, JointStatus) and msg.board_id < len(self._joint_rx):
            self._joint_rx[msg.board_id].update(msg, frame.timestamp)

    def _pump(self, timeout: float) -> None:
        """Process received frames; wait up to ``timeout`` until every board has news."""
        deadline = time.monotonic() + timeout
        try:
            while True:
                frame = self.transport.recv(0.0)
                if frame is None:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0 or all(rx.fresh for rx in self._rx):
                        return
                    frame = self.transport.recv(remaining)
                    if frame is None:
                        return
                self._on_frame(frame)
        except SafetyStop as stop:
            self._trip(stop)

    def _check(self, now: float) -> None:
        """Raise (after relaxing) the first limit any board breaks."""
        lim = self.limits
        for i, rx in enumerate(self._rx):
            where = self._where(i)
            age = now - rx.time
            if age > lim.silent_after_s:
                self._trip(BoardSilent(f"no status for {age:.2f} s (limit "
                                       f"{lim.silent_after_s} s)", **where))
            if (n := rx.corrupt_in_last_second(now)) > lim.corrupt_per_s:
                self._trip(CorruptFrames(f"{n} status frames failed their CRC in 1 s", **where))
            loss, n = rx.loss(now, lim.loss_window_s)
            if n >= 4 and loss > lim.max_loss:
                self._trip(FramesDropped(f"{loss:.0%} of status frames lost in the last "
                                         f"{lim.loss_window_s} s (counter gaps)", **where))
            msg = rx.msg
            if (found := fault_stop(msg.faults)) is not None:
                self._trip(found[0](found[1], **where))
            if msg.temperature_c >= lim.fault_c:
                self._trip(Overheat(f"{msg.temperature_c:.1f} °C >= {lim.fault_c} °C", **where))
            tension = (msg.loadcell_raw - self.offset_counts[i]) * self.n_per_count[i]
            if tension > lim.tension_margin * self.f_max[i]:
                self._trip(TensionLimit(f"{tension:.1f} N > {lim.tension_margin:g} x ceiling "
                                        f"{self.f_max[i]:.1f} N", **where))
        for j, rx in enumerate(self._joint_rx):
            if now - rx.time > lim.silent_after_s:
                self._trip(BoardSilent(f"joint encoder {self.robot.joints[j]} (frame id "
                                       f"0x{0x240 + j:03X}) silent for {now - rx.time:.2f} s",
                                       port=self.transport.port))

    def read_state(self, timeout: float = 0.05) -> ArmState:
        """Latest reading of every board, waiting up to ``timeout`` s for fresh frames."""
        self._refuse_if_tripped()
        self._pump(timeout)
        now = time.monotonic()
        self._check(now)
        msgs = [rx.msg for rx in self._rx]
        counts = np.array([m.position_counts for m in msgs], float)
        raw = np.array([m.loadcell_raw for m in msgs], float)
        state = ArmState(
            time=now, muscles=self.muscles,
            length=(counts - self.zero_counts) / self.counts_per_m,
            tension=(raw - self.offset_counts) * self.n_per_count,
            temperature=np.array([m.temperature_c for m in msgs]),
            faults=tuple(m.faults for m in msgs),
            seq=np.array([m.counter for m in msgs]),
            age=np.array([now - rx.time for rx in self._rx]),
            fresh=np.array([rx.fresh for rx in self._rx]),
            theta=(np.array([rx.msg.angle_rad for rx in self._joint_rx])
                   if self._joint_rx else None))
        for rx in (*self._rx, *self._joint_rx):
            rx.fresh = False
        self._state = state
        return state

    # -- send ------------------------------------------------------------------------------
    def _send_all(self, msgs: list[Message]) -> None:
        self._tx_counter = (self._tx_counter + 1) & 0xF
        try:
            for msg in msgs:
                self.transport.send(*encode(dataclasses.replace(msg, counter=self._tx_counter)))
        except SafetyStop as stop:
            self._trip(stop)

    def _refuse_if_tripped(self) -> None:
        if self.tripped is not None:
            raise self.tripped
        if self.closed:
            raise RuntimeError("ArmDriver is closed")

    def _modes(self, mode: str | Sequence[str]) -> list[type[Message]]:
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
        temperature = np.array([rx.msg.temperature_c for rx in self._rx])
        tension = self.limits.clamp_tension(np.nan_to_num(values, nan=0.0), self.f_floor,
                                            self.f_max, temperature)
        raw = self._raw(tension)
        counts = np.rint(self.zero_counts + values * self.counts_per_m)
        msgs: list[Message] = []
        for i, (kind, board) in enumerate(zip(kinds, self.board_ids, strict=True)):
            if kind is Relax:
                msgs.append(Relax(board, 0))
                continue
            if not np.isfinite(values[i]):
                raise ValueError(f"muscle {self.muscles[i]}: command {values[i]} is not finite")
            if kind is TensionCommand:
                msgs.append(TensionCommand(board, 0, int(raw[i])))
            elif not POSITION_RANGE[0] <= counts[i] <= POSITION_RANGE[1]:
                raise ValueError(f"muscle {self.muscles[i]}: length {values[i]:.4f} m is outside "
                                 f"the encoder range of the protocol")
            else:
                msgs.append(PositionCommand(board, 0, int(counts[i])))
        self._send_all(msgs)
        self._last = msgs

    def hold(self) -> None:
        """Repeat the last command (feeds the watchdogs while waiting in a pose)."""
        self._refuse_if_tripped()
        if self._last is None:
            self.relax()
        else:
            self._send_all(self._last)

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
        msgs = [Relax(b, 0) for b in self.board_ids]
        self._send_all(msgs)
        self._last = msgs

    def stop(self) -> None:
        """Every motor holds its current length (emergency; prefer ``relax``)."""
        msgs = [Stop(b, 0) for b in self.board_ids]
        self._send_all(msgs)
        self._last = msgs

    def zero(self, lengths=None) -> None:
        """Declare the current encoder positions to be ``lengths`` (default 0 m)."""
        self.read_state()
        counts = np.array([rx.msg.position_counts for rx in self._rx], float)
        target = np.zeros(len(counts)) if lengths is None else np.asarray(lengths, float)
        self.zero_counts = counts - target * self.counts_per_m

    # -- stop and close --------------------------------------------------------------------
    def _trip(self, stop: SafetyStop) -> None:
        """Relax every board we can still reach, remember the stop, raise it."""
        if self.tripped is None:
            self.tripped = stop
            self._relax_quietly()
        raise stop

    def _relax_quietly(self) -> None:
        try:
            for b in self.board_ids:
                self.transport.send(*encode(Relax(b, 0)))
        except Exception:  # noqa: BLE001 - bus-off/unplugged: the board watchdogs relax
            pass

    def close(self) -> None:
        """Relax the arm and release the transport (idempotent)."""
        if self.closed:
            return
        self._relax_quietly()
        self.closed = True
        self.transport.close()

    def __enter__(self) -> ArmDriver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
