"""Simulated muscle boards on a bus: the whole arm, runnable in a background thread.

``MockArm`` speaks the board protocol on a python-can bus (``virtual:NAME`` in-process, or
any port a CAN transport accepts, e.g. ``udp_multicast`` or ``vcan0`` across processes) or on
a pty (``link="pty"``; the driver opens ``mock.port``). Behind the boards is ``Plant``: the
arm model's static equilibrium with first-order settling, noisy sensors, load heating, an
optional concealed effect (``effects.py``) and injected faults (``faults.py``).

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
from pimbs_hw.mock.board import RAW_MAX, RAW_MIN, TEMP_MAX, TEMP_MIN, Reading, SimBoard
from pimbs_hw.mock.effects import EffectStack
from pimbs_hw.mock.faults import FaultSpec, parse_faults
from pimbs_hw.mock.plant import Plant
from pimbs_hw.protocol.codec import (
    MAX_BOARDS,
    CodecError,
    JointStatus,
    Status,
    decode,
    encode,
    signal_range,
)
from pimbs_hw.transport import CanTransport, PtyMaster, SerialTransport, Transport
from pimbs_hw.transport.base import CAN_ERR_BUSOFF

log = logging.getLogger(__name__)
OVERHEAT_RATE_C_PER_S = 400.0  # injected thermal runaway: past any limit within 0.15 s
DROP_KEEP_EVERY = 4  # drop-frames: 3 of every 4 status frames lost (75 %, never a long gap)
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


def _open_link(link: str) -> tuple[Transport, str]:
    if link == "pty":
        master = PtyMaster()
        return SerialTransport(master, name=f"mock pty {master.slave_path}"), master.slave_path
    return CanTransport(link), link


class MockArm:
    """Simulated boards of ``robot`` behind ``link``; ``port`` is what a driver opens."""

    def __init__(self, robot, link: str = "virtual", *, model=None, effect=None,
                 faults=(), seed: int = 0, speed: float = 1.0, tick_s: float = 0.01,
                 status_period_s: float = 0.02, noise: bool = True) -> None:
        from pimbs_calibration.arm_model import ArmModel
        from pimbs_calibration.description import load_robot

        self.robot = load_robot(robot) if isinstance(robot, str | Path) else robot
        self.muscles = tuple(m.name for m in self.robot.muscles)
        self.faults: tuple[FaultSpec, ...] = parse_faults(faults, self.muscles)
        self.effects = EffectStack(effect)
        # own model instance: pinocchio data is not thread-safe, the solver thread uses it
        self.model = self.effects.physics(model if model is not None else ArmModel(self.robot))
        self.rng = np.random.default_rng(seed)
        self.noise = noise
        self.tick_s, self.status_period_s = tick_s, status_period_s
        m = len(self.muscles)
        self.plant = Plant(self.model, speed=speed,
                           ambient_c=25.0 + (self.rng.normal(0, 0.5, m) if noise else 0.0))
        now = time.monotonic()
        self.boards = [SimBoard(spec, now) for spec in self.robot.muscles]
        self._by_id = {spec.board_id: i for i, spec in enumerate(self.robot.muscles)}
        if len(self._by_id) != m or not all(0 <= b < MAX_BOARDS for b in self._by_id):
            raise ValueError(f"{self.robot.name}: board ids must be unique in 0..{MAX_BOARDS - 1}")
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
        self._next_status = np.full(m, now)
        self._next_joints = self._last_tick = now
        self._readings = self._read_all(self.plant.state)

    # -- public ----------------------------------------------------------------------------
    def start(self) -> MockArm:
        self._thread = threading.Thread(target=self._run, name=f"mock-arm {self.port}",
                                        daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
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
            relax = np.array([(b.relax_raw - b.spec.loadcell_offset_counts)
                              * b.spec.loadcell_n_per_count for b in self.boards])
            true_relax = self.effects.true_tension(self.model, relax, s.approach, s.temperature)
            return MockSnapshot(s.theta.copy(), s.tension.copy(), s.length.copy(),
                                s.temperature.copy(), tuple(b.mode for b in self.boards),
                                true_relax, tuple(f"{f.kind}:{f.muscle or '*'}"
                                                  for f in self._active))

    def settled(self) -> bool:
        with self._lock:
            return self.plant.settled()

    # -- board loop ------------------------------------------------------------------------
    def _run(self) -> None:
        next_tick = time.monotonic()
        while not self._stop.is_set():
            try:
                frame = self.transport.recv(max(0.0, next_tick - time.monotonic()))
                while frame is not None:
                    self._on_frame(frame)
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
                self._tick(now)
                next_tick = max(next_tick + self.tick_s, now)

    def _on_frame(self, frame) -> None:
        if self._bus_off:
            return
        try:
            msg = decode(frame.arbitration_id, frame.data)
        except CodecError:
            return  # a board drops what fails its CRC; the host's watchdog story covers it
        i = self._by_id.get(msg.board_id)
        if i is None or isinstance(msg, Status | JointStatus):
            return
        now = time.monotonic()
        with self._lock:
            self.boards[i].receive(msg, now, self._readings[i])
        # The plant gets the new commands once the frames that arrived together are all in
        # (see _run): one host cycle reaches real boards within a fraction of a millisecond,
        # and the equilibrium solver (tens of ms, more on a loaded machine) must not freeze
        # the arm on a half-updated set of commands for that long.
        self._commanded = True
        self._send_status(i, now)

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
        for i in np.flatnonzero(now >= self._next_status):
            self._send_status(int(i), now)
        if self.robot.joint_encoders and now >= self._next_joints:
            self._next_joints = now + self.status_period_s
            self._send_joints(state)

    def _actuate(self) -> None:
        modes, values = zip(*(b.actuation() for b in self.boards), strict=True)
        values = np.array(values)
        tension = np.array([m == "tension" for m in modes])
        if tension.any():  # boards servo on the loadcell reading: find the true tension
            s = self.plant.state
            true = self.effects.true_tension(self.model, values, s.approach, s.temperature)
            values = np.where(tension, true, values)
        self.plant.command(tuple(modes), values)

    def _read_all(self, state) -> list[Reading]:
        """Every board's sensors: encoder counts, noisy loadcell (through the effects), °C."""
        tension = self.effects.read_tension(self.model, state.tension, state.approach,
                                            state.temperature)
        temperature = state.temperature
        if self.noise:
            tension = tension + self.rng.normal(0.0, 0.3, len(tension))
            temperature = temperature + self.rng.normal(0.0, 0.1, len(temperature))
        readings = []
        for i, board in enumerate(self.boards):
            spec = board.spec
            raw = round(spec.loadcell_offset_counts + tension[i] / spec.loadcell_n_per_count)
            if self._fault_on("saturate-loadcell", spec.name):
                raw = RAW_MAX
            readings.append(Reading(round(state.length[i] * spec.counts_per_m),
                                    int(np.clip(raw, RAW_MIN, RAW_MAX)),
                                    float(np.clip(temperature[i], TEMP_MIN, TEMP_MAX))))
        return readings

    # -- faults ----------------------------------------------------------------------------
    def _fault_on(self, kind: str, muscle: str | None = None) -> bool:
        return any(f.kind == kind and (muscle is None or f.hits(muscle)) for f in self._active)

    def _update_faults(self, now: float) -> None:
        for spec in self.faults:
            if spec not in self._active and spec.active(self._sample, now - self._t0,
                                                         self._cycles):
                self._active.add(spec)
                log.info("mock arm: fault %s active", spec)
                if spec.kind == "bus-off" and not self._bus_off:
                    self.transport.send_error(CAN_ERR_BUSOFF)
                    self._bus_off = True
        self.plant.heat_rate_c_per_s[:] = [
            OVERHEAT_RATE_C_PER_S if self._fault_on("overheat", name) else 0.0
            for name in self.muscles]

    def _send_status(self, i: int, now: float) -> None:
        board = self.boards[i]
        self._next_status[i] = now + self.status_period_s
        name = board.spec.name
        with self._lock:
            fid, data = encode(board.status(self._readings[i]))
        if self._bus_off or self._fault_on("silent-board", name):
            return
        if self._fault_on("drop-frames", name) and board.counter % DROP_KEEP_EVERY:
            return
        if self._fault_on("corrupt-frames", name):
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
