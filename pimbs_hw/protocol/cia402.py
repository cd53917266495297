"""CiA 402 servo drives over CANopen behind the board-protocol seam, through ``canopen``.

One drive per muscle, node id = the muscle's ``board_id``, described by the maker's EDS and
a drive file (``cia402_config.py``). At connect (``connect``, over SDO with canopen's
client): NMT pre-operational; identity (0x1018) and supported modes (0x6502) read; if any
drive runs a cyclic synchronous mode, the bus's SYNC started (``canopen_link.start_sync``,
``sync_period_us``, 1 ms by default) and the communication cycle period 0x1006 and the
interpolation time period 0x60C2 written where the EDS has them; the drive's heartbeat
producer (0x1017) and its consumer of the host's heartbeat (0x1016, the host watchdog)
set; the tension ceiling written to Max torque (0x6072) where the EDS has it; RPDOs and
TPDOs mapped (canopen ``PdoMap`` save, packed into the map sizes the EDS allows) with their
transmission types, read back to be sure the drive took them; the state machine walked
Shutdown 0x06 -> Switch on 0x07 -> Enable operation 0x0F (after a Fault reset, bit 7 rising
edge, if the drive reports Fault), each step waiting for the statusword to show the state;
then NMT start.

Cyclic: every command is RPDOs (controlword 0x0F, mode of operation, target) built with
canopen's PDO maps, plus the host's heartbeat frame: a host that stops commanding stops its
heartbeat, and the drives' heartbeat consumer acts. Under SYNC the RPDOs are synchronous
(transmission type 1: a drive takes them at the next SYNC) and the drives send their TPDOs
(statusword, mode display, actual torque, actual position, optional temperature) after
every n-th SYNC (type n = status period / SYNC period); without SYNC both are event-driven
(type 255, TPDO event timer = the status period, inhibit time half of it). Tension mode is
cyclic synchronous torque (10) or, where 0x6502 says the drive lacks it, profile torque (4);
length mode is cyclic synchronous position (8) or profile position (1). Relax = torque mode
at the holding floor; stop = the CiA 402 quick stop (controlword 0x02). ``close`` stops the
SYNC after one last SYNC, so the relax sent before it takes effect.

Everything the host reports is what a drive sent: the state from its statusword, the fault
from its EMCY (code, error register 0x1001), its NMT state from its heartbeat. A drive in a
cyclic synchronous mode that reports a communication error (EMCY 0x8100, what a SYNC
consumer sends when SYNC stops within its 0x1006 supervision) is named as SYNC lost at once:
its synchronous TPDOs, statusword included, need the SYNC it no longer hears.
"""

from __future__ import annotations

import math
import queue
import struct
import time
from collections.abc import Sequence

import canopen
from canopen.emcy import EmcyError
from canopen.nmt import NMT_STATES
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from pimbs_hw.host_lag import host_lag
from pimbs_hw.protocol import cia402_states as sm
from pimbs_hw.protocol.board import BoardLimits, BoardProtocol, Capabilities, RawFrame, Update
from pimbs_hw.protocol.canopen_link import SYNC_ID, SyncProducer, attached, start_sync
from pimbs_hw.protocol.cia402_config import DriveFile, DriveFileError, ObjectRef, find_object
from pimbs_hw.protocol.codec import Fault
from pimbs_hw.safety import BoardFault, BoardSilent, Overheat, SafetyStop, WatchdogExpired

NAME = "cia402"
SDO_TIMEOUT_S = 0.5  # per request; a drive on a loaded bus answers within milliseconds
# An SDO exchange that timed out while this process could not run for at least this long is
# asked again (at most SDO_STALL_RETRIES times): the answer may have come while nobody read
# it. A drive that does not answer a host that could run is silent at the first timeout.
SDO_STALL_S = 0.05
SDO_STALL_RETRIES = 3
# how canopen's SDO client says the answer it read belongs to another object
STALE_ANSWER = "Node returned a value for"
STATE_WAIT_S = 1.0  # per state machine step
HEARTBEAT_MISSES = 3  # producer periods without a heartbeat = the drive is lost
OPERATIONAL = 5  # NMT state code in a heartbeat
RPDO_SYNC, EVENT = 1, 255  # transmission types: taken at the next SYNC / at once (CiA 301)
EMCY_COMMUNICATION = 0x8100  # CiA 301 emergency code: communication, generic
_EMCY = struct.Struct("<HB5s")


def interpolation_period(period_us: int) -> tuple[int, int]:
    """0x60C2 (value, index) for a period: value x 10^index s, value 1..255 (CiA 402-2)."""
    for index in range(0, -7, -1):
        value, left = divmod(period_us, 10 ** (6 + index))
        if not left and 1 <= value <= 255:
            return value, index
    raise ValueError(f"{period_us} us cannot be written as 0x60C2 (1..255 x 10^n s)")


def _meaning(trans_type: int) -> str:
    if trans_type == 0:
        return "after a SYNC when changed"
    if trans_type <= 240:
        return f"every {trans_type}th SYNC" if trans_type > 1 else "every SYNC"
    return "event-driven" if trans_type >= 254 else "RTR only or reserved"


def _pdo_plan(node, pdos, refs: Sequence[ObjectRef], eds: str, what: str) -> list:
    """Pack ``refs`` in order into as few of ``pdos``'s maps as the EDS allows: the maps
    with the most entries first (fewer frames per cycle, on the bus and in the host)."""
    od, used, left = node.object_dictionary, [], list(refs)

    def room(pdo_map) -> int:
        record = od[pdo_map.map_array.od.index] if pdo_map.map_array.od.index in od else None
        return len(record) - 1 if record is not None else 0

    for n, pdo_map in sorted(pdos.map.items(), key=lambda item: -room(item[1])):
        if not left:
            break
        pdo_map.clear()
        bits = 0
        while (left and len(pdo_map.map) < room(pdo_map)
               and bits + len(find_object(od, left[0])) <= 64):
            ref = left.pop(0)
            pdo_map.add_variable(ref.index, ref.subindex)
            bits += len(find_object(od, ref))
        if pdo_map.map:
            used.append((n, pdo_map))
    if left:
        raise DriveFileError(f"EDS {eds}: no room in the drive's {what}s for object "
                             f"{left[0]} ({len(left)} of the objects do not fit in "
                             f"{len(pdos.map)} {what}s)")
    return sorted(used, key=lambda item: item[0])


class Cia402Protocol(BoardProtocol):
    """CiA 402 drives of one drive file (see the module docstring)."""

    name = NAME

    def __init__(self, indices: Sequence[int], specs, drive: DriveFile) -> None:
        super().__init__(indices, [s.board_id for s in specs])
        self.drive, self.specs = drive, list(specs)
        self.status_period_s = drive.status_period_ms / 1000.0
        self.capabilities = Capabilities(
            board_watchdog=True, board_limits=False, temperature=drive.temperature is not None,
            counter=False, checksum=False, configure=False, version=True)
        if not all(1 <= b <= 127 for b in self.board_ids):
            raise DriveFileError(f"{drive.path}: CANopen node ids (the muscles' board_id) "
                                 f"must be 1..127, got {list(self.board_ids)}")
        if drive.host_node_id in self.board_ids:
            raise DriveFileError(f"{drive.path}: host_node_id {drive.host_node_id} is also a "
                                 "drive's node id; pick a free one")
        self.nodes = [canopen.RemoteNode(b, drive.object_dictionary(b)) for b in self.board_ids]
        eds = drive.eds.name
        out = [ObjectRef(0x6040, 0), ObjectRef(0x6060, 0), drive.tension_target]
        out += [drive.position_target] if drive.position_target is not None else []
        back = [ObjectRef(0x6041, 0), ObjectRef(0x6061, 0), drive.tension_actual,
                drive.position_actual]
        back += [drive.temperature] if drive.temperature is not None else []
        self.rpdos = [_pdo_plan(n, n.rpdo, out, eds, "RPDO") for n in self.nodes]
        self.tpdos = [_pdo_plan(n, n.tpdo, back, eds, "TPDO") for n in self.nodes]
        for k, node in enumerate(self.nodes):  # transmission types: at connect
            for n, pdo_map in self.rpdos[k]:
                pdo_map.cob_id, pdo_map.enabled = 0x100 + 0x100 * n + node.id, True
            for n, pdo_map in self.tpdos[k]:
                pdo_map.cob_id, pdo_map.enabled = 0x80 + 0x100 * n + node.id, True
        self._tpdo_ids = {m.cob_id: (k, m) for k in range(len(self.nodes))
                          for _, m in self.tpdos[k]}
        n = len(self.nodes)
        self.state = ["not connected"] * n  # CiA 402 state from the last statusword
        self.statusword: list[int | None] = [None] * n
        self.nmt_state: list[str] = ["unknown"] * n
        self.emcy: list[tuple[int, int] | None] = [None] * n  # last (code, error register)
        self.identity: list[tuple[int, int, int] | None] = [None] * n
        self.tension_mode, self.position_mode = [10] * n, [8] * n
        self.relax_n = [s.f_floor for s in self.specs]
        # direction -1: the drive's position counts down as the wire pays out (docs/boards.md)
        self.sign = [float(getattr(s, "direction", 1)) for s in self.specs]
        self._since_heartbeat = [0] * n  # TPDOs decoded since the last heartbeat
        self._enabled = [False] * n  # reached Operation enabled at connect
        self._stopping = [False] * n  # a quick stop was commanded
        self._operational = [False] * n  # a heartbeat has said OPERATIONAL since connect
        self._patience_s = 0.0  # the host watchdog time, from ``connect``
        self.mode_display: list[int | None] = [None] * n  # 0x6061 as last reported
        self._mode_cmd: list[int | None] = [None] * n  # the mode last commanded by PDO
        self._mode_late = [0] * n  # PDOs since then that still report another mode
        self.synced = [False] * n  # runs a cyclic synchronous mode: PDOs on the host's SYNC
        self.sync: SyncProducer | None = None

    # -- connect ---------------------------------------------------------------------------
    def connect(self, transport, limits: Sequence[BoardLimits]) -> None:
        """NMT, SDO configuration, PDO mapping and the state machine walk of every drive."""
        self._patience_s = max(lim.watchdog_s for lim in limits) if limits else 0.0
        with attached(transport) as network:
            for node in self.nodes:
                network.add_node(node)
                node.sdo.RESPONSE_TIMEOUT = SDO_TIMEOUT_S
            for k, node in enumerate(self.nodes):
                self._probe(k, node)
            if any(self.synced):  # before any drive is enabled in a mode that needs it
                self.sync = start_sync(transport, self.drive.sync_period_us,
                                       str(self.drive.path))
            for k, node in enumerate(self.nodes):
                self._bring_up(k, node, limits[k])
            for node in self.nodes:
                node.nmt.send_command(0x01)  # start remote node: PDOs flow
        self._since_heartbeat = [0] * len(self.nodes)

    def _where(self, k: int) -> dict:
        return {"muscle": self.specs[k].name, "board_id": self.board_ids[k]}

    def _sdo(self, k: int, call):
        """One SDO exchange; a silent or refusing drive is a named stop. A timeout during
        which this process itself could not run is not the drive's silence: asked again.
        Nor is an answer to another object: the late answer to a request asked again after
        such a timeout, which arrived after the client last emptied its queue; it is
        dropped and the request asked again."""
        node, lag, retries = self.nodes[k], host_lag(), 0
        while True:
            t0 = time.monotonic()
            try:
                return call()
            except SdoCommunicationError as exc:
                stale = STALE_ANSWER in str(exc)
                if retries < SDO_STALL_RETRIES and (
                        stale or lag.starved(t0, time.monotonic()) >= SDO_STALL_S):
                    retries += 1
                    if stale:
                        node.sdo.responses = queue.Queue()
                    continue
                raise BoardSilent(f"no SDO answer from CANopen node {node.id} "
                                  f"({self.drive.eds.name}): {exc}; is the drive powered, its "
                                  "node id right and the bitrate the drive's?",
                                  **self._where(k)) from None
            except SdoAbortedError as exc:
                raise BoardFault(f"CANopen node {node.id} refused an SDO access "
                                 f"({self.drive.eds.name}): {exc}", **self._where(k)) from None

    def _write(self, k: int, ref: ObjectRef, value: int) -> None:
        var = self._var(k, ref.index, ref.subindex)
        self._sdo(k, lambda: setattr(var, "raw", value))

    def _read(self, k: int, index: int, subindex: int = 0) -> int:
        var = self._var(k, index, subindex)
        return self._sdo(k, lambda: var.raw)

    def _var(self, k: int, index: int, subindex: int) -> canopen.sdo.SdoVariable:
        obj = self.nodes[k].sdo[index]
        return obj if isinstance(obj, canopen.sdo.SdoVariable) else obj[subindex]

    def _probe(self, k: int, node) -> None:
        """Pre-operational, identity, and the modes the drive offers (0x6502)."""
        od, drive = node.object_dictionary, self.drive
        node.nmt.send_command(0x80)  # enter pre-operational: configure over SDO
        self.identity[k] = tuple(self._read(k, 0x1018, s) for s in (1, 2, 3))  # type: ignore
        if 0x6502 in od:
            supported = self._read(k, 0x6502)
            tq = sm.pick_mode(supported, (10, 4))
            if tq is None:
                raise DriveFileError(f"EDS {drive.eds.name}, node {node.id}: Supported drive "
                                     f"modes 0x6502:00 = 0x{supported:X} has no torque mode "
                                     "(cyclic synchronous torque or profile torque)")
            self.tension_mode[k] = tq
            self.position_mode[k] = sm.pick_mode(supported, (8, 1))  # type: ignore[call-arg]
        self.synced[k] = bool({self.tension_mode[k], self.position_mode[k]} & sm.CYCLIC)

    def _writable(self, k: int, index: int, subindex: int = 0) -> bool:
        entry = find_object(self.nodes[k].object_dictionary, ObjectRef(index, subindex))
        return entry is not None and entry.writable

    def _cycle(self, k: int) -> None:
        """0x1006 (a drive's SYNC supervision) and 0x60C2, where the EDS has them."""
        period = self.drive.sync_period_us if self.synced[k] else 0  # 0: not supervised
        if self._writable(k, 0x1006):
            self._write(k, ObjectRef(0x1006, 0), period)
        if self.synced[k] and self._writable(k, 0x60C2, 1) and self._writable(k, 0x60C2, 2):
            value, index = interpolation_period(period)
            self._write(k, ObjectRef(0x60C2, 1), value)
            self._write(k, ObjectRef(0x60C2, 2), index)

    def _map_pdos(self, k: int) -> None:
        """Save the PDO maps with their transmission types and read the types back."""
        sync, ms = self.synced[k], self.drive.status_period_ms
        for _, pdo_map in self.rpdos[k]:
            pdo_map.trans_type = RPDO_SYNC if sync else EVENT
        for _, pdo_map in self.tpdos[k]:
            pdo_map.trans_type = self.drive.sync_every if sync else EVENT
            subs = pdo_map.com_record.od
            if 5 in subs:  # event timer (ms) and inhibit time (100 us): event-driven only
                pdo_map.event_timer = 0 if sync else ms
            if 3 in subs:
                pdo_map.inhibit_time = 0 if sync else ms * 5
        for what, used in (("RPDO", self.rpdos[k]), ("TPDO", self.tpdos[k])):
            for n, pdo_map in used:
                self._sdo(k, pdo_map.save)
                index = pdo_map.com_record.od.index
                got, want = self._read(k, index, 2), pdo_map.trans_type
                if got != want:
                    why = ("its EDS makes it read-only" if not self._writable(k, index, 2)
                           else "the drive did not take it")
                    raise DriveFileError(
                        f"CANopen node {self.nodes[k].id} ({self.drive.eds.name}): {what}{n} "
                        f"keeps transmission type {got} ({_meaning(got)}, 0x{index:04X}:02) "
                        f"where the host set {want} ({_meaning(want)}): {why}; its PDOs would "
                        "not come and go when the host expects them")

    def _bring_up(self, k: int, node, lim: BoardLimits) -> None:
        od, drive = node.object_dictionary, self.drive
        self._cycle(k)
        self._write(k, ObjectRef(0x1017, 0), drive.heartbeat_ms)
        if 0x1016 in od:  # the drive watches the host's heartbeat: the host watchdog
            ms = max(1, round(lim.watchdog_s * 1000))
            self._write(k, ObjectRef(0x1016, 1), drive.host_node_id << 16 | ms)
        if 0x6072 in od:  # Max torque, in the same units as the target torque
            ceiling = round(lim.tension_ceiling_n * drive.tension_target.per_si)
            self._write(k, ObjectRef(0x6072, 0), min(ceiling, 0xFFFF))
        self._map_pdos(k)
        for pdos, used in ((node.rpdo, self.rpdos[k]), (node.tpdo, self.tpdos[k])):
            taken = {n for n, _ in used}
            for n, pdo_map in pdos.map.items():  # unused PDOs off: nothing unexpected flows
                if n not in taken and 1 in pdo_map.com_record:
                    cob = self._read(k, pdo_map.com_record.od.index, 1)
                    self._write(k, ObjectRef(pdo_map.com_record.od.index, 1),
                                cob | 0x80000000)
        self.relax_n[k] = lim.relax_tension_n
        self._write(k, ObjectRef(0x6060, 0), self.tension_mode[k])
        self._write(k, drive.tension_target, self._encode(k, drive.tension_target,
                                                          lim.relax_tension_n))
        self._walk(k)

    def _statusword(self, k: int) -> str:
        word = self._read(k, 0x6041)
        self.statusword[k], self.state[k] = word, sm.state_name(word)
        return self.state[k]

    def _await(self, k: int, target: str) -> None:
        deadline = time.monotonic() + STATE_WAIT_S
        while self._statusword(k) != target:
            if time.monotonic() > deadline:
                raise BoardFault(f"CANopen node {self.nodes[k].id} did not reach '{target}': "
                                 f"it reports '{self.state[k]}' (statusword "
                                 f"0x{self.statusword[k]:04X}){self._emcy_text(k)}",
                                 **self._where(k))
            time.sleep(0.005)

    def _walk(self, k: int) -> None:
        """Switch on disabled -> Ready to switch on -> Switched on -> Operation enabled."""
        cw = ObjectRef(0x6040, 0)
        if self._statusword(k) in sm.FAULT_STATES:
            self._write(k, cw, 0x00)  # bit 7 low first: the reset is its rising edge
            self._write(k, cw, sm.FAULT_RESET)
            self._await(k, "Switch on disabled")
        for word, state in ((sm.SHUTDOWN, "Ready to switch on"), (sm.SWITCH_ON, "Switched on"),
                            (sm.ENABLE_OPERATION, sm.OPERATION_ENABLED)):
            self._write(k, cw, word)
            self._await(k, state)
        self._enabled[k], self._stopping[k] = True, False

    # -- cyclic ----------------------------------------------------------------------------
    def _encode(self, k: int, ref: ObjectRef, value_si: float) -> int:
        entry = find_object(self.nodes[k].object_dictionary, ref)
        raw = round(value_si * ref.per_si)
        try:
            entry.encode_raw(raw)
        except (struct.error, ValueError, OverflowError):
            raise ValueError(f"muscle {self.specs[k].name}: {value_si:g} is out of the range "
                             f"of object {ref} ({entry.name}) in {self.drive.eds.name}") from None
        return raw

    def setup(self, i: int, limits: BoardLimits) -> list[RawFrame]:
        return []  # configured over SDO in ``connect``

    def command(self, i: int, kind: str, value: float = 0.0) -> list[RawFrame]:
        k = self.indices.index(i)
        drive, values = self.drive, {(0x6040, 0): sm.ENABLE_OPERATION}
        if kind == "stop":
            values[(0x6040, 0)] = sm.QUICK_STOP
            self._stopping[k] = True
        elif kind in ("relax", "tension"):
            values[(0x6060, 0)] = self.tension_mode[k]
            target = self.relax_n[k] if kind == "relax" else value
            values[drive.tension_target.key] = self._encode(k, drive.tension_target, target)
        elif kind == "length":
            if drive.position_target is None or self.position_mode[k] is None:
                why = ("the drive file names no position target (0x607A)"
                       if drive.position_target is None else
                       "Supported drive modes 0x6502 lists no position mode")
                raise ValueError(f"muscle {self.specs[k].name}: length control is not "
                                 f"available on its drive ({drive.eds.name}): {why}")
            values[(0x6060, 0)] = self.position_mode[k]
            values[drive.position_target.key] = self._encode(k, drive.position_target,
                                                             self.sign[k] * value)
        else:
            raise ValueError(f"unknown command kind {kind!r}")
        if kind != "stop":  # from here on a drive out of Operation enabled is a fault again
            self._stopping[k] = False
        if (0x6060, 0) in values and values[(0x6060, 0)] != self._mode_cmd[k]:
            self._mode_cmd[k], self._mode_late[k] = values[(0x6060, 0)], 0
        frames: list[RawFrame] = []
        for _, pdo_map in self.rpdos[k]:  # canopen's PDO maps encode the RPDOs
            for var in pdo_map.map:
                if (var.index, var.subindex) in values:
                    var.raw = values[(var.index, var.subindex)]
            frames.append((pdo_map.cob_id, bytes(pdo_map.data)))
        if k == 0:  # the host's heartbeat, fed by commands only: a hung host goes silent
            frames.append((0x700 + drive.host_node_id, bytes([OPERATIONAL])))
        return frames

    def decode(self, arbitration_id: int, data: bytes) -> list[Update]:
        hit = self._tpdo_ids.get(arbitration_id)
        if hit is not None:
            return [self._status(hit[0], hit[1], data)]
        node_id, function = arbitration_id & 0x7F, arbitration_id & 0x780
        if node_id not in self.board_ids or function not in (0x700, 0x080) or not data:
            return []
        k = self.board_ids.index(node_id)
        if function == 0x700:  # heartbeat: the drive's NMT state
            self._since_heartbeat[k] = 0
            self.nmt_state[k] = NMT_STATES.get(data[0] & 0x7F, f"0x{data[0]:02X}")
            if data[0] & 0x7F == OPERATIONAL:
                self._operational[k] = True
            elif self._operational[k]:  # (heartbeats from before NMT start do not count)
                return [Update(self.indices[k], stop=BoardFault, note=(
                    f"drive left NMT OPERATIONAL: its heartbeat says {self.nmt_state[k]}"
                    + (" (it rebooted)" if data[0] == 0 else "")))]
            return []
        if len(data) == 8:  # EMCY: code, error register, manufacturer bytes
            code, register, _ = _EMCY.unpack(data)
            self.emcy[k] = (code, register)
            if self._sync_lost(k):  # no SYNC, no synchronous TPDO: its statusword won't come
                return [Update(self.indices[k], faults=Fault.WATCHDOG, stop=WatchdogExpired,
                               note=self._sync_lost_text(k))]
        return []

    def _sync_lost(self, k: int) -> bool:
        """A drive running on the host's SYNC reports a communication error."""
        return (self.sync is not None and self.synced[k] and self._enabled[k]
                and self.emcy[k] is not None and self.emcy[k][0] == EMCY_COMMUNICATION)

    def _sync_lost_text(self, k: int) -> str:
        code, register = self.emcy[k]  # type: ignore[misc]
        mode = self.mode_display[k] if self.mode_display[k] is not None else self._mode_cmd[k]
        status = ("" if self.statusword[k] is None else
                  f" (statusword 0x{self.statusword[k]:04X})")
        return (f"SYNC lost: the drive sent EMCY 0x{code:04X} (communication error, error "
                f"register 0x{register:02X}: {sm.error_bits(register)}) in "
                f"{sm.MODES.get(mode, f'mode {mode}')}, which runs on a SYNC every "
                f"{self.drive.sync_period_us} us (0x1006); it last reported "
                f"'{self.state[k]}'{status}; check that the SYNC (COB-ID 0x{SYNC_ID:03X}) "
                f"reaches node {self.nodes[k].id}: the CAN wiring and termination, the bus "
                "load, and a host process that gets enough CPU")

    def _emcy_text(self, k: int) -> str:
        if self.emcy[k] is None:
            return "; no EMCY received"
        code, register = self.emcy[k]  # type: ignore[misc]
        desc = EmcyError(code, register, b"", 0.0).get_desc()
        return (f"; EMCY 0x{code:04X} ({desc}), error register 0x{register:02X} "
                f"({sm.error_bits(register)})")

    def _status(self, k: int, pdo_map, data: bytes) -> Update:
        values = {}
        for var in pdo_map.map:
            if not var.length:  # canopen's filler for a fixed-length mapping array
                continue
            start = var.offset // 8
            values[(var.index, var.subindex)] = var.od.decode_raw(
                bytes(data[start:start + var.length // 8]))
        drive, fields = self.drive, {}
        for name, ref in (("tension_n", drive.tension_actual),
                          ("position_m", drive.position_actual),
                          ("temperature_c", drive.temperature)):
            if ref is not None and ref.key in values:
                fields[name] = values[ref.key] / ref.per_si
        if "position_m" in fields:
            fields["position_m"] *= self.sign[k]
        if (0x6061, 0) in values:
            self.mode_display[k] = values[(0x6061, 0)]
            wrong = self._mode_wrong(k)
            if wrong is not None:
                return Update(self.indices[k], stop=BoardFault, note=wrong, **fields)
        if (0x6041, 0) not in values:
            return Update(self.indices[k], **fields)
        word = values[(0x6041, 0)]
        self.statusword[k], self.state[k] = word, sm.state_name(word)
        stop, faults, note = self._judge(k, word)
        return Update(self.indices[k], faults=faults, stop=stop, note=note, **fields)

    def _mode_wrong(self, k: int) -> str | None:
        """A drive that does not take the commanded mode of operation (0x6061 is the mode
        it runs): what it says, once it has had the host's silence limit to switch."""
        if self._mode_cmd[k] is None or self.mode_display[k] == self._mode_cmd[k]:
            self._mode_late[k] = 0
            return None
        self._mode_late[k] += 1
        if self._mode_late[k] <= math.ceil(max(self._patience_s, 0.1) / self.status_period_s):
            return None
        want, have = self._mode_cmd[k], self.mode_display[k]
        return (f"drive did not take mode of operation {want} ({sm.MODES.get(want, '?')}): "
                f"0x6061 still reports {have} ({sm.MODES.get(have, 'other')}) after "
                f"{self._mode_late[k]} PDOs")

    def _judge(self, k: int, word: int) -> tuple[type[SafetyStop] | None, Fault, str | None]:
        """The stop a statusword (and the heartbeat's age) calls for, if any."""
        state = self.state[k]
        said = f"drive reports '{state}' (statusword 0x{word:04X}){self._emcy_text(k)}"
        if state in sm.FAULT_STATES:
            if self._sync_lost(k):
                return WatchdogExpired, Fault.WATCHDOG, self._sync_lost_text(k)
            code = self.emcy[k][0] if self.emcy[k] else 0
            if code & 0xF000 == 0x4000:
                return Overheat, Fault.OVERHEAT, said
            if code & 0xFF00 == 0x8100:
                return WatchdogExpired, Fault.WATCHDOG, said
            return BoardFault, Fault.MOTOR, said
        if self._enabled[k] and state != sm.OPERATION_ENABLED and not (
                self._stopping[k] and state in ("Quick stop active", "Switch on disabled")):
            return BoardFault, Fault.MOTOR, f"drive left 'Operation enabled': {said}"
        # counted in frames, not seconds: a host that reads its queue late (loaded, or
        # hung for a moment) sees heartbeats and PDOs in the order the drive sent them
        self._since_heartbeat[k] += 1
        limit_s = max(HEARTBEAT_MISSES * self.drive.heartbeat_ms / 1000.0, self._patience_s)
        frames = len(self.tpdos[k]) * math.ceil(limit_s / self.status_period_s)
        if self._enabled[k] and self._since_heartbeat[k] > frames:
            return BoardSilent, Fault(0), (
                f"no heartbeat from CANopen node {self.nodes[k].id} over its last "
                f"{self._since_heartbeat[k]} PDOs (about {limit_s:g} s; producer time 0x1017 "
                f"= {self.drive.heartbeat_ms} ms); last NMT state {self.nmt_state[k]}, {said}")
        return None, Fault(0), None

    # -- reporting -------------------------------------------------------------------------
    def ids_used(self, i: int) -> set[int]:
        """CANopen's predefined connection set of the drive's node (CiA 301): EMCY 0x080,
        TPDO 0x180-0x480, RPDO 0x200-0x500, SDO 0x580/0x600 and heartbeat 0x700, + node id."""
        node = self.board_ids[self.indices.index(i)]
        return {base + node for base in (0x080, 0x180, 0x200, 0x280, 0x300, 0x380, 0x400,
                                         0x480, 0x500, 0x580, 0x600, 0x700)}

    def shared_ids(self) -> dict[str, set[int]]:
        host = self.drive.host_node_id
        return {"CANopen NMT and SYNC": {0x000, 0x080},
                f"the host's heartbeat (node {host})": {0x700 + host}}

    def describe(self) -> str:
        return self.drive.name

    def not_relaxed(self) -> list[str]:
        """Drives that cannot be at their holding floor: what their statusword said."""
        out = []
        for k, spec in enumerate(self.specs):
            where = f"{spec.name} (node {self.board_ids[k]})"
            if self._enabled[k] and self._sync_lost(k):
                out.append(f"{where}: SYNC lost (EMCY 0x{EMCY_COMMUNICATION:04X}); its "
                           "statusword needs SYNC and no longer comes, so its own reaction "
                           "(0x6007) is not seen from here")
            elif self._enabled[k] and self.state[k] != sm.OPERATION_ENABLED:
                out.append(f"{where}: drive reported '{self.state[k]}', power stage off or "
                           "stopping, not at the holding floor")
        return out

    def unreachable(self, watchdog_s: float) -> str:
        states = ", ".join(f"{s.name} '{st}'" for s, st in zip(self.specs, self.state,
                                                                strict=True))
        sync = (" (and, in cyclic synchronous modes, its SYNC supervision misses the SYNC)"
                if self.sync is not None else "")
        return (f"{self.name} drives (last reported: {states}): each drive's heartbeat "
                f"consumer (0x1016) misses the host within {watchdog_s:g} s{sync} and the "
                "drive leaves 'Operation enabled' by its own reaction (0x6007; not seen from "
                "here)")

    def close(self) -> None:
        """The host leaves, its last relax sent: one last SYNC applies it, then no more."""
        if self.sync is not None:
            self.sync.stop()
