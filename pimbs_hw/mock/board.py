"""Firmware logic of one simulated muscle board (no physics, no bus: see arm.py).

Implements the board side of PROTOCOL.md: limits, the four control modes, the watchdog fed
by commands, and the relax-on-fault reactions with latched fault bits.
"""

from __future__ import annotations

from dataclasses import dataclass

from pimbs_hw.protocol.codec import (
    Fault,
    Message,
    PositionCommand,
    Relax,
    SetLimits,
    Status,
    Stop,
    TensionCommand,
    signal_range,
)

RAW_MIN, RAW_MAX = (int(v) for v in signal_range(Status, "loadcell_raw"))
TEMP_MIN, TEMP_MAX = signal_range(Status, "temperature_c")
_RELAXING = Fault.WATCHDOG | Fault.OVERHEAT | Fault.TENSION_LIMIT | Fault.LOADCELL_SATURATED


@dataclass(frozen=True)
class Reading:
    """What the board's sensors say right now (raw units)."""

    position_counts: int
    loadcell_raw: int
    temperature_c: float


class SimBoard:
    """One board: ``receive`` commands, ``supervise`` each cycle, ``actuation`` for the motor."""

    def __init__(self, spec, now: float) -> None:
        self.spec = spec
        self.counter = 0
        self.configured = False
        self.watchdog_s = 0.0
        self.ceiling_raw = RAW_MAX
        self.relax_raw = round(spec.loadcell_offset_counts
                               + spec.f_floor / spec.loadcell_n_per_count)
        self.thermal_limit_c = TEMP_MAX
        self.mode = "hold"  # hold | position | tension | relax
        self.target = 0  # counts (position/hold) or loadcell raw (tension)
        self.hold_counts: int | None = None
        self.last_command = now
        self.latched = Fault(0)

    # -- host commands ---------------------------------------------------------------------
    def receive(self, msg: Message, now: float, reading: Reading) -> None:
        if isinstance(msg, SetLimits):
            self.configured = True
            self.watchdog_s = msg.watchdog_s
            self.ceiling_raw, self.relax_raw = msg.tension_ceiling_raw, msg.relax_raw
            self.thermal_limit_c = msg.thermal_limit_c
            self.last_command = now
            self.latched &= ~Fault.WATCHDOG  # a new session starts
            return
        if not isinstance(msg, Stop | Relax | PositionCommand | TensionCommand):
            return
        self.last_command = now
        self.latched &= ~Fault.WATCHDOG
        if not self.configured:
            return  # motion refused: fault_unconfigured stays set
        if isinstance(msg, Stop):
            self.mode, self.target = "hold", reading.position_counts
            return
        if self._conditions(reading):
            self.mode = "relax"  # a relaxing condition still holds: stay relaxed
            return
        self.latched &= ~_RELAXING
        if isinstance(msg, PositionCommand):
            self.mode, self.target = "position", msg.position_counts
        elif isinstance(msg, TensionCommand):
            self.mode, self.target = "tension", min(msg.loadcell_raw, self.ceiling_raw)
        else:
            self.mode = "relax"

    # -- every control cycle ---------------------------------------------------------------
    def _conditions(self, reading: Reading) -> Fault:
        found = Fault(0)
        if reading.temperature_c > self.thermal_limit_c:
            found |= Fault.OVERHEAT
        if reading.loadcell_raw >= RAW_MAX or reading.loadcell_raw <= RAW_MIN:
            found |= Fault.LOADCELL_SATURATED
        elif reading.loadcell_raw > self.ceiling_raw:
            found |= Fault.TENSION_LIMIT
        return found

    def supervise(self, now: float, reading: Reading) -> None:
        """Relax (and latch the reason) on watchdog expiry, heat, overload, saturation."""
        if self.hold_counts is None:
            self.hold_counts = reading.position_counts
            if self.mode == "hold":
                self.target = reading.position_counts
        if not self.configured:
            return
        found = self._conditions(reading)
        expired = self.watchdog_s > 0 and now - self.last_command > self.watchdog_s
        if expired and self.mode != "relax":  # already relaxed: nothing to undo
            found |= Fault.WATCHDOG
        if found:
            self.latched |= found
            self.mode = "relax"

    def actuation(self) -> tuple[str, float]:
        """(plant mode, value): "length" in m or "tension" as the loadcell should read, N."""
        spec = self.spec
        if self.mode in ("hold", "position"):
            return "length", self.target / spec.counts_per_m
        raw = self.relax_raw if self.mode == "relax" else self.target
        return "tension", (raw - spec.loadcell_offset_counts) * spec.loadcell_n_per_count

    def status(self, reading: Reading) -> Status:
        faults = self.latched
        if not self.configured:
            faults |= Fault.UNCONFIGURED
        if self.mode == "hold" and self.configured:
            faults |= Fault.STOPPED
        self.counter = (self.counter + 1) & 0xF
        return Status(self.spec.board_id, self.counter, reading.position_counts,
                      reading.loadcell_raw, reading.temperature_c, faults)
