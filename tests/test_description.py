"""Robot descriptions: built-ins load, and every kind of mistake names the file and the field."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from pimbs_calibration.description import (
    DescriptionError,
    MuscleSpec,
    RobotDescription,
    builtin_robots,
    load_robot,
)

ROBOTS = Path(__file__).resolve().parents[1] / "calibration" / "robots"


def test_builtin_robots_load():
    assert builtin_robots() == ["two-link-4-muscle", "left-arm-5dof"]
    two = load_robot("two-link-4-muscle")
    assert isinstance(two, RobotDescription)
    assert two.joints == ("shoulder_pitch", "elbow_pitch")
    np.testing.assert_array_equal(two.joint_range, [[-0.5, 0.5], [-0.5, 0.5]])
    assert [m.name for m in two.muscles] == ["m0", "m1", "m2", "m3"]
    assert two.joint_encoders is True
    arm5 = load_robot("left-arm-5dof")
    assert arm5.joints == ("shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow_pitch",
                           "forearm_yaw")
    assert [m.name for m in arm5.muscles] == [f"m{i}" for i in range(10)]
    assert arm5.joint_encoders is False
    for robot in (two, arm5):
        assert robot.joint_range.shape == (len(robot.joints), 2)
        assert len({m.board_id for m in robot.muscles}) == len(robot.muscles)
        for m in robot.muscles:
            assert isinstance(m, MuscleSpec) and m.K == 1000.0 and m.f_floor < m.f_max
            assert all(v.point.shape == (3,) for v in m.path)


def test_builtin_found_from_any_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert load_robot("two-link-4-muscle").urdf_path.is_file()


def test_load_by_path_resolves_urdf_next_to_muscle_file(tmp_path):
    robot = _copy_robot(tmp_path)
    loaded = load_robot(robot)
    assert loaded.urdf_path == (tmp_path / "two-link-4-muscle.urdf").resolve()
    assert loaded.muscle_path == robot.resolve()
    assert [m.name for m in loaded.muscles] == ["m0", "m1", "m2", "m3"]


def test_unknown_robot_name():
    with pytest.raises(DescriptionError, match="no such built-in robot"):
        load_robot("three-link-robot")


def _copy_robot(tmp_path: Path) -> Path:
    for name in ("two-link-4-muscle.urdf", "two-link-4-muscle.muscles.yaml"):
        shutil.copy(ROBOTS / name, tmp_path / name)
    return tmp_path / "two-link-4-muscle.muscles.yaml"


def _muscle(raw, i):
    return raw["muscles"][i]


def _set_defaults_k(raw, value):
    raw["defaults"]["K"] = value


def _drop(mapping, key):
    del mapping[key]


# Each case: (id, mutation of the parsed YAML, field the message must name)
BROKEN = [
    ("missing-board-id", lambda r: _drop(_muscle(r, 0), "board_id"), "muscles[0].board_id"),
    ("missing-K", lambda r: _drop(r["defaults"], "K"), "muscles[0].K"),
    ("missing-muscles", lambda r: _drop(r, "muscles"), "muscles"),
    ("missing-urdf", lambda r: _drop(r, "urdf"), "urdf"),
    ("unknown-link", lambda r: _muscle(r, 1)["path"][0].update(link="shin"),
     "muscles[1].path[0].link"),
    ("joint-not-in-urdf", lambda r: r["joints"][0].update(name="wrist"), "joints[0].name"),
    ("no-joints", lambda r: r.update(joints=[]), "joints"),
    ("lock-unknown-joint", lambda r: r.update(lock={"wrist": 0.1}), "lock.wrist"),
    ("lock-driven-joint", lambda r: r.update(lock={"elbow_pitch": 0.1}), "lock.elbow_pitch"),
    ("lock-outside-limits", lambda r: (r["joints"].pop(), r.update(lock={"elbow_pitch": 3.0})),
     "lock.elbow_pitch"),
    ("duplicate-joint", lambda r: r["joints"][1].update(name="shoulder_pitch"),
     "joints[1].name"),
    ("negative-K", lambda r: _set_defaults_k(r, -5.0), "muscles[0].K"),
    ("text-K", lambda r: _muscle(r, 2).update(K="stiff"), "muscles[2].K"),
    ("duplicate-board-id", lambda r: _muscle(r, 3).update(board_id=1), "muscles[3].board_id"),
    ("duplicate-name", lambda r: _muscle(r, 1).update(name="m0"), "muscles[1].name"),
    ("range-outside-limits", lambda r: r["joints"][0].update(range=[-2.0, 0.5]),
     "joints[0].range"),
    ("range-reversed", lambda r: r["joints"][1].update(range=[0.5, -0.5]), "joints[1].range"),
    ("one-via-point", lambda r: _muscle(r, 0).update(path=_muscle(r, 0)["path"][:1]),
     "muscles[0].path"),
    ("path-crosses-no-joint", lambda r: _muscle(r, 0).update(
        path=[{"link": "upper_arm", "point": [0.0, 0.0, -0.1]},
              {"link": "upper_arm", "point": [0.0, 0.0, -0.2]}]), "muscles[0].path"),
    ("point-not-3d", lambda r: _muscle(r, 0)["path"][0].update(point=[0.0, 0.1]),
     "muscles[0].path[0].point"),
    ("floor-above-ceiling", lambda r: _muscle(r, 0).update(f_floor=700.0), "muscles[0].f_floor"),
    ("encoders-not-bool", lambda r: r.update(joint_encoders="yes"), "joint_encoders"),
]


@pytest.mark.parametrize("mutate,field", [c[1:] for c in BROKEN], ids=[c[0] for c in BROKEN])
def test_broken_description_names_file_and_field(tmp_path, mutate, field):
    path = _copy_robot(tmp_path)
    raw = yaml.safe_load(path.read_text())
    mutate(raw)
    path.write_text(yaml.safe_dump(raw))
    with pytest.raises(DescriptionError) as err:
        load_robot(path)
    message = str(err.value)
    assert str(path) in message and f"field '{field}'" in message
    assert err.value.field == field


def test_unreadable_urdf(tmp_path):
    path = _copy_robot(tmp_path)
    (tmp_path / "two-link-4-muscle.urdf").write_text("<robot name='x'><link name=")
    with pytest.raises(DescriptionError, match="field 'urdf'.*cannot parse URDF") as err:
        load_robot(path)
    assert str(path) in str(err.value)


def test_urdf_file_missing(tmp_path):
    path = _copy_robot(tmp_path)
    (tmp_path / "two-link-4-muscle.urdf").unlink()
    with pytest.raises(DescriptionError, match="field 'urdf'.*not found"):
        load_robot(path)


def test_bad_yaml_syntax(tmp_path):
    path = tmp_path / "bad.muscles.yaml"
    path.write_text("robot: [unclosed\n")
    with pytest.raises(DescriptionError, match="cannot read YAML") as err:
        load_robot(path)
    assert str(path) in str(err.value)


def test_descriptions_compare_by_value_and_are_read_only():
    a, b = load_robot("left-arm-5dof"), load_robot("left-arm-5dof")
    assert a == b and a != load_robot("two-link-4-muscle")
    assert hash(a.muscles[0]) == hash(b.muscles[0])
    with pytest.raises(ValueError, match="read-only"):
        a.joint_range[0, 0] = 1.0
    with pytest.raises(ValueError, match="read-only"):
        a.muscles[0].path[0].point[0] = 1.0
