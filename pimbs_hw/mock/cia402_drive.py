"""A simulated CiA 402 servo drive: a ``canopen.LocalNode`` built from the drive's EDS.

Written from CiA 301 (NMT, SDO server, PDOs, heartbeat producer 0x1017 and consumer 0x1016,
EMCY with the error register 0x1001) and CiA 402-2 (the power drive state machine driven by
the controlword 0x6040 and shown in the statusword 0x6041; modes of operation 0x6060/0x6061;
quick stop option code 0x605A), not from the PIMBS host: the host is tested against it.
canopen's LocalNode holds the object dictionary and answers SDO; this module adds what a
drive's firmware does with the objects (canopen leaves that to the application).

Faults (``--fault`` kinds): ``drive-fault`` (the drive detects an overcurrent: EMCY 0x2310,
Fault), ``overheat`` (the motor heats; past ``TRIP_C`` the drive faults with EMCY 0x4310),
``lost-heartbeat`` (its heartbeat producer stops; PDOs go on), and a host whose heartbeat
stops (the consumer 0x1016 fires: EMCY 0x8130, Fault, as abort connection option 1 says).
"""

from __future__ import annotations

import canopen

from pimbs_hw.protocol.board import RawFrame

TRIP_C = 85.0  # the drive's own thermal trip
RELAX_MATCH_N = 0.5
# statusword bits per state (CiA 402-2 table "state coding"); 0x10 voltage enabled
STATUSWORD = {"Not ready to switch on": 0x00, "Switch on disabled": 0x40,
              "Ready to switch on": 0x31, "Switched on": 0x33, "Operation enabled": 0x37,
              "Quick stop active": 0x17, "Fault reaction active": 0x1F, "Fault": 0x18}
REMOTE = 0x200  # statusword bit 9: the controlword is obeyed
OPERATIONAL = 5
EMCY_CODES = {"drive-fault": (0x2310, 0x03), "overheat": (0x4310, 0x09),
              "host-heartbeat": (0x8130, 0x11)}  # code, error register (CiA 301 bits)


class _Task:
    """A periodic frame canopen asked for (heartbeat), sent on the simulation's clock."""

    def __init__(self, can_id: int, data, period: float) -> None:
        self.can_id, self.data, self.period = can_id, bytes(data), period
        self.due, self.stopped = 0.0, False

    def stop(self) -> None:
        self.stopped = True

    def update(self, data) -> None:
        self.data = bytes(data)


class _Outbox(canopen.Network):
    """A canopen network whose sends wait for the board's turn on the bus."""

    def __init__(self) -> None:
        super().__init__()
        self.outbox: list[RawFrame] = []
        self.tasks: list[_Task] = []

    def send_message(self, can_id: int, data, remote: bool = False) -> None:
        self.outbox.append((can_id, bytes(data)))

    def send_periodic(self, can_id: int, data, period: float, remote: bool = False) -> _Task:
        task = _Task(can_id, data, period)
        self.tasks.append(task)
        return task


def command_of(cw: int) -> str:
    """The device control command a controlword carries (CiA 402-2 command coding)."""
    if cw & 0x82 == 0x00:
        return "disable voltage"
    if cw & 0x86 == 0x02:
        return "quick stop"
    if cw & 0x87 == 0x06:
        return "shutdown"
    if cw & 0x8F == 0x07:
        return "switch on"  # also "disable operation"
    if cw & 0x8F == 0x0F:
        return "enable operation"  # also "switch on + enable operation"
    return "none"


# (state, command) -> next state: the transitions of the CiA 402-2 state machine
TRANSITIONS = {
    ("Switch on disabled", "shutdown"): "Ready to switch on",  # 2
    ("Ready to switch on", "switch on"): "Switched on",  # 3
    ("Ready to switch on", "enable operation"): "Operation enabled",  # 3 + 4
    ("Ready to switch on", "disable voltage"): "Switch on disabled",  # 7
    ("Ready to switch on", "quick stop"): "Switch on disabled",  # 7
    ("Switched on", "enable operation"): "Operation enabled",  # 4
    ("Switched on", "shutdown"): "Ready to switch on",  # 6
    ("Switched on", "disable voltage"): "Switch on disabled",  # 10
    ("Switched on", "quick stop"): "Switch on disabled",  # 10
    ("Operation enabled", "switch on"): "Switched on",  # 5
    ("Operation enabled", "shutdown"): "Ready to switch on",  # 8
    ("Operation enabled", "disable voltage"): "Switch on disabled",  # 9
    ("Operation enabled", "quick stop"): "Quick stop active",  # 11
    ("Quick stop active", "disable voltage"): "Switch on disabled",  # 12
}


class Cia402Board:
    """One simulated drive for ``MockArm`` (same duck type as ``boards.ProfileBoard``)."""

    checksum = False

    def __init__(self, spec, drive, now: float, winding: int = 1) -> None:
        self.spec, self.drive = spec, drive
        self.node = canopen.LocalNode(spec.board_id, drive.object_dictionary(spec.board_id))
        self.net = _Outbox()
        self.net[self.node.id] = self.node
        self.node.add_write_callback(self._on_write)
        self.node.add_read_callback(self._on_read)
        for pdo_map in self.node.rpdo.map.values():
            pdo_map.add_callback(self._on_rpdo)
        nid = self.node.id
        self.frame_ids = {0x600 + nid, *(base + nid for base in (0x200, 0x300, 0x400, 0x500))}
        self.host_heartbeat_id = 0x700 + drive.host_node_id
        self.broadcast_ids = {0x000, self.host_heartbeat_id}  # NMT, the host's heartbeat
        self.state = "Switch on disabled"  # after the automatic transition 1
        self.history = [self.state]  # every state entered (for tests)
        self.controlwords: list[int] = []  # every controlword received, SDO or RPDO
        self.cw = 0
        self.mode_op = 0
        self.targets: dict[tuple[int, int], int] = {}
        self.hold_m = 0.0
        # -1: this drive's position counts down as its wire pays out (how it is wound)
        self.winding = winding
        self.error_register, self.relax_n = 0, spec.f_floor
        self.injected: set[str] = set()
        self.host_seen: float | None = None
        self.consumer_ms = 0
        self.reading = None
        self._tpdo_due: dict[int, float] = {}
        self.node.nmt.send_command(0x81)  # power on: initialising, boot-up message
        self.node.nmt.send_command(0x80)  # then pre-operational (CiA 301)

    # -- object dictionary -----------------------------------------------------------------
    def _on_read(self, index: int, subindex: int, od):
        d, r = self.drive, self.reading
        if index == 0x6041:
            return STATUSWORD[self.state] | REMOTE
        if index == 0x6061:
            return self.mode_op
        if index == 0x1001:
            return self.error_register
        if r is None:
            return None
        for ref, value in ((d.tension_actual, r.tension_n), (d.position_actual, r.position_m),
                           (d.temperature, r.temperature_c)):
            if ref is not None and (index, subindex) == (ref.index, ref.subindex):
                sign = self.winding if ref is d.position_actual else 1
                raw = round(sign * value * ref.per_si)
                lo, hi = _range(od)
                return max(lo, min(hi, raw))
        return None

    def _on_write(self, index: int, subindex: int, od, data: bytes) -> None:
        value = od.decode_raw(data)
        if index == 0x6040:
            self._controlword(value)
        elif index == 0x6060:
            self.mode_op = value
        elif index == 0x1016 and subindex == 1:
            self.consumer_ms = value & 0xFFFF if value >> 16 & 0x7F == self.drive.host_node_id \
                else 0
        else:
            self.targets[(index, subindex)] = value

    def _on_rpdo(self, pdo_map) -> None:
        for var in pdo_map.map:
            self.node.set_data(var.index, var.subindex, var.get_data())

    # -- state machine ---------------------------------------------------------------------
    def _enter(self, state: str) -> None:
        if state != self.state:
            self.state = state
            self.history.append(state)
            if state == "Quick stop active" and self.reading is not None:
                self.hold_m = self.reading.position_m

    def _controlword(self, cw: int) -> None:
        self.controlwords.append(cw)
        rising = cw & 0x80 and not self.cw & 0x80
        self.cw = cw
        if self.state == "Fault":
            if rising and not self._fault_present():  # 15: fault reset
                self.error_register = 0
                self.node.emcy.reset(0)
                self._enter("Switch on disabled")
            return
        if self.state == "Fault reaction active" or cw & 0x80:
            return
        nxt = TRANSITIONS.get((self.state, command_of(cw)))
        if (self.state, command_of(cw)) == ("Quick stop active", "enable operation") and (
                self._quick_stop_option() in (5, 6, 7, 8)):
            nxt = "Operation enabled"  # 16: only drives that stay in quick stop (0x605A 5-8)
        if nxt is not None:
            self._enter(nxt)

    def _fault(self, kind: str) -> None:
        if self.state in ("Fault", "Fault reaction active"):
            return
        code, register = EMCY_CODES[kind]
        self.error_register = register
        self.node.emcy.send(code, register)
        self._enter("Fault reaction active")  # 13

    def _fault_present(self) -> bool:
        r = self.reading
        return "drive-fault" in self.injected or (r is not None and r.temperature_c >= TRIP_C)

    # -- MockArm interface -----------------------------------------------------------------
    def set_faults(self, kinds: set[str]) -> None:
        self.injected = kinds

    def receive(self, fid: int, data: bytes, now: float, reading) -> bool:
        self.reading = reading
        if fid == self.host_heartbeat_id:
            self.host_seen = now
            return False
        before = self.node.nmt.state
        self.net.notify(fid, bytearray(data), now)
        if self.node.nmt.state != before and self.node.nmt.state == "OPERATIONAL":
            self.node.tpdo.read()  # the PDO configuration the host wrote, now in force
            self.node.rpdo.read()
            self._tpdo_due = {}
        return bool(self.net.outbox)

    def supervise(self, now: float, reading) -> None:
        self.reading = reading
        if self.state == "Fault reaction active":
            self._enter("Fault")  # 14: the reaction (power stage off) is done
        elif self.state == "Quick stop active" and self._quick_stop_option() in (1, 2, 3, 4):
            self._enter("Switch on disabled")  # 12: quick stop done (0x605A 1..4)
        if "drive-fault" in self.injected:
            self._fault("drive-fault")
        if reading.temperature_c >= TRIP_C:
            self._fault("overheat")
        if (self.consumer_ms and self.host_seen is not None
                and now - self.host_seen > self.consumer_ms / 1000.0):
            self.host_seen = None  # one event per loss (CiA 301: consumer restarts on the
            self._fault("host-heartbeat")  # next heartbeat received)

    def _quick_stop_option(self) -> int:
        """0x605A; 2 (ramp, then Switch on disabled) where the EDS has none."""
        return self.node.sdo[0x605A].raw if 0x605A in self.node.object_dictionary else 2

    @property
    def powered(self) -> bool:
        return self.state in ("Operation enabled", "Quick stop active")

    def actuation(self) -> tuple[str, float]:
        d = self.drive
        if self.state == "Quick stop active":
            return "length", self.hold_m
        if self.state != "Operation enabled":
            return "tension", 0.0  # power stage off: the motor turns freely, the wire is slack
        if self.mode_op in (8, 1) and d.position_target is not None:
            ref = d.position_target
            return "length", (self.winding * self.targets.get((ref.index, ref.subindex), 0)
                              / ref.per_si)
        ref = d.tension_target
        return "tension", max(0.0, self.targets.get((ref.index, ref.subindex), 0) / ref.per_si)

    @property
    def mode(self) -> str:
        kind, value = self.actuation()
        if not self.powered:
            return "off"
        if self.state == "Quick stop active":
            return "hold"
        if kind == "tension":
            return "relax" if abs(value - self.relax_n) < RELAX_MATCH_N else "tension"
        return "position"

    def frames(self, now: float, reading, reply: bool = False) -> list[RawFrame]:
        self.reading = reading
        out, self.net.outbox = self.net.outbox, []
        for task in self.net.tasks:
            if not task.stopped and now >= task.due:
                task.due = max(task.due + task.period, now)
                if "lost-heartbeat" not in self.injected:
                    out.append((task.can_id, task.data))
        self.net.tasks = [t for t in self.net.tasks if not t.stopped]
        if self.node.nmt.state != "OPERATIONAL" or reply:
            return out
        for n, pdo_map in self.node.tpdo.map.items():
            if not pdo_map.enabled or not pdo_map.event_timer or not pdo_map.map:
                continue
            due = self._tpdo_due.get(n, now)
            if now >= due:
                self._tpdo_due[n] = max(due + pdo_map.event_timer / 1000.0, now)
                out.append((pdo_map.cob_id, b"".join(
                    self.node.get_data(v.index, v.subindex) for v in pdo_map.map)))
        return out


def _range(od) -> tuple[int, int]:
    bits = len(od)
    signed = od.data_type in (0x2, 0x3, 0x4, 0x15)
    return (-(1 << bits - 1), (1 << bits - 1) - 1) if signed else (0, (1 << bits) - 1)
