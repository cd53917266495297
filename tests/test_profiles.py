"""Boards described by data (a DBC + a mapping) and the shipped ODrive CANSimple profile:
validation that names file, line and signal; every fault ends in a named state; and the
whole collection hardware-in-the-loop, over python-can virtual and a real interface."""

from __future__ import annotations

import uuid
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pimbs_arm.model import ArmModel
from pimbs_cli.main import main
from pimbs_hw import open_arm
from pimbs_hw.connect import SIMULATED_LIMITS
from pimbs_hw.mock import MockArm
from pimbs_hw.protocol.profile import ProfileError, load_profile
from pimbs_hw.protocol.profiles import profile_path
from pimbs_hw.safety import (
    BoardSilent,
    BusOff,
    CorruptFrames,
    FramesDropped,
    LoadcellSaturated,
    Overheat,
    SafetyStop,
)
from pimbs_recording.format import read_recording
from tests.test_collect import _balance_residual
from tests.test_driver_mock import wait_until

LAB = Path(__file__).parent.parent / "fixtures" / "lab-board"
LAB_ROBOT = LAB / "two-link-lab.muscles.yaml"
ODRIVE_ROBOT = LAB / "two-link-odrive.muscles.yaml"
LAB_PROFILE = LAB / "lab_muscle_board.profile.yaml"


# --------------------------------------------------------------------------- validation
def _broken(tmp_path: Path, old: str, new: str) -> Path:
    for name in ("lab_muscle_board.dbc",):
        (tmp_path / name).write_text((LAB / name).read_text())
    text = LAB_PROFILE.read_text()
    assert old in text
    path = tmp_path / "lab.profile.yaml"
    path.write_text(text.replace(old, new))
    return path


def _line_of(path: Path, needle: str) -> int:
    return next(n for n, line in enumerate(path.read_text().splitlines(), 1) if needle in line)


@pytest.mark.parametrize("old, new, says", [
    ("signal: force}", "signal: forse}", "message LOADCELL has no signal 'forse' (it has: force)"),
    ("message: LOADCELL,", "message: LOADCEL,", "the DBC has no message 'LOADCEL'"),
    ("{node: loadcell, message: LOADCELL", "{node: amp, message: LOADCELL",
     "unknown node 'amp'"),
    ("target: value}, per_si: 1000", "target: 5}, per_si: 1000",
     "commands.length: no frame carries the command"),
    ("signals: {mode: 3, target: 0}", "signals: {mode: 3}", "also needs target"),
    ("signal: error, kind: motor", "signal: error, kind: melted", "unknown fault kind 'melted'"),
])
def test_profile_errors_name_file_line_and_signal(tmp_path, old, new, says):
    path = _broken(tmp_path, old, new)
    with pytest.raises(ProfileError) as err:
        load_profile(path)
    message = str(err.value)
    assert says in message and "\n" not in message
    assert message.startswith(f"{path}:{_line_of(path, new.split(',')[0].strip('{} '))}:")


def test_missing_dbc_and_broken_yaml_are_one_line(tmp_path):
    path = _broken(tmp_path, "dbc: lab_muscle_board.dbc", "dbc: nowhere.dbc")
    with pytest.raises(ProfileError, match=r"lab.profile.yaml:\d+: dbc: cannot load .*nowhere"):
        load_profile(path)
    path.write_text("status: [unclosed\n")
    with pytest.raises(ProfileError, match="not valid YAML"):
        load_profile(path)


def test_shipped_profile_declares_what_the_host_covers():
    odrive = load_profile(profile_path("odrive-cansimple"))
    caps = odrive.capabilities
    assert caps.board_watchdog and caps.temperature and caps.version
    assert not caps.counter and not caps.checksum and not caps.board_limits
    assert odrive.status_period_s() == pytest.approx(0.01)  # from the DBC's cycle time
    assert any("arrival rate" in gap for gap in caps.gaps())


def test_profile_round_trip_through_the_dbc():
    """What the host encodes is what a board decodes, in the DBC's units."""
    from pimbs_calibration.description import load_robot

    robot = load_robot(LAB_ROBOT)
    proto = load_profile(LAB_PROFILE).protocol([0], [robot.muscles[0]])
    (fid, data), = proto.command(0, "length", 0.0123)
    assert fid == 0x280 + robot.muscles[0].board_id
    msg = proto.profile.db.get_message_by_name("MOTOR_CMD").decode(data, decode_choices=False)
    assert msg["target"] == pytest.approx(12.3) and msg["mode"] == 1
    status = proto.profile.db.get_message_by_name("LOADCELL")
    update, = proto.decode(0x400 + robot.muscles[0].board_id, status.encode({"force": 123.45}))
    assert update.tension_n == pytest.approx(123.45) and not update.saturated
    update, = proto.decode(0x400 + robot.muscles[0].board_id, status.encode({"force": 1500}))
    assert update.saturated


# ------------------------------------------------------------- faults and their end state
LIMITS = SIMULATED_LIMITS  # boards simulated in this process share its CPU: long limits
CASES = [  # (fault, stop, names the muscle)
    ("silent-board:m1@2", BoardSilent, True),
    ("drop-frames:m2@2", FramesDropped, True),
    ("corrupt-frames:m3@2", CorruptFrames, False),  # no checksum: CAN error frames, the bus
    ("overheat:m0@2", Overheat, True),
    ("saturate-loadcell:m1@2", LoadcellSaturated, True),
    ("bus-off@2", BusOff, False),
]


@pytest.mark.parametrize("robot, unreachable", [(LAB_ROBOT, "relax"), (ODRIVE_ROBOT, "idle")],
                         ids=["lab-board", "odrive"])
@pytest.mark.parametrize("spec, stop, per_muscle", CASES,
                         ids=[c[0].split(":")[0].split("@")[0] for c in CASES])
def test_every_fault_ends_in_a_named_state(robot, unreachable, spec, stop, per_muscle):
    with open_arm("virtual", robot, faults=[spec], speed=10.0, limits=LIMITS) as (driver, mock):
        with pytest.raises(stop) as err:
            for sample in range(30):
                mock.set_sample(sample)
                driver.command("tension", 60.0)
                driver.dwell(0.1)
        assert sample >= 2, "fault fired too early"
        if per_muscle:
            assert err.value.muscle == spec.split(":")[1].split("@")[0]
        assert err.value.port == mock.port
        if stop is BusOff:  # nothing reaches the boards: their own watchdog decides
            assert unreachable in err.value.end_state
            want = "relax" if unreachable == "relax" else "idle"
            assert wait_until(lambda: mock.snapshot().modes == (want,) * 4, timeout=3.0)
            floor = 10.0 if want == "relax" else 0.0
        else:
            assert err.value.end_state.startswith("relaxed")
            assert wait_until(lambda: mock.snapshot().relaxed().all(), timeout=2.0)
            floor = 10.0
        assert wait_until(lambda: np.allclose(mock.snapshot().tension, floor, atol=1.0))
        with pytest.raises(SafetyStop):
            driver.command("tension", 60.0)


@pytest.mark.parametrize("robot", [LAB_ROBOT, ODRIVE_ROBOT], ids=["lab-board", "odrive"])
def test_boards_simulated_beside_the_host_keep_its_watchdog_where_theirs_is_shorter(robot):
    """A board's own watchdog (the profile's 0.6 s, set in its firmware) holds wherever the
    boards are not simulated in the host's process (``pimbs mockbus``); beside the host,
    where they share its CPU, they get the host's longer watchdog time."""
    def watchdogs(mock):
        return [b.watchdog_s if hasattr(b, "watchdog_s") else b.watchdog[0]
                for b in mock.boards]

    profile_s = load_profile(profile_path("odrive-cansimple") if robot == ODRIVE_ROBOT
                             else LAB / "lab_muscle_board.profile.yaml").watchdog[0]
    assert profile_s == 0.6 < LIMITS.watchdog_s
    with MockArm(robot, f"virtual:dog-{uuid.uuid4().hex[:10]}") as mock:
        assert watchdogs(mock) == [profile_s] * 4
    with open_arm("virtual", robot, limits=LIMITS) as (_, mock):
        assert watchdogs(mock) == [LIMITS.watchdog_s] * 4


# ------------------------------------------------------------- whole collection, HIL
@pytest.mark.parametrize("robot, port", [
    (LAB_ROBOT, "virtual"), (LAB_ROBOT, "slcan-pty"), (ODRIVE_ROBOT, "virtual"),
    (ODRIVE_ROBOT, "slcan-pty"), ("two-link-4-muscle", "slcan-pty")],
    ids=["lab-board-virtual", "lab-board-slcan", "odrive-virtual", "odrive-slcan",
         "pimbs-v1-slcan"])
def test_collection_runs_hil_on_profile_boards(tmp_path, robot, port):
    out = tmp_path / "p.parquet"
    res = CliRunner().invoke(main, ["collect", "--port", port, "--robot", str(robot),
                                    "--samples", "4", "--seed", "3", "--out", str(out),
                                    "--mock-speed", "20", "--settle-window", "0.06"])
    assert res.exit_code == 0, res.output
    rec = read_recording(out)
    arm = ArmModel.load(robot)
    assert rec.n_rows == 4 and rec.array("settled").all()
    assert np.abs(rec.theta - rec.theta_command).max() < 2e-3
    assert np.abs(_balance_residual(arm, rec)).max() < 0.05
    assert np.isfinite(rec.temperature).all()


def test_collection_on_profile_boards_stops_safely_mid_run(tmp_path):
    out = tmp_path / "f.parquet"
    res = CliRunner().invoke(main, ["collect", "--port", "virtual", "--robot", str(ODRIVE_ROBOT),
                                    "--samples", "6", "--out", str(out), "--mock-speed", "20",
                                    "--settle-window", "0.06", "--fault", "overheat:m2@3"])
    assert res.exit_code == 1 and "Overheat" in res.output and "muscle m2" in res.output
    assert "Traceback" not in res.output and "--resume" in res.output
    assert read_recording(out).sample.tolist() == [0, 1, 2]
