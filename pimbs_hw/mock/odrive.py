"""A simulated ODrive axis (firmware 0.6, CANSimple), written from ODrive's documentation.

Not from PIMBS's driver or profile: the frames are packed by hand from ODrive's CAN protocol
page (little-endian; frame id = node_id << 5 | cmd_id; every message 8 bytes except
Clear_Errors, 1, and Estop, 0), and the behaviour follows ODrive's documented state machine:

- the axis boots in IDLE (``AxisState`` 1) with the motor off;
- ``Set_Axis_State`` 8 enters CLOSED_LOOP_CONTROL, refused while an error is latched
  (``Clear_Errors`` first); entering it holds the current position (input_pos = pos_estimate,
  input_torque = 0); ``Set_Axis_State`` 1 goes back to IDLE;
- any error disarms: the axis drops to IDLE and the error stays in the heartbeat's
  ``Axis_Error`` (active_errors | disarm_reason, ``ODriveError`` flags) until
  ``Clear_Errors``; a condition that still holds (an injected gate-driver fault) is raised
  again at once;
- the watchdog (``axis.config.enable_watchdog``) expires when no frame for the axis arrived
  within ``watchdog_timeout`` while armed: ``WATCHDOG_TIMER_EXPIRED`` (0x01000000), IDLE;
- the heartbeat carries the true Axis_State, Axis_Error and Procedure_Result (BUSY while
  in closed loop, CANCELLED after an IDLE request, DISARMED after an error);
- estimates move the way the motor turns: a positive torque turns the rotor positive. The
  wire is wound on a pulley either way round (``winding`` +1: a positive turn reels the
  wire in, so it pulls and shortens the muscle; -1: it pays the wire out). A torque that
  pays the wire out makes the wire slack and the unloaded rotor run at ``vel_limit``
  (ODrive's torque-mode velocity limiter) until the torque reverses.
- Get_Torques reports the torque setpoint (Torque_Target) and the torque the wire's
  tension puts on the rotor (Torque_Estimate); Get_Temperature the FET (inverter) and motor
  temperatures.

Same interface as ``boards.ProfileBoard``; ``MockArm`` uses it for the ``odrive-cansimple``
profile.
"""

from __future__ import annotations

import math
import struct

from pimbs_hw.protocol.board import RawFrame

# CANSimple command ids (ODrive CAN protocol, firmware 0.6)
GET_VERSION, HEARTBEAT, ESTOP = 0x00, 0x01, 0x02
SET_AXIS_STATE, GET_ENCODER_ESTIMATES, SET_CONTROLLER_MODE = 0x07, 0x09, 0x0B
SET_INPUT_POS, SET_INPUT_TORQUE, GET_TEMPERATURE = 0x0C, 0x0E, 0x15
CLEAR_ERRORS, GET_TORQUES = 0x18, 0x1C
# AxisState, ControlMode, ProcedureResult and ODriveError values used here
IDLE, CLOSED_LOOP_CONTROL = 1, 8
TORQUE_CONTROL, POSITION_CONTROL = 1, 3
SUCCESS, BUSY, CANCELLED, DISARMED = 0, 1, 2, 3
DRV_FAULT, WATCHDOG_TIMER_EXPIRED, ESTOP_REQUESTED = 0x20, 0x01000000, 0x02000000

VEL_LIMIT_TURNS_S = 2.0  # controller.config.vel_limit default
PERIODS_S = {HEARTBEAT: 0.1, GET_ENCODER_ESTIMATES: 0.01, GET_TORQUES: 0.01,
             GET_TEMPERATURE: 0.1, GET_VERSION: 1.0}  # *_msg_rate_ms as the profile asks
MAX_CATCH_UP = 50
RELAX_MATCH_N = 0.5  # a torque this close to the holding floor is the host's relax
FIRMWARE = (2, 3, 6, 56, 0, 6, 11, 0)  # protocol 2, hw v3.6-56V, fw 0.6.11 (released)


class ODriveAxis:
    """One simulated ODrive axis on node ``spec.board_id``, driving one muscle."""

    checksum = False

    def __init__(self, spec, now: float, *, turns_per_m: float, nm_per_n: float,
                 winding: int = 1, watchdog_s: float | None = 0.6,
                 torque_limit_nm: float = 5.0) -> None:
        if not 0 <= spec.board_id <= 63:
            raise ValueError(f"muscle {spec.name}: ODrive node_id {spec.board_id} is outside "
                             "0..63")
        self.spec, self.node = spec, spec.board_id
        self.turns_per_m, self.nm_per_n = abs(turns_per_m), abs(nm_per_n)
        self.winding = 1 if winding >= 0 else -1
        self.watchdog_s, self.torque_limit = watchdog_s, torque_limit_nm
        self.relax_n = spec.f_floor
        self.state, self.procedure = IDLE, SUCCESS
        self.active = 0  # conditions that hold now (ODriveError flags)
        self.disarm_reason = 0  # latched until Clear_Errors
        self.persistent = 0  # injected conditions that no Clear_Errors removes
        self.control_mode, self.input_pos, self.input_torque = POSITION_CONTROL, math.nan, 0.0
        self.commanded = False  # an input arrived since the axis was armed
        self.last_feed = now
        self.slack_m = 0.0  # wire paid out beyond taut by a rotor running free
        self.turns = self.vel = math.nan
        self.last_t = now
        self.frame_ids = {self.node << 5 | cmd for cmd in range(32)}
        self.due = {cmd: now for cmd in PERIODS_S}

    # -- what the host sees ------------------------------------------------------------------
    @property
    def axis_error(self) -> int:
        return self.active | self.disarm_reason

    @property
    def mode(self) -> str:
        """For ``MockArm.snapshot``: idle | hold | position | relax | tension."""
        if self.state != CLOSED_LOOP_CONTROL:
            return "idle"
        if self.control_mode == POSITION_CONTROL:
            return "position" if self.commanded else "hold"
        pull = self._pull_n()
        return "relax" if abs(pull - self.relax_n) < RELAX_MATCH_N else "tension"

    def _turns_of(self, position_m: float) -> float:
        """Rotor turns for a wire length (plus the slack it paid out): reeling in = +."""
        return -self.winding * (position_m + self.slack_m) * self.turns_per_m

    def _pull_n(self) -> float:
        """Tension the torque setpoint asks of the wire (negative: it pays the wire out)."""
        torque = max(-self.torque_limit, min(self.torque_limit, self.input_torque))
        return self.winding * torque / self.nm_per_n

    # -- host frames -------------------------------------------------------------------------
    def receive(self, fid: int, data: bytes, now: float, reading) -> bool:
        if fid >> 5 != self.node:
            return False
        cmd = fid & 0x1F
        self.last_feed = now  # every frame to the axis feeds its watchdog
        if cmd == SET_AXIS_STATE and len(data) >= 4:
            requested = struct.unpack_from("<I", data)[0]
            if requested == CLOSED_LOOP_CONTROL and self.state != CLOSED_LOOP_CONTROL:
                if self.axis_error:
                    return False  # refused: errors must be cleared first
                self.state, self.procedure = CLOSED_LOOP_CONTROL, BUSY
                self.input_pos = self._turns_of(reading.position_m)
                self.input_torque, self.commanded = 0.0, False
            elif requested == IDLE and self.state != IDLE:
                self.state, self.procedure = IDLE, CANCELLED
        elif cmd == SET_CONTROLLER_MODE and len(data) >= 8:
            mode = struct.unpack_from("<II", data)[0]
            if mode != self.control_mode:
                self.control_mode = mode
                if mode == POSITION_CONTROL:
                    self.input_pos = self._turns_of(reading.position_m)
        elif cmd == SET_INPUT_POS and len(data) >= 8:
            self.input_pos = struct.unpack_from("<f", data)[0]
            self.commanded = True
        elif cmd == SET_INPUT_TORQUE and len(data) >= 4:
            self.input_torque = struct.unpack_from("<f", data)[0]
            self.commanded = True
        elif cmd == CLEAR_ERRORS:
            self.active = self.persistent  # what still holds is raised again at once
            self.disarm_reason = self.persistent
        elif cmd == ESTOP:
            self._disarm(ESTOP_REQUESTED)
        return False  # CANSimple answers no command; the axis reports on its cycle

    def _disarm(self, error: int) -> None:
        self.disarm_reason |= error
        if self.state == CLOSED_LOOP_CONTROL:
            self.procedure = DISARMED
        self.state = IDLE

    def inject(self, kind: str) -> None:
        """Fault injection: ``drive-fault`` = the gate driver faults and stays faulted."""
        if kind == "drive-fault":
            self.persistent |= DRV_FAULT
            self.active |= DRV_FAULT
            self._disarm(DRV_FAULT)

    # -- every control cycle -----------------------------------------------------------------
    def supervise(self, now: float, reading) -> None:
        dt, self.last_t = max(now - self.last_t, 0.0), now
        if (self.state == CLOSED_LOOP_CONTROL and self.watchdog_s
                and now - self.last_feed > self.watchdog_s):
            self._disarm(WATCHDOG_TIMER_EXPIRED)
        free = VEL_LIMIT_TURNS_S / self.turns_per_m * dt  # m of wire a free rotor moves
        if self.state == CLOSED_LOOP_CONTROL and self.control_mode == TORQUE_CONTROL:
            pull = self._pull_n()
            if pull < 0:
                self.slack_m += free  # the rotor runs free, paying the wire out
            elif pull > 0:
                self.slack_m = max(0.0, self.slack_m - free)  # reels the slack back in
        turns = self._turns_of(reading.position_m)
        if math.isfinite(self.turns) and dt > 0:
            self.vel += 0.3 * ((turns - self.turns) / dt - self.vel)  # estimator low-pass
        else:
            self.vel = 0.0
        self.turns = turns

    def actuation(self) -> tuple[str, float]:
        """(plant mode, value): the wire's length (encoder frame, m) or tension (N)."""
        if self.state != CLOSED_LOOP_CONTROL:
            return "tension", 0.0  # motor off: nothing holds the wire
        if self.control_mode == POSITION_CONTROL:
            if math.isnan(self.input_pos):
                return "tension", 0.0
            return "length", -self.input_pos / (self.winding * self.turns_per_m) - self.slack_m
        pull = self._pull_n()
        return "tension", pull if pull > 0 and self.slack_m == 0.0 else 0.0

    def _torques(self, reading) -> tuple[float, float]:
        """(Torque_Target, Torque_Estimate) in N·m."""
        if self.state != CLOSED_LOOP_CONTROL:
            return 0.0, 0.0
        taut = self.slack_m == 0.0
        load = (self.torque_limit * self.winding if reading.saturated else
                self.winding * reading.tension_n * self.nm_per_n) if taut else 0.0
        if self.control_mode == TORQUE_CONTROL:
            target = max(-self.torque_limit, min(self.torque_limit, self.input_torque))
            return target, load
        return load, load

    def _payload(self, cmd: int, reading) -> bytes:
        if cmd == HEARTBEAT:
            done = 1 if self.state == CLOSED_LOOP_CONTROL else 0
            return struct.pack("<IBBBx", self.axis_error, self.state, self.procedure, done)
        if cmd == GET_ENCODER_ESTIMATES:
            return struct.pack("<ff", self.turns, self.vel)
        if cmd == GET_TORQUES:
            return struct.pack("<ff", *self._torques(reading))
        if cmd == GET_TEMPERATURE:
            motor = reading.temperature_c
            fet = 25.0 + 0.3 * (motor - 25.0)  # the inverter warms with the motor's load
            return struct.pack("<ff", fet, motor)
        return bytes(FIRMWARE)

    def frames(self, now: float, reading, reply: bool = False) -> list[RawFrame]:
        if math.isnan(self.turns):
            self.supervise(now, reading)
        out = []
        for cmd, period in PERIODS_S.items():
            if now < self.due[cmd]:
                continue
            owed = min(1 + int((now - self.due[cmd]) / period), MAX_CATCH_UP)
            self.due[cmd] = max(self.due[cmd] + owed * period, now - period)
            payload = self._payload(cmd, reading)
            out.extend([(self.node << 5 | cmd, payload)] * owed)
        return out
