"""Safety limits and the stops they raise.

Two lines of defence, because the host can hang:
- on the boards: tension ceiling, thermal limit and a watchdog that relaxes the muscle when
  commands stop. The watchdog is fed only by the control loop's own commands (never a
  background timer), so a hung or crashed host relaxes the arm.
- on the host (this module, applied by ``ArmDriver``): commands clamped between the holding
  floor and a temperature-derated ceiling; readings that break a limit raise a ``SafetyStop``
  naming the muscle and board, after which the driver relaxes the arm.

"Relaxed" always means a low pre-tension (the muscle's ``f_floor``), never slack: a dropped
wire can jump off its pulleys and a slack arm falls.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pimbs_hw.errors import HardwareError
from pimbs_hw.protocol.codec import Fault


class SafetyStop(HardwareError):
    """The arm was (or must be) relaxed; ``muscle``/``board_id``/``port`` say where."""

    def __init__(self, detail: str, *, muscle: str | None = None, board_id: int | None = None,
                 port: str | None = None) -> None:
        self.muscle, self.board_id, self.port, self.detail = muscle, board_id, port, detail
        self.end_state = "relaxed"  # set by the driver when it stops: the state it left
        where = []
        if muscle is not None:
            where.append(f"muscle {muscle} (board {board_id})")
        if port is not None:
            where.append(f"port {port}")
        super().__init__(f"{type(self).__name__}: {' on '.join(where) or 'arm'}: {detail}")


class BoardSilent(SafetyStop):
    """No status frame from a board for longer than ``silent_after_s`` of the time the host
    could have heard one (``ArmDriver._silence``)."""


class FramesDropped(SafetyStop):
    """Too many status frames lost (gaps in the rolling counter)."""


class CorruptFrames(SafetyStop):
    """Too many frames failing their CRC, or CAN error frames, in one second."""


class Overheat(SafetyStop):
    """Board temperature above the host fault threshold, or the board's thermal limit hit."""


class TensionLimit(SafetyStop):
    """Tension above the ceiling."""


class LoadcellSaturated(SafetyStop):
    """Loadcell ADC at its rail: the tension is unknown."""


class BoardFault(SafetyStop):
    """Motor or encoder fault, or a board that reset (lost its limits)."""


class WatchdogExpired(SafetyStop):
    """A board relaxed because the host stopped commanding it for ``watchdog_s``."""


class BusOff(SafetyStop):
    """The CAN controller went bus-off: nothing reaches the boards, their watchdogs relax."""


class LinkLost(SafetyStop):
    """The receive thread died or the port vanished (USB unplugged)."""


@dataclass(frozen=True)
class SafetyLimits:
    """Host-side thresholds and the limits sent to every board at start-up."""

    watchdog_s: float = 0.25  # boards relax when no command arrives for this long
    tension_ceiling: float | None = None  # N, caps every muscle's f_max when set
    relax_tension: float | None = None  # N, relax target; None = each muscle's f_floor
    derate_start_c: float = 60.0  # above this the ceiling shrinks linearly ...
    fault_c: float = 75.0  # ... to f_floor here, where the host stops
    board_thermal_limit_c: float = 80.0  # the board relaxes on its own above this
    tension_margin: float = 1.1  # readings above margin * ceiling stop (commands are clamped)
    silent_after_s: float = 0.3
    loss_window_s: float = 0.25  # the loss ratio counts counter gaps of this recent past
    max_loss: float = 0.5
    corrupt_per_s: int = 3  # per board (CRC) or per bus (error frames / bad serial frames)

    def ceilings(self, f_max: np.ndarray) -> np.ndarray:
        return f_max if self.tension_ceiling is None else np.minimum(f_max, self.tension_ceiling)

    def relax_targets(self, f_floor: np.ndarray) -> np.ndarray:
        return f_floor if self.relax_tension is None else np.full_like(f_floor, self.relax_tension)

    def derate(self, temperature: np.ndarray) -> np.ndarray:
        """Ceiling scale in [0, 1]: 1 when cool, 0 at ``fault_c``."""
        span = max(self.fault_c - self.derate_start_c, 1e-9)
        return np.clip((self.fault_c - np.asarray(temperature)) / span, 0.0, 1.0)

    def clamp_tension(self, f: np.ndarray, f_floor: np.ndarray, f_max: np.ndarray,
                      temperature: np.ndarray) -> np.ndarray:
        """Tension commands held between the floor and the derated ceiling."""
        ceiling = f_floor + (self.ceilings(f_max) - f_floor) * self.derate(temperature)
        return np.clip(f, f_floor, np.maximum(ceiling, f_floor))


# board fault bit -> stop it raises (first match wins: the most specific cause first)
_FAULT_STOPS: tuple[tuple[Fault, type[SafetyStop], str], ...] = (
    (Fault.LOADCELL_SATURATED, LoadcellSaturated, "loadcell saturated; the board relaxed"),
    (Fault.OVERHEAT, Overheat, "board thermal limit reached; the board relaxed"),
    (Fault.TENSION_LIMIT, TensionLimit, "board tension ceiling reached; the board relaxed"),
    (Fault.MOTOR, BoardFault, "motor driver fault"),
    (Fault.ENCODER, BoardFault, "encoder fault"),
    (Fault.UNCONFIGURED, BoardFault, "board lost its limits (reset or power glitch)"),
    (Fault.WATCHDOG, WatchdogExpired, "no command within the watchdog time; the board relaxed"),
)


def fault_stop(faults: Fault) -> tuple[type[SafetyStop], str] | None:
    """The stop a board's fault bits call for, or None (STOPPED alone is not a fault)."""
    if not int(faults) & ~int(Fault.STOPPED):
        return None  # the common case, without enum arithmetic
    for bit, kind, detail in _FAULT_STOPS:
        if faults & bit:
            return kind, detail
    return None
