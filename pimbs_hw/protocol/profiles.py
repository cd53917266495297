"""Which ``BoardProtocol`` drives each muscle: the robot description names a profile.

A muscle's ``protocol`` (in the ``.muscles.yaml``, per muscle or under ``defaults``) is
``pimbs-v1`` (the default), a shipped profile name (``odrive-cansimple``), or a path to a
lab's own profile file (``*.profile.yaml``: its ``.dbc`` plus the mapping, see
``profile.py``), or a path to a CiA 402 drive file (``*.cia402.yaml``: the drive's EDS and
which objects carry what, see ``cia402_config.py``; node id = ``board_id``). Muscles with
the same profile share one protocol object.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from pimbs_hw.protocol.board import BoardProtocol
from pimbs_hw.protocol.ids import check_ids
from pimbs_hw.protocol.pimbs_v1 import NAME as V1
from pimbs_hw.protocol.pimbs_v1 import PimbsV1

PROFILE_DIR = resources.files("pimbs_hw.protocol") / "profiles"
SHIPPED = ("odrive-cansimple",)


def profile_path(name: str) -> Path:
    """The profile file a ``protocol`` value names (a shipped name or a path)."""
    if name in SHIPPED:
        return Path(str(PROFILE_DIR / f"{name}.profile.yaml"))
    return Path(name)


def is_cia402(name: str) -> bool:
    """Whether a ``protocol`` value names a CiA 402 drive file."""
    return name.endswith(".cia402.yaml")


def muscle_protocol(spec) -> str:
    return getattr(spec, "protocol", None) or V1


def protocols_for(robot) -> list[BoardProtocol]:
    """One protocol object per distinct profile of ``robot``'s muscles; a robot whose
    boards' CAN ids collide is refused (``ids.IdCollision``)."""
    from pimbs_hw.protocol.profile import load_profile

    groups: dict[str, list[int]] = {}
    for i, spec in enumerate(robot.muscles):
        groups.setdefault(muscle_protocol(spec), []).append(i)
    protocols: list[BoardProtocol] = []
    n_joints = len(robot.joints) if robot.joint_encoders else 0
    for name, indices in groups.items():
        specs = [robot.muscles[i] for i in indices]
        if name == V1:
            protocols.append(PimbsV1(indices, specs, n_joints))
            n_joints = 0
        elif is_cia402(name):
            from pimbs_hw.protocol.cia402 import Cia402Protocol
            from pimbs_hw.protocol.cia402_config import load_drive_file

            protocols.append(Cia402Protocol(indices, specs, load_drive_file(name)))
        else:
            protocols.append(load_profile(profile_path(name)).protocol(indices, specs))
    if n_joints:  # joint encoders speak v1 JOINT frames whatever the muscle boards speak
        protocols.append(PimbsV1([], [], n_joints))
    check_ids(robot, protocols)
    return protocols
