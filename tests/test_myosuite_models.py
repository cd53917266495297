"""MyoSuite's finger models as shipped (fixtures/myosuite: Apache-2.0, unmodified): `pimbs
robot` explains them, the limits their actuators declare become the muscles' limits (the
holding floor scaled to each), `pimbs simulate` records them, and a description built on them
that fails the both-ways check is still explained, drawn and exported, while `simulate` and
`collect` refuse it with the same line."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from pimbs_arm.model import ArmModel
from pimbs_calibration.description import load_robot
from pimbs_cli.main import main
from pimbs_recording.format import read_recording

FINGER = Path(__file__).resolve().parents[1] / "fixtures" / "myosuite" / "finger"
MOTOR, MYO, BARE = (FINGER / f"{n}.xml" for n in ("motorfinger_v0", "myofinger_v0",
                                                    "finger_v0"))
JOINTS = ("IFadb", "IFmcp", "IFpip", "IFdip")
TENDONS = ("extn", "mflx", "dflx", "adabR", "adabL")


def test_the_motor_fingers_limits_come_from_its_motors():
    """Each tendon's geared, control-limited motor declares |ctrl| x gear: 20 N on the
    extensor, 10 N on the flexors, 5 N on the ab/adductors; the holding floor is 1/20 of that
    (10 N, the default of a strong muscle, would be half or all of a finger muscle's force)."""
    robot = load_robot(MOTOR)
    assert robot.joints == JOINTS and tuple(m.name for m in robot.muscles) == TENDONS
    assert [m.f_max for m in robot.muscles] == pytest.approx([20, 10, 10, 5, 5])
    assert [m.f_floor for m in robot.muscles] == pytest.approx([1, 0.5, 0.5, 0.25, 0.25])
    # the muscle model's peak forces (thousands of N): the floor stays at 10 N
    assert {m.f_floor for m in load_robot(MYO).muscles} == {10.0}


@pytest.mark.parametrize("xml", [MOTOR, MYO, BARE], ids=["motor", "myo", "bare"])
def test_pimbs_robot_explains_each_finger(xml):
    res = CliRunner().invoke(main, ["robot", str(xml), "--poses", "30"])
    assert res.exit_code == 0, res.output
    assert "driven joints (4" in res.output and "muscles (5)" in res.output
    assert res.output.count("ok at all 47 poses") == 4  # centre + 16 corners + 30 random
    assert "pulley /2" in res.output  # the extensor splits over two pulleys


@pytest.mark.parametrize("xml, map_kind", [(MYO, "atl"), (MOTOR, "al"), (BARE, "al")],
                         ids=["myo", "motor", "bare"])
def test_pimbs_simulate_records_each_finger(tmp_path, xml, map_kind):
    out = tmp_path / "finger.parquet"
    res = CliRunner().invoke(main, ["simulate", "--robot", str(xml), "-n", "6", "--map",
                                    map_kind, "--noise", "0", "--out", str(out)])
    assert res.exit_code == 0, res.output
    rec = read_recording(out)
    arm = ArmModel.load(xml)
    assert tuple(rec.joints) == JOINTS and tuple(rec.muscles) == TENDONS and rec.n_rows == 6
    # every row holds the finger still with MuJoCo's moment arms and gravity, within limits
    residual = arm.gravity_torque(rec.theta) + np.einsum(
        "bmn,bm->bn", arm.muscle_jacobian(rec.theta), rec.tension)
    assert np.abs(residual).max() < 1e-6
    assert (rec.tension <= 0.9 * arm.f_max + 1e-9).all() and (rec.tension >= -1e-9).all()


def test_a_finger_without_its_extensor_is_explained_and_refused(tmp_path, monkeypatch):
    """Leave the extensor out: nothing turns the finger's flexion joints back. `pimbs robot`
    still lists the muscles and moment arms, marks the check where it fails, draws and
    exports, and ends with one line and status 1; simulate and collect refuse the same way."""
    monkeypatch.chdir(tmp_path)
    for xml in (MOTOR, BARE):
        shutil.copy(xml, tmp_path / xml.name)
    path = tmp_path / "no-extensor.muscles.yaml"
    path.write_text(yaml.safe_dump({"mjcf": MOTOR.name,
                                    "muscles": [{"name": n} for n in TENDONS[1:]]}))
    res = CliRunner().invoke(main, ["robot", str(path), "--plot", "f.png"])
    assert res.exit_code == 1
    lines = res.output.strip().splitlines()
    assert "muscles (4)" in res.output and "moment arms r = -dl/dtheta" in res.output
    assert "  IFadb                  ok at all 217 poses" in lines
    assert "  IFpip                  FAILS at 217 of 217 poses, e.g.:" in lines
    assert "wrote f.png" in res.output and Path("f.png").stat().st_size > 10_000
    refusal = lines[-1]
    assert refusal.startswith(f"Error: {path}: some driven joints cannot be turned both ways (")
    assert "IFpip not towards negative angles" in refusal and "Traceback" not in res.output
    # the export too: written, and the same failure said in one line
    Path("poses.csv").write_text("IFadb,IFmcp,IFpip,IFdip\n0,0.1,0.2,0.3\n")
    res = CliRunner().invoke(main, ["robot", str(path), "--poses-file", "poses.csv",
                                    "--json", "g.json"])
    assert res.exit_code == 1 and "cannot be turned both ways" in res.output.splitlines()[-1]
    table = json.loads(Path("g.json").read_text())
    assert table["muscles"] == list(TENDONS[1:]) and len(table["jacobian"]) == 1
    # simulate and collect: the one check both run, the same words, nothing written
    said = refusal[refusal.index("(IF"):refusal.index("); route")]
    for command in (["simulate", "-n", "3", "--out", "s.parquet"],
                    ["collect", "--port", "virtual", "-n", "3", "--out", "c.parquet"]):
        res = CliRunner().invoke(main, [*command, "--robot", str(path)])
        assert res.exit_code == 1 and res.output.count("\n") == 1, res.output
        assert said in res.output
    assert not Path("s.parquet").exists() and not Path("c.parquet").exists()


def test_more_tendons_than_one_bus_carries_is_one_line(tmp_path, monkeypatch):
    """MyoSuite's legs have 80 tendons, its torso 210: as a bare MJCF they get boards 1..N,
    more than PIMBS v1's 32 ids on one bus. `collect` says so, and how to pick a bus's
    muscles, before anything is sent."""
    monkeypatch.chdir(tmp_path)
    sites = "".join(f'<site name="o{i}" pos="{0.001 * i - 0.02} 0 0.1"/>' for i in range(33))
    inserts = "".join(f'<site name="i{i}" pos="{0.001 * i - 0.02} 0 -0.1"/>' for i in range(33))
    tendons = "".join(f'<spatial name="t{i}"><site site="o{i}"/><site site="i{i}"/></spatial>'
                      for i in range(33))
    xml = tmp_path / "many.xml"
    xml.write_text(f'<mujoco><worldbody>{sites}<body><joint name="j" axis="0 1 0" '
                   f'range="-0.3 0.3"/><geom size="0.02" mass="0.1"/>{inserts}</body>'
                   f'</worldbody><tendon>{tendons}</tendon></mujoco>')
    res = CliRunner().invoke(main, ["collect", "--port", "virtual", "--robot", str(xml),
                                    "-n", "2", "--out", "c.parquet"])
    assert res.exit_code == 1 and res.output.count("\n") == 1, res.output
    assert f"{xml}: muscle t31 (board 32, pimbs-v1): board_id 32 out of range 0..31" \
        in res.output
    assert "write a muscle file naming many.xml ('mjcf:')" in res.output
    assert "Traceback" not in res.output
