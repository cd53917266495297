"""Which boards answer on a port: listen, and decode every frame with every known protocol.

The scan only listens: it sends nothing, so it is safe on a running arm. Boards report on
their own cycle (PIMBS v1 every 20 ms, even before they are configured; profile boards on
the cycle times of their DBC), so a second of listening finds every powered board. Each
frame is tried with PIMBS v1 first (its CRC makes a match certain), then the robot's own
profiles, then the shipped profiles, for board ids 0..31.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from types import SimpleNamespace

from pimbs_hw.protocol.board import BoardProtocol, CorruptFrame
from pimbs_hw.protocol.busload import frame_bits
from pimbs_hw.protocol.codec import MAX_BOARDS, Fault
from pimbs_hw.protocol.pimbs_v1 import PimbsV1
from pimbs_hw.protocol.profile import ProfileError, load_profile
from pimbs_hw.protocol.profiles import SHIPPED, is_cia402, muscle_protocol, profile_path
from pimbs_hw.transport.base import Transport


@dataclass
class BoardSeen:
    """One board heard on the bus."""

    protocol: str
    board_id: int
    frames: int = 0
    bad_frames: int = 0  # failed their checksum
    temperature_c: float | None = None
    faults: Fault = Fault(0)
    version: str | None = None
    muscle: str | None = None  # the robot description's muscle on this board, if any


@dataclass
class ScanResult:
    port: str
    seconds: float
    boards: dict[tuple[str, int], BoardSeen] = field(default_factory=dict)
    frames: int = 0
    unknown_frames: int = 0
    joint_frames: int = 0  # joint encoders (PIMBS v1 JOINT frames)
    bits: int = 0

    def bus_load(self, bitrate: float) -> float:
        """Fraction of a ``bitrate`` bus the heard traffic occupies (stuffing included)."""
        return self.bits / self.seconds / bitrate


def _any_board(b: int) -> SimpleNamespace:
    # scan shows temperature and faults, which need no calibration: unit scales suffice
    return SimpleNamespace(name=f"board {b}", board_id=b, counts_per_m=1.0,
                           loadcell_n_per_count=1.0, loadcell_offset_counts=0.0)


def scan_protocols(robot=None) -> list[tuple[BoardProtocol, dict[int, str]]]:
    """Decoders for every board id, with each decoder's board-index -> muscle name."""
    boards = [_any_board(b) for b in range(MAX_BOARDS)]
    names: dict[str, dict[int, str]] = {}
    profiles: list[str] = []
    for spec in (robot.muscles if robot is not None else ()):
        proto = muscle_protocol(spec)
        names.setdefault(proto, {})[spec.board_id] = spec.name
        if proto != "pimbs-v1" and proto not in profiles and not is_cia402(proto):  # CANopen
            # nodes are asked, not overheard: ``canopen_scan``
            profiles.append(proto)
    out: list[tuple[BoardProtocol, dict[int, str]]] = [
        (PimbsV1(range(MAX_BOARDS), boards, n_joints=MAX_BOARDS), names.get("pimbs-v1", {}))]
    for name in [*profiles, *(p for p in SHIPPED if p not in profiles)]:
        profile = load_profile(profile_path(name))
        for count in (64, MAX_BOARDS):  # ODrive node ids go to 63; other boards to 31
            try:
                out.append((profile.protocol(range(count), [_any_board(b) for b in range(
                    count)]), names.get(name, {})))
                break
            except ProfileError:
                continue
        else:  # ids collide across 32 boards: decode the robot's boards only
            ids = sorted(names.get(name, {}))
            if ids:
                out.append((load_profile(profile_path(name)).protocol(
                    range(len(ids)), [_any_board(b) for b in ids]), names[name]))
    return out


def scan_bus(transport: Transport, seconds: float = 1.0, robot=None,
             decoders: Sequence[tuple[BoardProtocol, dict[int, str]]] | None = None
             ) -> ScanResult:
    """Listen on ``transport`` for ``seconds`` and report every board heard."""
    decoders = decoders if decoders is not None else scan_protocols(robot)
    result = ScanResult(transport.port, seconds)
    end = time.monotonic() + seconds
    while (left := end - time.monotonic()) > 0:
        frame = transport.recv(left)
        if frame is None:
            continue
        result.frames += 1
        if frame.arbitration_id < 0x800 and len(frame.data) <= 8:
            result.bits += frame_bits(frame.arbitration_id, frame.data)
        for proto, muscles in decoders:
            try:
                decoded = proto.decode(frame.arbitration_id, frame.data)
            except CorruptFrame as bad:
                board = _seen(result, proto, bad.muscle, muscles)
                board.bad_frames += 1
                break
            if decoded:
                result.joint_frames += sum(u.joint for u in decoded)
                for u in (u for u in decoded if not u.joint):
                    board = _seen(result, proto, u.muscle, muscles)
                    board.frames += 1
                    if u.temperature_c is not None:
                        board.temperature_c = u.temperature_c
                    if u.faults is not None:
                        board.faults = u.faults
                    if u.version is not None:
                        board.version = u.version
                break
        else:
            result.unknown_frames += 1
    return result


def _seen(result: ScanResult, proto: BoardProtocol, index: int,
          muscles: dict[int, str]) -> BoardSeen:
    board_id = proto.board_ids[list(proto.indices).index(index)]
    key = (proto.name, board_id)
    if key not in result.boards:
        result.boards[key] = BoardSeen(proto.name, board_id, muscle=muscles.get(board_id))
    return result.boards[key]


def fault_names(faults: Fault) -> str:
    names = [f.name.lower() for f in Fault if faults & f]
    return ", ".join(names) if names else "none"
