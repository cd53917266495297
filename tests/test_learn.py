"""Body-schema learning: network derivatives, losses, selection rule, training, model files,
and refusal of bad input. Small networks and short runs keep this well under a minute."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from pimbs_learn.data import LearnError, Samples, check_compatible, fill_gravity, split
from pimbs_learn.io import load_body_schema, save_model
from pimbs_learn.losses import LossConfig, pinn_loss
from pimbs_learn.model import (
    BodySchemaNet,
    Scaling,
    gtf,
    hidden_layers,
    init_params,
    jacobian,
    network_inputs,
)
from pimbs_learn.objective import Batch, objective, objective_and_grads
from pimbs_learn.reference import autograd_jacobian, train_reference
from pimbs_learn.run import Run, TrainOptions
from pimbs_learn.synthetic import muscle_jacobian, synthetic_samples
from pimbs_learn.train import train, train_runs

torch.set_num_threads(1)
F64 = torch.float64
SMALL = dict(hidden=48, dtype=F64)


def _net(atl: bool = True, seed: int = 0) -> tuple[BodySchemaNet, Samples]:
    s = synthetic_samples(9, seed=seed, atl=atl)
    run = Run(s, s, atl=atl)
    scaling = run.scaling()
    p = init_params(scaling.n_inputs, 4, seed, 48, F64)
    return BodySchemaNet(p, scaling), s


@pytest.mark.parametrize("atl", [True, False])
def test_analytic_jacobian_and_gtf_match_autograd(atl: bool) -> None:
    net, s = _net(atl)
    theta = torch.tensor(s.theta, requires_grad=True)
    f = torch.tensor(s.tension)
    l_pred = net(theta, f)
    g_auto = autograd_jacobian(l_pred, theta)  # (B, M, N)
    x = network_inputs(theta.detach(), f if atl else None, net.input_inverse)
    a1, a2 = hidden_layers(net.params, x)
    th_inv = net.input_inverse[:2]
    g_closed = jacobian(net.params, a1, a2, net.length_scale, th_inv)
    torch.testing.assert_close(g_closed, g_auto)
    gtf_auto = torch.einsum("bmn,bm->bn", g_auto, f)
    torch.testing.assert_close(gtf(net.params, a1, a2, f, net.length_scale, th_inv), gtf_auto)


def _batch(r: int = 3, b: int = 6, n: int = 2, m: int = 4) -> tuple[dict, Batch]:
    gen = torch.Generator().manual_seed(0)
    ps = [init_params(n + m, m, s, 32, F64) for s in range(r)]
    p = {k: torch.stack([q[k] for q in ps]).requires_grad_(True) for k in ps[0]}
    x = torch.randn(r, b + 1, n + m, generator=gen, dtype=F64)
    x[:, b] = 0
    batch = Batch(x=x, length=0.01 * torch.randn(r, b, m, generator=gen, dtype=F64),
                  tension=300 * torch.rand(r, b, m, generator=gen, dtype=F64),
                  tau=torch.randn(r, b, n, generator=gen, dtype=F64),
                  length_scale=0.05 * torch.rand(r, 1, m, generator=gen, dtype=F64),
                  theta_inverse=1 + torch.rand(r, 1, n, generator=gen, dtype=F64),
                  const_weight=torch.tensor([1.0, 0.0, 1.0], dtype=F64),
                  pinn_weight=torch.tensor([1e-5, 1e-3, 0.0], dtype=F64))
    return p, batch


def test_hand_written_gradient_matches_autograd() -> None:
    assert_hand_written_gradient(*_batch())


def assert_hand_written_gradient(p: dict, batch: Batch) -> None:
    """objective_and_grads gives L_basic and the gradient that autograd gives."""
    total, lb = objective(p, batch)
    want = torch.autograd.grad(total.sum(), list(p.values()))
    lb2, got, _ = objective_and_grads({k: v.detach() for k, v in p.items()}, batch)
    torch.testing.assert_close(lb2, lb.detach())
    for k, w in zip(p, want, strict=True):
        torch.testing.assert_close(got[k], w, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("linear", [True, False])
def test_pinn_loss_vanishes_with_true_jacobian(linear: bool) -> None:
    s = synthetic_samples(50, linear=linear)
    from pimbs_learn.synthetic import body
    r, q = body(2, 4, 1234, linear)
    g = muscle_jacobian(s.theta, r, q)
    gtf_true = torch.tensor(np.einsum("bmn,bm->bn", g, s.tension))
    assert pinn_loss(gtf_true, torch.tensor(s.tau)).item() < 1e-20
    # and it notices a wrong sign (τ = −Gᵀf, not +Gᵀf)
    assert pinn_loss(-gtf_true, torch.tensor(s.tau)).item() > 1.0


def _run(n_train: int = 8, loss: str = "basic+const+pinn", seed: int = 0) -> Run:
    return Run(synthetic_samples(n_train, seed=seed), synthetic_samples(64, seed=99),
               LossConfig.parse(loss, 1e-5), seed=seed)


@pytest.mark.parametrize("trainer", [train, train_reference])
def test_selection_rule_picks_lowest_training_loss(trainer) -> None:
    # a large learning rate makes the training loss jump around, so the last epoch is not
    # the best one and the rule has something to choose
    res = trainer(_run(), TrainOptions(epochs=6, lr=0.05, curve_every=1, **SMALL))
    k = int(np.argmin(res.curve_train))
    assert 0 < k < 5  # neither the first nor the last epoch: the rule really chose
    assert res.best_epoch == k
    assert res.train_loss == pytest.approx(res.curve_train[k], rel=1e-12)
    assert res.eval_loss == pytest.approx(res.curve_eval[k], rel=1e-9)


@pytest.mark.parametrize("schedule", ["constant", "exp"])
def test_fast_trainer_agrees_with_reference(schedule: str) -> None:
    run, opts = _run(), TrainOptions(epochs=30, schedule=schedule, **SMALL)
    fast, ref = train(run, opts), train_reference(run, opts)
    assert fast.best_epoch == ref.best_epoch
    assert fast.eval_loss == pytest.approx(ref.eval_loss, rel=1e-6)


def test_stacked_runs_are_independent() -> None:
    runs = [_run(seed=1), _run(loss="basic", seed=2)]
    opts = TrainOptions(epochs=15, **SMALL)
    together = train_runs(runs, opts)
    for run, res in zip(runs, together, strict=True):
        alone = train(run, opts)
        assert res.best_epoch == alone.best_epoch
        assert res.eval_loss == pytest.approx(alone.eval_loss, rel=1e-9)


def test_exp_schedule_settles_where_a_constant_lr_keeps_jumping() -> None:
    # Adam steps ~lr whatever the gradient, so at a large constant lr the training loss
    # keeps jumping to the end; decaying lr to 1 % lets the fit settle (why it is the default)
    kw = dict(epochs=300, lr=0.05, curve_every=1, **SMALL)
    const = train(_run(), TrainOptions(**kw))
    exp = train(_run(), TrainOptions(schedule="exp", **kw))
    assert TrainOptions(schedule="exp", **kw).lr_at(300) == pytest.approx(0.05 * 0.01)

    def jumps(curve: np.ndarray) -> float:  # largest epoch-to-epoch change, last 30 epochs
        return float(np.abs(np.diff(np.log(curve[-30:]))).max())

    assert jumps(exp.curve_train) < 0.1 * jumps(const.curve_train)


def test_training_lowers_eval_error() -> None:
    res = train(_run(n_train=20), TrainOptions(epochs=150, curve_every=149, **SMALL))
    assert res.eval_loss < 0.2 * res.curve_eval[0]


def test_save_load_round_trip_without_pickle(tmp_path, monkeypatch) -> None:
    run = _run()
    res = train(run, TrainOptions(epochs=5, hidden=48))
    save_model(res, tmp_path / "m")
    meta = json.loads((tmp_path / "m" / "model.json").read_text())
    for key in ("scaling", "joints", "muscles", "map", "loss", "alpha", "metrics", "data",
                "epochs", "seed", "robot"):
        assert key in meta

    def no_pickle(*a, **k):
        raise AssertionError("loading must not unpickle")

    monkeypatch.setattr(pickle, "load", no_pickle)
    monkeypatch.setattr(pickle, "loads", no_pickle)
    monkeypatch.setattr(torch, "load", no_pickle)
    model = load_body_schema(tmp_path / "m")
    net = BodySchemaNet({k: torch.tensor(v, dtype=F64) for k, v in res.params.items()},
                        res.scaling)
    s = run.eval
    want = net(torch.tensor(s.theta), torch.tensor(s.tension)).detach().numpy()
    np.testing.assert_allclose(model.length(s.theta, s.tension), want, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(model.length(s.theta[0], s.tension[0]), want[0], atol=1e-12)
    g = model.jacobian(s.theta, s.tension)
    assert g.shape == (64, 4, 2)
    np.testing.assert_allclose(model.torque(s.theta, s.tension),
                               -np.einsum("bmn,bm->bn", g, s.tension))
    with pytest.raises(LearnError, match="ATL-Map"):
        model.length(s.theta)
    with pytest.raises(LearnError, match="theta must have shape"):
        model.length(np.zeros((3, 5)), np.zeros((3, 4)))


def test_model_dir_errors(tmp_path) -> None:
    with pytest.raises(LearnError, match="missing model.safetensors"):
        load_body_schema(tmp_path)


def test_bad_inputs_are_refused() -> None:
    s = synthetic_samples(10)
    with pytest.raises(ValueError, match="not one of"):
        LossConfig.parse("basic+magic")
    with pytest.raises(ValueError, match="not one of"):
        LossConfig.parse("const+pinn")
    with pytest.raises(LearnError, match="leaves no evaluation samples"):
        split(s, 10, seed=0)
    other = synthetic_samples(5, n_muscles=3)
    with pytest.raises(LearnError, match="does not match"):
        check_compatible(s, other)
    from dataclasses import replace
    no_tau = replace(s, tau=np.full_like(s.tau, np.nan))
    with pytest.raises(LearnError, match="--robot"):
        fill_gravity(no_tau, None)
    with pytest.raises(LearnError, match="tau_gravity"):
        Run(no_tau, s).check()
    with pytest.raises(LearnError, match="--epochs"):
        train(Run(s, s), TrainOptions(epochs=0))
    with pytest.raises(LearnError, match="--lr-schedule must be one of exp"):
        train(Run(s, s), TrainOptions(epochs=1, schedule="linear"))
    with pytest.raises(LearnError, match="same n_train"):
        train_runs([Run(s, s), Run(synthetic_samples(4), s)], TrainOptions(epochs=1))


def _write(path, samples: Samples, tau_null: bool = False, zero_tension: bool = False) -> None:
    from pimbs_recording.format import make_meta, write_recording

    n = samples.n_samples
    data = {"sample": np.arange(n),
            "time": np.datetime64("2026-11-21T10:00:00", "us") + np.arange(n).astype(
                "timedelta64[s]"),
            "theta": samples.theta, "theta_command": samples.theta,
            "tension": 0 * samples.tension if zero_tension else samples.tension,
            "length": samples.length, "temperature": np.full(samples.length.shape, 30.0),
            "approach": np.zeros(samples.length.shape, np.int8),
            "tau_gravity": np.full_like(samples.tau, np.nan) if tau_null else samples.tau}
    write_recording(path, data, make_meta(list(samples.joints), list(samples.muscles),
                                          "simulation", robot="synthetic"))


def test_cli_train_and_its_errors(tmp_path) -> None:
    from pimbs_cli.train import command

    rec = tmp_path / "rec.parquet"
    try:
        _write(rec, synthetic_samples(20))
    except Exception as e:  # the recording module is a sibling's work in progress
        pytest.skip(f"cannot write a recording here: {e}")
    runner = CliRunner()
    out = runner.invoke(command, [str(rec), "--n-train", "8", "--epochs", "3", "--out",
                                  str(tmp_path / "m"), "--json", str(tmp_path / "m.json")])
    assert out.exit_code == 0, out.output
    metrics = json.loads((tmp_path / "m.json").read_text())
    assert {"eval_loss", "train_loss", "best_epoch", "epochs", "seconds"} <= set(metrics)
    assert load_body_schema(tmp_path / "m").n_muscles == 4

    def err(*args: str) -> str:
        res = runner.invoke(command, [str(a) for a in args])
        assert res.exit_code != 0
        return res.output

    assert "no such recording" in err(tmp_path / "missing.parquet", "--n-train", "3")
    assert "leaves no evaluation" in err(rec, "--n-train", "20")
    other = tmp_path / "other.parquet"
    _write(other, synthetic_samples(6, n_muscles=3))
    assert "does not match" in err(rec, "--eval", other)
    nulls = tmp_path / "nulls.parquet"
    _write(nulls, synthetic_samples(20), tau_null=True)
    assert "--robot" in err(nulls, "--n-train", "5", "--epochs", "2")
    zero = tmp_path / "zero.parquet"
    _write(zero, synthetic_samples(20), zero_tension=True)
    assert "tension" in err(zero, "--n-train", "5", "--epochs", "2")
    # an AL-Map without PINN needs no tension at all
    ok = runner.invoke(command, [str(zero), "--n-train", "5", "--epochs", "2", "--map", "al",
                                 "--loss", "basic+const"])
    assert ok.exit_code == 0, ok.output


def test_scaling_maps_zero_to_zero() -> None:
    sc = Scaling.from_data(np.array([[0.2, -0.4]]), np.array([[10.0, 0, 0, 0]]),
                           np.array([[0.01, 0, 0, 0]]))
    assert np.all(sc.input_inverse() > 0) and np.all(np.isfinite(sc.input_inverse()))
    x = network_inputs(torch.zeros(1, 2), torch.zeros(1, 4),
                       torch.tensor(sc.input_inverse()))
    assert torch.count_nonzero(x) == 0


def test_missing_tau_is_computed_from_the_robot(tmp_path) -> None:
    from pimbs_arm.model import ArmModel
    from pimbs_cli.train import command
    from pimbs_recording.format import write_recording
    from pimbs_sim.simulate import simulate

    data, meta = simulate(ArmModel.load("two-link-4-muscle"), 12, "atl", seed=0, noise=0.0)
    tau = data["tau_gravity"].copy()
    data["tau_gravity"] = np.full_like(tau, np.nan)
    rec = tmp_path / "no-tau.parquet"
    write_recording(rec, data, meta)
    from pimbs_learn.data import load_samples

    filled = fill_gravity(load_samples(rec), "two-link-4-muscle")
    np.testing.assert_allclose(filled.tau, tau, rtol=1e-9, atol=1e-12)
    res = CliRunner().invoke(command, [str(rec), "--n-train", "6", "--epochs", "2",
                                       "--robot", "two-link-4-muscle"])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(command, [str(rec), "--n-train", "6", "--epochs", "2",
                                       "--robot", "left-arm-5dof"])
    assert res.exit_code != 0 and "joints" in res.output


def test_best_weight_keeping_is_the_same_on_host_and_device_paths() -> None:
    from pimbs_learn.train import _keep_best

    p = {"w": torch.arange(12.0).view(3, 2, 2)}
    improved = torch.tensor([True, False, True])
    a, b = {"w": torch.zeros(3, 2, 2)}, {"w": torch.zeros(3, 2, 2)}
    _keep_best(p, a, improved, on_host=True)
    _keep_best(p, b, improved, on_host=False)
    torch.testing.assert_close(a["w"], b["w"])
    assert a["w"][1].abs().sum() == 0 and torch.equal(a["w"][2], p["w"][2])
