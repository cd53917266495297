"""`pimbs import`: ROS 1 and ROS 2 logs of an arm moving between held poses -> one row per
held pose within the sensors' noise; clear errors for logs that do not fit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from pimbs_arm.model import ArmModel
from pimbs_cli.main import main
from pimbs_import.synthetic import LogSpec, write_log
from pimbs_recording.approach import BAND_M
from pimbs_recording.format import read_recording

ROBOT = "two-link-4-muscle"


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load(ROBOT)


def _log(tmp_path: Path, arm: ArmModel, fmt: str = "ros1", **spec) -> tuple[Path, object]:
    path = tmp_path / ("arm.bag" if fmt == "ros1" else f"arm_{fmt}")
    return path, write_log(path, arm, LogSpec(**spec), fmt)


def _import(log: Path, out: Path, *args: str, robot: str = ROBOT):
    return CliRunner().invoke(main, ["import", str(log), "--robot", robot, "--out", str(out),
                                     *args])


@pytest.mark.parametrize("fmt", ["ros1", "sqlite3", "mcap"])
def test_one_row_per_held_pose_within_the_noise(tmp_path, arm, fmt):
    log, truth = _log(tmp_path, arm, fmt, poses=6, seed=3)
    out = tmp_path / "imported.parquet"
    res = _import(log, out)
    assert res.exit_code == 0, res.output
    rec = read_recording(out)
    assert rec.n_rows == 6 and rec.source == "import"
    # means over >= 2.5 s of readings: far inside one reading's noise (theta 2e-4 rad,
    # tension 0.3 N, length 5 µm)
    assert np.abs(rec.theta - truth.theta).max() < 1e-4
    assert np.abs(rec.tension - truth.tension).max() < 0.15
    assert np.abs(rec.length - truth.length).max() < 2.5e-6
    np.testing.assert_allclose(rec.tau_gravity, arm.gravity_torque(rec.theta))
    # each row lies inside its hold, not on a ramp
    t = rec.time.astype("datetime64[ns]").astype(np.int64)
    for k, (start, stop) in enumerate(truth.hold_windows):
        assert start <= t[k] <= stop + 10_000_000
    # the approach: the direction of each muscle's motion from the previous pose
    previous = np.vstack([arm.length(np.zeros(2), np.full(4, 10.0)), truth.length[:-1]])
    moved = truth.length - previous
    big = np.abs(moved) > 2 * BAND_M
    assert big.any()
    np.testing.assert_array_equal(rec.approach[big], np.sign(moved[big]))
    meta = rec.meta
    assert meta["log"] == log.name and meta["mapping"]["channels"]["theta"]["topic"] == \
        "/joint_states"
    assert meta["temperature"] == "from the log" and 29 < rec.temperature.mean() < 32


def test_joint_states_split_over_two_publishers(tmp_path, arm):
    log, truth = _log(tmp_path, arm, poses=4, split_joints=True)
    out = tmp_path / "split.parquet"
    res = _import(log, out)
    assert res.exit_code == 0, res.output
    rec = read_recording(out)
    assert rec.n_rows == 4 and np.abs(rec.theta - truth.theta).max() < 1e-4


def test_without_temperatures_says_what_the_recording_holds(tmp_path, arm):
    log, _ = _log(tmp_path, arm, temperature=False, poses=3)
    out = tmp_path / "x.parquet"
    res = _import(log, out)
    assert res.exit_code == 0, res.output
    assert "temperature: absent from the log: every value is 25" in res.output
    assert "reading arm.bag: " in res.output and " messages" in res.output  # progress (log)
    rec = read_recording(out)
    assert (rec.temperature == 25.0).all() and "absent" in rec.meta["temperature"]


def test_mapping_selects_topics_fields_orders_scales_and_names(tmp_path, arm):
    """A lab's own conventions: joint names swapped, lengths published in mm from another
    zero, temperatures in reversed order; the mapping undoes each."""
    log, truth = _log(tmp_path, arm, poses=4, length_unit=1000.0, length_zero=0.25)
    mapping = tmp_path / "map.yaml"
    mapping.write_text(yaml.safe_dump({
        "theta": {"rename": {"shoulder_pitch": "elbow_pitch", "elbow_pitch": "shoulder_pitch"}},
        "length": {"scale": 0.001, "offset": [-0.25, -0.25, -0.25, -0.25]},
        "temperature": {"order": ["m3", "m2", "m1", "m0"]},
        "settle": {"min_hold": 1.0}}))
    out = tmp_path / "mapped.parquet"
    res = _import(log, out, "--map", str(mapping))
    assert res.exit_code == 0, res.output
    rec = read_recording(out)
    assert rec.n_rows == 4
    np.testing.assert_allclose(rec.theta, truth.theta[:, ::-1], atol=1e-4)
    np.testing.assert_allclose(rec.length, truth.length, atol=3e-6)
    assert rec.meta["mapping"]["clock"] == "log" and rec.meta["mapping"]["source"] == str(mapping)
    assert rec.meta["mapping"]["channels"]["temperature"]["order"] == ["m3", "m2", "m1", "m0"]


@pytest.mark.parametrize("mapping,message", [
    ({"tension": {"topic": "/loadcells"}},
     "no topic /loadcells for tension (the log has 3 topic(s): /joint_states "
     "(sensor_msgs/msg/JointState)"),
    ({"temperature": {"topic": "/joint_states"}},
     "topic /joint_states (temperature) has type sensor_msgs/msg/JointState, expected "
     "std_msgs/msg/Float64MultiArray"),
    ({"length": {"rename": {"m2": "biceps"}}},
     "has no element(s) ['m2'] of the robot in its 'name'"),
    ({"settle": {"min_hold": 60.0}}, "no held pose in"),
    ({"theta": {"field": "angle"}}, "has no field 'angle' for theta"),
    ({"tension": {"scale": [1, 2]}}, "tension.scale: 2 values for 4 elements"),
    ({"clock": "gps"}, "clock: 'gps'; use 'log'"),
])
def test_errors_name_the_log_the_topic_and_the_fix(tmp_path, arm, mapping, message):
    log, _ = _log(tmp_path, arm, poses=2)
    path = tmp_path / "map.yaml"
    path.write_text(yaml.safe_dump(mapping))
    res = _import(log, tmp_path / "x.parquet", "--map", str(path))
    assert res.exit_code == 1, res.output
    assert message in res.output and "Traceback" not in res.output
    error = res.output.strip().splitlines()[-1]  # (progress lines before it)
    assert error.startswith("Error: ") and message in error
    assert not (tmp_path / "x.parquet").exists()


def test_log_of_another_robot_is_refused_by_name(tmp_path, arm):
    log, _ = _log(tmp_path, arm, poses=2)
    res = _import(log, tmp_path / "x.parquet", robot="left-arm-5dof")
    assert res.exit_code == 1
    assert "has no element(s)" in res.output and "of the robot in its 'name'" in res.output
    assert "rename" in res.output


def test_not_a_log_and_existing_output(tmp_path, arm):
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"not a bag")
    res = _import(junk, tmp_path / "x.parquet")
    assert res.exit_code == 1 and f"{junk}: not a readable ROS 1 .bag" in res.output
    log, _ = _log(tmp_path, arm, poses=2)
    (tmp_path / "x.parquet").write_bytes(b"keep me")
    res = _import(log, tmp_path / "x.parquet")
    assert res.exit_code == 1 and "--force" in res.output
    assert (tmp_path / "x.parquet").read_bytes() == b"keep me"


def test_imported_recording_trains(tmp_path, arm):
    log, _ = _log(tmp_path, arm, poses=12, hold_s=1.0, ramp_s=0.5)
    out = tmp_path / "imp.parquet"
    assert _import(log, out).exit_code == 0
    res = CliRunner().invoke(main, ["train", str(out), "--n-train", "10", "--epochs", "20",
                                    "--threads", "1", "--out", str(tmp_path / "model")])
    assert res.exit_code == 0, res.output


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "cdr"])
def test_bulk_decoding_agrees_with_rosbags(ros1):
    """The fast path reads what rosbags reads, also for mixed layouts (frame ids, names, array
    lengths that change from message to message)."""
    from rosbags.typesys import Stores, get_typestore

    from pimbs_import.fastdecode import FastDecoder

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    T = store.types
    rng = np.random.default_rng(1)
    raws, expect = [], []
    for i in range(60):
        names = ["a", "bb", "ccc"][: 1 + i % 3]
        stamp = T["builtin_interfaces/msg/Time"](sec=1000 + i, nanosec=7 * i)
        header = (T["std_msgs/msg/Header"](seq=i, stamp=stamp, frame_id="f" * (i % 4))
                  if ros1 else T["std_msgs/msg/Header"](stamp=stamp, frame_id="f" * (i % 4)))
        msg = T["sensor_msgs/msg/JointState"](
            header=header, name=names, position=rng.normal(size=len(names)),
            velocity=np.zeros(0), effort=rng.normal(size=len(names) if i % 5 else 0))
        serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
        raws.append(bytes(serialize(msg, "sensor_msgs/msg/JointState")))
        expect.append(msg)
    for max_layouts in (32, 3):  # 3: most messages decoded one by one
        seen = set()
        for batch in FastDecoder().decode_many(raws, "sensor_msgs/msg/JointState", not ros1,
                                               max_layouts=max_layouts):
            for k, i in enumerate(batch.rows):
                seen.add(int(i))
                assert batch.name == tuple(expect[i].name)
                for field in ("position", "velocity", "effort"):
                    np.testing.assert_array_equal(batch.fields[field][k],
                                                  getattr(expect[i], field))
                assert batch.stamp_ns[k] == (1000 + i) * 1_000_000_000 + 7 * i
        assert seen == set(range(60))
    arr = store.types["std_msgs/msg/Float64MultiArray"](
        layout=store.types["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0),
        data=np.array([1.5, -2.0, 3.25]))
    raw = bytes((store.serialize_ros1 if ros1 else store.serialize_cdr)(
        arr, "std_msgs/msg/Float64MultiArray"))
    (batch,) = FastDecoder().decode_many([raw], "std_msgs/msg/Float64MultiArray", not ros1)
    np.testing.assert_array_equal(batch.fields["data"][0], [1.5, -2.0, 3.25])
