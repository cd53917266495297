"""`pimbs import` on logs as they come from other labs and other tools: bags without message
definitions, damaged bags, files that are not bags, bags with many topics, single-value
fields, mappings that do not fit, and readings the robot cannot have.

Every bag is written here with ``rosbags``' own writers. Every refusal is one line that names
the log (and the topic and field where there is one) and what to do, with exit status 1 and
nothing written next to the output.
"""

from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from pimbs_arm.model import ArmModel
from pimbs_cli.main import main
from pimbs_import.synthetic import LogSpec, write_log, write_messages
from pimbs_recording.format import read_recording

ROBOT = "two-link-4-muscle"
START_NS = 1_760_000_000_000_000_000
TEMPS_MSG = "float64[] celsius\nuint32 sensor_count\n"  # a lab's own message type
TEMPS_TYPE = "lab_msgs/msg/MuscleTemperatures"


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load(ROBOT)


def _store(fmt: str):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(TEMPS_MSG, TEMPS_TYPE))
    return store


def _log_path(tmp_path: Path, fmt: str, name: str = "arm") -> Path:
    return tmp_path / (f"{name}.bag" if fmt == "ros1" else f"{name}_{fmt}")


def _joint_state(store, fmt: str, ns: int, names, position, effort=()):
    T = store.types
    stamp = T["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000,
                                            nanosec=ns % 1_000_000_000)
    header = (T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id="") if fmt == "ros1"
              else T["std_msgs/msg/Header"](stamp=stamp, frame_id=""))
    return T["sensor_msgs/msg/JointState"](
        header=header, name=list(names), position=np.asarray(position, dtype=np.float64),
        velocity=np.zeros(0), effort=np.asarray(effort, dtype=np.float64))


def _held_log(path: Path, fmt: str, arm: ArmModel, theta: np.ndarray, tension: np.ndarray,
              *, hold_s: float = 1.2, rate: float = 50.0, theta_topic: str = "joints",
              header_back_s: float | None = None, nan_tension: int = 0,
              compression: str | None = None) -> None:
    """A log of ``arm`` holding each pose ``theta[k]`` at ``tension[k]`` for ``hold_s``
    (jumping between them): ``/joint_states`` and ``/muscle_states`` as JointState, or the
    single joint's angle as ``std_msgs/Float64`` on ``/shoulder_angle`` (``theta_topic``
    "float64"). ``header_back_s`` sets the joint-state header clock back by that much once,
    half-way; ``nan_tension`` readings of m1 are NaN."""
    store = _store(fmt)
    T = store.types
    per = int(hold_s * rate)
    messages = []
    for k, (th, f) in enumerate(zip(theta, tension, strict=True)):
        length = arm.length(th, np.maximum(f, 0.0))
        for i in range(per):
            n = k * per + i
            ns = START_NS + int(n * 1e9 / rate)
            stamp = ns
            if header_back_s is not None and n >= len(theta) * per // 2:
                stamp -= int(header_back_s * 1e9)
            if theta_topic == "float64":
                messages.append((ns, "/shoulder_angle", "std_msgs/msg/Float64",
                                 T["std_msgs/msg/Float64"](data=float(th[0]))))
            else:
                messages.append((ns, "/joint_states", "sensor_msgs/msg/JointState",
                                 _joint_state(store, fmt, stamp, arm.joints, th)))
            effort = f.copy()
            if n < nan_tension:
                effort[1] = np.nan
            messages.append((ns + 1000, "/muscle_states", "sensor_msgs/msg/JointState",
                             _joint_state(store, fmt, ns + 1000, arm.muscles, length, effort)))
    write_messages(path, fmt, store, messages, compression)


def _strip_definitions(bag: Path) -> None:
    """Make a rosbags-written sqlite3 bag look like one recorded before ROS Iron: no
    message_definitions table (database schema 3), metadata version 5 without type hashes."""
    (db,) = bag.glob("*.db3")
    with sqlite3.connect(db) as con:
        con.execute("DROP TABLE message_definitions")
        con.execute("UPDATE schema SET schema_version = 3")
    meta_path = bag / "metadata.yaml"
    meta = yaml.safe_load(meta_path.read_text())
    info = meta["rosbag2_bagfile_information"]
    info["version"] = 5
    for topic in info["topics_with_message_count"]:
        topic["topic_metadata"].pop("type_description_hash", None)
    meta_path.write_text(yaml.safe_dump(meta))


def _import(log: Path, out: Path, *args: str, robot: str = ROBOT):
    return CliRunner().invoke(main, ["import", str(log), "--robot", robot, "--out", str(out),
                                     *args])


def _refused(res, folder: Path, before: set[Path], *parts: str) -> str:
    """The one error line of a refused import; checks exit status 1, no traceback, each of
    ``parts`` in that line, and nothing added to or removed from ``folder``."""
    assert res.exit_code == 1, res.output
    # a clean exit (click's SystemExit), not an exception that escaped the command
    assert isinstance(res.exception, SystemExit), repr(res.exception)
    assert "Traceback" not in res.output
    errors = [line for line in res.output.splitlines() if line.startswith("Error")]
    assert len(errors) == 1, res.output
    line = errors[0]
    assert res.output.rstrip().endswith(line)
    for part in parts:
        assert part in line, (part, line)
    assert set(folder.iterdir()) == before, "an import that was refused left files behind"
    return line


def _map(tmp_path: Path, mapping: dict) -> Path:
    path = tmp_path / "map.yaml"
    path.write_text(yaml.safe_dump(mapping))
    return path


def _one_joint_robot(tmp_path: Path) -> Path:
    """The two-link URDF driven at its shoulder only, by the shoulder's muscle pair."""
    from importlib.resources import files

    robots = files("pimbs_calibration") / "robots"
    folder = tmp_path / "robot"
    folder.mkdir()
    (folder / "two-link-4-muscle.urdf").write_text(
        (robots / "two-link-4-muscle.urdf").read_text())
    desc = yaml.safe_load((robots / "two-link-4-muscle.muscles.yaml").read_text())
    desc["robot"] = "one-joint"
    desc["joints"] = desc["joints"][:1]
    desc["muscles"] = desc["muscles"][:2]
    path = folder / "one-joint.muscles.yaml"
    path.write_text(yaml.safe_dump(desc))
    return path


# --- logs that are not what they seem -------------------------------------------------------

def test_ros2_bag_without_message_definitions_imports(tmp_path, arm):
    """Bags recorded before ROS Iron hold no message definitions; the standard types are
    known anyway."""
    from rosbags.highlevel import AnyReader, AnyReaderError

    log = _log_path(tmp_path, "sqlite3")
    truth = write_log(log, arm, LogSpec(poses=3, hold_s=1.5, ramp_s=0.5), "sqlite3")
    _strip_definitions(log)
    with pytest.raises(AnyReaderError, match="no type definitions"):  # really without them
        AnyReader([log]).open()
    out = tmp_path / "x.parquet"
    res = _import(log, out)
    assert res.exit_code == 0, res.output
    rec = read_recording(out)
    assert rec.n_rows == 3 and np.abs(rec.theta - truth.theta).max() < 2e-4
    info = CliRunner().invoke(main, ["info", str(out)])
    assert info.exit_code == 0 and "pose accuracy  none: no commanded poses" in \
        info.output and "0°" not in info.output


def test_ros2_bag_without_the_definition_of_a_labs_own_type(tmp_path, arm):
    """A package's own type cannot be guessed: one line names the topic, the type and
    --msg-dir; with the package's .msg files the import reads it."""
    store = _store("sqlite3")
    T = store.types
    log = _log_path(tmp_path, "sqlite3")
    theta = np.array([[0.2, -0.1], [-0.2, 0.3]])
    tension = np.stack([arm.tension_distribution(t, np.full(4, 10.0)) for t in theta])
    messages = []
    for n in range(120):
        ns = START_NS + n * 20_000_000
        k = n // 60
        messages.append((ns, "/joint_states", "sensor_msgs/msg/JointState",
                         _joint_state(store, "sqlite3", ns, arm.joints, theta[k])))
        messages.append((ns + 1000, "/muscle_states", "sensor_msgs/msg/JointState",
                         _joint_state(store, "sqlite3", ns, arm.muscles,
                                      arm.length(theta[k], tension[k]), tension[k])))
        messages.append((ns + 2000, "/temps", TEMPS_TYPE,
                         T[TEMPS_TYPE](celsius=np.array([31.0, 32.0, 33.0, 34.0]),
                                       sensor_count=4)))
    write_messages(log, "sqlite3", store, messages)
    _strip_definitions(log)
    mapping = _map(tmp_path, {"temperature": {"topic": "/temps", "type": TEMPS_TYPE,
                                              "field": "celsius",
                                              "order": ["m0", "m1", "m2", "m3"]}})
    out = tmp_path / "x.parquet"
    before = set(tmp_path.iterdir())
    res = _import(log, out, "--map", str(mapping))
    _refused(res, tmp_path, before, str(log), "topic /temps", TEMPS_TYPE, "--msg-dir",
             "lab_msgs/msg/MuscleTemperatures.msg")
    msgs = tmp_path / "defs" / "lab_msgs" / "msg"
    msgs.mkdir(parents=True)
    (msgs / "MuscleTemperatures.msg").write_text(TEMPS_MSG)
    res = _import(log, out, "--map", str(mapping), "--msg-dir", str(tmp_path / "defs"))
    assert res.exit_code == 0, res.output
    rec = read_recording(out)
    assert rec.n_rows == 2
    np.testing.assert_allclose(rec.temperature, [[31, 32, 33, 34]] * 2)


@pytest.mark.parametrize("where", [0.2, 0.35, 0.5, 0.65, 0.8])
@pytest.mark.parametrize("fill", [b"\xff", b"\x00"], ids=["ff", "zeros"])
def test_ros1_bag_damaged_mid_file(tmp_path, arm, where, fill):
    """64 bytes overwritten in the middle of the messages; the index at the end is intact, so
    the bag opens and the damage shows only while reading."""
    from rosbags.highlevel import AnyReader

    good = tmp_path / "good.bag"
    write_log(good, arm, LogSpec(poses=2, hold_s=1.0, ramp_s=0.5))
    log = tmp_path / "damaged.bag"
    shutil.copy(good, log)
    with open(log, "r+b") as f:
        f.seek(int(good.stat().st_size * where))
        f.write(fill * 64)
    with AnyReader([log]) as reader:  # the index is intact: it opens, topics are listed
        assert "/joint_states" in reader.topics
    before = set(tmp_path.iterdir())
    line = _refused(_import(log, tmp_path / "x.parquet"), tmp_path, before, str(log),
                    "nothing was imported", "Copy the bag again")
    assert len(line) < 400


@pytest.mark.parametrize("fmt,compression", [("ros1", "bz2"), ("ros1", "lz4"),
                                             ("mcap", "zstd")])
def test_compressed_bag_damaged_mid_file(tmp_path, arm, fmt, compression):
    """`rosbag record -j` / `--lz4` and zstd-compressed ROS 2 bags: read as they are,
    refused by name once damaged (the decompressors' own errors named no file, or came out
    as tracebacks)."""
    theta = np.array([[0.2, -0.1], [-0.2, 0.3], [0.1, 0.1]])
    tension = np.stack([arm.tension_distribution(t, np.full(4, 10.0)) for t in theta])
    good = _log_path(tmp_path, fmt, "good")
    _held_log(good, fmt, arm, theta, tension, compression=compression)
    res = _import(good, tmp_path / "good.parquet")
    assert res.exit_code == 0, res.output
    np.testing.assert_allclose(read_recording(tmp_path / "good.parquet").theta, theta)
    log = _log_path(tmp_path, fmt, "damaged")
    (shutil.copy if fmt == "ros1" else shutil.copytree)(good, log)
    storage = log if fmt == "ros1" else next(log.glob("*.mcap"))
    with open(storage, "r+b") as f:
        f.seek(storage.stat().st_size * 3 // 10)
        f.write(b"\xff" * 64)
    before = set(tmp_path.iterdir())
    _refused(_import(log, tmp_path / "x.parquet"), tmp_path, before, str(log),
             "damaged after", "readable message(s)", "nothing was imported",
             "Copy the bag again")


@pytest.mark.parametrize("fmt,where", [("mcap", 0.1), ("mcap", 0.3), ("mcap", 0.5),
                                       ("sqlite3", 0.5)])
@pytest.mark.parametrize("fill", [b"\xff", b"\x00"], ids=["ff", "zeros"])
def test_ros2_bag_damaged_mid_file(tmp_path, arm, fmt, where, fill):
    """A damaged .mcap chunk can end rosbags' pass early without an error (zeros at 10 %:
    85 of 800 joint states read); the import counts what it read against the index."""
    log = _log_path(tmp_path, fmt)
    write_log(log, arm, LogSpec(poses=2, hold_s=1.0, ramp_s=0.5), fmt)
    (storage,) = (p for p in log.iterdir() if p.suffix in (".mcap", ".db3"))
    with open(storage, "r+b") as f:
        f.seek(int(storage.stat().st_size * where))
        f.write(fill * 64)
    before = set(tmp_path.iterdir())
    line = _refused(_import(log, tmp_path / "x.parquet"), tmp_path, before, str(log))
    assert "nothing was imported" in line or (
        "a bag that cannot be opened" in line and "malformed" in line)
    assert len(line) < 400


def test_binary_file_renamed_bag(tmp_path):
    png = tmp_path / "photo.bag"
    png.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(range(256)) * 8)
    for args in ([], ["--list-topics"]):
        before = set(tmp_path.iterdir())
        line = _refused(_import(png, tmp_path / "x.parquet", *args), tmp_path, before,
                        f"{png}: not a readable ROS 1 .bag or ROS 2 bag directory",
                        "give a .bag file or the directory holding metadata.yaml")
        assert "a PNG image that does not start with '#ROSBAG V2.0'" in line
        assert "codec" not in line and len(line) < 300


@pytest.mark.parametrize("what,reason", [
    ("empty file", "an empty file"),
    ("ROS 1 bag named .orig", "a ROS 1 bag without the .bag suffix; rename it"),
    ("folder", "a folder without metadata.yaml"),
])
def test_other_things_that_are_not_bags(tmp_path, arm, what, reason):
    if what == "empty file":
        log = tmp_path / "empty.bag"
        log.write_bytes(b"")
    elif what == "folder":
        log = tmp_path / "not_a_bag"
        log.mkdir()
        (log / "notes.txt").write_text("x")
    else:
        write_log(tmp_path / "arm.bag", arm, LogSpec(poses=2, hold_s=1.0, ramp_s=0.5))
        log = (tmp_path / "arm.bag").rename(tmp_path / "arm.bag.orig")
    before = set(tmp_path.iterdir())
    _refused(_import(log, tmp_path / "x.parquet"), tmp_path, before,
             f"{log}: not a readable ROS 1 .bag or ROS 2 bag directory ({reason}")


@pytest.mark.parametrize("fmt", ["mcap", "sqlite3"])
def test_a_ros2_storage_file_on_its_own_imports(tmp_path, arm, fmt):
    """The .mcap or .db3 file without its folder's metadata.yaml is read as it is."""
    log = _log_path(tmp_path, fmt)
    write_log(log, arm, LogSpec(poses=2, hold_s=1.0, ramp_s=0.5), fmt)
    (storage,) = (p for p in log.iterdir() if p.suffix in (".mcap", ".db3"))
    alone = storage.rename(tmp_path / storage.name)
    res = _import(alone, tmp_path / "x.parquet")
    assert res.exit_code == 0, res.output
    assert read_recording(tmp_path / "x.parquet").n_rows == 2


@pytest.mark.parametrize("fmt", ["ros1", "mcap"])
def test_many_topics_none_mapped(tmp_path, fmt):
    """A robot's whole bag (90 topics), none of them the convention's: a short line naming a
    handful, the JointState topic (the likely one to map) first, and how to list them all;
    --list-topics lists all 90."""
    store = _store(fmt)
    Float64 = store.types["std_msgs/msg/Float64"]
    topics = [f"/robot/sensor_{k:02d}/value" for k in range(89)]
    log = _log_path(tmp_path, fmt, "whole_robot")
    messages = [(START_NS + k * 1000, t, "std_msgs/msg/Float64", Float64(data=float(k)))
                for k, t in enumerate(topics)]
    messages.append((START_NS + 10**6, "/robot/zz_arm/joint_states", "sensor_msgs/msg/JointState",
                     _joint_state(store, fmt, START_NS, ["j1"], [0.5])))
    write_messages(log, fmt, store, messages)
    before = set(tmp_path.iterdir())
    line = _refused(_import(log, tmp_path / "x.parquet"), tmp_path, before, str(log),
                    "no topic /joint_states for theta", "the log has 90 topic(s): "
                    "/robot/zz_arm/joint_states (sensor_msgs/", "and 85 more", "--map",
                    "--list-topics")
    assert sum(t in line for t in topics) == 4 and len(line) < 600
    res = CliRunner().invoke(main, ["import", str(log), "--list-topics"])
    assert res.exit_code == 0, res.output
    listed = res.output.strip().splitlines()
    assert len(listed) == 90 and sum("std_msgs/msg/Float64  1 messages" in s for s in listed) == 89
    assert sorted(s.split()[0] for s in listed) == [*topics, "/robot/zz_arm/joint_states"]


# --- mappings that do not fit the log -------------------------------------------------------

@pytest.mark.parametrize("fmt", ["ros1", "sqlite3"])
def test_single_value_float64_field_mapped(tmp_path, fmt):
    """A joint angle published as std_msgs/Float64 `data` (a single value) is read."""
    robot = _one_joint_robot(tmp_path)
    one = ArmModel.load(robot)
    theta = np.array([[0.3], [-0.2], [0.1]])
    tension = np.stack([one.tension_distribution(t, np.full(2, 10.0)) for t in theta])
    log = _log_path(tmp_path, fmt)
    _held_log(log, fmt, one, theta, tension, theta_topic="float64")
    mapping = _map(tmp_path, {"theta": {"topic": "/shoulder_angle", "type": "std_msgs/Float64",
                                        "field": "data", "order": ["shoulder_pitch"]},
                              "temperature": None})
    out = tmp_path / "x.parquet"
    res = _import(log, out, "--map", str(mapping), robot=str(robot))
    assert res.exit_code == 0, res.output
    rec = read_recording(out)
    np.testing.assert_allclose(rec.theta, theta)
    np.testing.assert_allclose(rec.tension, tension, atol=1e-9)


@pytest.mark.parametrize("order,robot,parts", [
    (["shoulder_pitch"], ROBOT, ["topic /shoulder_angle (theta)", "['elbow_pitch']", "rename"]),
    (None, "one", ["topic /shoulder_angle (theta) has no field 'name' naming its values",
                   "order: [...]"]),
], ids=["two joints", "no order"])
def test_single_value_field_that_does_not_fit(tmp_path, order, robot, parts):
    """The same Float64 mapped to a two-joint robot (the joint it lacks, by name), or
    without the name of its value."""
    log = tmp_path / "arm.bag"
    one_path = _one_joint_robot(tmp_path)
    one = ArmModel.load(one_path)
    theta = np.array([[0.3], [-0.2]])
    tension = np.stack([one.tension_distribution(t, np.full(2, 10.0)) for t in theta])
    _held_log(log, "ros1", one, theta, tension, theta_topic="float64")
    theta_map = {"topic": "/shoulder_angle", "type": "std_msgs/Float64", "field": "data"}
    mapping = _map(tmp_path, {"theta": {**theta_map, **({"order": order} if order else {})}})
    before = set(tmp_path.iterdir())
    _refused(_import(log, tmp_path / "x.parquet", "--map", str(mapping),
                     robot=ROBOT if robot == ROBOT else str(one_path)), tmp_path, before,
             str(log), *parts)


def test_order_longer_than_the_array(tmp_path, arm):
    log = tmp_path / "arm.bag"
    write_log(log, arm, LogSpec(poses=2, hold_s=1.0, ramp_s=0.5))
    mapping = _map(tmp_path, {"temperature": {"order": ["spare", "m0", "m1", "m2", "m3"]}})
    before = set(tmp_path.iterdir())
    line = _refused(_import(log, tmp_path / "x.parquet", "--map", str(mapping)), tmp_path,
                    before, str(log), "topic /muscle_temperature (temperature)",
                    "messages too short", "field 'data' has 4 value(s)", "needs 5", "'order'")
    assert "has no message" not in line


@pytest.mark.parametrize("quantity,rename,parts", [
    ("theta", {"shoulder_pich": "shoulder_pitch"},
     ["theta (/joint_states): ['shoulder_pich']", "'shoulder_pitch'"]),
    ("tension", {"M0": "m0", "m1": "m1"}, ["tension (/muscle_states): ['M0']", "'m0'"]),
])
def test_rename_keys_that_match_nothing(tmp_path, arm, quantity, rename, parts):
    log = tmp_path / "arm.bag"
    write_log(log, arm, LogSpec(poses=2, hold_s=1.0, ramp_s=0.5))
    mapping = _map(tmp_path, {quantity: {"rename": rename}})
    before = set(tmp_path.iterdir())
    _refused(_import(log, tmp_path / "x.parquet", "--map", str(mapping)), tmp_path, before,
             str(log), "rename key(s) that match no element name", "correct or remove them",
             *parts)


# --- readings the robot cannot have --------------------------------------------------------

@pytest.mark.parametrize("fmt", ["ros1", "mcap"])
def test_angle_outside_the_limits_and_negative_tension(tmp_path, arm, fmt):
    """The Panda case: −2.28 rad on a joint limited to [−1, 1] and −0.54 N tension are
    refused with counts; --keep-out-of-range imports them and says so in the metadata."""
    theta = np.array([[0.2, -0.1], [-2.28, 0.1], [0.1, 0.3]])
    tension = np.stack([arm.tension_distribution(np.clip(t, -0.5, 0.5), np.full(4, 10.0))
                        for t in theta])
    tension[2, 1] = -0.54
    log = _log_path(tmp_path, fmt)
    _held_log(log, fmt, arm, theta, tension)
    out = tmp_path / "x.parquet"
    before = set(tmp_path.iterdir())
    _refused(_import(log, out), tmp_path, before, str(log),
             "1 of 3 held pose(s) with a joint outside its URDF limits",
             "shoulder_pitch: 1, [-2.28, 0.2] rad against [-1, 1]",
             "1 of 3 held pose(s) with a negative tension (m1: 1, down to -0.54 N)",
             "--keep-out-of-range")
    res = _import(log, out, "--keep-out-of-range")
    assert res.exit_code == 0, res.output
    assert "Warning: kept readings and poses out of range" in res.output
    rec = read_recording(out)
    assert rec.n_rows == 3
    np.testing.assert_allclose(rec.theta, theta, atol=1e-12)
    assert rec.meta["import_flags"] == {"outside_joint_limits": {"shoulder_pitch": 1},
                                        "negative_tension": {"m1": 1}}


def test_nan_tension_refused_or_dropped(tmp_path, arm):
    theta = np.array([[0.2, -0.1], [-0.2, 0.1]])
    tension = np.stack([arm.tension_distribution(t, np.full(4, 10.0)) for t in theta])
    log = tmp_path / "arm.bag"
    _held_log(log, "ros1", arm, theta, tension, nan_tension=7)
    out = tmp_path / "x.parquet"
    before = set(tmp_path.iterdir())
    _refused(_import(log, out), tmp_path, before, str(log),
             "7 NaN or infinite value(s) for tension in 120 message(s) on /muscle_states",
             "nothing was imported", "--keep-out-of-range")
    res = _import(log, out, "--keep-out-of-range")
    assert res.exit_code == 0, res.output
    rec = read_recording(out)
    assert rec.n_rows == 2 and np.isfinite(rec.tension).all()
    np.testing.assert_allclose(rec.tension, tension, atol=1e-9)
    assert rec.meta["import_flags"] == {"nonfinite_values": {"tension": 7}}


def test_header_time_running_backwards(tmp_path, arm):
    theta = np.array([[0.2, -0.1], [-0.2, 0.1]])
    tension = np.stack([arm.tension_distribution(t, np.full(4, 10.0)) for t in theta])
    log = tmp_path / "arm.bag"
    _held_log(log, "ros1", arm, theta, tension, header_back_s=5.0)
    mapping = _map(tmp_path, {"clock": "header"})
    before = set(tmp_path.iterdir())
    _refused(_import(log, tmp_path / "x.parquet", "--map", str(mapping)), tmp_path, before,
             str(log), "1 of 120 message(s) on /joint_states (theta) stamped earlier than the "
             "message before", "try clock: log", "--keep-out-of-range")
    res = _import(log, tmp_path / "x.parquet", "--map", str(mapping), "--keep-out-of-range")
    assert res.exit_code == 0, res.output
    assert read_recording(tmp_path / "x.parquet").meta["import_flags"] == {
        "time_backwards": {"theta": 1}}
