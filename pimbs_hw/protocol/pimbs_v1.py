"""PIMBS board protocol v1 (PROTOCOL.md) behind the ``BoardProtocol`` seam.

Raw units stay here: encoder counts and loadcell counts are converted with each muscle's
calibration from the robot description (``counts_per_m``, ``loadcell_n_per_count``,
``loadcell_offset_counts``). JOINT frames (joint encoders) are decoded here too.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from pimbs_hw.protocol.board import (
    BoardLimits,
    BoardProtocol,
    Capabilities,
    CorruptFrame,
    RawFrame,
    Update,
)
from pimbs_hw.protocol.codec import (
    MESSAGE_TYPES,
    CodecError,
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

NAME = "pimbs-v1"
POSITION_RANGE = signal_range(PositionCommand, "position_counts")
RAW_RANGE = signal_range(TensionCommand, "loadcell_raw")
CAPABILITIES = Capabilities(board_watchdog=True, board_limits=True, temperature=True,
                            counter=True, checksum=True, configure=True)


class PimbsV1(BoardProtocol):
    """Muscles ``indices`` with descriptions ``specs`` (``MuscleSpec``), plus ``n_joints``
    joint encoders (JOINT frames) when the robot has them."""

    name = NAME
    capabilities = CAPABILITIES
    status_period_s = 0.02

    def __init__(self, indices: Sequence[int], specs: Sequence, n_joints: int = 0) -> None:
        super().__init__(indices, [s.board_id for s in specs])
        self.specs = {i: s for i, s in zip(indices, specs, strict=True)}
        self._by_board = {s.board_id: i for i, s in self.specs.items()}
        self.n_joints = n_joints
        self._counter = 0
        # direction -1: the encoder counts down as the wire pays out (see docs/boards.md)
        self.sign = {i: float(getattr(s, "direction", 1)) for i, s in self.specs.items()}

    # -- conversions -----------------------------------------------------------------------
    def raw(self, i: int, tension_n: float) -> int:
        """Loadcell counts for a tension; the rails (saturated) are never commanded."""
        s = self.specs[i]
        raw = np.rint(s.loadcell_offset_counts + tension_n / s.loadcell_n_per_count)
        return int(np.clip(raw, RAW_RANGE[0] + 1, RAW_RANGE[1] - 1))

    def position_range_m(self, i: int) -> tuple[float, float]:
        ends = sorted(self.sign[i] * v / self.specs[i].counts_per_m for v in POSITION_RANGE)
        return ends[0], ends[1]

    def ids_used(self, i: int) -> set[int]:
        board = self.specs[i].board_id
        return {frame_id(cls, board) for cls in MESSAGE_TYPES if cls is not JointStatus}

    def shared_ids(self) -> dict[str, set[int]]:
        if not self.n_joints:
            return {}
        return {"joint encoders": {frame_id(JointStatus, j) for j in range(self.n_joints)}}

    def _frame(self, msg: Message) -> RawFrame:
        self._counter = (self._counter + 1) & 0xF
        return encode(dataclasses.replace(msg, counter=self._counter))

    # -- the seam --------------------------------------------------------------------------
    def setup(self, i: int, limits: BoardLimits) -> list[RawFrame]:
        return [self._frame(SetLimits(self.specs[i].board_id, 0, limits.watchdog_s,
                                      self.raw(i, limits.tension_ceiling_n),
                                      self.raw(i, limits.relax_tension_n),
                                      limits.thermal_limit_c))]

    def command(self, i: int, kind: str, value: float = 0.0) -> list[RawFrame]:
        spec = self.specs[i]
        board = spec.board_id
        if kind == "relax":
            return [self._frame(Relax(board, 0))]
        if kind == "stop":
            return [self._frame(Stop(board, 0))]
        if kind == "tension":
            return [self._frame(TensionCommand(board, 0, self.raw(i, value)))]
        counts = np.rint(self.sign[i] * value * spec.counts_per_m)
        if not POSITION_RANGE[0] <= counts <= POSITION_RANGE[1]:
            raise ValueError(f"muscle {spec.name}: length {value:.4f} m is outside the encoder "
                             "range of the protocol")
        return [self._frame(PositionCommand(board, 0, int(counts)))]

    def decode(self, arbitration_id: int, data: bytes) -> list[Update]:
        try:
            msg = decode(arbitration_id, data)
        except CodecError as exc:
            i = self._by_board.get(board_of(arbitration_id))
            if i is not None and arbitration_id == frame_id(Status, self.specs[i].board_id):
                raise CorruptFrame(i, str(exc)) from exc
            return []
        if isinstance(msg, Status):
            i = self._by_board.get(msg.board_id)
            if i is None:
                return []
            s = self.specs[i]
            return [Update(i, position_m=self.sign[i] * msg.position_counts / s.counts_per_m,
                           tension_n=(msg.loadcell_raw - s.loadcell_offset_counts)
                           * s.loadcell_n_per_count,
                           temperature_c=msg.temperature_c, faults=msg.faults,
                           counter=msg.counter)]
        if isinstance(msg, JointStatus) and msg.board_id < self.n_joints:
            return [Update(msg.board_id, counter=msg.counter, joint=True,
                           angle_rad=msg.angle_rad)]
        return []
