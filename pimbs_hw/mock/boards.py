"""Simulated boards of each protocol, as the simulated arm sees them: frames in, frames out.

``MockArm`` gives every board an ``SiReading`` (what its sensors see, SI units) and asks it
which frames it sends; the board turns commands into a plant target (``actuation``). One
class per protocol: ``V1Board`` (PIMBS v1 firmware, ``board.SimBoard``) and
``ProfileBoard`` (any board a DBC profile describes: no firmware logic beyond following its
commands, since such boards have no PIMBS relax, watchdog or limits).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pimbs_hw.mock.board import RAW_MAX, RAW_MIN, TEMP_MAX, TEMP_MIN, Reading, SimBoard
from pimbs_hw.protocol.board import RawFrame
from pimbs_hw.protocol.codec import (
    MESSAGE_TYPES,
    CodecError,
    Fault,
    JointStatus,
    Status,
    decode,
    encode,
    frame_id,
)
from pimbs_hw.protocol.profile import Profile

VERSION_PERIOD_S = 1.0  # profile boards announce their firmware version once a second
MAX_CATCH_UP = 50  # frames per message a late simulation sends at once (0.5 s at 10 ms)
RELAX_MATCH_N = 0.5  # a tension command this close to f_floor is the host's relax


@dataclass(frozen=True)
class SiReading:
    """What one board's sensors see: encoder (with its power-up offset), loadcell, heat."""

    position_m: float
    tension_n: float  # as the loadcell reads it (effects applied)
    temperature_c: float
    saturated: bool = False  # the loadcell is at its rail


class V1Board:
    """A PIMBS v1 board (``SimBoard`` firmware) behind the codec."""

    checksum = True

    def __init__(self, spec, now: float, status_period_s: float, winding: int = 1) -> None:
        self.spec, self.sim = spec, SimBoard(spec, now)
        self.winding = 1 if winding >= 0 else -1  # -1: the encoder counts down as wire pays out
        self.period = status_period_s
        self.next_status = now
        self.frame_ids = {frame_id(cls, spec.board_id) for cls in MESSAGE_TYPES
                          if cls not in (Status, JointStatus)}

    def _raw(self, r: SiReading) -> Reading:
        s = self.spec
        raw = RAW_MAX if r.saturated else round(s.loadcell_offset_counts
                                               + r.tension_n / s.loadcell_n_per_count)
        return Reading(round(self.winding * r.position_m * s.counts_per_m),
                       int(np.clip(raw, RAW_MIN, RAW_MAX)),
                       float(np.clip(r.temperature_c, TEMP_MIN, TEMP_MAX)))

    @property
    def mode(self) -> str:
        return self.sim.mode

    @property
    def relax_n(self) -> float:
        s = self.spec
        return (self.sim.relax_raw - s.loadcell_offset_counts) * s.loadcell_n_per_count

    def receive(self, fid: int, data: bytes, now: float, reading: SiReading) -> bool:
        """Take a command; True when the board answers it with a status frame."""
        try:
            msg = decode(fid, data)
        except CodecError:
            return False  # a board drops what fails its CRC; the host's watchdog story covers it
        self.sim.receive(msg, now, self._raw(reading))
        return True

    def supervise(self, now: float, reading: SiReading) -> None:
        self.sim.supervise(now, self._raw(reading))

    def actuation(self) -> tuple[str, float]:
        mode, value = self.sim.actuation()
        return mode, value * self.winding if mode == "length" else value

    def inject(self, kind: str) -> None:
        """Fault injection: ``drive-fault`` = the motor driver faults (latched, relaxed)."""
        if kind == "drive-fault":
            self.sim.latched |= Fault.MOTOR
            self.sim.mode = "relax"
    def frames(self, now: float, reading: SiReading, reply: bool = False) -> list[RawFrame]:
        """Frames due now (periodic), or the reply to a command."""
        if not reply and now < self.next_status:
            return []
        self.next_status = now + self.period
        return [encode(self.sim.status(self._raw(reading)))]


class ProfileBoard:
    """A board of a DBC profile: follows length/tension commands, reports on its cycle."""

    checksum = False

    def __init__(self, spec, profile: Profile, now: float, winding: int = 1,
                 watchdog: tuple[float, str] | None = None) -> None:
        """``watchdog``: (timeout s, action) the firmware runs with; default the profile's."""
        self.spec, self.profile = spec, profile
        self.watchdog = profile.watchdog if watchdog is None else watchdog
        self.winding = 1 if winding >= 0 else -1  # -1: the encoder counts down as wire pays out
        node_id = {name: node for name, node in profile.nodes.items()}
        self.mode, self.target = "hold", math.nan
        self.relax_n = spec.f_floor
        self.counter = 0
        # command frame id -> (kind, frame spec) of every command frame with that id: one id
        # can carry several commands, told apart by their constant signals (a mode byte)
        self.commands: dict[int, list[tuple[str, object]]] = {}
        self.frame_ids: set[int] = set()
        for kind, frames in profile.commands.items():
            for f in frames:
                msg = profile.db.get_message_by_name(f.message)
                fid = node_id[f.node].frame_id(msg.frame_id, spec.board_id)
                self.frame_ids.add(fid)
                if f.value_signal is not None or kind == "stop":
                    self.commands.setdefault(fid, []).append((kind, f))
        for f in profile.setup:
            msg = profile.db.get_message_by_name(f.message)
            self.frame_ids.add(node_id[f.node].frame_id(msg.frame_id, spec.board_id))
        self.outgoing = []  # (frame id, message, readings, period)
        for (node, message), readings in profile.status_messages().items():
            msg = profile.db.get_message_by_name(message)
            period = profile.periods.get(message) or (
                VERSION_PERIOD_S if profile.version and message == profile.version[1]
                else profile.status_period_s())
            self.outgoing.append((node_id[node].frame_id(msg.frame_id, spec.board_id), msg,
                                  readings, period))
        self.due = [now] * len(self.outgoing)
        self.faults = Fault(0)  # latched by the board (its watchdog), cleared by a command
        self.last_command = now

    def receive(self, fid: int, data: bytes, now: float, reading: SiReading) -> bool:
        candidates = self.commands.get(fid)
        if not candidates:
            return False  # mode switches, setup: accepted, nothing to do in simulation
        try:
            values = self.profile.db.get_message_by_name(candidates[0][1].message).decode(
                data, decode_choices=False)
        except Exception:  # noqa: BLE001 - a malformed frame is ignored, as firmware does
            return False
        match = [(k, f) for k, f in candidates
                 if all(abs(values[n] - v) < 1e-9 for n, v in f.constants.items())]
        if not match:
            return False
        kind, frame = match[0]
        self.last_command, self.faults = now, Fault(0)
        if frame.value_signal is None:  # a stop: hold the current length
            self.mode, self.target = "hold", reading.position_m
            return False
        value = float(values[frame.value_signal]) / frame.per_si
        if kind == "length":
            self.mode, self.target = "position", value * self.winding
        elif kind == "tension":
            relax = abs(value - self.relax_n) < RELAX_MATCH_N
            self.mode, self.target = ("relax" if relax else "tension"), value
        return False  # these boards do not answer commands; they report on their cycle

    def supervise(self, now: float, reading: SiReading) -> None:
        if self.mode == "hold" and math.isnan(self.target):
            self.target = reading.position_m  # power-up: hold where it is
        dog = self.watchdog
        if dog is not None and now - self.last_command > dog[0] and self.mode not in (
                "relax", "idle", "hold"):
            self.mode, self.target = ("relax", self.relax_n) if dog[1] == "relax" else (
                "idle", 0.0)  # idle: motor off, the wire goes slack
            self.faults |= Fault.WATCHDOG

    def actuation(self) -> tuple[str, float]:
        if self.mode in ("hold", "position"):
            return "length", self.target
        return "tension", self.target

    def inject(self, kind: str) -> None:
        """Fault injection: ``drive-fault`` = the motor driver faults (reported, relaxed)."""
        if kind == "drive-fault":
            self.faults |= Fault.MOTOR
            self.mode, self.target = "relax", self.relax_n

    def _signals(self, msg, readings, reading: SiReading) -> dict[str, float]:
        values = {s.name: 0.0 for s in msg.signals}
        status = self.profile.status
        for r in readings:
            if r.kind is not None:  # a fault signal: set when the board has that fault
                values[r.signal] = float(bool(self.faults & r.kind
                                              or (r.kind == Fault.MOTOR and self.faults)))
                continue
            quantity = next(q for q, s in status.items() if s is r)
            if quantity == "counter":
                self.counter = (self.counter + 1) & 0xFF
                values[r.signal] = float(self.counter)
                continue
            si = {"position": self.winding * reading.position_m, "tension": reading.tension_n,
                  "temperature": reading.temperature_c}[quantity]
            value = si * r.per_si
            if r.rail is not None:
                value = r.rail[1] if quantity == "tension" and reading.saturated else float(
                    np.clip(value, *r.rail))
            values[r.signal] = value
        if self.profile.version and msg.name == self.profile.version[1]:
            for k, name in enumerate(self.profile.version[2]):
                values[name] = float((0, 6, 11)[k % 3])  # simulated firmware 0.6.11
        return values

    def frames(self, now: float, reading: SiReading, reply: bool = False) -> list[RawFrame]:
        out = []
        for k, (fid, msg, readings, period) in enumerate(self.outgoing):
            if now < self.due[k]:
                continue
            # a board keeps its own clock: if this simulation was descheduled, the frames
            # it owed go out now (a real host sees them queued in a burst, not missing)
            owed = min(1 + int((now - self.due[k]) / period), MAX_CATCH_UP)
            self.due[k] = max(self.due[k] + owed * period, now - period)
            for _ in range(owed):
                out.append((fid, msg.encode(self._signals(msg, readings, reading),
                                            strict=False)))
        return out
