"""Board messages as plain dataclasses <-> CAN frames ``(arbitration_id, data)``.

Commands are built as plain data and handed to a transport (moteus style), so the same
objects serve the driver, the simulated boards, tests and logs. The bit layout lives only in
``pimbs_board.dbc``; this module adds what a DBC cannot say: frame id = base id + board_id,
and the CRC-8 + 4-bit counter that start every message (see PROTOCOL.md).
"""

from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass
from importlib import resources
from typing import ClassVar

import cantools

from pimbs_hw.protocol.crc import crc8_j1850

MAX_BOARDS = 32  # board_id 0..31: base ids are 32 apart
DBC_PATH = resources.files("pimbs_hw.protocol") / "pimbs_board.dbc"
DB = cantools.database.load_string(DBC_PATH.read_text(), database_format="dbc")


class Fault(enum.IntFlag):
    """Status fault bits; member ``X`` is DBC signal ``fault_x``, bit order = DBC order."""

    WATCHDOG = 1
    OVERHEAT = 2
    TENSION_LIMIT = 4
    LOADCELL_SATURATED = 8
    ENCODER = 16
    MOTOR = 32
    STOPPED = 64
    UNCONFIGURED = 128


class CodecError(ValueError):
    """A frame that is not a valid board message (unknown id, wrong length, bad CRC)."""

    def __init__(self, arbitration_id: int, reason: str) -> None:
        self.arbitration_id = arbitration_id
        self.board_id = board_of(arbitration_id)
        super().__init__(f"frame 0x{arbitration_id:03X}: {reason}")


@dataclass(frozen=True)
class _Message:
    board_id: int
    counter: int  # 4-bit rolling counter, set by the sender
    MESSAGE: ClassVar[str]


@dataclass(frozen=True)
class Stop(_Message):
    """Hold the current length; motion commands resume control."""

    MESSAGE: ClassVar[str] = "STOP"


@dataclass(frozen=True)
class Relax(_Message):
    """Tension control at the board's relax tension (from SetLimits)."""

    MESSAGE: ClassVar[str] = "RELAX"


@dataclass(frozen=True)
class PositionCommand(_Message):
    position_counts: int
    MESSAGE: ClassVar[str] = "POSITION"


@dataclass(frozen=True)
class TensionCommand(_Message):
    loadcell_raw: int
    MESSAGE: ClassVar[str] = "TENSION"


@dataclass(frozen=True)
class SetLimits(_Message):
    watchdog_s: float  # 0 disables the watchdog
    tension_ceiling_raw: int
    relax_raw: int
    thermal_limit_c: float
    MESSAGE: ClassVar[str] = "SET_LIMITS"


@dataclass(frozen=True)
class Status(_Message):
    position_counts: int
    loadcell_raw: int
    temperature_c: float
    faults: Fault
    MESSAGE: ClassVar[str] = "STATUS"


@dataclass(frozen=True)
class JointStatus(_Message):
    """Joint encoder reading; ``board_id`` is the joint's index in the description."""

    angle_rad: float
    MESSAGE: ClassVar[str] = "JOINT"


Message = Stop | Relax | PositionCommand | TensionCommand | SetLimits | Status | JointStatus
MESSAGE_TYPES: tuple[type[_Message], ...] = (
    Stop, Relax, PositionCommand, TensionCommand, SetLimits, Status, JointStatus,
)
_BY_NAME = {cls.MESSAGE: cls for cls in MESSAGE_TYPES}
# every valid frame id -> (dataclass, board_id); a dict lookup per received frame
_BY_ID = {
    DB.get_message_by_name(cls.MESSAGE).frame_id + board: (cls, board)
    for cls in MESSAGE_TYPES for board in range(MAX_BOARDS)
}
_FAULT_SIGNALS = tuple((f"fault_{f.name.lower()}", f) for f in Fault)
_SPECS = {cls: DB.get_message_by_name(cls.MESSAGE) for cls in MESSAGE_TYPES}
_FIELDS = {cls: tuple(f.name for f in dataclasses.fields(cls) if f.name != "board_id")
           for cls in MESSAGE_TYPES}


def frame_id(cls: type[_Message], board_id: int) -> int:
    """CAN id of message ``cls`` for ``board_id``."""
    if not 0 <= board_id < MAX_BOARDS:
        raise ValueError(f"board_id {board_id} out of range 0..{MAX_BOARDS - 1}")
    return _SPECS[cls].frame_id + board_id


def board_of(arbitration_id: int) -> int | None:
    """Board id a frame id belongs to, or None for a foreign frame."""
    entry = _BY_ID.get(arbitration_id)
    return None if entry is None else entry[1]


def signal_range(cls: type[_Message], signal: str) -> tuple[float, float]:
    """(min, max) of a signal as the DBC declares it: senders clamp to this."""
    sig = DB.get_message_by_name(cls.MESSAGE).get_signal_by_name(signal)
    return float(sig.minimum), float(sig.maximum)


def _data_id(arbitration_id: int) -> bytes:
    return arbitration_id.to_bytes(2, "little")


def encode(msg: Message) -> tuple[int, bytes]:
    """Frame for ``msg``; raises CodecError if a value is outside its DBC range."""
    cls = type(msg)
    fid = frame_id(cls, msg.board_id)
    signals = {name: getattr(msg, name) for name in _FIELDS[cls]}
    signals["counter"] &= 0xF
    signals["crc"] = 0
    if isinstance(msg, Status):
        faults = signals.pop("faults")
        signals.update({name: int(bool(faults & bit)) for name, bit in _FAULT_SIGNALS})
    try:
        data = bytearray(_SPECS[cls].encode(signals))
    except (cantools.database.EncodeError, ValueError, KeyError) as exc:
        raise CodecError(fid, f"cannot encode {msg}: {exc}") from exc
    data[0] = crc8_j1850(_data_id(fid) + bytes(data[1:]))
    return fid, bytes(data)


def decode(arbitration_id: int, data: bytes) -> Message:
    """Message in a frame; raises CodecError for foreign ids, wrong length or bad CRC."""
    entry = _BY_ID.get(arbitration_id)
    if entry is None:
        raise CodecError(arbitration_id, "not a PIMBS board frame id")
    cls, board = entry
    spec = _SPECS[cls]
    if len(data) != spec.length:
        raise CodecError(arbitration_id,
                         f"{cls.MESSAGE} has {len(data)} bytes, expected {spec.length}")
    if crc8_j1850(_data_id(arbitration_id) + bytes(data[1:])) != data[0]:
        raise CodecError(arbitration_id, f"{cls.MESSAGE} CRC mismatch (corrupted payload)")
    values = spec.decode(data, decode_choices=False)
    values.pop("crc")
    if cls is Status:
        faults = Fault(0)
        for name, bit in _FAULT_SIGNALS:
            if values.pop(name):
                faults |= bit
        values["faults"] = faults
    return cls(board_id=board, **values)
