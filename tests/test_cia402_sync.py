"""CiA 402 drives on SYNC, as industrial drives run: CiA 301 PDO transmission types on the
simulated drive (fed frames with explicit times: nothing here depends on how fast this
machine is), the host's SYNC, 0x1006 and transmission types, a drive that loses SYNC, and
canopen's own ``BaseNode402`` (a host we did not write) driving the simulated drive through
the state machine into cyclic synchronous position on SYNC, over python-can's ``virtual``
bus and the emulated SLCAN adapter.

No test asserts how exact a period is: only that TPDOs follow SYNCs, in the numbers the
transmission types say, and never come without them."""

from __future__ import annotations

import re
import subprocess
import sys
import time
import uuid
from pathlib import Path
from types import SimpleNamespace

import canopen
import pytest

from pimbs_hw import open_arm
from pimbs_hw.connect import SIMULATED_LIMITS
from pimbs_hw.mock import MockArm
from pimbs_hw.mock.cia402_drive import SYNC_LOSS_CYCLES, Cia402Board
from pimbs_hw.protocol.cia402 import interpolation_period
from pimbs_hw.protocol.cia402_config import DriveFileError, load_drive_file, read_eds
from pimbs_hw.protocol.cia402_states import state_name
from pimbs_hw.safety import WatchdogExpired
from tests.test_driver_mock import wait_until

HERE = Path(__file__).parent.parent / "fixtures" / "cia402"
ROBOT = HERE / "two-link-cia402.muscles.yaml"  # CSP/CST drives: SYNC
TORQUE_ROBOT = HERE / "two-link-cia402-torque.muscles.yaml"  # profile torque: no SYNC
WALK = ["Switch on disabled", "Ready to switch on", "Switched on", "Operation enabled"]
NODE = 5
SYNC, NMT = 0x080, 0x000
READING = SimpleNamespace(position_m=0.0, tension_n=12.0, temperature_c=25.0)


# --------------------------------------------------------------------- the simulated drive
def _drive(drive_file: str = "foc-mc-csp.cia402.yaml", **kwargs) -> Cia402Board:
    spec = SimpleNamespace(name="m0", board_id=NODE, f_floor=10.0)
    return Cia402Board(spec, load_drive_file(HERE / drive_file), 0.0, **kwargs)


def _sent(board: Cia402Board, now: float, frames: list) -> None:
    frames += [f for f in board.frames(now, READING, reply=True) if f[0] & 0x780 != 0x700]


def _start(board: Cia402Board, now: float = 0.0) -> None:
    board.receive(NMT, bytes([0x01, NODE]), now, READING)  # NMT start: PDOs in force


def _count(frames: list, cob_id: int) -> int:
    return sum(1 for f in frames if f[0] == cob_id)


def test_simulated_drive_sends_tpdos_by_their_transmission_type():
    board = _drive()
    sdo = board.node.sdo  # the host's SDO downloads, as they land in the drive
    sdo[0x1800][2].raw = 3  # TPDO1 (statusword): after every 3rd SYNC
    sdo[0x1801][2].raw = 0  # TPDO2 (statusword, mode display): after a SYNC, if changed
    sdo[0x1802][2].raw = 255  # TPDO3: event-driven, event timer 50 ms, inhibit 20 ms
    sdo[0x1802][5].raw = 50
    sdo[0x1802][3].raw = 200  # 100 us units
    sdo[0x1803][1].raw = 0x80000000 | 0x480 + NODE  # TPDO4 off
    frames: list = []
    for k in range(5):  # pre-operational: SYNC is heard, no PDO goes out
        board.receive(SYNC, b"", 0.001 * k, READING)
        _sent(board, 0.001 * k, frames)
    assert frames == [] and board.syncs == 5
    _start(board)
    tpdo1, tpdo2, tpdo3, tpdo4 = (0x180 + NODE + 0x100 * n for n in range(4))
    for k in range(9):  # nine SYNCs, 1 ms apart; nothing changes
        board.receive(SYNC, b"", 0.01 + 0.001 * k, READING)
    _sent(board, 0.019, frames)
    assert _count(frames, tpdo1) == 3  # every 3rd SYNC
    assert _count(frames, tpdo2) == 1  # the first SYNC (new data), then no change
    assert _count(frames, tpdo3) == 1  # event-driven: once (first), not on SYNC
    assert _count(frames, tpdo4) == 0
    board.node.sdo[0x6040].raw = 0x06  # Shutdown: the statusword changes
    frames.clear()
    board.receive(SYNC, b"", 0.020, READING)
    _sent(board, 0.020, frames)  # TPDO3 (sent at 19 ms) changed too: its inhibit time holds
    assert _count(frames, tpdo2) == 1 and _count(frames, tpdo1) == 0
    status = frames[[f[0] for f in frames].index(tpdo2)][1][:2]
    assert status == (0x0231).to_bytes(2, "little")  # 'Ready to switch on', remote
    assert _count(frames, tpdo3) == 0
    frames.clear()
    _sent(board, 0.030, frames)  # 11 ms after it: still inhibited
    assert _count(frames, tpdo3) == 0
    _sent(board, 0.040, frames)  # 21 ms: past its inhibit time, the change goes out
    assert _count(frames, tpdo3) == 1
    frames.clear()
    _sent(board, 0.080, frames)  # unchanged, its event timer not run out
    assert _count(frames, tpdo3) == 0
    _sent(board, 0.091, frames)  # event timer (50 ms) ran out
    assert _count(frames, tpdo3) == 1 and _count(frames, tpdo1) == 0  # no SYNC, no TPDO1


def test_simulated_drive_takes_synchronous_rpdos_at_the_next_sync():
    board = _drive()
    board.node.sdo[0x1400][2].raw = 1  # RPDO1 (controlword): synchronous
    board.node.sdo[0x1401][2].raw = 255  # RPDO2 (controlword, mode): at once
    _start(board)
    board.receive(0x200 + NODE, (0x06).to_bytes(2, "little"), 0.001, READING)
    assert board.state == "Switch on disabled"  # received, not yet in force
    board.receive(SYNC, b"", 0.002, READING)
    assert board.state == "Ready to switch on"
    board.receive(0x300 + NODE, (0x07).to_bytes(2, "little") + bytes([10]), 0.003, READING)
    assert board.state == "Switched on" and board.mode_op == 10  # event-driven: at once
    # two synchronous RPDOs in one cycle: the last one received is the one taken
    board.receive(0x200 + NODE, (0x06).to_bytes(2, "little"), 0.004, READING)
    board.receive(0x200 + NODE, (0x0F).to_bytes(2, "little"), 0.005, READING)
    assert board.state == "Switched on"
    board.receive(SYNC, b"", 0.006, READING)
    assert board.state == "Operation enabled" and board.controlwords[-1] == 0x0F


def _enabled_in_cst(board: Cia402Board, cycle_us: int = 1000) -> None:
    sdo = board.node.sdo
    sdo[0x1006].raw = cycle_us
    sdo[0x6060].raw = 10  # cyclic synchronous torque
    for word in (0x06, 0x07, 0x0F):
        sdo[0x6040].raw = word
    assert board.state == "Operation enabled"


def test_simulated_drive_faults_when_sync_stops_within_its_tolerance():
    board = _drive(sync_loss_cycles=60)  # 60 x 1 ms
    _enabled_in_cst(board)
    _start(board)
    frames: list = []
    now = 0.0
    for _ in range(300):  # 3 s of 10 ms ticks with a SYNC every tick: supervised, healthy
        now += 0.01
        board.receive(SYNC, b"", now, READING)
        board.supervise(now, READING)
    assert board.state == "Operation enabled"
    # 10 ms since the last SYNC; then this whole process stalls 10 s: one tick of drive
    # time (25 ms), which no drive with its own CPU would see
    now += 10.0
    board.supervise(now, READING)
    assert board.state == "Operation enabled"
    now += 0.015  # 50 ms of drive time without SYNC: inside 60 cycles
    board.supervise(now, READING)
    assert board.state == "Operation enabled"
    now += 0.015  # 65 ms: lost
    board.supervise(now, READING)
    _sent(board, now, frames)
    emcy = [data for cob, data in frames if cob == 0x080 + NODE]
    assert emcy and emcy[0][:3] == bytes([0x00, 0x81, 0x11])  # 0x8100, generic+communication
    assert board.state == "Fault reaction active"
    board.supervise(now + 0.01, READING)
    assert board.state == "Fault"


def test_sync_supervision_is_off_without_a_cycle_period_or_a_cyclic_mode():
    board = _drive(sync_loss_cycles=5)
    _enabled_in_cst(board, cycle_us=0)  # 0x1006 = 0: SYNC not supervised
    board.supervise(0.01, READING)
    board.supervise(0.5, READING)
    assert board.state == "Operation enabled"
    board.node.sdo[0x1006].raw = 1000
    board.node.sdo[0x6060].raw = 4  # profile torque runs without SYNC
    board.supervise(0.51, READING)
    board.supervise(0.55, READING)
    assert board.state == "Operation enabled"
    assert SYNC_LOSS_CYCLES * 1000e-6 >= 0.1  # default: a loaded host's stalls are not loss


# --------------------------------------------------------------------- the drive file
@pytest.mark.parametrize("extra, says", [
    ("status_period_ms: 15\nsync_period_us: 2000\n", "must be 1 to 240 whole SYNC periods"),
    ("status_period_ms: 500\n", "must be 1 to 240 whole SYNC periods"),
    ("sync_period_us: 50\n", "sync_period_us must be a whole number from 100"),
])
def test_drive_file_sync_period_errors_are_one_line(tmp_path, extra, says):
    (tmp_path / "foc-mc-csp.eds").write_text((HERE / "foc-mc-csp.eds").read_text())
    path = tmp_path / "d.cia402.yaml"
    path.write_text("eds: foc-mc-csp.eds\n" + extra + "objects:\n"
                    '  tension: {actual: "0x6077:0", target: "0x6071:0"}\n'
                    '  position: {actual: "0x6064:0", target: "0x607A:0"}\n')
    with pytest.raises(DriveFileError, match=re.escape(says)) as err:
        load_drive_file(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_interpolation_period_is_the_standards_value_and_index():
    assert interpolation_period(1000) == (1, -3)  # 1 x 10^-3 s
    assert interpolation_period(250) == (25, -5)
    assert interpolation_period(20000) == (2, -2)


# --------------------------------------------------------------------- the host on SYNC
@pytest.mark.parametrize("port", ["virtual", "slcan-pty"])
def test_host_runs_cyclic_synchronous_drives_on_its_sync(port):
    with open_arm(port, ROBOT, speed=10.0, limits=SIMULATED_LIMITS) as (driver, mock):
        proto = driver.protocols[0]
        assert proto.sync is not None and proto.sync.period_us == 1000
        driver.command("tension", 40.0)
        driver.dwell(0.3)
        for board in mock.boards:
            assert board.cycle_us == 1000  # 0x1006 written: the drive supervises SYNC
            assert board.mode_op == 10  # cyclic synchronous torque
            assert {m.trans_type for m, _ in board._sync_tx} == {20}  # every 20th SYNC
            assert not board._event_tx
            assert {m.trans_type for m in board.node.rpdo.map.values() if m.enabled} == {1}
        syncs = [b.syncs for b in mock.boards]
        assert wait_until(lambda: all(b.syncs > s + 40 for b, s in zip(mock.boards, syncs,
                                                                          strict=True)))
        tpdos = {fid: n for fid, n in mock._sent.items() if 0x180 <= fid < 0x500}
        assert len(tpdos) == 8  # two TPDOs per drive (statusword+mode, torque+position)
        # each of them went out after every 20th SYNC the drive heard while OPERATIONAL
        for board in mock.boards:
            ours = [n for fid, n in tpdos.items() if fid & 0x7F == board.spec.board_id]
            assert all(0 < n <= board.syncs // 20 + 1 for n in ours), (ours, board.syncs)


def test_event_driven_drives_get_no_sync():
    with open_arm("virtual", TORQUE_ROBOT, speed=10.0, limits=SIMULATED_LIMITS) as (driver,
                                                                                    mock):
        driver.command("tension", 30.0)
        driver.dwell(0.2)
        assert driver.protocols[0].sync is None
        for board in mock.boards:
            assert board.syncs == 0 and board.cycle_us == 0 and board.mode_op == 4
            assert not board._sync_tx
            assert {(m.trans_type, m.event_timer, m.inhibit_time)
                    for m, _ in board._event_tx} == {(255, 10, 50)}  # 10 ms, 5 ms


SYNC_LOST = (r"WatchdogExpired: muscle {m} \(board {n}\) on port .*: SYNC lost: the drive "
             r"sent EMCY 0x8100 \(communication error, error register 0x11: generic, "
             r"communication\) in cyclic synchronous torque, which runs on a SYNC every "
             r"1000 us \(0x1006\); it last reported 'Operation enabled' \(statusword "
             r"0x0237\); check that the SYNC \(COB-ID 0x080\) reaches node {n}: ")


def test_a_drive_that_stops_hearing_sync_is_named():
    with open_arm("virtual", ROBOT, faults=["lost-sync:m2@2"], speed=10.0,
                  limits=SIMULATED_LIMITS) as (driver, mock):
        with pytest.raises(WatchdogExpired) as err:
            for sample in range(200):  # the drive's tolerance is 0.5 s of SYNC-less time
                mock.set_sample(sample)
                driver.command("tension", 40.0)
                driver.dwell(0.1)
        assert sample >= 2, "fault fired too early"
        assert re.match(SYNC_LOST.format(m="m2", n=3), str(err.value)), str(err.value)
        assert "\n" not in str(err.value) and err.value.muscle == "m2"
        # its statusword cannot come (its TPDOs need SYNC): the end state says so
        assert "m2 (node 3): SYNC lost (EMCY 0x8100)" in err.value.end_state
        assert wait_until(lambda: mock.boards[2].state == "Fault")
        assert mock.snapshot().modes[2] == "off"  # power stage off: its wire is slack


def test_when_the_hosts_sync_stops_every_drive_faults_and_is_named():
    with open_arm("virtual", ROBOT, speed=10.0, limits=SIMULATED_LIMITS) as (driver, mock):
        driver.command("tension", 40.0)
        driver.dwell(0.2)
        driver.protocols[0].sync._task.stop()  # the host's SYNC producer dies
        with pytest.raises(WatchdogExpired) as err:
            for _ in range(100):
                driver.command("tension", 40.0)
                driver.dwell(0.1)
        assert re.match(SYNC_LOST.format(m=r"m\d", n=r"\d"), str(err.value)), str(err.value)
        assert wait_until(lambda: all(b.state == "Fault" for b in mock.boards))
        assert all(b.error_register & 0x10 for b in mock.boards)  # communication error


def test_leaving_applies_the_relax_with_one_last_sync_then_sync_stops():
    with open_arm("virtual", ROBOT, speed=10.0, limits=SIMULATED_LIMITS) as (driver, mock):
        driver.command("tension", 150.0)
        driver.dwell(0.2)
    # the relax (torque mode at the 10 N floor = 100 units) was taken at a SYNC
    assert all(b.targets.get((0x6071, 0)) == 100 and b.mode_op == 10 for b in mock.boards)
    syncs = [b.syncs for b in mock.boards]
    time.sleep(0.1)
    assert [b.syncs for b in mock.boards] == syncs  # no SYNC after the host left


INTERPOLATION = """
[60C2]
ParameterName=Interpolation time period
ObjectType=0x09
SubNumber=3

[60C2sub0]
ParameterName=Highest sub-index supported
ObjectType=0x07
DataType=0x0005
AccessType=const
DefaultValue=2
PDOMapping=0

[60C2sub1]
ParameterName=Interpolation time period value
ObjectType=0x07
DataType=0x0005
AccessType=rw
DefaultValue=0
PDOMapping=0

[60C2sub2]
ParameterName=Interpolation time index
ObjectType=0x07
DataType=0x0002
AccessType=rw
DefaultValue=0
PDOMapping=0
"""


def _robot_with_eds(tmp_path: Path, eds: str) -> Path:
    (tmp_path / "foc-mc-csp.eds").write_text(eds)
    (tmp_path / "foc-mc-csp.cia402.yaml").write_text(
        (HERE / "foc-mc-csp.cia402.yaml").read_text())
    robot = tmp_path / "two-link-cia402.muscles.yaml"
    robot.write_text(ROBOT.read_text().replace("../../calibration",
                                               str(HERE.parent.parent / "calibration")))
    return robot


def test_interpolation_time_period_is_written_where_the_eds_has_it(tmp_path):
    robot = _robot_with_eds(tmp_path, (HERE / "foc-mc-csp.eds").read_text() + INTERPOLATION)
    with open_arm("virtual", robot, speed=10.0, limits=SIMULATED_LIMITS) as (_, mock):
        for board in mock.boards:  # 1 x 10^-3 s: the SYNC period
            assert (board.node.sdo[0x60C2][1].raw, board.node.sdo[0x60C2][2].raw) == (1, -3)


def test_a_transmission_type_the_drive_keeps_is_refused_by_name(tmp_path):
    """A drive whose EDS makes TPDO2's transmission type read-only (fixed at 1: every SYNC)
    cannot report every 20th SYNC as the host sets it: refused at connect, in one line."""
    eds = (HERE / "foc-mc-csp.eds").read_text()
    fixed = re.sub(r"(\[1801sub2\][^\[]*?AccessType=)rw", r"\1ro", eds, count=1)
    assert fixed != eds
    robot = _robot_with_eds(tmp_path, fixed)
    with pytest.raises(DriveFileError) as err:
        with open_arm("virtual", robot, speed=10.0, limits=SIMULATED_LIMITS):
            pass
    assert str(err.value) == (
        "CANopen node 1 (foc-mc-csp.eds): TPDO2 keeps transmission type 1 (every SYNC, "
        "0x1801:02) where the host set 20 (every 20th SYNC): its EDS makes it read-only; "
        "its PDOs would not come and go when the host expects them")


# --------------------------------------------------------------------- canopen's BaseNode402
@pytest.mark.parametrize("link, period_s", [
    ("virtual", 0.001),
    # four TPDOs after every SYNC (this EDS's defaults) at 1 kHz are 4000 frames/s, more
    # than python-can's SLCAN reader (one read per byte) takes on a loaded host: 10 ms
    ("slcan", 0.01),
])
def test_canopens_base_node_402_drives_the_simulated_drive_on_sync(link, period_s):
    name = f"virtual:bn402-{uuid.uuid4().hex[:12]}" if link == "virtual" else "slcan"
    with MockArm(ROBOT, name, speed=10.0) as mock:
        board = mock.boards[0]
        board.sync_loss_cycles = 50  # the drive's own setting: 50 SYNC periods
        network = canopen.Network()
        channel = mock.port.split(":", 1)[1]
        if link == "virtual":
            network.connect(interface="virtual", channel=channel)
        else:
            network.connect(interface="slcan", channel=channel, sleep_after_open=0)
        try:
            _base_node_402_session(network, board, mock, round(period_s * 1e6), period_s)
        finally:
            network.sync.stop()
            network.disconnect()


def _base_node_402_session(network, board, mock, cycle_us: int, period_s: float) -> None:
    node = canopen.BaseNode402(1, read_eds(HERE / "foc-mc-csp.eds", 1))
    network.add_node(node)
    # canopen's timeouts are tuned for a drive on its own CPU; this one shares a loaded one
    node.sdo.RESPONSE_TIMEOUT = 2.0
    node.TIMEOUT_CHECK_TPDO, node.TIMEOUT_SWITCH_STATE_SINGLE = 2.0, 4.0
    node.TIMEOUT_SWITCH_STATE_FINAL, node.TIMEOUT_SWITCH_OP_MODE = 10.0, 4.0
    node.nmt.state = "PRE-OPERATIONAL"
    node.sdo[0x1006].raw = cycle_us  # the application's SYNC period: the drive supervises it
    node.setup_402_state_machine()  # reads the drive's PDO configuration over SDO
    assert [m.trans_type for m in node.tpdo.map.values()] == [1, 1, 1, 1]  # the EDS's
    heard: list[float] = []
    node.tpdo[1].add_callback(lambda pdo_map: heard.append(pdo_map.timestamp))
    node.nmt.state = "OPERATIONAL"
    time.sleep(0.3)
    assert heard == []  # synchronous TPDOs: none without a SYNC
    for _ in range(5):
        network.sync.transmit()
    assert wait_until(lambda: len(heard) == 5, timeout=10.0)
    assert board.syncs == 5 and mock._sent[0x181] == 5  # one TPDO1 per SYNC, none else
    network.sync.start(period_s)  # what an application does for cyclic synchronous modes
    node.state = "OPERATION ENABLED"  # canopen's own transitions, statusword from TPDO1
    assert board.history == WALK and board.controlwords[-3:] == [0x06, 0x07, 0x0F]
    # RPDO2 of the EDS carries the controlword beside the mode: keep "enable operation"
    node.rpdo[2][0x6040].raw = 0x0F
    node.op_mode = "CYCLIC SYNCHRONOUS POSITION"  # waits for 0x6061 in TPDO2
    assert node.op_mode == "CYCLIC SYNCHRONOUS POSITION" and board.mode_op == 8
    assert node.state == "OPERATION ENABLED" and board.state == "Operation enabled"
    before = len(heard)
    assert wait_until(lambda: len(heard) > before + 3, timeout=10.0)  # TPDOs on SYNC
    network.sync.stop()  # the application's SYNC stops: the drive sees it
    assert wait_until(lambda: any(e.code == 0x8100 for e in node.emcy.log), timeout=10.0)
    assert [e.register for e in node.emcy.log if e.code == 0x8100] == [0x11]
    # over SDO now: its TPDOs need SYNC
    assert wait_until(lambda: state_name(node.sdo[0x6041].raw) == "Fault", timeout=10.0)
    sent = mock._sent[0x181]
    assert wait_until(lambda: len(heard) == sent, timeout=10.0)  # every one arrived
    assert sent <= board.syncs  # and none without its SYNC


# --------------------------------------------------------------------- pimbs mockbus
@pytest.mark.parametrize("verbose", [False, True])
def test_mockbus_prints_only_its_own_lines_unless_verbose(verbose):
    cmd = [sys.executable, "-c", "from pimbs_cli.main import main; main()", "mockbus",
           "--robot", str(ROBOT), "--port", "slcan", "--duration", "0.3"]
    res = subprocess.run(cmd + (["--verbose"] if verbose else []), capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    out = (res.stdout + res.stderr).splitlines()
    canopen_lines = [line for line in out if "to PDO map" in line]
    if verbose:
        assert canopen_lines  # canopen's own log, on request
        return
    assert not canopen_lines and res.stderr == ""
    assert [line.split(" ")[0] for line in out] == ["simulated", "connect", "mockbus"]
