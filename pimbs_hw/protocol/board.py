"""The seam between the arm driver and a board protocol: commands and status as plain data.

The driver (``pimbs_hw.driver``) knows muscles, SI units and safety; a ``BoardProtocol``
knows frames. Per muscle the driver asks for the frames of a ``length``/``tension``/
``relax``/``stop`` command, and hands every received frame to ``decode``, which answers
with ``Update``s: position [m], tension [N], temperature [°C], faults, a rolling counter.
Everything safety needs (watchdog feeding, ceilings, derate, relax on exit, silent-board
and stale-data detection) stays above the seam and works for every protocol; what a
protocol cannot do is declared in ``Capabilities`` and covered on the host.

Implementations: ``pimbs_v1.PimbsV1`` (the PIMBS board of PROTOCOL.md),
``profile.ProfileProtocol`` (any CAN board described by its ``.dbc`` and a mapping file,
e.g. the shipped ODrive CANSimple profile) and ``cia402.Cia402Protocol`` (CiA 402 servo
drives over CANopen, configured by request and answer in ``connect``, from their EDS).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass

from pimbs_hw.protocol.codec import Fault
from pimbs_hw.safety import SafetyStop

COMMAND_KINDS = ("length", "tension", "relax", "stop")
RawFrame = tuple[int, bytes]


@dataclass(frozen=True)
class Capabilities:
    """What the boards of a protocol do by themselves (the host covers the rest)."""

    board_watchdog: bool  # relaxes the muscle when commands stop (a hung host)
    board_limits: bool  # enforces a tension ceiling and a thermal limit on its own
    temperature: bool  # reports a temperature
    counter: bool  # status carries a rolling counter: loss and repeats by counter gaps
    checksum: bool  # payload checksum: corruption is seen per board
    configure: bool  # the host must configure a board before it moves (v1 SET_LIMITS)
    version: bool = False  # reports a firmware version (shown by ``pimbs scan``)

    def gaps(self) -> list[str]:
        """Plain-language list of what the host covers because the boards do not."""
        notes = {
            "board_watchdog": "no board-side watchdog: a hung host is not relaxed by the "
                              "boards; the host relaxes on every exit it lives through",
            "board_limits": "no board-side tension/thermal limit: the host clamps every "
                            "command and stops on a reading above the ceiling",
            "temperature": "no temperature: no thermal derate or overheat stop",
            "counter": "no rolling counter: frame loss is judged from the arrival rate (over 2 s) "
                       "against the message cycle time",
            "checksum": "no payload checksum beyond CAN's own CRC: corruption shows as CAN "
                        "error frames (or, behind an adapter that hides them, as lost frames)",
        }
        return [text for name, text in notes.items() if not getattr(self, name)]


@dataclass(frozen=True)
class BoardLimits:
    """Limits the host sends at start-up (protocols that can take them), SI units."""

    watchdog_s: float
    tension_ceiling_n: float
    relax_tension_n: float
    thermal_limit_c: float


@dataclass(frozen=True)
class Update:
    """News from one frame about one muscle (``muscle`` = index in the arm's order).

    Only the fields the frame carries are set. ``joint`` updates carry ``angle_rad`` for
    joint ``muscle`` (the joint's column index) instead.
    """

    muscle: int
    position_m: float | None = None  # encoder, in the protocol's own zero (driver zeroes)
    tension_n: float | None = None
    temperature_c: float | None = None
    faults: Fault | None = None
    counter: int | None = None
    saturated: bool = False  # a reading at its rail: the value is not a measurement
    version: str | None = None
    joint: bool = False
    angle_rad: float | None = None
    state: int | None = None  # the board's own state (boards with a state machine)
    error_code: int | None = None  # the board's raw error word, as it reported it
    # a protocol that reads its device's own state (CiA 402) names the stop it calls for
    # and what the device reported; the driver raises it like its own limit stops
    stop: type[SafetyStop] | None = None
    note: str | None = None


class CorruptFrame(ValueError):
    """A frame addressed to one of our boards that failed its checksum or length."""

    def __init__(self, muscle: int, reason: str) -> None:
        self.muscle = muscle
        super().__init__(reason)


class BoardProtocol(ABC):
    """Frames for the muscles ``indices`` (positions in the arm's muscle order)."""

    name: str
    capabilities: Capabilities
    status_period_s: float  # how often a board reports unprompted

    def __init__(self, indices: Sequence[int], board_ids: Sequence[int]) -> None:
        self.indices = tuple(indices)
        self.board_ids = tuple(board_ids)

    def connect(self, transport, limits: Sequence[BoardLimits]) -> None:
        """Configure the boards by request and answer before the first ``setup`` round
        (CANopen SDO); ``limits`` per muscle of ``indices``. Frame protocols need nothing."""
        return None

    @abstractmethod
    def setup(self, i: int, limits: BoardLimits) -> list[RawFrame]:
        """Frames that configure muscle ``i``'s board (repeated until it answers)."""

    def configured(self, faults: Fault) -> bool:
        """Whether a board with these fault bits has taken its configuration."""
        return not faults & Fault.UNCONFIGURED

    @abstractmethod
    def command(self, i: int, kind: str, value: float = 0.0) -> list[RawFrame]:
        """Frames for one command to muscle ``i``: ``length`` m, ``tension`` N, ``relax``
        (the board's low pre-tension) or ``stop`` (hold the current length).

        Raises ``ValueError`` naming the muscle when the value cannot be encoded.
        """

    @abstractmethod
    def decode(self, arbitration_id: int, data: bytes) -> list[Update]:
        """Updates in a received frame ([] when it is not for these boards); raises
        ``CorruptFrame`` for a frame of ours that fails its checksum."""

    def position_range_m(self, i: int) -> tuple[float, float]:
        """Encoder range a length command must stay in (protocol's own zero)."""
        return (-float("inf"), float("inf"))

    def describe(self) -> str:
        return self.name

    def ids_used(self, i: int) -> set[int]:
        """Every CAN id muscle ``i``'s board sends or listens to (collisions are refused)."""
        return set()

    def shared_ids(self) -> dict[str, set[int]]:
        """Ids this protocol uses that belong to no muscle (e.g. joint encoders), by owner."""
        return {}

    # boards with a state machine (ODrive: IDLE / CLOSED_LOOP_CONTROL) must report their
    # armed state before the host commands them; others are always ready
    has_state = False

    def armed(self, state: int | None) -> bool:
        """Whether a board reporting ``state`` takes commands."""
        return True

    def state_text(self, state: int | None, error: int | None) -> str:
        """The state and error as the board reported them, by the device's own names."""
        return ""
    def not_relaxed(self) -> list[str]:
        """Boards that reported a state in which a relax cannot reach them (a drive in
        Fault), each with what it reported; [] where the protocol cannot tell."""
        return []

    def unreachable(self, watchdog_s: float) -> str:
        """What these boards do when the host cannot reach them any more (the end state)."""
        return f"{self.name} boards: relaxed by their own watchdog within {watchdog_s:g} s"

    def close(self) -> None:
        """The host is leaving and has sent its last relax; the transport closes next
        (CANopen: the SYNC that applies synchronous RPDOs stops after one more)."""
        return None
