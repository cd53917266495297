"""Joint angles from lengths and tensions: the estimator, `pimbs estimate`, `pimbs train`."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from pimbs_arm.model import ArmModel
from pimbs_cli.main import main
from pimbs_learn import load_body_schema
from pimbs_learn.estimate import GeometricSchema, estimate_joint_angles
from tests.schema_models import small_model


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load("two-link-4-muscle")


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    return small_model(tmp_path_factory.mktemp("estimate"))


def _poses(arm: ArmModel, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return (rng.uniform(arm.joint_range[:, 0], arm.joint_range[:, 1], (n, arm.n_joints)),
            rng.uniform(10, 300, (n, arm.n_muscles)))


def test_geometric_estimate_inverts_the_length_model(arm):
    theta, f = _poses(arm, 12)
    est = estimate_joint_angles(GeometricSchema(arm), arm.length(theta, f), f,
                                arm.joint_limits)
    np.testing.assert_allclose(est.theta, theta, atol=1e-7)
    assert est.residual.max() < 1e-9


def test_estimate_stays_within_the_joint_range(arm):
    """Lengths of a pose beyond the range: the estimate is the nearest pose inside it."""
    theta, f = _poses(arm, 4, seed=1)
    theta[:, 1] = 0.8
    rng = np.array([[-0.5, 0.5], [-0.5, 0.5]])
    est = estimate_joint_angles(GeometricSchema(arm), arm.length(theta, f), f, rng)
    assert (est.theta >= rng[:, 0]).all() and (est.theta <= rng[:, 1]).all()
    np.testing.assert_allclose(est.theta[:, 1], 0.5, atol=1e-9)


def test_learned_estimate_inverts_its_schema(model):
    schema = load_body_schema(model[0])
    rng = np.random.default_rng(2)
    lo, hi = schema.domain.theta.T
    theta = rng.uniform(lo, hi, (10, 2))
    f = rng.uniform(*schema.domain.tension.T, (10, 4))
    est = estimate_joint_angles(schema, schema.length(theta, f), f, schema.domain.theta)
    np.testing.assert_allclose(est.theta, theta, atol=1e-4)


def test_cli_estimate_reports_degrees_beside_the_geometric_model(model, tmp_path):
    model_dir, data = model
    j, png = tmp_path / "e.json", tmp_path / "e.png"
    res = CliRunner().invoke(main, ["estimate", str(model_dir), str(data), "--json", str(j),
                                    "--plot", str(png)])
    assert res.exit_code == 0, res.output
    out = json.loads(j.read_text())
    assert out["joints"] == ["shoulder_pitch", "elbow_pitch"]
    assert len(out["rms_error_deg"]) == 2 and np.isfinite(out["rms_error_deg"]).all()
    # clean simulation: the geometric model is exact there, so its estimate is too
    assert max(out["geometric_rms_error_deg"]) < 1e-3
    assert len(out["theta_estimate"]) == out["n_samples"] == 40
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert "geometric" in res.output
    assert f"wrote {j}:" in res.output and f"wrote {png}:" in res.output  # says what it wrote
    again = CliRunner().invoke(main, ["estimate", str(model_dir), str(data), "--json", str(j)])
    assert again.exit_code == 1 and "--force" in again.output


def test_train_reports_the_joint_angle_error(model, tmp_path):
    _, data = model
    res = CliRunner().invoke(main, ["train", str(data), "--n-train", "20", "--epochs", "3",
                                    "--loss", "basic", "--json", str(tmp_path / "m.json")])
    assert res.exit_code == 0, res.output
    metrics = json.loads((tmp_path / "m.json").read_text())
    assert len(metrics["eval_joint_angle_rms_deg"]) == 2
    assert max(metrics["eval_joint_angle_rms_deg_geometric"]) < 1e-3
