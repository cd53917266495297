"""Sensor terms in the torque balance: exact gradients, and a consistent loadcell error is
absorbed by its own parameter instead of by the body schema's moment arms."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from pimbs_learn import sensor_terms
from pimbs_learn.data import LearnError
from pimbs_learn.losses import LossConfig
from pimbs_learn.method_spec import parse_method
from pimbs_learn.run import Run, TrainOptions
from pimbs_learn.synthetic import synthetic_samples
from pimbs_learn.train import train_runs
from tests.test_learn import _batch, assert_hand_written_gradient

F64 = torch.float64


def test_hand_written_gradient_with_sensor_terms_matches_autograd() -> None:
    p, batch = _batch()
    r, b, m = batch.length.shape
    n = batch.tau.shape[-1]
    gen = torch.Generator().manual_seed(1)
    # away from the prior mean, so the prior's gradient is tested too
    p.update({k: torch.randn(*v.shape, generator=gen, dtype=F64).requires_grad_(True)
              for k, v in sensor_terms.zeros(r, m, n, F64).items()})
    batch = replace(batch, const_weight=torch.tensor([1.0, 1.0, 0.0], dtype=F64),
                    pinn_weight=torch.tensor([1.0, 1.0, 2.0], dtype=F64),
                    auto=torch.ones(r, dtype=F64),
                    length_floor=torch.full((r,), 1e-9, dtype=F64),
                    torque_floor=torch.full((r,), 1e-4, dtype=F64),
                    # the middle run has none: its parameters get no gradient
                    sensors=torch.tensor([1.0, 0.0, 1.0], dtype=F64),
                    tension_scale=torch.full((r, 1, m), 300.0, dtype=F64))
    assert_hand_written_gradient(p, batch)


def test_a_consistent_loadcell_gain_moves_its_own_parameter() -> None:
    """One loadcell reads 30 % high on every sample. With sensor terms the fit scales that
    loadcell down against the others (which stay near 1), and the held-out lengths are
    better than without them, where the moment arms absorb the error."""
    truth = synthetic_samples(30, seed=3)
    wrong = truth.tension.copy()
    wrong[:, 1] *= 1.3
    recorded = replace(truth, tension=wrong)
    ev = synthetic_samples(64, seed=99)
    loss = LossConfig.parse("basic+const+pinn", 1.0, "auto", sensors=True)
    run = Run(recorded, replace(ev, tension=ev.tension * np.array([1, 1.3, 1, 1])), loss,
              seed=0)
    without = replace(run, loss=replace(loss, sensors=False))
    opts = TrainOptions(epochs=3000, hidden=48, dtype=F64, schedule="exp")
    res, plain = train_runs([run, without], opts)
    gains = np.array(res.sensor_terms["tension_gain"])
    others = np.delete(gains, 1)
    assert gains[1] / np.median(others) < 0.9  # toward 1/1.3 = 0.77
    assert np.abs(others - 1).max() < 0.1
    assert res.eval_loss < 0.95 * plain.eval_loss
    assert plain.sensor_terms is None
    assert set(res.metrics()["sensor_terms"]) == {"tension_gain", "tension_offset_n",
                                                  "gravity_scale", "tension_scale_n"}
    # the user's line names that loadcell first
    said = sensor_terms.line(res.sensor_terms, list(recorded.muscles), list(recorded.joints))
    assert said.split(": ", 1)[1].startswith(f"{recorded.muscles[1]} loadcell ×")
    assert not set(res.params) & set(sensor_terms.KEYS)  # the model file holds none


def test_sensor_terms_are_asked_for_explicitly_and_only_where_they_mean_something() -> None:
    assert parse_method("se:basic+const+pinn@auto~exp!sensors").loss.sensors
    m = parse_method("se:basic+const+pinn@auto~exp!check,sensors")
    assert m.check and m.loss.sensors
    assert not parse_method("se:basic+const+pinn@auto~exp!check").loss.sensors
    with pytest.raises(ValueError, match="pinn@auto"):
        parse_method("se:basic+const+pinn@1e-5!sensors")
    with pytest.raises(ValueError, match="flags are"):
        parse_method("se:basic+const+pinn@auto!sensor")
    run = Run(synthetic_samples(5), synthetic_samples(5, seed=9),
              LossConfig.parse("basic+pinn", 1.0, "auto", sensors=True), atl=False)
    with pytest.raises(LearnError, match="ATL-Map"):
        run.check()


def test_pimbs_train_reports_the_fitted_sensor_terms_and_refuses_them_where_meaningless(
        tmp_path) -> None:
    from click.testing import CliRunner

    from pimbs_cli.main import main
    from pimbs_learn.io import load_body_schema
    from tests.foreign_arm import record

    torch.set_num_threads(1)
    data = tmp_path / "f.parquet"
    record(data, 30, 1)
    args = ["train", str(data), "--n-train", "10", "--epochs", "30", "--threads", "1",
            "--sensor-terms"]
    out = CliRunner().invoke(main, [*args, "--no-prior", "--json", str(tmp_path / "m.json"),
                                    "--out", str(tmp_path / "model")])
    assert out.exit_code == 0, out.output
    assert "sensor terms" in out.output
    import json
    fitted = json.loads((tmp_path / "m.json").read_text())["sensor_terms"]
    assert len(fitted["tension_gain"]) == len(fitted["tension_offset_n"]) > 0
    load_body_schema(tmp_path / "model")  # the model file is the body schema alone
    out = CliRunner().invoke(main, [*args, "--no-prior", "--alpha", "1e-5"])
    assert out.exit_code != 0 and "automatic weight" in out.output
    # on by default where the balance can carry them; off with --no-sensor-terms, --paper
    base = args[:-1] + ["--json", str(tmp_path / "d.json"), "--force", "--no-prior"]
    for extra, on in (([], True), (["--no-sensor-terms"], False), (["--paper"], False),
                      (["--alpha", "1e-5"], False)):
        out = CliRunner().invoke(main, base + extra)
        assert out.exit_code == 0, out.output
        assert ("sensor terms" in out.output) == on, extra
        assert (json.loads((tmp_path / "d.json").read_text())["sensor_terms"] is None) != on
