"""Robot descriptions exactly as public description packages ship them (example-robot-data:
Panda, UR, TALOS, Solo, …). Most are xacro output: the root declares ``xmlns:xacro`` and
commented-out xacro lines remain. They are URDFs and must load; live xacro must not."""

from __future__ import annotations

import importlib.metadata
from pathlib import Path

import pytest
import yaml

from pimbs_arm.model import ArmModel
from pimbs_calibration.description import DescriptionError, load_robot
from pimbs_calibration.xacro_check import live_xacro


def _shipped_robots() -> Path:
    dist = importlib.metadata.distribution("example-robot-data")
    return Path(str(dist.locate_file("cmeel.prefix/share/example-robot-data/robots")))


ROBOTS = _shipped_robots()
URDFS = sorted(ROBOTS.rglob("*.urdf"))
PANDA = ROBOTS / "panda_description" / "urdf" / "panda.urdf"


def test_the_shipped_set_is_xacro_output():
    """The premise: the package ships dozens of URDFs and most declare the xacro namespace."""
    assert len(URDFS) > 30
    declared = [p for p in URDFS if "xmlns:xacro" in p.read_text(errors="replace")]
    assert len(declared) > len(URDFS) // 3


@pytest.mark.parametrize("urdf", URDFS, ids=lambda p: p.relative_to(ROBOTS).as_posix())
def test_no_shipped_urdf_is_taken_for_xacro(urdf: Path):
    assert live_xacro(urdf.read_text(errors="replace")) is None


def test_shipped_xacro_sources_are_still_refused():
    sources = sorted(ROBOTS.rglob("*.xacro"))
    assert sources, "example-robot-data ships xacro sources"
    live = [p for p in sources if live_xacro(p.read_text(errors="replace")) is not None]
    assert live, "at least one shipped .xacro holds live macros"


def test_xacro_in_comments_and_the_namespace_are_not_live():
    text = ('<?xml version="1.0"?>\n<robot xmlns:xacro="http://www.ros.org/wiki/xacro" n="a">\n'
            '<!-- <xacro:include filename="$(find arm)/x.xacro"/> ${pi/2} -->\n</robot>\n')
    assert live_xacro(text) is None
    assert live_xacro(text.replace("</robot>", '<xacro:property name="r" value="1"/></robot>')
                      ) == "a <xacro:property> element on line 4"
    assert live_xacro(text.replace("</robot>", '<link name="${prefix}l"/></robot>')
                      ).startswith("a ${…} expression on line 4")


def test_panda_as_shipped_drives_a_muscle_arm(tmp_path):
    """The Panda URDF, unchanged, referenced by a muscle file: its elbow driven by a pair of
    muscles, every other joint locked."""
    muscles = {
        "robot": "panda-elbow",
        "urdf": str(PANDA),
        "joint_encoders": True,
        "joints": [{"name": "panda_joint4", "range": [-2.0, -1.0]}],
        "defaults": {"K": 1000.0, "f_max": 600.0, "f_floor": 10.0,
                     "counts_per_m": 108650.0, "loadcell_n_per_count": 0.25,
                     "loadcell_offset_counts": 2048.0},
        "muscles": [
            {"name": "flexor", "board_id": 1, "path": [
                {"link": "panda_link3", "point": [0.05, 0.0, 0.0]},
                {"link": "panda_link4", "point": [0.05, 0.0, 0.0]}]},
            {"name": "extensor", "board_id": 2, "path": [
                {"link": "panda_link3", "point": [-0.05, 0.0, 0.0]},
                {"link": "panda_link4", "point": [-0.05, 0.0, 0.0]}]},
        ],
    }
    path = tmp_path / "panda.muscles.yaml"
    path.write_text(yaml.safe_dump(muscles))
    try:
        robot = load_robot(path)
    except DescriptionError as err:  # a refusal must never be about xacro
        assert "xacro" not in str(err)
        raise
    assert robot.urdf_path == PANDA.resolve()
    arm = ArmModel(robot)  # pinocchio builds the reduced model; both ways drivable
    G = arm.muscle_jacobian([-1.5])
    assert G.shape == (2, 1) and G[0, 0] * G[1, 0] < 0  # the pair pulls opposite ways
