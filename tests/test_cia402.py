"""CiA 402 servo drives over CANopen (the ``canopen`` package) from a maker's public EDS:
drive-file checks that name the EDS and the object, the host's controlword sequence and
statusword reading against the standard's state machine, every fault kind ending in the
state the drive reported, Ctrl-C, ``pimbs scan`` and the whole collection over ``virtual``
and the SLCAN pty."""

from __future__ import annotations

import dataclasses
import re
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pimbs_arm.model import ArmModel
from pimbs_calibration.description import load_robot
from pimbs_cli.main import main
from pimbs_hw import open_arm
from pimbs_hw.connect import SIMULATED_LIMITS
from pimbs_hw.driver import ArmDriver
from pimbs_hw.mock import MockArm
from pimbs_hw.protocol.cia402_config import DriveFileError, load_drive_file
from pimbs_hw.protocol.cia402_states import state_name
from pimbs_hw.safety import (
    BoardFault,
    BoardSilent,
    BusOff,
    Overheat,
    SafetyStop,
    WatchdogExpired,
)
from pimbs_hw.transport import CanTransport
from pimbs_recording.format import read_recording
from tests.test_collect import _balance_residual
from tests.test_driver_mock import wait_until

HERE = Path(__file__).parent.parent / "fixtures" / "cia402"
ROBOT = HERE / "two-link-cia402.muscles.yaml"  # CSP/CST variant of the EDS
TORQUE_ROBOT = HERE / "two-link-cia402-torque.muscles.yaml"  # the EDS as AMD publishes it
LIMITS = SIMULATED_LIMITS
# CiA 402-2 controlword commands and statusword codings, written out from the standard
SHUTDOWN, SWITCH_ON, ENABLE_OPERATION, QUICK_STOP, FAULT_RESET = 0x06, 0x07, 0x0F, 0x02, 0x80
WALK = ["Switch on disabled", "Ready to switch on", "Switched on", "Operation enabled"]


# --------------------------------------------------------------------- the drive file
def _drive_file(tmp_path: Path, objects: str, eds: str = "foc-mc.eds") -> Path:
    (tmp_path / eds).write_text((HERE / "foc-mc.eds").read_text())
    path = tmp_path / "d.cia402.yaml"
    path.write_text(f"eds: {eds}\nobjects:\n{objects}")
    return path


@pytest.mark.parametrize("objects, says", [
    ('  tension: {actual: "0x6077:0", target: "0x6071:0"}\n'
     '  position: {actual: "0x6064:0", target: "0x607A:0"}\n',
     "EDS foc-mc.eds has no object 0x607A:00 (position target)"),
    ('  tension: {actual: "0x6077:0", target: "0x6071:0"}\n'
     '  position: {actual: "0x1017:0"}\n',
     "object 0x1017:00 (position actual, Producer heartbeat time) cannot be mapped"),
    ('  tension: {actual: "0x6077:0", target: "0x6041:0"}\n  position: {actual: "0x6064:0"}\n',
     "object 0x6041:00 (tension target, Statusword) is not writable"),
    ('  tension: {actual: "0x6077:0", target: "6071"}\n  position: {actual: "0x6064:0"}\n',
     "objects.tension.target: '6071' is not an object"),
    ('  tension: {actual: "0x6077:0"}\n  position: {actual: "0x6064:0"}\n',
     "objects.tension needs `target:`"),
])
def test_drive_file_errors_name_the_eds_and_the_object(tmp_path, objects, says):
    path = _drive_file(tmp_path, objects)
    with pytest.raises(DriveFileError) as err:
        load_drive_file(path)
    assert says in str(err.value) and str(path) in str(err.value)
    assert "\n" not in str(err.value)


def test_missing_or_broken_eds_is_one_line(tmp_path):
    path = tmp_path / "d.cia402.yaml"
    path.write_text('eds: nowhere.eds\nobjects: {tension: {actual: "0x6077:0"}}\n')
    with pytest.raises(DriveFileError, match="nowhere.eds: cannot read the EDS"):
        load_drive_file(path)
    (tmp_path / "bad.eds").write_text("[1000]\nDataType=0x0007\n")  # no ParameterName
    path.write_text('eds: bad.eds\nobjects: {}\n')
    with pytest.raises(DriveFileError, match="bad.eds: not a readable EDS"):
        load_drive_file(path)


def test_statusword_codings_of_the_standard():
    # (statusword, state): CiA 402-2 state coding; bits 4 (voltage), 7, 9 (remote) and above
    # are not part of it and must not change the state read
    for word, state in [(0x0000, "Not ready to switch on"), (0x0040, "Switch on disabled"),
                        (0x0021, "Ready to switch on"), (0x0023, "Switched on"),
                        (0x0027, "Operation enabled"), (0x0007, "Quick stop active"),
                        (0x000F, "Fault reaction active"), (0x0008, "Fault")]:
        for extra in (0x0000, 0x0010, 0x0290, 0x1600):
            assert state_name(word | extra) == state, hex(word | extra)


# --------------------------------------------------------------------- state machine
def test_host_walks_the_state_machine_and_reads_what_the_drive_reports():
    with open_arm("virtual", ROBOT, speed=10.0, limits=LIMITS) as (driver, mock):
        proto = driver.protocols[0]
        for k, board in enumerate(mock.boards):
            assert board.controlwords[:3] == [SHUTDOWN, SWITCH_ON, ENABLE_OPERATION]
            assert board.history == WALK
            assert proto.state[k] == board.state == "Operation enabled"
            assert proto.identity[k] == (0x586, 0x13, 0x11)  # 0x1018 of the EDS
            assert board.node.sdo[0x1017].raw == 50  # heartbeat producer set over SDO
            assert board.consumer_ms == 1000  # watches the host's heartbeat (watchdog)
        driver.command("tension", 40.0)
        state = driver.dwell(0.3)
        assert state.tension == pytest.approx(np.full(4, 40.0), abs=2.0)
        assert mock.snapshot().modes == ("tension",) * 4
        assert all(b.mode_op == 10 for b in mock.boards)  # cyclic synchronous torque
        driver.command("length", state.length)
        driver.dwell(0.2)
        assert all(b.mode_op == 8 for b in mock.boards)  # cyclic synchronous position
        assert set(sum((b.controlwords[3:] for b in mock.boards), [])) == {ENABLE_OPERATION}


def test_a_drive_left_in_fault_is_reset_by_a_rising_edge_then_walked():
    link = "virtual:cia402-fault-reset"
    with MockArm(ROBOT, link, speed=10.0) as mock:
        board = mock.boards[2]
        board._fault("drive-fault")  # latched before the host connects (a crashed host)
        board.set_faults(set())  # the cause is gone; the fault stays latched until a reset
        with ArmDriver(CanTransport(link), mock.robot, LIMITS, connect_timeout_s=5.0):
            cw = board.controlwords
            assert cw[:2] == [0x00, FAULT_RESET]  # bit 7 low, then high: the rising edge
            assert cw[2:5] == [SHUTDOWN, SWITCH_ON, ENABLE_OPERATION]
            assert board.history == ["Switch on disabled", "Fault reaction active", "Fault",
                                     *WALK]


def test_torque_only_drive_uses_profile_torque_and_refuses_length_by_name():
    with open_arm("virtual", TORQUE_ROBOT, speed=10.0, limits=LIMITS) as (driver, mock):
        assert all(b.mode_op == 4 for b in mock.boards)  # 0x6502 = 0xC: no CST
        with pytest.raises(ValueError, match=r"foc-mc.eds\): the drive file names no "
                                             r"position target \(0x607A\)"):
            driver.command("length", 0.0)
        driver.command("tension", 30.0)
        assert driver.dwell(0.2).tension == pytest.approx(np.full(4, 30.0), abs=2.0)


# --------------------------------------------------------------------- faults
FAULTED = r"drive reports 'Fault( reaction active)?' \(statusword 0x021[8F]\); "
CASES = [  # (fault, stop, what the message must carry: the drive's own state and EMCY)
    ("drive-fault:m1@2", BoardFault, FAULTED + r"EMCY 0x2310 \(Current\), error register "
                                               r"0x03 \(generic, current\)"),
    ("overheat:m0@2", Overheat, FAULTED + r"EMCY 0x4310 \(Temperature\), error register 0x09 "
                                          r"\(generic, temperature\)"),
    ("lost-heartbeat:m3@2", BoardSilent, r"no heartbeat from CANopen node 4 over .* last NMT "
                                         r"state OPERATIONAL, drive reports 'Operation enabled'"),
    ("bus-off@2", BusOff, "bus-off"),
]


@pytest.mark.parametrize("spec, stop, says", CASES, ids=[c[0].split(":")[0].split("@")[0]
                                                         for c in CASES])
def test_every_fault_ends_in_a_named_state_the_drive_reported(spec, stop, says):
    with open_arm("virtual", ROBOT, faults=[spec], speed=10.0, limits=LIMITS) as (driver, mock):
        with pytest.raises(stop) as err:
            for sample in range(200):  # ends at the stop (within 1-2 s unloaded)
                mock.set_sample(sample)
                driver.command("tension", 60.0)
                driver.dwell(0.1)
        assert sample >= 2, "fault fired too early"
        assert re.search(says, str(err.value)), str(err.value)
        if stop is BusOff:  # nothing reaches the drives: their heartbeat consumer decides
            assert "last reported: m0 'Operation enabled'" in err.value.end_state
            assert "0x1016" in err.value.end_state
            return
        muscle = spec.split(":")[1].split("@")[0]
        assert err.value.muscle == muscle
        i = mock.muscles.index(muscle)
        if stop is BoardSilent:  # the drive itself is fine: every drive took the relax
            assert err.value.end_state == "relaxed: every board at its holding floor"
            assert wait_until(lambda: mock.snapshot().relaxed().all())
        else:  # the faulted drive cannot relax: said so, with its own state
            assert err.value.end_state.startswith("relaxed where the boards took it; "
                                                  f"{muscle} (node {i + 1}): drive reported "
                                                  "'Fault")
            assert wait_until(lambda: mock.boards[i].state == "Fault")
            assert mock.snapshot().modes[i] == "off"
            others = [j for j in range(4) if j != i]
            assert wait_until(lambda: mock.snapshot().relaxed()[others].all())
        with pytest.raises(SafetyStop):
            driver.command("tension", 60.0)


def test_ctrl_c_leaves_drives_at_the_floor_then_their_own_watchdogs_act():
    with open_arm("virtual", ROBOT, speed=10.0, limits=LIMITS) as (driver, mock):
        with pytest.raises(KeyboardInterrupt):
            with driver:
                driver.command("tension", 150.0)
                driver.dwell(0.2)
                raise KeyboardInterrupt
        # the last command each drive took: torque mode at the holding floor (10 N x 10/N)
        assert wait_until(lambda: all(b.targets.get((0x6071, 0)) == 100 and b.mode_op == 10
                                      for b in mock.boards))
        # no host SYNC nor heartbeat any more: each drive's SYNC supervision (0.5 s) or its
        # heartbeat consumer (1 s) faults it, EMCY 0x8100 or 0x8130
        assert wait_until(lambda: all(b.state == "Fault" for b in mock.boards), timeout=3.0)
        assert all(b.error_register & 0x10 for b in mock.boards)  # communication error
        assert mock.snapshot().modes == ("off",) * 4  # power stage off: slack, not tense


def test_a_hung_host_is_seen_by_each_drives_heartbeat_consumer():
    with open_arm("virtual", ROBOT, speed=10.0, limits=LIMITS) as (driver, mock):
        driver.command("tension", 40.0)
        driver.dwell(0.1)
        time.sleep(1.6)  # the host hangs: no commands, so no host heartbeat (consumer 1 s)
        with pytest.raises(WatchdogExpired) as err:
            driver.read_state()
        assert re.search(FAULTED + r"EMCY 0x8130 \(Monitoring\), error register 0x11 "
                                   r"\(generic, communication\)", str(err.value)), str(err.value)
        assert all(b.state == "Fault" for b in mock.boards)


# --------------------------------------------------------------------- scan and collection
def test_scan_lists_canopen_nodes_with_identity_and_state():
    res = CliRunner().invoke(main, ["scan", "--port", "virtual", "--robot", str(ROBOT),
                                    "--seconds", "0.3"])
    assert res.exit_code == 0, res.output
    for node in range(1, 5):
        assert f"CANopen node {node}" in res.output
    assert "vendor 0x00000586 product 0x00000013 revision 0x00000011" in res.output
    # powered up, not yet enabled by a host: the state each drive's statusword reports; no
    # heartbeat yet (the EDS's producer time 0x1017 is 0 until a host sets it)
    assert res.output.count("CiA 402 'Switch on disabled'  no heartbeat (0x1017 = 0 ms)") == 4


@pytest.mark.parametrize("port", ["virtual", "slcan-pty"])
def test_collection_runs_hil_on_cia402_drives(tmp_path, port):
    out = tmp_path / "c.parquet"
    res = CliRunner().invoke(main, ["collect", "--port", port, "--robot", str(ROBOT),
                                    "--samples", "4", "--seed", "3", "--out", str(out),
                                    "--mock-speed", "20", "--settle-window", "0.06"])
    assert res.exit_code == 0, res.output
    rec = read_recording(out)
    arm = ArmModel.load(ROBOT)
    assert rec.n_rows == 4 and rec.array("settled").all()
    assert np.abs(rec.theta - rec.theta_command).max() < 2e-3
    assert np.abs(_balance_residual(arm, rec)).max() < 0.05
    # the EDS has no temperature object: a fill, and the metadata says so (none invented)
    assert (rec.temperature == 25.0).all()
    assert rec.meta["temperature"].startswith("not reported by the boards of m0, m1, m2, m3")


def test_quick_stop_is_the_standards_and_its_end_is_reported_truthfully():
    with open_arm("virtual", ROBOT, speed=10.0, limits=LIMITS) as (driver, mock):
        driver.command("tension", 40.0)
        driver.dwell(0.1)
        driver.stop()
        assert wait_until(lambda: all(b.controlwords[-1] == QUICK_STOP for b in mock.boards))
        # quick stop option code 0x605A = 2 in the EDS: ramp down, then Switch on disabled
        assert wait_until(lambda: all(b.history[-2:] == ["Quick stop active",
                                                         "Switch on disabled"]
                                      for b in mock.boards))
        driver.read_state(0.1)  # a commanded quick stop is not a fault
        proto = driver.protocols[0]
        assert wait_until(lambda: (driver.read_state(0.02), proto.state)[1]
                          == ["Switch on disabled"] * 4)
        assert proto.not_relaxed()[0] == ("m0 (node 1): drive reported 'Switch on disabled', "
                                          "power stage off or stopping, not at the holding "
                                          "floor")


def test_a_missing_drive_is_named_at_connect():
    robot = load_robot(ROBOT)
    moved = dataclasses.replace(robot, muscles=tuple(
        dataclasses.replace(m, board_id=m.board_id + 10) for m in robot.muscles))
    link = "virtual:cia402-missing"
    with MockArm(robot, link, speed=10.0):
        with pytest.raises(BoardSilent) as err:
            ArmDriver(CanTransport(link), moved, LIMITS, connect_timeout_s=5.0)
    assert "no SDO answer from CANopen node 11 (foc-mc-csp.eds)" in str(err.value)
    assert err.value.muscle == "m0"


def test_cli_refuses_a_broken_drive_file_in_one_line_and_writes_nothing(tmp_path):
    for name in ("foc-mc-csp.eds", "two-link-cia402.muscles.yaml"):
        (tmp_path / name).write_text((HERE / name).read_text().replace(
            "../../calibration", str(HERE.parent.parent / "calibration")))
    (tmp_path / "foc-mc-csp.cia402.yaml").write_text(
        (HERE / "foc-mc-csp.cia402.yaml").read_text().replace('"0x6077:0"', '"0x6078:0"'))
    out = tmp_path / "c.parquet"
    res = CliRunner().invoke(main, ["collect", "--port", "virtual", "--robot",
                                    str(tmp_path / "two-link-cia402.muscles.yaml"),
                                    "--samples", "2", "--out", str(out)])
    assert res.exit_code == 1 and "Traceback" not in res.output
    assert "EDS foc-mc-csp.eds has no object 0x6078:00 (tension actual)" in res.output
    assert len(res.output.strip().splitlines()) == 1 and not out.exists()


@pytest.mark.parametrize("start, words, end, statusword", [
    # (state, controlwords in order, state after, statusword & 0x6F): CiA 402-2 transitions
    ("Switch on disabled", [0x0F], "Switch on disabled", 0x40),  # enable needs shutdown first
    ("Switch on disabled", [0x06], "Ready to switch on", 0x21),  # 2
    ("Ready to switch on", [0x0F], "Operation enabled", 0x27),  # 3 + 4
    ("Operation enabled", [0x07], "Switched on", 0x23),  # 5
    ("Operation enabled", [0x06], "Ready to switch on", 0x21),  # 8
    ("Operation enabled", [0x00], "Switch on disabled", 0x40),  # 9
    ("Operation enabled", [0x02], "Quick stop active", 0x07),  # 11
    ("Switched on", [0x02], "Switch on disabled", 0x40),  # 10
    ("Fault", [0x80], "Fault", 0x08),  # bit 7 already high: no rising edge, no reset
    ("Fault", [0x00, 0x80], "Switch on disabled", 0x40),  # 15
    ("Fault", [0x00, 0x0F], "Fault", 0x08),  # nothing but a reset leaves Fault
])
def test_simulated_drive_follows_the_standards_transitions(start, words, end, statusword):
    from types import SimpleNamespace

    from pimbs_hw.mock.cia402_drive import Cia402Board

    spec = SimpleNamespace(name="m0", board_id=5, f_floor=10.0)
    board = Cia402Board(spec, load_drive_file(HERE / "foc-mc.cia402.yaml"), 0.0)
    board.state, board.cw = start, 0x80 if start == "Fault" else 0x00
    for word in words:
        board.node.sdo[0x6040].raw = word  # as an SDO download from a host would write it
    assert board.state == end
    assert board.node.sdo[0x6041].raw & 0x6F == statusword


@pytest.mark.parametrize("option, end", [(2, "Switch on disabled"), (6, "Operation enabled")])
def test_simulated_quick_stop_ends_as_its_option_code_says(option, end):
    from types import SimpleNamespace

    from pimbs_hw.mock.cia402_drive import Cia402Board

    board = Cia402Board(SimpleNamespace(name="m0", board_id=5, f_floor=10.0),
                        load_drive_file(HERE / "foc-mc.cia402.yaml"), 0.0)
    board.node.sdo[0x605A].raw = option
    board.state = "Operation enabled"
    board.node.sdo[0x6040].raw = QUICK_STOP  # 11
    reading = SimpleNamespace(position_m=0.0, tension_n=0.0, temperature_c=25.0)
    board.supervise(0.0, reading)  # 0x605A 1-4: the drive ends the quick stop itself (12)
    board.node.sdo[0x6040].raw = ENABLE_OPERATION  # 16 where 0x605A is 5-8
    assert board.state == end


def test_a_drive_that_does_not_take_the_commanded_mode_is_named():
    # decoding only: the drive's TPDO with the mode display 0x6061 (and the statusword,
    # 'Operation enabled') as it would answer a length command while staying in cyclic
    # synchronous torque (mode 10)
    proto = load_robot_protocol(ROBOT)
    proto._enabled[0], proto._patience_s = True, 0.2  # 10 PDO periods of 20 ms
    proto.command(0, "length", 0.01)
    tpdo = next(m for _, m in proto.tpdos[0] if 0x6061 in [v.index for v in m.map])
    assert [v.index for v in tpdo.map] == [0x6041, 0x6061]  # packed: statusword, mode

    def frame(mode: int) -> bytes:
        return (0x0237).to_bytes(2, "little") + bytes([mode])

    updates = [proto.decode(tpdo.cob_id, frame(10))[0] for _ in range(11)]
    assert all(u.stop is None for u in updates[:10])
    assert updates[10].stop is BoardFault
    assert updates[10].note == ("drive did not take mode of operation 8 (cyclic synchronous "
                               "position): 0x6061 still reports 10 (cyclic synchronous torque) "
                               "after 11 PDOs")
    assert proto.decode(tpdo.cob_id, frame(8))[0].stop is None  # it switched: all is well


def load_robot_protocol(path):
    from pimbs_hw.protocol.profiles import protocols_for

    return protocols_for(load_robot(path))[0]


def test_check_wiring_names_a_drive_whose_position_counts_backwards():
    """direction applies to CiA 402 drives too: m2's drive counts down as its wire pays out,
    the robot file says +1; pulling it, the tension rises while the length seems to grow."""
    from pimbs_hw.wiring import check_wiring

    with open_arm("virtual", ROBOT, speed=10.0, limits=LIMITS,
                  mock_options={"winding": [1, 1, -1, 1]}) as (driver, _):
        results = check_wiring(driver, settle_s=0.4, watch_s=0.15)
    assert [r.muscle for r in results if not r.ok] == ["m2"]
    assert all(r.d_tension > 5 and r.d_length < 0 for r in results if r.ok)


def test_canopen_ids_that_collide_with_another_board_are_refused(tmp_path):
    """A CiA 402 drive owns CANopen's predefined ids of its node (0x180 + n, 0x580 + n, …): an
    ODrive whose block of ids lands there is refused before anything is sent."""
    from pimbs_hw.protocol.ids import IdCollision, check_ids
    from pimbs_hw.protocol.profiles import protocols_for

    text = (HERE / "two-link-cia402.muscles.yaml").read_text().replace(
        "../../calibration", str(HERE.parent.parent / "calibration"))
    for name in ("foc-mc-csp.eds", "foc-mc-csp.cia402.yaml"):
        (tmp_path / name).write_text((HERE / name).read_text())
    path = tmp_path / "two-link-cia402.muscles.yaml"
    path.write_text(text)
    robot = load_robot(path)
    check_ids(robot, protocols_for(robot))  # four drives, nodes 1-4: no collision
    # m1 becomes ODrive node 12: its ids 0x180-0x19F hold the drives' TPDO1 0x181-0x184
    clash = text.replace("    board_id: 2\n",
                         "    board_id: 12\n    protocol: odrive-cansimple\n", 1)
    path.write_text(clash)
    robot = load_robot(path)
    with pytest.raises(IdCollision, match=r"muscle m\d \(board \d+, .*\) and muscle m\d "
                       r"\(board \d+, .*\) both use CAN id\(s\) 0x18"):
        check_ids(robot, protocols_for(robot))


def _bare_protocol(node, muscle: str):
    """A ``Cia402Protocol`` with one drive, ``node``, and nothing else set up: what its SDO
    exchanges (``_sdo``) need."""
    from types import SimpleNamespace

    from pimbs_hw.protocol import cia402

    proto = object.__new__(cia402.Cia402Protocol)
    proto.nodes = [node]
    proto.drive = SimpleNamespace(eds=SimpleNamespace(name="drive.eds"))
    proto.specs = [SimpleNamespace(name=muscle)]
    proto.board_ids = [node.id]
    return proto


def test_an_sdo_timeout_while_the_host_could_not_run_is_asked_again(monkeypatch):
    """A timeout during which this process was starved (a loaded host: the answer may have
    come while nobody read it) is asked again; one while the host could run is the drive's
    silence, named at once."""
    from types import SimpleNamespace

    from canopen.sdo import SdoCommunicationError

    from pimbs_hw.protocol import cia402

    proto = _bare_protocol(SimpleNamespace(id=3), "m0")
    calls = []

    def answers_second_time():
        calls.append(1)
        if len(calls) == 1:
            raise SdoCommunicationError("No SDO response received")
        return 7

    class Lag:
        def __init__(self, starved_s):
            self.starved_s = starved_s

        def starved(self, t0, t1):
            return self.starved_s

    monkeypatch.setattr(cia402, "host_lag", lambda: Lag(0.2))
    assert proto._sdo(0, answers_second_time) == 7 and len(calls) == 2

    def never():
        calls.append(1)
        raise SdoCommunicationError("No SDO response received")

    calls.clear()
    with pytest.raises(BoardSilent, match="no SDO answer from CANopen node 3"):
        proto._sdo(0, never)  # a host starved every time: asked again, then named
    assert len(calls) == cia402.SDO_STALL_RETRIES + 1
    calls.clear()
    monkeypatch.setattr(cia402, "host_lag", lambda: Lag(0.0))
    with pytest.raises(BoardSilent):
        proto._sdo(0, answers_second_time)  # the host could run: the drive was silent
    assert len(calls) == 1


def test_a_late_answer_to_an_earlier_request_is_dropped_and_asked_again(monkeypatch):
    """Under load, a request asked again after a timeout gets two answers; the second can
    arrive after the client emptied its queue for the next request, which then reads an
    answer for another object. That is no silent drive: the stale answer is dropped and
    the request asked again, with the host never starved."""
    import queue
    from types import SimpleNamespace

    from canopen.sdo import SdoCommunicationError

    from pimbs_hw.protocol import cia402

    stale = queue.Queue()
    stale.put(b"late")
    proto = _bare_protocol(SimpleNamespace(id=4, sdo=SimpleNamespace(responses=stale)), "m3")
    calls = []

    def late_answer_first():
        calls.append(1)
        if len(calls) == 1:
            raise SdoCommunicationError(
                "Node returned a value for 0x1018:02 instead, maybe there is another SDO "
                "client communicating on the same SDO channel?")
        return 0x13

    monkeypatch.setattr(cia402, "host_lag",
                        lambda: SimpleNamespace(starved=lambda t0, t1: 0.0))
    assert proto._sdo(0, late_answer_first) == 0x13 and len(calls) == 2
    assert proto.nodes[0].sdo.responses.empty()  # the stale answer was dropped
