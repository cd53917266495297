"""`pimbs robot ROBOT --poses-file P.csv --json F`: lengths and Jacobians at given poses, for
any robot, and one clear line (nothing written) for a bad CSV."""

from __future__ import annotations

import json
from pathlib import Path

import mujoco
import numpy as np
import pytest
from click.testing import CliRunner

from pimbs_arm.model import ArmModel
from pimbs_cli.main import main

SPATIAL = Path(__file__).resolve().parents[1] / "fixtures" / "mujoco" / "spatial_3dof.xml"


def _run(robot: str, csv: Path, out: Path):
    return CliRunner().invoke(main, ["robot", robot, "--poses-file", str(csv),
                                     "--json", str(out)])


def test_mjcf_geometry_is_mujocos(tmp_path):
    csv = tmp_path / "poses.csv"
    # columns in another order than the description, an extra column that is ignored
    csv.write_text("elbow,label,shoulder_roll,shoulder_pitch\n"
                   "0.1,a,0.0,0.0\n-0.5,b,0.2,-0.3\n0.3,c,-0.4,0.4\n")
    out = tmp_path / "geometry.json"
    res = _run(str(SPATIAL), csv, out)
    assert res.exit_code == 0, res.output
    assert "label" in res.output and "ignored" in res.output
    doc = json.loads(out.read_text())
    assert doc["joints"] == ["shoulder_pitch", "shoulder_roll", "elbow"]
    assert doc["muscles"] == ["delt_front", "delt_back", "delt_left", "delt_right", "biceps",
                              "triceps"]
    theta = np.array(doc["theta"])
    np.testing.assert_array_equal(theta, [[0, 0, 0.1], [-0.3, 0.2, -0.5], [0.4, -0.4, 0.3]])
    length, jac = np.array(doc["length"]), np.array(doc["jacobian"])
    assert length.shape == (3, 6) and jac.shape == (3, 6, 3)
    model = mujoco.MjModel.from_xml_path(str(SPATIAL))
    data = mujoco.MjData(model)
    for p, q in enumerate(theta):
        data.qpos[:] = q  # this arm's qpos is exactly its three hinges, in order
        mujoco.mj_fwdPosition(model, data)
        J = np.zeros((model.ntendon, model.nv))
        mujoco.mju_sparse2dense(J, data.ten_J, model.ten_J_rownnz, model.ten_J_rowadr,
                                model.ten_J_colind)
        np.testing.assert_allclose(length[p], data.ten_length, atol=1e-12)
        np.testing.assert_allclose(jac[p], J, atol=1e-12)
    np.testing.assert_allclose(np.array(doc["h_geom"]), ArmModel.load(SPATIAL).h_geom(theta),
                               atol=1e-12)


def test_urdf_robot_geometry_is_the_arm_models(tmp_path):
    csv = tmp_path / "poses.csv"
    csv.write_text("shoulder_pitch,elbow_pitch\n0.2,-0.1\n-0.4,0.3\n")
    out = tmp_path / "g.json"
    res = _run("two-link-4-muscle", csv, out)
    assert res.exit_code == 0, res.output
    doc = json.loads(out.read_text())
    arm = ArmModel.load("two-link-4-muscle")
    theta = np.array(doc["theta"])
    np.testing.assert_allclose(np.array(doc["h_geom"]), arm.h_geom(theta), atol=1e-12)
    np.testing.assert_allclose(np.array(doc["jacobian"]), arm.muscle_jacobian(theta),
                               atol=1e-12)


@pytest.mark.parametrize("text, words", [
    ("shoulder_pitch,elbow\n0.1,0.2\n", "no column for joint(s) shoulder_roll"),
    ("shoulder_pitch,shoulder_roll,elbow\n0.1,0.2,0.3\n0.1,abc,0.3\n",
     "row 2, column 'shoulder_roll': 'abc' is not a finite number"),
    ("shoulder_pitch,shoulder_roll,elbow\n0.1,0.2\n", "row 1, column 'elbow': '' is not"),
    ("shoulder_pitch,shoulder_roll,elbow\n0.1,nan,0.2\n", "row 1, column 'shoulder_roll'"),
    ("shoulder_pitch,shoulder_roll,elbow\n", "a header but no poses"),
    ("", "empty"),
])
def test_bad_poses_csv_is_one_line_and_writes_nothing(tmp_path, text, words):
    csv = tmp_path / "poses.csv"
    csv.write_text(text)
    out = tmp_path / "g.json"
    res = _run(str(SPATIAL), csv, out)
    assert res.exit_code == 1
    assert res.output.startswith(f"Error: {csv}: ") and res.output.count("\n") == 1
    assert words in res.output
    assert not out.exists()


def test_poses_file_and_json_go_together(tmp_path):
    res = CliRunner().invoke(main, ["robot", str(SPATIAL), "--json", str(tmp_path / "g.json")])
    assert res.exit_code == 1 and "--poses-file and --json go together" in res.output
