"""CAN-id collisions between the boards of one robot, refused when the robot is loaded.

Every protocol declares the ids each board owns (``BoardProtocol.ids_used``: a PIMBS v1
board its message ids, an ODrive node its whole block ``node_id << 5 | 0..31``) and the ids
it uses for no muscle (``shared_ids``: the joint encoders' 0x240 + j). Two owners with a
common id would read each other's frames as their own, or command the wrong motor, so a
robot whose id sets intersect never reaches the bus.
"""

from __future__ import annotations

from collections.abc import Sequence

from pimbs_hw.protocol.board import BoardProtocol

MAX_STANDARD_ID = 0x7FF  # 11-bit CAN identifiers


class IdCollision(ValueError):
    """Two boards of a robot use the same CAN id (one line: both boards, the ids)."""


def _ids(ids: set[int]) -> str:
    shown = sorted(ids)
    text = ", ".join(f"0x{i:03X}" for i in shown[:6])
    return text + (f" and {len(shown) - 6} more" if len(shown) > 6 else "")


def _fewer_boards(robot) -> str:
    """What to do about a board id out of the protocol's range."""
    if robot.mjcf_path is not None and robot.muscle_path == robot.mjcf_path:
        return (f"an MJCF's tendons get boards 1, 2, ... in file order: write a muscle file "
                f"naming {robot.mjcf_path.name} ('mjcf:') that lists the tendons on this bus "
                "under 'muscles' with their board_id")
    return f"give it a board_id in range in {robot.muscle_path.name}"


def check_ids(robot, protocols: Sequence[BoardProtocol]) -> None:
    """Raise ``IdCollision`` naming both boards and the ids they share."""
    owners: list[tuple[str, set[int]]] = []
    for proto in protocols:
        for i in proto.indices:
            spec = robot.muscles[i]
            owner = f"muscle {spec.name} (board {spec.board_id}, {proto.name})"
            try:
                ids = proto.ids_used(i)
            except ValueError as exc:  # a board id the protocol has no CAN ids for
                raise IdCollision(f"{robot.muscle_path}: {owner}: {exc}, so one bus carries "
                                  f"no such board ({len(robot.muscles)} muscles here); "
                                  f"{_fewer_boards(robot)}") from exc
            if ids and max(ids) > MAX_STANDARD_ID:
                raise IdCollision(f"{robot.name}: {owner} would use CAN ids up to "
                                  f"0x{max(ids):X}, beyond the 11-bit 0x7FF; give it a lower "
                                  f"board_id (ODrive node ids are 0-63)")
            owners.append((owner, ids))
        for what, ids in proto.shared_ids().items():  # (two drive files share NMT/SYNC)
            if (f"{what} ({proto.name})", ids) not in owners:
                owners.append((f"{what} ({proto.name})", ids))
    for a, (name_a, ids_a) in enumerate(owners):
        for name_b, ids_b in owners[a + 1:]:
            if common := ids_a & ids_b:
                raise IdCollision(f"{robot.name}: {name_a} and {name_b} both use CAN id(s) "
                                  f"{_ids(common)}; change a board_id in {robot.muscle_path.name}"
                                  " so that their ids differ")
