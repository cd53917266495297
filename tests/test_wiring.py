"""Winding direction as data: a per-muscle `direction` and `pimbs check-wiring`, which
pulls each muscle gently and names every muscle whose sign is wrong, on the simulated arm
whose wires are deliberately wound against the robot file."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from pimbs_calibration.description import DescriptionError, load_robot
from pimbs_cli.main import main
from pimbs_hw import open_arm
from pimbs_hw.wiring import check_wiring
from tests.test_profiles import LIMITS, ODRIVE_ROBOT


def _with_direction(tmp_path: Path, muscle_index: int, direction) -> Path:
    urdf = ODRIVE_ROBOT.parent.parent.parent / "calibration" / "robots"
    text = ODRIVE_ROBOT.read_text().replace("../../calibration/robots", str(urdf))
    board = f"board_id: {muscle_index + 1}\n"
    text = text.replace(board, f"{board}    direction: {direction}\n", 1)
    path = tmp_path / "robot.muscles.yaml"
    path.write_text(text)
    return path


def test_check_wiring_names_the_odrive_muscle_wound_the_wrong_way(tmp_path):
    """m2 is wound the other way round and its file says so (direction -1): fine. m1 is wound
    the other way round but its file says +1: its motor pays the wire out; named."""
    robot = _with_direction(tmp_path, 2, -1)
    res = CliRunner().invoke(main, ["check-wiring", "--port", "virtual", "--robot", str(robot),
                                    "--mock-speed", "10", "--mock-winding", "1,-1,-1,1"])
    assert res.exit_code == 1, res.output
    lines = res.output.splitlines()
    wrong = [line for line in lines if "WRONG SIGN" in line]
    assert len(wrong) == 1 and wrong[0].strip().startswith("m1: WRONG SIGN: the length runs on")
    assert "flip its `direction`" in wrong[0]
    for name in ("m0", "m2", "m3"):
        line = next(x for x in lines if x.strip().startswith(f"{name}:"))
        assert line.strip().startswith(f"{name}: ok (tension +"), line
        assert " length -" in line  # shortened while the tension rose
    assert "1 muscle(s) failed the check: m1" in res.output and "Traceback" not in res.output


def test_check_wiring_names_a_loadcell_board_whose_encoder_counts_backwards():
    with open_arm("virtual", "two-link-4-muscle", speed=10.0, limits=LIMITS,
                  mock_options={"winding": [1, 1, -1, 1]}) as (driver, mock):
        results = check_wiring(driver, settle_s=0.4, watch_s=0.15)
    verdicts = {r.muscle: r for r in results}
    assert [r.muscle for r in results if not r.ok] == ["m2"]
    assert verdicts["m2"].line.startswith("m2: WRONG SIGN: the tension rose but the length grew")
    assert verdicts["m2"].d_tension > 5 and verdicts["m2"].d_length > 0
    assert all(r.d_tension > 5 and r.d_length < 0 for r in results if r.ok)


@pytest.mark.parametrize("value", [2, 0, "backwards", True])
def test_direction_must_be_plus_or_minus_one(tmp_path, value):
    with pytest.raises(DescriptionError) as err:
        load_robot(_with_direction(tmp_path, 1, value))
    message = str(err.value)
    assert "muscles[1].direction" in message and "is not 1 or -1" in message
    assert "\n" not in message


def test_direction_minus_one_flips_both_odrive_signs(tmp_path):
    from pimbs_hw.protocol.profiles import protocols_for

    robot = load_robot(_with_direction(tmp_path, 1, -1))
    (proto,) = [p for p in protocols_for(robot) if p.indices]
    db = proto.profile.db
    (_, torque), = [f for f in proto.command(1, "tension", 60.0) if f[0] & 0x1F == 14]
    (_, pos), = [f for f in proto.command(1, "length", 0.01) if f[0] & 0x1F == 12]
    assert db.get_message_by_name("Set_Input_Torque").decode(torque)["Input_Torque"] == \
        pytest.approx(-0.36, rel=1e-6)  # direction -1: a negative torque reels the wire in
    assert db.get_message_by_name("Set_Input_Pos").decode(pos)["Input_Pos"] == \
        pytest.approx(0.265258, rel=1e-6)  # and paying out is a positive turn
    (_, pos0), = [f for f in proto.command(0, "length", 0.01) if f[0] & 0x1F == 12]
    assert db.get_message_by_name("Set_Input_Pos").decode(pos0)["Input_Pos"] == \
        pytest.approx(-0.265258, rel=1e-6)  # direction +1: paying out is a negative turn
