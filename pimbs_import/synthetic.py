"""A synthetic ROS log of a simulated arm moving between held poses (tests, benchmarks, demos).

What a lab's ``rosbag record`` of a tendon-driven arm looks like: the arm ramps between
poses of the seeded plan and holds each for a while; ``/joint_states`` (with joints the robot
does not drive, in another order), ``/muscle_states`` and ``/muscle_temperature`` are
published at different rates, with sensor noise and receive-time jitter; the joint-state
publisher's header clock may run offset from the recorder's. ``truth`` gives the noise-free
held values, so an import can be checked row by row.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pimbs_arm.model import ArmModel
from pimbs_arm.poses import plan_poses
from pimbs_sim.simulate import SensorNoise

FORMATS = ("ros1", "sqlite3", "mcap")


@dataclass
class LogSpec:
    poses: int = 8
    hold_s: float = 3.0
    ramp_s: float = 1.5
    rates: dict[str, float] = field(default_factory=lambda: {
        "joints": 200.0, "muscles": 100.0, "temperature": 10.0})
    header_offset_s: float = 3.25  # joint-state publisher's clock ahead of the recorder's
    noise: SensorNoise = SensorNoise()
    extra_joints: tuple[str, ...] = ("head_pan", "r_elbow")
    temperature: bool = True
    split_joints: bool = False  # two publishers on /joint_states, each with some joints
    length_unit: float = 1.0  # published length = this * (length + length_zero): mm -> 1000
    length_zero: float = 0.0  # m: the motor encoder's zero is not the model's
    seed: int = 0
    start_ns: int = 1_760_000_000_000_000_000


@dataclass
class Truth:
    """Noise-free held values, one row per held pose."""

    theta: np.ndarray
    tension: np.ndarray
    length: np.ndarray
    hold_windows: list[tuple[int, int]]  # ns (start, end) of each hold


def write_log(path: Path, arm: ArmModel, spec: LogSpec, fmt: str = "ros1") -> Truth:
    """Write the log to ``path`` (a .bag file for ros1, a bag directory otherwise)."""
    from rosbags.typesys import Stores, get_typestore

    plan = plan_poses(arm, spec.poses, spec.seed, "atl")
    theta_hold = plan.poses
    tension_hold = np.stack([arm.tension_distribution(t, f, f_max=0.9 * arm.f_max)
                             for t, f in zip(plan.poses, plan.floors, strict=True)])
    length_hold = np.stack([arm.length(t, f) for t, f in
                            zip(theta_hold, tension_hold, strict=True)])
    # home pose, relaxed at the floors, then ramp -> hold for every pose
    floor = np.array([m.f_floor for m in arm.robot.muscles])
    home = np.clip(np.zeros(arm.n_joints), arm.joint_range[:, 0], arm.joint_range[:, 1])
    knots_t, knots = [0.0], [(home, floor, arm.length(home, floor))]
    windows = []
    t = 0.5
    for k in range(spec.poses):
        t += spec.ramp_s
        knots_t.append(t)
        knots.append((theta_hold[k], tension_hold[k], length_hold[k]))
        windows.append((t, t + spec.hold_s))
        t += spec.hold_s
        knots_t.append(t)
        knots.append(knots[-1])
    end = t + 0.5
    windows[-1] = (windows[-1][0], end)  # the arm rests in its last pose until the log ends
    knot_t = np.array(knots_t)

    def state(times: np.ndarray, which: int) -> np.ndarray:
        values = np.stack([kn[which] for kn in knots])
        return np.stack([np.interp(times, knot_t, values[:, j], right=values[-1, j])
                         for j in range(values.shape[1])], axis=1)

    rng = np.random.default_rng([spec.seed, 7])
    store = get_typestore(Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE)
    T = store.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    JointState = T["sensor_msgs/msg/JointState"]
    Arr, Layout = T["std_msgs/msg/Float64MultiArray"], T["std_msgs/msg/MultiArrayLayout"]

    def stamp(ns: int) -> object:
        return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)

    def header(ns: int) -> object:
        return (Header(seq=0, stamp=stamp(ns), frame_id="") if fmt == "ros1"
                else Header(stamp=stamp(ns), frame_id=""))

    s = spec.noise
    jnames = [spec.extra_joints[0], *reversed(arm.joints), *spec.extra_joints[1:]]

    def joint_states():
        times = np.arange(0.0, end, 1 / spec.rates["joints"])
        theta = state(times, 0) + rng.normal(0, s.theta, (len(times), arm.n_joints))
        for tt, th in zip(times, theta, strict=True):
            names, position = jnames, np.array([0.1, *th[::-1], -0.2])
            parts = [(names, position)]
            if spec.split_joints:  # e.g. one publisher per limb: first joint, the others
                parts = [([names[0], names[-2]], position[[0, -2]]),
                         (names[1:-2] + names[-1:], np.r_[position[1:-2], position[-1:]])]
            for k, (nm, pos) in enumerate(parts):
                yield (_ns(spec.start_ns, tt + k * 1e-3 + rng.uniform(0, 1e-3)),
                       "/joint_states", "sensor_msgs/msg/JointState", JointState(
                           header=header(_ns(spec.start_ns, tt + spec.header_offset_s)),
                           name=nm, position=pos, velocity=np.zeros(0), effort=np.zeros(0)))

    def muscle_states():
        times = np.arange(0.003, end, 1 / spec.rates["muscles"])
        tension = state(times, 1) + rng.normal(0, s.tension, (len(times), arm.n_muscles))
        length = state(times, 2) + rng.normal(0, s.length, (len(times), arm.n_muscles))
        for tt, f, ln in zip(times, tension, length, strict=True):
            recv = _ns(spec.start_ns, tt + rng.uniform(0, 2e-3))
            yield (recv, "/muscle_states", "sensor_msgs/msg/JointState", JointState(
                header=header(recv), name=list(arm.muscles),
                position=spec.length_unit * (ln + spec.length_zero),
                velocity=np.zeros(0), effort=f))

    def temperatures():
        for tt in np.arange(0.007, end, 1 / spec.rates["temperature"]):
            temp = 30.0 + 0.01 * tt + rng.normal(0, s.temperature, arm.n_muscles)
            yield (_ns(spec.start_ns, tt), "/muscle_temperature",
                   "std_msgs/msg/Float64MultiArray",
                   Arr(layout=Layout(dim=[], data_offset=0), data=temp))

    streams = [joint_states(), muscle_states()] + ([temperatures()] if spec.temperature else [])
    write_messages(path, fmt, store, heapq.merge(*streams, key=lambda m: m[0]))
    return Truth(theta=theta_hold, tension=tension_hold, length=length_hold,
                 hold_windows=[(_ns(spec.start_ns, a), _ns(spec.start_ns, b))
                               for a, b in windows])


def _ns(start: int, seconds: float) -> int:
    return start + int(round(seconds * 1e9))


def write_messages(path: Path, fmt: str, store, messages, compression: str | None = None
                   ) -> None:
    """Write ``(receive ns, topic, msgtype, message)`` tuples, in time order, as a ROS 1
    ``.bag`` (``fmt`` ros1) or a ROS 2 bag directory (sqlite3, mcap); ``store`` is the
    ``rosbags`` typestore the messages were made with. ``compression``: "bz2" or "lz4" for
    compressed ROS 1 chunks (``rosbag record -j`` / ``--lz4``), "zstd" for ROS 2 messages
    compressed one by one (``ros2 bag record --compression-mode message``)."""
    if fmt not in FORMATS:
        raise ValueError(f"format must be one of {FORMATS}, not {fmt!r}")
    if compression not in ((None, "bz2", "lz4") if fmt == "ros1" else (None, "zstd")):
        raise ValueError(f"compression {compression!r} is not one for {fmt}")
    if fmt == "ros1":
        from rosbags.rosbag1 import Writer

        writer, serialize = Writer(path), store.serialize_ros1
        if compression is not None:
            writer.set_compression(Writer.CompressionFormat[compression.upper()])
            writer.chunk_threshold = 16 * 1024  # several chunks even in a short test log
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3
        writer, serialize = Writer(path, version=9, storage_plugin=plugin), store.serialize_cdr
        if compression is not None:
            from rosbags.rosbag2 import CompressionFormat, CompressionMode

            writer.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    with writer:
        conns = {}
        for recv, topic, msgtype, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(conns[topic], recv, serialize(msg, msgtype))


def main(argv: list[str] | None = None) -> None:
    """``python -m pimbs_import.synthetic OUT [--robot R] [--poses N] [--format F]``: a demo
    log to try ``pimbs import`` without a lab's bag."""
    import argparse

    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("out", type=Path)
    parser.add_argument("--robot", default="two-link-4-muscle")
    parser.add_argument("--poses", type=int, default=60)
    parser.add_argument("--format", default="ros1", choices=FORMATS)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.out.exists():
        parser.error(f"{args.out} exists; choose another path")
    spec = LogSpec(poses=args.poses, seed=args.seed)
    write_log(args.out, ArmModel.load(args.robot), spec, args.format)
    span = 0.5 + args.poses * (spec.ramp_s + spec.hold_s) + 0.5
    print(f"wrote {args.out}: {args.format} log of {args.robot}, {args.poses} held poses, "
          f"{span:.0f} s")


if __name__ == "__main__":
    main()
