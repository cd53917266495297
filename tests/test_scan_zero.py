"""`pimbs scan` finds every board with its protocol; `pimbs zero` measures the encoder zeros
at the home pose, writes them as data, and the collection applies them."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from pimbs_arm.model import ArmModel
from pimbs_calibration.description import load_robot
from pimbs_calibration.zeroing import CalibrationError, load
from pimbs_cli.main import main
from pimbs_hw.mock import MockArm
from pimbs_hw.scan import scan_bus
from pimbs_hw.transport import open_transport
from pimbs_recording.format import read_recording
from tests.test_profiles import LAB_ROBOT, ODRIVE_ROBOT

ROBOT = "two-link-4-muscle"


@pytest.mark.parametrize("robot, protocol, version", [
    (ROBOT, "pimbs-v1", None), (ODRIVE_ROBOT, "odrive-cansimple", "0.6.11"),
    (LAB_ROBOT, "lab-muscle-board", None)], ids=["v1", "odrive", "lab-board"])
def test_scan_names_every_board_and_its_protocol(robot, protocol, version):
    description = load_robot(robot)
    with MockArm(description, "virtual:scan-" + protocol, faults=["overheat:m2"]) as mock:
        with open_transport(mock.port) as transport:
            result = scan_bus(transport, 1.2, description)
    ids = {m.board_id: m.name for m in description.muscles}
    assert {(b.protocol, b.board_id) for b in result.boards.values()} == {
        (protocol, b) for b in ids}
    for b in result.boards.values():
        assert b.muscle == ids[b.board_id] and b.frames > 0 and b.version == version
        assert b.temperature_c is not None
    hot = next(b for b in result.boards.values() if b.muscle == "m2")
    assert hot.temperature_c > 60  # the injected thermal runaway shows in the scan
    assert 0 < result.bus_load(1_000_000) < 0.5


def test_scan_without_robot_finds_shipped_protocols_and_prints_a_table():
    res = CliRunner().invoke(main, ["scan", "--port", "virtual", "--robot", str(ODRIVE_ROBOT),
                                    "--seconds", "0.5"])
    assert res.exit_code == 0, res.output
    assert "4 board(s)" in res.output and "odrive-cansimple   m3" in res.output
    assert "bus load" in res.output
    res = CliRunner().invoke(main, ["scan", "--port", "pimbsnocan5", "--seconds", "0.2"])
    assert res.exit_code == 1 and res.output.count("\n") == 1 and "pimbsnocan5" in res.output


def test_zero_measures_the_offsets_and_the_collection_applies_them(tmp_path):
    """Encoders that powered up anywhere: zero at the held home pose, then collect."""
    robot = load_robot(ROBOT)
    offsets = np.array([0.0123, -0.0211, 0.0057, 0.0309])
    cal = tmp_path / "arm.calibration.yaml"
    with MockArm(robot, "pty", speed=20.0, encoder_offset_m=offsets, seed=2) as mock:
        mock.hold_home()
        res = CliRunner().invoke(main, ["zero", "--port", mock.port, "--yes",
                                        "--calibration", str(cal)])
        assert res.exit_code == 0, res.output
        zero = load(cal, robot)
        np.testing.assert_allclose(zero, offsets, atol=3e-5)  # a few counts + loadcell noise
        assert yaml.safe_load(cal.read_text())["robot"] == ROBOT
        again = CliRunner().invoke(main, ["zero", "--port", mock.port, "--yes",
                                          "--calibration", str(cal)])
        assert again.exit_code == 1 and "--force" in again.output  # never overwritten silently
        mock.hold_home(False)
        out = tmp_path / "c.parquet"
        res = CliRunner().invoke(main, ["collect", "--port", mock.port, "--calibration",
                                        str(cal), "--samples", "2", "--seed", "5", "--out",
                                        str(out), "--settle-window", "0.06"])
        assert res.exit_code == 0, res.output
    rec = read_recording(out)
    arm = ArmModel(robot)
    assert np.abs(rec.theta - rec.theta_command).max() < 3e-3  # the poses were reached
    # recorded lengths are relative to the zero pose: the model's lengths at those poses
    np.testing.assert_allclose(rec.length, arm.length(rec.theta, rec.tension), atol=1e-4)


def test_zero_asks_first_and_bad_calibration_files_are_named(tmp_path):
    res = CliRunner().invoke(main, ["zero", "--port", "virtual", "--calibration",
                                    str(tmp_path / "z.yaml")], input="n\n")
    assert res.exit_code == 1 and not (tmp_path / "z.yaml").exists()
    robot = load_robot(ROBOT)
    bad = tmp_path / "bad.calibration.yaml"
    bad.write_text("robot: two-link-4-muscle\nzero_position_m: {m0: 0.1, m1: 0.2}\n")
    with pytest.raises(CalibrationError, match=r"bad.calibration.yaml: field 'zero_position_m'"):
        load(bad, robot)
    bad.write_text("robot: left-arm-5dof\nzero_position_m: {}\n")
    with pytest.raises(CalibrationError, match="is for 'left-arm-5dof'"):
        load(bad, robot)
    res = CliRunner().invoke(main, ["collect", "--port", "virtual", "--calibration", str(bad),
                                    "--samples", "1", "--out", str(tmp_path / "o.parquet")])
    assert res.exit_code == 1 and "is for 'left-arm-5dof'" in res.output
    assert not (tmp_path / "o.parquet").exists()
