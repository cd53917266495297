"""A simulated CiA 402 servo drive: a ``canopen.LocalNode`` built from the drive's EDS.

Written from CiA 301 (NMT, SDO server, PDOs, SYNC consumer, heartbeat producer 0x1017 and
consumer 0x1016, EMCY with the error register 0x1001) and CiA 402-2 (the power drive state
machine driven by the controlword 0x6040 and shown in the statusword 0x6041; modes of
operation 0x6060/0x6061; quick stop option code 0x605A), not from the PIMBS host: the host
is tested against it, and so is canopen's own ``BaseNode402``. canopen's LocalNode holds
the object dictionary and answers SDO; this module adds what a drive's firmware does with
the objects (canopen leaves that to the application).

PDOs, in NMT OPERATIONAL only, by each PDO's transmission type (0x14xx/0x18xx:02, CiA 301):
a TPDO of type 1..240 is sampled and sent after every n-th SYNC, type 0 after a SYNC when
its data changed, type 254/255 when its data changed or its event timer (0x18xx:05, ms)
ran out, never sooner than its inhibit time (0x18xx:03, 100 us) after the previous one;
types 241..253 (RTR only, reserved) are not sent. An RPDO of type 0..240 is taken into the
object dictionary at the next SYNC (the last one received counts), of type 254/255 at once.

SYNC supervision: with a communication cycle period 0x1006 set, a drive in Operation
enabled and a cyclic synchronous mode (8, 9, 10) that hears no SYNC for
``sync_loss_cycles`` periods reports it as a SYNC consumer does (EMCY 0x8100, communication
error) and faults. Real drives allow from 1.5 periods (the CANopenNode stack) to a SYNC
timeout set in milliseconds (Bonfiglioli's inverters: off, or up to 60 s); this one allows
``SYNC_LOSS_CYCLES`` periods (0.5 s at 1 kHz), what a Python host that shares a loaded
computer with the simulation holds: its SYNC thread has been seen 100 ms late. The drive's
clock advances with the simulation's ticks, at most ``CLOCK_STEP_S`` per tick, so a stall
of this whole process (which a drive on its own CPU never has) is not mistaken for a lost
SYNC; a SYNC that stops is.

Faults (``--fault`` kinds): ``drive-fault`` (the drive detects an overcurrent: EMCY 0x2310,
Fault), ``overheat`` (the motor heats; past ``TRIP_C`` the drive faults with EMCY 0x4310),
``lost-heartbeat`` (its heartbeat producer stops; PDOs go on), ``lost-sync`` (SYNC no longer
reaches it: it faults as above), and a host whose heartbeat stops (the consumer 0x1016
fires: EMCY 0x8130, Fault, as abort connection option 1 says).
"""

from __future__ import annotations

from dataclasses import dataclass

import canopen

from pimbs_hw.protocol.board import RawFrame

TRIP_C = 85.0  # the drive's own thermal trip
SYNC_ID = 0x080  # 0x1005 COB-ID SYNC (CiA 301 default)
SYNC_LOSS_CYCLES = 500  # SYNC periods (0x1006) without a SYNC before the drive faults
CLOCK_STEP_S = 0.025  # most drive time one simulation tick may advance (see docstring)
CYCLIC_MODES = (8, 9, 10)  # cyclic synchronous position, velocity, torque
RELAX_MATCH_N = 0.5
# statusword bits per state (CiA 402-2 table "state coding"); 0x10 voltage enabled
STATUSWORD = {"Not ready to switch on": 0x00, "Switch on disabled": 0x40,
              "Ready to switch on": 0x31, "Switched on": 0x33, "Operation enabled": 0x37,
              "Quick stop active": 0x17, "Fault reaction active": 0x1F, "Fault": 0x18}
REMOTE = 0x200  # statusword bit 9: the controlword is obeyed
OPERATIONAL = 5
EMCY_CODES = {"drive-fault": (0x2310, 0x03), "overheat": (0x4310, 0x09),
              "host-heartbeat": (0x8130, 0x11),
              "sync-loss": (0x8100, 0x11)}  # code, error register (CiA 301 bits)


@dataclass
class _Sent:
    """Transmission state of one TPDO."""

    syncs: int = 0  # SYNCs since it last went out (cyclic types)
    time: float = float("-inf")  # when it last went out
    data: bytes | None = None  # what it carried


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

    def __init__(self, spec, drive, now: float, winding: int = 1,
                 sync_loss_cycles: int = SYNC_LOSS_CYCLES) -> None:
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
        # NMT, SYNC, the host's heartbeat
        self.broadcast_ids = {0x000, SYNC_ID, self.host_heartbeat_id}
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
        self.syncs = 0  # SYNCs heard (for tests)
        self.cycle_us = 0  # 0x1006 communication cycle period, 0: SYNC not supervised
        self.sync_loss_cycles = sync_loss_cycles
        self._since_sync = 0.0  # drive time without a SYNC while supervised
        self._clock = now  # the simulation time the drive clock last advanced to
        self._sync_tx: list[tuple[object, _Sent]] = []  # TPDOs sent on SYNC (types 0..240)
        self._event_tx: list[tuple[object, _Sent]] = []  # event-driven TPDOs (254, 255)
        self._pending: dict[int, object] = {}  # RPDOs (by COB-ID) to take at the next SYNC
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
        elif index == 0x1006:
            self.cycle_us = value
        elif index == 0x1016 and subindex == 1:
            self.consumer_ms = value & 0xFFFF if value >> 16 & 0x7F == self.drive.host_node_id \
                else 0
        else:
            self.targets[(index, subindex)] = value

    def _on_rpdo(self, pdo_map) -> None:
        if self.node.nmt.state != "OPERATIONAL":
            return  # CiA 301: PDOs only in OPERATIONAL
        if pdo_map.trans_type is not None and pdo_map.trans_type <= 240:
            self._pending[pdo_map.cob_id] = pdo_map  # synchronous: taken at the next SYNC
        else:
            self._take(pdo_map)

    def _take(self, pdo_map) -> None:
        for var in pdo_map.map:
            self.node.set_data(var.index, var.subindex, var.get_data())

    # -- PDO transmission (CiA 301) --------------------------------------------------------
    def _in_force(self) -> None:
        """At NMT start: the PDO configuration the host wrote takes effect."""
        self.node.tpdo.read()
        self.node.rpdo.read()
        self._pending = {}
        self._sync_tx, self._event_tx = [], []
        for pdo_map in self.node.tpdo.map.values():
            kind = pdo_map.trans_type
            if not (pdo_map.enabled and pdo_map.map and kind is not None):
                continue
            if kind <= 240:
                self._sync_tx.append((pdo_map, _Sent()))
            elif kind >= 254:  # 241..253: RTR only or reserved, never sent unasked
                self._event_tx.append((pdo_map, _Sent()))

    def _sample(self, pdo_map) -> bytes:
        return b"".join(self._value(v) for v in pdo_map.map)

    def _value(self, var) -> bytes:
        """An object's bytes as the drive would send them; zeros for one it does not model
        (velocity actual 0x606C) and whose EDS gives no default."""
        try:
            return self.node.get_data(var.index, var.subindex)
        except canopen.SdoAbortedError:
            return bytes(len(var.od) // 8)

    def _send(self, pdo_map, sent: _Sent, data: bytes, now: float) -> None:
        sent.syncs, sent.time, sent.data = 0, now, data
        self.net.outbox.append((pdo_map.cob_id, data))

    def _on_sync(self, now: float) -> None:
        """Synchronous TPDOs sample and go out, then synchronous RPDOs take effect."""
        self.syncs += 1
        self._since_sync = 0.0
        if self.node.nmt.state != "OPERATIONAL":
            return
        for pdo_map, sent in self._sync_tx:
            kind = pdo_map.trans_type
            sent.syncs += 1
            if kind and sent.syncs >= kind:
                self._send(pdo_map, sent, self._sample(pdo_map), now)
            elif kind == 0 and (data := self._sample(pdo_map)) != sent.data:
                self._send(pdo_map, sent, data, now)
        pending, self._pending = self._pending, {}
        for pdo_map in pending.values():
            self._take(pdo_map)

    def _events(self, now: float) -> None:
        """Event-driven TPDOs (254, 255): on a change, or when the event timer runs out."""
        if self.node.nmt.state != "OPERATIONAL":
            return
        for pdo_map, sent in self._event_tx:
            if now - sent.time < (pdo_map.inhibit_time or 0) / 1e4:
                continue
            data = self._sample(pdo_map)
            timer = (pdo_map.event_timer or 0) / 1000.0
            if data != sent.data or (timer and now - sent.time >= timer):
                self._send(pdo_map, sent, data, now)

    def _supervise_sync(self, now: float) -> None:
        step, self._clock = min(max(0.0, now - self._clock), CLOCK_STEP_S), now
        if not (self.cycle_us and self.state == "Operation enabled"
                and self.mode_op in CYCLIC_MODES):
            self._since_sync = 0.0
            return
        self._since_sync += step
        if self._since_sync > self.sync_loss_cycles * self.cycle_us / 1e6:
            self._fault("sync-loss")

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
        if fid == SYNC_ID:
            if "lost-sync" not in self.injected:
                self._on_sync(now)
            return bool(self.net.outbox)
        before = self.node.nmt.state
        self.net.notify(fid, bytearray(data), now)
        if self.node.nmt.state != before and self.node.nmt.state == "OPERATIONAL":
            self._in_force()
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
        self._supervise_sync(now)
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
        """What the drive sends now: answers, EMCY and SYNC-driven TPDOs queued since the
        last call, its heartbeat when due, and event-driven TPDOs."""
        self.reading = reading
        self._events(now)
        out, self.net.outbox = self.net.outbox, []
        for task in self.net.tasks:
            if not task.stopped and now >= task.due:
                task.due = max(task.due + task.period, now)
                if "lost-heartbeat" not in self.injected:
                    out.append((task.can_id, task.data))
        self.net.tasks = [t for t in self.net.tasks if not t.stopped]
        return out


def _range(od) -> tuple[int, int]:
    bits = len(od)
    signed = od.data_type in (0x2, 0x3, 0x4, 0x15)
    return (-(1 << bits - 1), (1 << bits - 1) - 1) if signed else (0, (1 << bits) - 1)
