"""ODrive checked against ODrive's own definition, not against our driver.

Every frame on the bus (sniffed by a third python-can virtual bus node) is decoded strictly
with the DBC that ODrive publishes for firmware 0.6 (shipped in the ``odrive-can`` package)
and read with ODrive's own enums (``odrive_can.enums``: AxisState, ODriveError,
ProcedureResult). The simulated axis (``pimbs_hw.mock.odrive``) is tested against ODrive's
documented behaviour directly, without the host.
"""

from __future__ import annotations

import dataclasses
import threading
import time
import uuid
from pathlib import Path

import can
import numpy as np
import pytest
from click.testing import CliRunner

odrive_can = pytest.importorskip("odrive_can")
import cantools  # noqa: E402
from odrive_can.enums import AxisState, ODriveError, ProcedureResult  # noqa: E402

from pimbs_cli.main import main  # noqa: E402
from pimbs_hw import open_arm  # noqa: E402
from pimbs_hw.mock.boards import SiReading  # noqa: E402
from pimbs_hw.mock.odrive import ODriveAxis  # noqa: E402
from pimbs_hw.protocol.codec import Fault  # noqa: E402
from pimbs_hw.safety import BoardFault, WatchdogExpired  # noqa: E402
from tests.test_driver_mock import wait_until  # noqa: E402
from tests.test_profiles import LIMITS, ODRIVE_ROBOT  # noqa: E402

ODRIVE_DBC = Path(odrive_can.__file__).parent / "dbc" / "odrive-cansimple-0.6.10.dbc"
DB = cantools.database.load_file(str(ODRIVE_DBC), strict=True)
NODES = (1, 2, 3, 4)  # the fixture robot's node ids (m0..m3)
HOST_CMDS = {"Estop", "Set_Axis_State", "Set_Controller_Mode", "Set_Input_Pos",
             "Set_Input_Torque", "Clear_Errors"}
JOINT_IDS = {0x240, 0x241}  # the robot's joint encoders (PIMBS v1 JOINT frames)


def odrive_decode(fid: int, data: bytes) -> tuple[int, str, dict]:
    """(node, message, signals) of one frame, by ODrive's DBC; fails on any size mismatch."""
    msg = DB.get_message_by_frame_id(fid & 0x1F)  # Axis0_*: node 0 carries ids 0..31
    assert len(data) == msg.length, f"{msg.name}: {len(data)} bytes, ODrive's DBC says {msg.length}"
    values = msg.decode(data, decode_choices=False, allow_truncated=False, allow_excess=False)
    return fid >> 5, msg.name.split("_", 1)[1], values


class Sniffer:
    """A passive node on the virtual channel: every frame the host and the ODrives send."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.frames: list[tuple[int, str, dict]] = []

    def drain(self) -> list[tuple[int, str, dict]]:
        while (m := self.bus.recv(0.0)) is not None:
            if m.arbitration_id in JOINT_IDS:
                continue
            assert m.arbitration_id >> 5 in NODES, f"frame 0x{m.arbitration_id:X} is no one's"
            self.frames.append(odrive_decode(m.arbitration_id, bytes(m.data)))
        return self.frames

    def close(self) -> None:
        self.bus.shutdown()


@pytest.fixture()
def bus():
    channel = f"pimbs-odrive-{uuid.uuid4().hex[:10]}"
    sniffer = Sniffer(channel)
    yield f"virtual:{channel}", sniffer
    sniffer.close()


def _index(frames, node, name, where=lambda v: True, start=0) -> int:
    return next(k for k in range(start, len(frames))
                if frames[k][0] == node and frames[k][1] == name and where(frames[k][2]))


def test_collection_frames_are_odrives_and_commands_wait_for_closed_loop(bus):
    port, sniff = bus
    with open_arm(port, ODRIVE_ROBOT, speed=10.0, limits=LIMITS) as (driver, mock):
        driver.command("tension", 60.0)
        driver.dwell(0.5)
        sniff.drain()
        n_before_pull = len(sniff.frames)
        driver.command("length", driver.read_state().length + 0.002)
        driver.dwell(0.3)
    frames = sniff.drain()
    names = {name for _, name, _ in frames}
    assert {"Heartbeat", "Get_Encoder_Estimates", "Get_Torques", "Get_Temperature",
            "Set_Axis_State", "Set_Input_Torque", "Set_Input_Pos", "Clear_Errors"} <= names
    closed = int(AxisState.CLOSED_LOOP_CONTROL)
    for node in NODES:
        beat = _index(frames, node, "Heartbeat")
        assert frames[beat][2]["Axis_State"] == AxisState.IDLE  # boots idle: motor off
        request = _index(frames, node, "Set_Axis_State")
        assert frames[request][2]["Axis_Requested_State"] == closed
        confirmed = _index(frames, node, "Heartbeat", lambda v: v["Axis_State"] == closed)
        assert request < confirmed
        first_input = min(_index(frames, node, n) for n in ("Set_Input_Torque",
                                                            "Set_Input_Pos", "Set_Controller_Mode"))
        assert confirmed < first_input, "the host commanded an axis before CLOSED_LOOP_CONTROL"
        beats = [v for n, name, v in frames if n == node and name == "Heartbeat"]
        assert all(b["Axis_Error"] == ODriveError.NONE for b in beats)
        assert all(b["Procedure_Result"] == ProcedureResult.BUSY
                   for b in beats if b["Axis_State"] == closed)
        # 60 N through the 6 mm pulley is 0.36 N·m (direction 1: a positive torque pulls)
        torques = [v["Input_Torque"] for n, name, v in frames
                   if n == node and name == "Set_Input_Torque"]
        assert max(torques) == pytest.approx(0.36, rel=1e-6)
        # the motor turns the way of its torque: under the pull the rotor turned positive
        pos = [(k, v["Pos_Estimate"]) for k, (n, name, v) in enumerate(frames)
               if n == node and name == "Get_Encoder_Estimates"]
        pulled = _index(frames, node, "Set_Input_Torque", lambda v: v["Input_Torque"] > 0.3)
        before = [p for k, p in pos if k < pulled][-1]
        after = [p for k, p in pos if k < n_before_pull][-1]
        assert after > before
        torque = [v for n, name, v in frames if n == node and name == "Get_Torques"]
        # in torque control the setpoint is the command (in position control, the load)
        assert any(t["Torque_Target"] == pytest.approx(0.36, rel=1e-6) for t in torque)
        assert max(t["Torque_Estimate"] for t in torque) > 0.2
        assert any(v["Vel_Estimate"] > 0 for n, name, v in frames
                   if n == node and name == "Get_Encoder_Estimates")
        fet = [v["FET_Temperature"] for n, name, v in frames
               if n == node and name == "Get_Temperature"]
        assert 15.0 < min(fet) and max(fet) < 60.0
    # every host frame is one of ODrive's commands, at ODrive's length (checked in decode)
    host = {name for _, name, _ in frames} & HOST_CMDS
    assert host == {"Set_Axis_State", "Set_Controller_Mode", "Set_Input_Pos",
                    "Set_Input_Torque", "Clear_Errors"}


def test_watchdog_trip_reports_idle_then_rearms_and_confirms(bus):
    port, sniff = bus
    # a host watchdog no longer than ODrive's own: the simulated axes keep their 0.6 s
    limits = dataclasses.replace(LIMITS, watchdog_s=0.6)
    with open_arm(port, ODRIVE_ROBOT, speed=10.0, limits=limits) as (driver, mock):
        assert [b.watchdog_s for b in mock.boards] == [0.6] * 4
        driver.command("tension", 30.0)
        driver.dwell(0.2)
        time.sleep(1.2)  # a hung host: ODrive's watchdog (0.6 s) disarms every axis
        with pytest.raises(WatchdogExpired) as err:
            driver.command("tension", 30.0)
        assert "Axis_State IDLE (1)" in str(err.value)
        assert "Axis_Error 0x01000000 WATCHDOG_TIMER_EXPIRED" in str(err.value)
        assert err.value.end_state.startswith("relaxed: every board at its holding floor")
        assert "re-armed, confirmed by their own state report" in err.value.end_state
        assert "idled by their own watchdog" in err.value.end_state  # and slack after that
        frames = sniff.drain()
    watchdog = int(ODriveError.WATCHDOG_TIMER_EXPIRED)
    assert watchdog == 0x01000000
    for node in NODES:
        trip = _index(frames, node, "Heartbeat", lambda v: v["Axis_Error"] & watchdog)
        assert frames[trip][2]["Axis_State"] == AxisState.IDLE
        assert frames[trip][2]["Procedure_Result"] == ProcedureResult.DISARMED
        clear = _index(frames, node, "Clear_Errors", start=trip)
        rearm = _index(frames, node, "Set_Axis_State",
                       lambda v: v["Axis_Requested_State"] == AxisState.CLOSED_LOOP_CONTROL,
                       start=clear)
        back = _index(frames, node, "Heartbeat",
                      lambda v: v["Axis_State"] == AxisState.CLOSED_LOOP_CONTROL, start=rearm)
        assert frames[back][2]["Axis_Error"] == 0  # cleared: errors latch until Clear_Errors
        for k in range(trip, clear):  # latched: every heartbeat in between still says so
            if frames[k][0] == node and frames[k][1] == "Heartbeat":
                assert frames[k][2]["Axis_Error"] & watchdog


def test_a_board_loop_running_late_still_sees_every_command_that_reached_it(bus):
    """The simulated axes' loop stops in one tick (a slow solve) for longer than their
    watchdog while the host keeps commanding: the commands that reached the axes meanwhile
    feed their watchdogs before the next tick checks them, as on an ODrive, whose watchdog
    is fed as each frame arrives."""
    port, _ = bus
    # ODrive's own 0.6 s; the loop's stop (0.9 s) stays short of the host's silence limit
    limits = dataclasses.replace(LIMITS, watchdog_s=0.6)
    with open_arm(port, ODRIVE_ROBOT, speed=10.0, limits=limits) as (driver, mock):
        late_s = 1.5 * mock.boards[0].watchdog_s
        assert late_s < limits.silent_after_s
        driver.command("tension", 30.0)
        driver.dwell(0.3)
        step, slow, started = mock.plant.step, threading.Event(), threading.Event()

        def slow_step(dt):
            if slow.is_set() and not started.is_set():
                started.set()
                time.sleep(late_s)  # sleeps without the GIL: not a stall of this process
            return step(dt)

        mock.plant.step = slow_step
        time.sleep(0.05)  # the axes have taken every command: none is left over for later
        slow.set()
        assert started.wait(1.0)
        time.sleep(0.1)  # the next commands reach the axes well after that tick began
        driver.dwell(late_s + 0.5)  # commands every 20 ms; raises WatchdogExpired on a trip
        assert mock.snapshot().modes == ("tension",) * 4  # a disarmed axis is "idle"


def test_fault_that_persists_is_reported_idle_with_the_devices_words():
    with open_arm("virtual", ODRIVE_ROBOT, speed=10.0, limits=LIMITS,
                  faults=["drive-fault:m1@1"]) as (driver, mock):
        with pytest.raises(BoardFault) as err:
            for sample in range(20):
                mock.set_sample(sample)
                driver.command("tension", 30.0)
                driver.dwell(0.1)
        assert err.value.muscle == "m1"
        end = err.value.end_state
        assert end.startswith("m1 (board 2): motor off, its wire may be slack; after a re-arm "
                              "the board still reports Axis_State IDLE (1), Axis_Error "
                              "0x00000020 DRV_FAULT")
        assert "the others relaxed at their holding floor" in end
        # the others relaxed (until their own watchdog idles them 0.6 s after the last frame)
        assert wait_until(lambda: mock.snapshot().modes == ("relax", "idle", "relax", "relax"),
                          timeout=0.5)
        assert mock.snapshot().tension[1] < 1.0  # nothing holds m1's wire


# ------------------------------------------------ the simulated axis against ODrive's docs
def _axis(winding: int = 1) -> ODriveAxis:
    from pimbs_calibration.description import load_robot

    spec = load_robot(ODRIVE_ROBOT).muscles[0]
    return ODriveAxis(spec, 0.0, turns_per_m=26.5258, nm_per_n=0.006, winding=winding,
                      watchdog_s=0.6)


def _send(axis, name: str, t: float, reading, **signals) -> None:
    msg = DB.get_message_by_name(f"Axis0_{name}")
    axis.receive(axis.node << 5 | msg.frame_id, msg.encode(signals), t, reading)


def _frame(axis, cmd: int, reading) -> dict:
    """The axis's next cyclic frame ``cmd`` (its clock moved on by 10 s each call)."""
    axis.clock = getattr(axis, "clock", 1e6) + 10.0
    fid, data = next(f for f in axis.frames(axis.clock, reading) if f[0] & 0x1F == cmd)
    return odrive_decode(fid, data)[2]


def _heartbeat(axis, reading) -> dict:
    return _frame(axis, 0x01, reading)


def test_simulated_axis_follows_odrives_state_machine():
    r = SiReading(0.0, 10.0, 25.0)
    axis = _axis()
    assert _heartbeat(axis, r)["Axis_State"] == AxisState.IDLE
    axis.inject("drive-fault")
    _send(axis, "Set_Axis_State", 0.1, r, Axis_Requested_State=8)
    assert axis.state == AxisState.IDLE  # refused while an error is latched
    _send(axis, "Clear_Errors", 0.2, r, Identify=0)
    assert _heartbeat(axis, r)["Axis_Error"] == ODriveError.DRV_FAULT  # the cause persists
    axis = _axis()
    _send(axis, "Set_Axis_State", 0.1, r, Axis_Requested_State=8)
    assert axis.state == AxisState.CLOSED_LOOP_CONTROL
    axis.supervise(0.5, r)
    assert axis.state == AxisState.CLOSED_LOOP_CONTROL  # fed 0.4 s ago: within 0.6 s
    axis.supervise(0.8, r)
    beat = _heartbeat(axis, r)
    assert (beat["Axis_State"], beat["Axis_Error"]) == (AxisState.IDLE,
                                                        ODriveError.WATCHDOG_TIMER_EXPIRED)
    _send(axis, "Set_Axis_State", 0.9, r, Axis_Requested_State=8)
    assert axis.state == AxisState.IDLE  # latched until Clear_Errors
    _send(axis, "Clear_Errors", 1.0, r, Identify=0)
    _send(axis, "Set_Axis_State", 1.0, r, Axis_Requested_State=8)
    assert _heartbeat(axis, r)["Axis_State"] == AxisState.CLOSED_LOOP_CONTROL
    _send(axis, "Estop", 1.1, r)
    beat = _heartbeat(axis, r)
    assert beat["Axis_State"] == AxisState.IDLE and beat["Axis_Error"] & ODriveError.ESTOP_REQUESTED


@pytest.mark.parametrize("winding", [1, -1])
def test_simulated_rotor_turns_the_way_of_its_torque(winding):
    """A positive torque turns the rotor positive whichever way the wire is wound: wound to
    pull (+1) it reels the wire in against its tension; wound the other way (-1) the wire
    goes slack and the free rotor runs at vel_limit, paying it out."""
    axis = _axis(winding)
    r = SiReading(0.0, 10.0, 25.0)
    _send(axis, "Set_Axis_State", 0.0, r, Axis_Requested_State=8)
    _send(axis, "Set_Controller_Mode", 0.0, r, Control_Mode=1, Input_Mode=1)
    _send(axis, "Set_Input_Torque", 0.0, r, Input_Torque=0.36)
    mode, value = axis.actuation()
    if winding == 1:
        assert (mode, value) == ("tension", pytest.approx(60.0))  # pulls the wire
        axis.supervise(0.01, r)
        axis.supervise(0.02, SiReading(-0.001, 60.0, 25.0))  # the wire came in 1 mm
    else:
        assert (mode, value) == ("tension", 0.0)  # slack: the wire is paid out
        for k in range(1, 11):
            _send(axis, "Set_Input_Torque", k / 100, r, Input_Torque=0.36)
            axis.supervise(k / 100, r)
        assert axis.slack_m == pytest.approx(0.1 * 2.0 / 26.5258, rel=0.02)  # vel_limit
    est = _frame(axis, 0x09, r)
    assert est["Vel_Estimate"] > 0 and est["Pos_Estimate"] > 0


# ------------------------------------------------------------------ CAN-id collisions
def _robot(tmp_path: Path, board_ids: dict[str, int], protocol: dict[str, str] | None = None,
           ) -> Path:
    """The fixture ODrive robot (m0..m3 on nodes 1..4) with other node ids / protocols."""
    urdf = ODRIVE_ROBOT.parent.parent.parent / "calibration" / "robots"
    text = ODRIVE_ROBOT.read_text().replace("../../calibration/robots", str(urdf))
    for k, name in enumerate(("m0", "m1", "m2", "m3")):
        extra = f"\n    protocol: {protocol[name]}" if protocol and name in protocol else ""
        text = text.replace(f"board_id: {k + 1}\n",
                            f"board_id: {board_ids.get(name, k + 1)}X{extra}\n", 1)
    path = tmp_path / "robot.muscles.yaml"
    path.write_text(text.replace("X\n", "\n").replace("X\n", "\n"))
    return path


@pytest.mark.parametrize("ids, protocol, says", [
    ({"m2": 18}, None, "muscle m2 (board 18, odrive-cansimple) and joint encoders (pimbs-v1) "
     "both use CAN id(s) 0x240, 0x241"),
    ({"m0": 0, "m3": 5}, {"m0": "pimbs-v1"}, "muscle m0 (board 0, pimbs-v1) and muscle m3 "
     "(board 5, odrive-cansimple) both use CAN id(s) 0x0A0"),
    ({"m1": 64}, None, "muscle m1 (board 64, odrive-cansimple) would use CAN ids up to 0x81F"),
], ids=["odrive-node-18-vs-joints", "v1-vs-odrive", "node-64"])
def test_id_collisions_are_refused_at_load_in_one_line(tmp_path, ids, protocol, says):
    robot = _robot(tmp_path, ids, protocol)
    res = CliRunner().invoke(main, ["scan", "--port", "virtual", "--robot", str(robot)])
    assert res.exit_code == 1, res.output
    assert says in res.output, res.output
    assert "Traceback" not in res.output and len(res.output.strip().splitlines()) == 1


def test_odrive_node_ids_up_to_63_are_accepted(tmp_path):
    from pimbs_calibration.description import load_robot
    from pimbs_hw.protocol.profiles import protocols_for

    protos = protocols_for(load_robot(_robot(tmp_path, {"m0": 63, "m1": 40, "m2": 0})))
    used = set().union(*(p.ids_used(i) for p in protos for i in p.indices))
    assert max(used) == 0x7FF and np.isin([0x000, 0x500, 0x7E0], list(used)).all()


def test_axis_idled_by_another_node_is_reported_and_rearmed(bus):
    """Someone else on the bus (odrivetool, a second host) idles node 2: no error, IDLE."""
    port, sniff = bus
    with open_arm(port, ODRIVE_ROBOT, speed=10.0, limits=LIMITS) as (driver, mock):
        driver.command("tension", 30.0)
        driver.dwell(0.2)
        request = DB.get_message_by_name("Axis0_Set_Axis_State")
        sniff.bus.send(can.Message(arbitration_id=2 << 5 | request.frame_id, is_extended_id=False,
                                   data=request.encode({"Axis_Requested_State": 1})))
        with pytest.raises(BoardFault) as err:
            driver.dwell(1.0)
        assert err.value.muscle == "m1"
        assert "the board reports Axis_State IDLE (1), Axis_Error 0x00000000" in str(err.value)
        assert err.value.end_state.startswith("relaxed: every board at its holding floor (m1 "
                                              "re-armed, confirmed by their own state report)")
    frames = sniff.drain()
    idle = _index(frames, 2, "Heartbeat", lambda v: v["Axis_State"] == AxisState.IDLE
                  and v["Procedure_Result"] == ProcedureResult.CANCELLED)
    _index(frames, 2, "Heartbeat", lambda v: v["Axis_State"] == AxisState.CLOSED_LOOP_CONTROL,
           start=idle)


def test_every_frame_of_a_pimbs_collect_run_decodes_with_odrives_dbc(bus, tmp_path):
    port, sniff = bus
    out = tmp_path / "o.parquet"
    res = CliRunner().invoke(main, ["collect", "--port", port, "--robot", str(ODRIVE_ROBOT),
                                    "--samples", "2", "--seed", "1", "--out", str(out),
                                    "--mock-speed", "20", "--settle-window", "0.06"])
    assert res.exit_code == 0, res.output
    frames = sniff.drain()  # every frame decoded strictly (odrive_decode) or it fails here
    assert len(frames) > 500
    closed = int(AxisState.CLOSED_LOOP_CONTROL)
    for node in NODES:
        confirmed = _index(frames, node, "Heartbeat", lambda v: v["Axis_State"] == closed)
        inputs = [k for k, (n, name, _) in enumerate(frames) if n == node
                  and name in ("Set_Input_Torque", "Set_Input_Pos", "Set_Controller_Mode")]
        assert inputs and min(inputs) > confirmed
        assert all(v["Axis_Error"] == 0 for n, name, v in frames
                   if n == node and name == "Heartbeat")


def test_an_axis_that_will_not_arm_is_refused_before_any_command(bus):
    port, sniff = bus
    with pytest.raises(BoardFault) as err:
        with open_arm(port, ODRIVE_ROBOT, speed=10.0, limits=LIMITS, connect_timeout_s=1.0,
                      faults=["drive-fault:m1"]):
            pass
    assert err.value.detail.startswith("not armed within 1.0 s: m1 (board 2, profile "
                                     "odrive-cansimple, reports Axis_State IDLE (1), "
                                     "Axis_Error 0x00000020 DRV_FAULT)")
    assert err.value.end_state.startswith("m1 (board 2): motor off, its wire may be slack")
    frames = sniff.drain()
    assert not [f for f in frames if f[0] == 2 and f[1] in ("Set_Input_Torque", "Set_Input_Pos")
                and f[2].get("Input_Torque", 0) > 0.07]  # m1 never got more than its relax


@pytest.mark.parametrize("error, faults", [
    (0, Fault(0)), (0x01000000, Fault.WATCHDOG), (0x00000020, Fault.MOTOR),
    (0x00002000, Fault.OVERHEAT), (0x80000000, Fault.MOTOR),
    (0x01000020, Fault.WATCHDOG | Fault.MOTOR)])
def test_host_reads_heartbeats_as_odrives_enums_define_them(error, faults):
    from pimbs_calibration.description import load_robot
    from pimbs_hw.protocol.profiles import protocols_for

    (proto,) = [p for p in protocols_for(load_robot(ODRIVE_ROBOT)) if p.indices]
    beat = DB.get_message_by_name("Axis0_Heartbeat")
    data = beat.encode({"Axis_Error": error, "Axis_State": int(AxisState.IDLE),
                        "Procedure_Result": int(ProcedureResult.DISARMED),
                        "Trajectory_Done_Flag": 0})
    (update,) = proto.decode(3 << 5 | beat.frame_id, data)
    assert (update.muscle, update.state, update.error_code, update.faults) == (2, 1, error, faults)
    assert not proto.armed(update.state) and proto.armed(int(AxisState.CLOSED_LOOP_CONTROL))
    text = proto.state_text(update.state, update.error_code)
    assert text.startswith(f"Axis_State IDLE (1), Axis_Error 0x{error:08X}")
    for flag in ODriveError:
        if flag and error & flag and flag.name in {n for _, n, _ in proto.profile.faults[0].bits}:
            assert flag.name in text  # named as ODrive's enum names it
