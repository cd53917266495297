"""Two networks averaged into one: the merged model computes exactly the members' mean,
and saves, loads and differentiates as any other model."""

from __future__ import annotations

import numpy as np
import pytest

from pimbs_learn.ensemble import member_runs, members_for, merge
from pimbs_learn.graph import SERIES_ELASTIC
from pimbs_learn.io import load_body_schema, save_model, schema_from_result
from pimbs_learn.losses import LossConfig
from pimbs_learn.run import Run, TrainOptions
from pimbs_learn.synthetic import synthetic_samples
from pimbs_learn.train import train, train_runs

OPTS = TrainOptions(epochs=40, hidden=16, dtype=__import__("torch").float64)


def _run(structure: str = SERIES_ELASTIC, loss: str = "basic+const+pinn", n: int = 5) -> Run:
    return Run(synthetic_samples(n, seed=1), synthetic_samples(40, seed=98),
               LossConfig.parse(loss, 1.0, "auto", sensors="pinn" in loss), seed=3,
               structure=structure)


@pytest.mark.parametrize("structure", ["mlp", SERIES_ELASTIC])
def test_merged_network_is_the_members_mean(structure, tmp_path) -> None:
    runs = member_runs(_run(structure), 2)
    assert [r.seed for r in runs] == [3, 1003]
    members = train_runs(runs, OPTS)
    merged = merge(members)
    ev = runs[0].eval
    preds = [schema_from_result(m).length_and_jacobian(ev.theta, ev.tension) for m in members]
    length, g = schema_from_result(merged).length_and_jacobian(ev.theta, ev.tension)
    np.testing.assert_allclose(length, (preds[0][0] + preds[1][0]) / 2, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(g, (preds[0][1] + preds[1][1]) / 2, rtol=1e-5, atol=1e-9)
    # the reported losses are the merged network's own, not a member's
    assert merged.eval_loss == pytest.approx(np.mean((length - ev.length) ** 2), rel=1e-5)
    assert merged.eval_loss != members[0].eval_loss
    assert merged.params["w1"].shape[0] == 2 * OPTS.hidden
    assert [m["seed"] for m in merged.metrics()["members"]] == [3, 1003]
    # and it is an ordinary model on disk
    save_model(merged, tmp_path / "m")
    loaded = load_body_schema(tmp_path / "m")
    np.testing.assert_allclose(loaded.length(ev.theta, ev.tension), length, rtol=1e-5,
                               atol=1e-9)


def test_train_with_members_trains_them_stacked() -> None:
    run = _run()
    two = train(run, TrainOptions(epochs=40, hidden=16, members=2))
    alone = train(run, TrainOptions(epochs=40, hidden=16))
    assert two.members is not None and len(two.members) == 2
    assert two.members[0]["eval_loss"] == pytest.approx(alone.eval_loss, rel=1e-6)
    assert alone.members is None and alone.metrics()["members"] is None


def test_members_follow_the_training_set_size() -> None:
    assert members_for(5) == 2 and members_for(10) == 2 and members_for(20) == 2
    assert members_for(21) == 1 and members_for(30) == 1


def test_beside_a_physics_run_of_8_to_20_samples_the_other_leaves_out_only_the_home_pose(
) -> None:
    for n in (8, 10, 20):
        physics = _run(n=n)
        pair = member_runs(physics, 2)
        assert [(r.loss.pinn, r.loss.const) for r in pair] == [(True, True), (True, False)]
        # the torque balance as asked: weight and sensor terms unchanged
        assert (pair[1].loss.weighting, pair[1].loss.alpha, pair[1].loss.sensors) == \
            (physics.loss.weighting, physics.loss.alpha, physics.loss.sensors)
    assert [r.loss.name for r in member_runs(_run(loss="basic+const", n=10), 2)] == \
        ["basic+const", "basic"]


def test_with_at_most_7_samples_the_other_network_is_basic() -> None:
    for n in (5, 7):
        pair = member_runs(_run(n=n), 2)
        assert [r.loss.name for r in pair] == ["basic+const+pinn", "basic"]
        assert [r.seed for r in pair] == [3, 1003]
    basic = _run(loss="basic")
    pair = member_runs(basic, 2)
    assert [r.loss.name for r in pair] == ["basic", "basic"]
    assert [r.seed for r in pair] == [3, 1003]


def test_pimbs_train_averages_two_networks_at_few_samples_only(tmp_path) -> None:
    from click.testing import CliRunner

    from pimbs_arm.model import ArmModel
    from pimbs_cli.train import command
    from pimbs_recording.format import write_recording
    from pimbs_sim.simulate import simulate

    data, meta = simulate(ArmModel.load("two-link-4-muscle"), 30, "atl", seed=0, noise=0.0)
    rec = tmp_path / "rec.parquet"
    write_recording(rec, data, meta)

    def trained(*args: str) -> dict:
        out = tmp_path / f"m{len(list(tmp_path.iterdir()))}"
        res = CliRunner().invoke(command, [str(rec), "--epochs", "3", "--hidden", "8",
                                           "--out", str(out), *args])
        assert res.exit_code == 0, res.output
        return load_body_schema(out).meta

    few = trained("--n-train", "5")
    assert few["architecture"]["layers"][1] == 16
    assert [m["loss"] for m in few["metrics"]["members"]] == ["basic+const+pinn", "basic"]
    assert [m["loss"] for m in trained("--n-train", "10")["metrics"]["members"]] == \
        ["basic+const+pinn", "basic+pinn"]
    # without a prior the physics network's sensor terms are kept beside a Basic one
    assert trained("--n-train", "5", "--no-prior")["metrics"]["sensor_terms"] is not None
    assert [m["loss"] for m in trained("--n-train", "10", "--loss", "basic")["metrics"]
            ["members"]] == ["basic", "basic"]
    assert trained("--n-train", "25")["metrics"]["members"] is None
    assert trained("--n-train", "5", "--paper", "--hidden", "8")["metrics"]["members"] is None
    assert trained("--n-train", "25", "--members", "2")["architecture"]["layers"][1] == 16
