"""Simulated muscle boards on a bus: the whole arm, runnable in a background thread.

``MockArm`` speaks the board protocol on a python-can bus (``virtual:NAME`` in-process, or
any port a CAN transport accepts, e.g. ``vcan0`` across processes on one host) or on
a pty (``link="pty"``; the driver opens ``mock.port``), or behind an emulated SLCAN USB-CAN
adapter on a pty (``link="slcan"``; ``mock.port`` is ``slcan:/dev/pts/N`` for python-can).
Behind the boards is ``Plant``: the arm model's static equilibrium with first-order
settling (or, with ``plant=arm.xml``, ``MujocoPlant``: MuJoCo's dynamics), noisy sensors,
load heating, an optional concealed effect (``effects.py``) and
injected faults (``faults.py``). The boards and the plant run on a clock that stands still
while this process cannot run (``MockArm._clock``), so a loaded machine slows the simulated
arm down instead of tripping its boards' watchdogs.

    with MockArm(robot, "virtual:demo", speed=10, faults=["overheat:m1@3"]) as mock:
        ...  # ArmDriver(CanTransport(mock.port), robot)
        mock.set_sample(3)  # collection loop says where it is; triggers @3 faults
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pimbs_hw.errors import HardwareError
from pimbs_hw.host_lag import host_lag
from pimbs_hw.mock.boards import ProfileBoard, SiReading, V1Board
from pimbs_hw.mock.effects import EffectStack
from pimbs_hw.mock.faults import FaultSpec, parse_faults
from pimbs_hw.mock.odrive import ODriveAxis
from pimbs_hw.mock.plant import Plant
from pimbs_hw.protocol.codec import MAX_BOARDS, JointStatus, encode, signal_range
from pimbs_hw.transport import CanTransport, PtyMaster, SerialTransport, Transport
from pimbs_hw.transport.base import CAN_ERR_BUSOFF

CAN_ERR_PROT = 0x08  # SocketCAN error class: protocol violation (a frame failed CAN's CRC)

log = logging.getLogger(__name__)
OVERHEAT_RATE_C_PER_S = 400.0  # injected thermal runaway: past any limit within 0.15 s
DROP_KEEP_EVERY = 4  # drop-frames: 3 of every 4 status frames lost (75 %, never a long gap)
DRAIN_S = 0.05  # the longest the board loop acts on received frames before its next tick
_ANGLE_MIN, _ANGLE_MAX = signal_range(JointStatus, "angle_rad")


@dataclass(frozen=True)
class MockSnapshot:
    """True state of the simulated arm (what no sensor shows), for tests and demos."""

    theta: np.ndarray
    tension: np.ndarray
    length: np.ndarray
    temperature: np.ndarray
    modes: tuple[str, ...]  # board modes: hold | position | tension | relax
    relax_tension: np.ndarray  # N, each board's relax target as its loadcell reads it
    active_faults: tuple[str, ...]

    def relaxed(self, tol: float = 1.0) -> np.ndarray:
        """Per muscle: board in relax mode and tension near its relax target."""
        return (np.array([m == "relax" for m in self.modes])
                & (np.abs(self.tension - self.relax_tension) < tol))


IN_PROCESS: set[str] = set()  # ports served by a MockArm running in this process


def served_in_process(port: str) -> bool:
    """Whether simulated boards in this very process answer on ``port`` (they share its
    CPU and GIL with the driver, unlike real boards)."""
    return port in IN_PROCESS


def _open_link(link: str) -> tuple[Transport, str]:
    if link == "pty":
        master = PtyMaster()
        return SerialTransport(master, name=f"mock pty {master.slave_path}"), master.slave_path
    if link == "slcan":
        from pimbs_hw.mock.slcan import SlcanAdapter

        adapter = SlcanAdapter()
        return adapter, adapter.port
    return CanTransport(link), link


class MockArm:
    """Simulated boards of ``robot`` behind ``link``; ``port`` is what a driver opens."""

    def __init__(self, robot, link: str = "virtual", *, model=None, effect=None,
                 faults=(), seed: int = 0, speed: float = 1.0, tick_s: float = 0.01,
                 status_period_s: float = 0.02, noise: bool = True,
                 encoder_offset_m=None, winding=None,
                 plant: Path | str | None = None, plant_damping: dict[str, float] | None = None,
                 watchdog_floor_s: float = 0.0) -> None:
        from pimbs_arm.model import ArmModel
        from pimbs_calibration.description import load_robot

        self.robot = load_robot(robot) if isinstance(robot, str | Path) else robot
        from pimbs_hw.protocol.profiles import protocols_for

        protocols_for(self.robot)  # boards whose CAN ids collide cannot share a bus
        self.muscles = tuple(m.name for m in self.robot.muscles)
        self.faults: tuple[FaultSpec, ...] = parse_faults(faults, self.muscles)
        self.effects = EffectStack(effect)
        # own model instance: pinocchio data is not thread-safe, the solver thread uses it
        self.model = self.effects.physics(model if model is not None else ArmModel(self.robot))
        self.rng = np.random.default_rng(seed)
        self.noise = noise
        self.tick_s, self.status_period_s = tick_s, status_period_s
        # the shortest watchdog time of a board that keeps its own (a profile's, set in its
        # firmware): ``open_arm`` gives boards simulated beside the host the host's own
        # watchdog time as for every board it configures (see ``pimbs_hw.connect``)
        self.watchdog_floor_s = watchdog_floor_s
        m = len(self.muscles)
        ambient = 25.0 + (self.rng.normal(0, 0.5, m) if noise else 0.0)
        if plant is None:
            self.plant = Plant(self.model, speed=speed, ambient_c=ambient)
        else:  # MuJoCo integrates the arm (``plant`` is an MJCF, the "real" arm)
            from pimbs_hw.mock.mujoco_plant import MujocoPlant

            body = [e.name for e in self.effects.effects
                    if getattr(e, "name", None) in ("link_mass", "routing")]
            if body:
                raise ValueError(f"--conceal {body[0]} changes the description's body, but with "
                                 f"--plant {plant} the plant MJCF is the true arm: make that "
                                 "change in the plant file")
            self.plant = MujocoPlant(Path(plant), self.model, speed=speed, ambient_c=ambient,
                                     joint_damping=plant_damping)
        self.host_lag = host_lag()
        self._now = -np.inf
        now = self._clock()
        # incremental encoders power up anywhere: the host must zero them (``pimbs zero``)
        self.encoder_offset_m = (np.zeros(m) if encoder_offset_m is None
                                 else np.broadcast_to(np.asarray(encoder_offset_m, float),
                                                      (m,)).copy())
        # how each wire is truly wound on its motor (+1: a positive turn reels it in); the
        # description's ``direction`` says what the host believes; a test makes them differ
        self.winding = ([getattr(s, "direction", 1) for s in self.robot.muscles]
                        if winding is None else [int(w) for w in winding])
        self.boards = [self._board(spec, now, w)
                       for spec, w in zip(self.robot.muscles, self.winding, strict=True)]
        if len({spec.board_id for spec in self.robot.muscles}) != m:
            raise ValueError(f"{self.robot.name}: board ids must be unique")
        self._by_frame = {fid: i for i, b in enumerate(self.boards) for fid in b.frame_ids}
        self._broadcast: dict[int, list[int]] = {}  # ids every board of a kind hears (NMT)
        for i, b in enumerate(self.boards):
            for fid in getattr(b, "broadcast_ids", ()):
                self._broadcast.setdefault(fid, []).append(i)
        self._home = False
        self._sent: dict[int, int] = {}  # frames sent per id (drop-frames keeps every 4th)
        try:
            self.transport, self.port = _open_link(link)
        except BaseException:
            self.plant.close()
            raise
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sample = 0
        self._commanded = False  # commands received since the plant last got them
        self._cycles = 0
        self._t0 = now
        self._active: set[FaultSpec] = set()
        self._bus_off = False
        self._joint_counter = 0
        self._next_joints = self._last_tick = now
        self._readings = self._read_all(self.plant.state)

    def _board(self, spec, now: float, winding: int):
        from pimbs_hw.protocol.profiles import is_cia402, muscle_protocol, profile_path

        name = muscle_protocol(spec)
        if name == "pimbs-v1":
            if not 0 <= spec.board_id < MAX_BOARDS:
                raise ValueError(f"muscle {spec.name}: board_id {spec.board_id} is outside "
                                 f"0..{MAX_BOARDS - 1}")
            return V1Board(spec, now, self.status_period_s, winding)
        if is_cia402(name):
            from pimbs_hw.mock.cia402_drive import Cia402Board
            from pimbs_hw.protocol.cia402_config import load_drive_file

            return Cia402Board(spec, load_drive_file(name), now, winding)
        from pimbs_hw.protocol.profile import load_profile

        profile = load_profile(profile_path(name))
        watchdog = None if profile.watchdog is None else (
            max(profile.watchdog[0], self.watchdog_floor_s), profile.watchdog[1])
        if profile.name == "odrive-cansimple":  # the device itself, from ODrive's documentation
            tension = profile.status["tension"]
            return ODriveAxis(spec, now, turns_per_m=profile.status["position"].per_si,
                              nm_per_n=tension.per_si, winding=winding,
                              watchdog_s=watchdog[0] if watchdog else None,
                              torque_limit_nm=tension.rail[1] if tension.rail else 5.0)
        return ProfileBoard(spec, profile, now, winding, watchdog)

    # -- public ----------------------------------------------------------------------------
    def start(self) -> MockArm:
        IN_PROCESS.add(self.port)
        self._thread = threading.Thread(target=self._run, name=f"mock-arm {self.port}",
                                        daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        IN_PROCESS.discard(self.port)
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self._drain()
        self.plant.close()
        self.transport.close()

    def __enter__(self) -> MockArm:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def set_sample(self, index: int) -> None:
        """The collection loop's current sample index (triggers ``@SAMPLE`` faults)."""
        self._sample = index

    def snapshot(self) -> MockSnapshot:
        with self._lock:
            s = self.plant.state
            relax = np.array([b.relax_n for b in self.boards])
            true_relax = self.effects.true_tension(self.model, relax, s.approach, s.temperature)
            return MockSnapshot(s.theta.copy(), s.tension.copy(), s.length.copy(),
                                s.temperature.copy(), tuple(b.mode for b in self.boards),
                                true_relax, tuple(f"{f.kind}:{f.muscle or '*'}"
                                                  for f in self._active))

    def hold_home(self, on: bool = True) -> None:
        """Someone holds the arm at its home pose (all joints 0 rad), e.g. to zero it."""
        with self._lock:
            self.plant.hold_home(on)

    def settled(self) -> bool:
        with self._lock:
            return self.plant.settled()

    @property
    def quasi_static(self) -> bool:
        """The arm behind the boards is the quasi-static one (no inertia, nothing rings) and
        no concealed capstan friction couples the boards' tension loops to the wires' motion
        (with it, a wire loaded fast overshoots through the friction as on a real arm)."""
        return isinstance(self.plant, Plant) and not any(
            getattr(e, "name", None) == "tendon_friction" for e in self.effects.effects)

    def at_rest(self) -> bool | None:
        """Whether the simulated arm is at rest, where it knows (the quasi-static arm: its
        equilibrium is solved); None where, as on a real arm, only the readings can tell."""
        if not self.quasi_static:
            return None
        with self._lock:
            return self.plant.at_rest()

    def failure(self) -> str | None:
        """Why the simulated arm stopped following its commands (None: it follows them): a
        MuJoCo step that blew up, a static solve that found no rest position."""
        return self.plant.failure

    # -- board loop ------------------------------------------------------------------------
    def _clock(self) -> float:
        """The simulated boards' time: wall time less the stalls of this process.

        The boards stand for devices with CPUs of their own, but run in this process: when
        it cannot run (other work has every core, a call holds the GIL), the host's commands
        and the boards' own loop stall together, and on a wall clock the boards' watchdogs
        would relax the arm for the machine's load rather than for anything the host did. On
        this clock a stalled process is a pause of the simulated world, as a lagging solver
        is for the plant (``HostLag``); a host that stops commanding while it runs still
        trips the watchdog.
        """
        t = time.monotonic()
        self._now = max(self._now, t - self.host_lag.total(t))
        return self._now

    def _run(self) -> None:
        next_tick = time.monotonic()
        while not self._stop.is_set():
            try:
                frame = self.transport.recv(max(0.0, next_tick - time.monotonic()))
                # every frame that arrived before the tick runs is acted on first (a board's
                # watchdog must see the command that reached it in time, also when this loop
                # runs late behind a long tick), but a steady stream (CANopen SYNC at 1 kHz)
                # must not hold the tick off: frames newer than this moment wait for it, and
                # a backlog of them (after a stall) is taken at most DRAIN_S at a time
                cutoff = max(next_tick, time.monotonic())
                give_up = time.monotonic() + DRAIN_S
                while frame is not None:
                    self._on_frame(frame)
                    if frame.timestamp >= cutoff or time.monotonic() > give_up:
                        break
                    frame = self.transport.recv(0.0)
            except HardwareError as exc:  # a broken link is the host's problem to report
                log.debug("mock arm link: %s", exc)
                self._stop.wait(self.tick_s)
            if self._commanded:
                self._commanded = False
                with self._lock:
                    self._actuate()
            now = time.monotonic()
            if now >= next_tick:
                self._tick(self._clock())
                next_tick = max(next_tick + self.tick_s, now)

    def _drain(self, timeout_s: float = 0.2) -> None:
        """Act on the frames the host sent before it closed the link (its last relax among
        them): real boards process what reached them, however busy this machine was."""
        deadline = time.monotonic() + timeout_s
        try:
            frame = self.transport.recv(0.02)
            while frame is not None and time.monotonic() < deadline:
                self._on_frame(frame)
                frame = self.transport.recv(0.02)
        except HardwareError:  # the host's end is gone and nothing is left to read
            pass
        if self._commanded:
            self._commanded = False
            with self._lock:
                self._actuate()

    def _on_frame(self, frame) -> None:
        if self._bus_off:
            return
        i = self._by_frame.get(frame.arbitration_id)
        now = self._clock()
        if i is None:
            for j in self._broadcast.get(frame.arbitration_id, ()):
                with self._lock:
                    reply = self.boards[j].receive(frame.arbitration_id, frame.data, now,
                                                   self._readings[j])
                if reply:
                    self._send_status(j, now, reply=True)
            return
        with self._lock:
            reply = self.boards[i].receive(frame.arbitration_id, frame.data, now,
                                           self._readings[i])
        # The plant gets the new commands once the frames that arrived together are all in
        # (see _run): one host cycle reaches real boards within a fraction of a millisecond,
        # and the equilibrium solver (tens of ms, more on a loaded machine) must not freeze
        # the arm on a half-updated set of commands for that long.
        self._commanded = True
        if reply:
            self._send_status(i, now, reply=True)

    def _tick(self, now: float) -> None:
        self._cycles += 1
        self._update_faults(now)
        with self._lock:
            state = self.plant.step(min(now - self._last_tick, 0.1))
            self._last_tick = now
            self._readings = self._read_all(state)
            for board, reading in zip(self.boards, self._readings, strict=True):
                board.supervise(now, reading)
            self._actuate()
        for i in range(len(self.boards)):
            self._send_status(i, now)
        if self.robot.joint_encoders and now >= self._next_joints:
            self._next_joints = now + self.status_period_s
            self._send_joints(state)

    def _actuate(self) -> None:
        modes, values = zip(*(b.actuation() for b in self.boards), strict=True)
        values = np.array(values, float)
        values = np.where(np.array(modes) == "length", values - self.encoder_offset_m, values)
        tension = np.array([m == "tension" for m in modes])
        if tension.any():  # boards servo on the loadcell reading: find the true tension
            s = self.plant.state
            true = self.effects.true_tension(self.model, values, s.approach, s.temperature)
            values = np.where(tension, true, values)
        self.plant.command(tuple(modes), values)

    def _read_all(self, state) -> list[SiReading]:
        """Every board's sensors: encoder, noisy loadcell (through the effects), °C."""
        tension = self.effects.read_tension(self.model, state.tension, state.approach,
                                            state.temperature)
        temperature = state.temperature
        if self.noise:
            tension = tension + self.rng.normal(0.0, 0.3, len(tension))
            temperature = temperature + self.rng.normal(0.0, 0.1, len(temperature))
        return [SiReading(float(state.length[i] + self.encoder_offset_m[i]), float(tension[i]),
                          float(temperature[i]),
                          self._fault_on("saturate-loadcell", board.spec.name))
                for i, board in enumerate(self.boards)]

    # -- faults ----------------------------------------------------------------------------
    def _fault_on(self, kind: str, muscle: str | None = None) -> bool:
        return any(f.kind == kind and (muscle is None or f.hits(muscle)) for f in self._active)

    def _update_faults(self, now: float) -> None:
        for spec in self.faults:
            if spec not in self._active and spec.active(self._sample, now - self._t0,
                                                         self._cycles):
                self._active.add(spec)
                log.info("mock arm: fault %s active", spec)
                if spec.kind == "drive-fault":  # latched by the board (edge)
                    with self._lock:
                        for board in self.boards:
                            if spec.hits(board.spec.name) and hasattr(board, "inject"):
                                board.inject(spec.kind)
                if spec.kind == "bus-off" and not self._bus_off:
                    self.transport.send_error(CAN_ERR_BUSOFF)
                    self._bus_off = True
        for board in self.boards:  # boards that follow the active set (level)
            if hasattr(board, "set_faults"):
                board.set_faults({f.kind for f in self._active if f.hits(board.spec.name)})
        self.plant.heat_rate_c_per_s[:] = [
            OVERHEAT_RATE_C_PER_S if self._fault_on("overheat", name) else 0.0
            for name in self.muscles]

    def _send_status(self, i: int, now: float, reply: bool = False) -> None:
        board = self.boards[i]
        name = board.spec.name
        with self._lock:
            frames = board.frames(now, self._readings[i], reply)
        if self._bus_off or self._fault_on("silent-board", name):
            return
        for fid, data in frames:
            self._sent[fid] = self._sent.get(fid, 0) + 1
            if self._fault_on("drop-frames", name) and self._sent[fid] % DROP_KEEP_EVERY:
                continue
            if self._fault_on("corrupt-frames", name):
                if not board.checksum:  # CAN's own CRC fails: the controllers see an error
                    self.transport.send_error(CAN_ERR_PROT)  # frame, the frame is lost
                    continue
                bad = bytearray(data)
                bad[1 + int(self.rng.integers(len(data) - 1))] ^= 1 << int(self.rng.integers(8))
                data = bytes(bad)
            self._send(fid, data)

    def _send_joints(self, state) -> None:
        if self._bus_off:
            return
        angles = self.effects.joint_reading(self.model, state.theta)
        self._joint_counter = (self._joint_counter + 1) & 0xF
        for j, angle in enumerate(angles):
            angle = float(np.clip(angle + (self.rng.normal(0, 1e-4) if self.noise else 0.0),
                                  _ANGLE_MIN, _ANGLE_MAX))
            self._send(*encode(JointStatus(j, self._joint_counter, angle)))

    def _send(self, fid: int, data: bytes) -> None:
        try:
            self.transport.send(fid, data)
        except HardwareError as exc:
            log.debug("mock arm send: %s", exc)
