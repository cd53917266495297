"""`pimbs simulate`: the paper's data obey the statics; concealed effects act where they
should and are labelled nowhere; `pimbs info` summarises or refuses cleanly."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from pimbs_arm.model import ArmModel
from pimbs_cli.main import main
from pimbs_recording.format import read_recording
from pimbs_sim.effects import EffectSpecError, parse_effect
from pimbs_sim.simulate import simulate


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load("two-link-4-muscle")


def _run(arm, effects=(), n=40, map_kind="atl", noise=0.0, seed=3):
    data, _ = simulate(arm, n, map_kind, seed=seed, effects=tuple(
        parse_effect(e, seed=seed) for e in effects), noise=noise)
    return data


@pytest.mark.parametrize("map_kind", ["al", "atl"])
def test_exact_data_satisfy_torque_balance_and_length_model(arm, map_kind):
    d = _run(arm, map_kind=map_kind)
    G = arm.muscle_jacobian(d["theta"])
    residual = -np.einsum("bmn,bm->bn", G, d["tension"]) - d["tau_gravity"]
    assert np.abs(residual).max() < 1e-8
    np.testing.assert_allclose(d["length"], arm.length(d["theta"], d["tension"]), atol=1e-12)
    assert (d["tension"] >= (0 if map_kind == "al" else 10) - 1e-9).all()
    if map_kind == "atl":
        assert d["tension"].max() > 100  # the floors really vary up to 300 N


def test_noisy_recording_carries_what_a_collection_would(arm):
    d = _run(arm, n=120, noise=1.0)
    temps = d["temperature"]
    assert temps.min() > 24 and temps.max() > 28  # warms with load
    # a muscle held harder runs hotter: temperature follows the recent mean tension
    kernel = np.exp(-np.arange(120) * 4.0 / 240.0)
    recent = np.stack([np.convolve(d["tension"][:, j], kernel)[:120] for j in range(4)], 1)
    assert np.corrcoef(temps[20:].ravel(), recent[20:].ravel())[0, 1] > 0.8
    assert set(np.unique(d["approach"])) <= {-1, 0, 1} and (d["approach"] != 0).mean() > 0.5
    assert np.all(np.diff(d["time"]).astype(np.int64) > 0)
    assert 0 < np.abs(d["theta"] - d["theta_command"]).max() < 2e-3


def test_concealed_and_clean_pair_by_sample(arm):
    clean, real = _run(arm), _run(arm, ["tendon_friction:0.2"])
    np.testing.assert_array_equal(clean["theta_command"], real["theta_command"])
    np.testing.assert_array_equal(clean["sample"], real["sample"])


def test_each_effect_acts_where_it_should(arm):
    clean = _run(arm)
    f, a, temp = clean["tension"], clean["approach"], clean["temperature"]

    fr = _run(arm, ["tendon_friction:0.2"])
    np.testing.assert_allclose(fr["tension"], f * np.exp(-0.2 * a), rtol=1e-9)
    np.testing.assert_allclose(fr["length"], clean["length"], atol=1e-12)

    off = _run(arm, ["tension_offset:12,muscles=m1"])
    np.testing.assert_allclose(off["tension"] - f, np.outer(np.ones(len(f)), [0, 12, 0, 0]),
                               atol=1e-9)

    drift = _run(arm, ["thermal_drift:0.5,muscles=m2"])
    np.testing.assert_allclose((drift["tension"] - f)[:, 2], 0.5 * (temp[:, 2] - 25.0),
                               atol=1e-9)

    stiff = _run(arm, ["elastic_stiffness:0.5"])
    np.testing.assert_allclose(stiff["tension"], f, atol=1e-9)
    np.testing.assert_allclose(clean["length"] - stiff["length"], np.log1p(f) / 1000.0,
                               rtol=1e-6)

    off_j = _run(arm, ["joint_offset:0.05,joints=elbow_pitch"])
    true_theta = clean["theta_command"] - [0.0, 0.05]
    np.testing.assert_allclose(off_j["length"], arm.length(true_theta, off_j["tension"]),
                               atol=1e-12)
    np.testing.assert_allclose(off_j["theta"], clean["theta"])

    heavy = _run(arm, ["link_mass:1.5"])
    G = arm.muscle_jacobian(heavy["theta"])
    residual = -np.einsum("bmn,bm->bn", G, heavy["tension"]) - heavy["tau_gravity"]
    # the forearm weighs 50 % more: the elbow residual is half the modelled elbow torque
    np.testing.assert_allclose(residual[:, 1], 0.5 * heavy["tau_gravity"][:, 1], atol=1e-8)


def test_bad_effect_specs_are_refused(arm):
    with pytest.raises(EffectSpecError, match="unknown effect"):
        parse_effect("gremlins:3")
    with pytest.raises(EffectSpecError, match="not a number"):
        parse_effect("tendon_friction:lots")
    with pytest.raises(EffectSpecError, match="unknown muscle 'm9'"):
        _run(arm, ["tension_offset:5,muscles=m9"])


def test_cli_simulate_conceals_and_info_summarises(tmp_path):
    runner = CliRunner()
    clean, real = tmp_path / "sim.parquet", tmp_path / "real.parquet"
    r = runner.invoke(main, ["simulate", "--samples", "30", "--seed", "4", "--out", str(clean)])
    assert r.exit_code == 0, r.output
    r = runner.invoke(main, ["simulate", "--samples", "30", "--seed", "4", "--out", str(real),
                             "--conceal", "tension_offset:20,muscles=m0"])
    assert r.exit_code == 0, r.output
    a, b = read_recording(clean), read_recording(real)
    np.testing.assert_array_equal(a.theta_command, b.theta_command)
    raw = pq.read_schema(real).metadata[b"pimbs"].decode()
    assert "offset" not in raw and "conceal" not in raw and b.extra_columns == []
    assert json.loads(raw)["robot"] == "two-link-4-muscle"
    r = runner.invoke(main, ["info", str(real)])
    assert r.exit_code == 0 and "rows     30" in r.output and "m0, m1, m2, m3" in r.output


def test_cli_refuses_bad_input_without_traceback(tmp_path):
    runner = CliRunner()
    junk = tmp_path / "junk.parquet"
    junk.write_text("nope")
    r = runner.invoke(main, ["info", str(junk)])
    assert r.exit_code == 1 and "junk.parquet" in r.output and "Traceback" not in r.output
    r = runner.invoke(main, ["simulate", "--robot", str(tmp_path / "nope.muscles.yaml"),
                             "--samples", "3", "--out", str(tmp_path / "x.parquet")])
    assert r.exit_code == 1 and "nope.muscles.yaml" in r.output
    r = runner.invoke(main, ["simulate", "--samples", "3", "--conceal", "gremlins",
                             "--out", str(tmp_path / "x.parquet")])
    assert r.exit_code == 1 and "unknown effect" in r.output
