"""The self-check keeps the physics where the recorded torques help predict lengths at
poses left out, and falls back to Basic where they do not; `pimbs train` says which."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest
import torch
from click.testing import CliRunner

from pimbs_cli.main import main
from pimbs_learn.data import load_samples, split
from pimbs_learn.losses import LossConfig
from pimbs_learn.run import Run, TrainOptions
from pimbs_learn.selfcheck import (
    BASIC,
    KEEP_BELOW,
    SelfCheck,
    applies,
    keep_below,
    self_check,
    train_checked,
)
from pimbs_learn.train import train
from tests.foreign_arm import record

DEFAULT = LossConfig.parse("basic+const+pinn", 1.0, "auto")


@pytest.fixture(scope="module")
def foreign(tmp_path_factory):
    path = tmp_path_factory.mktemp("sc") / "foreign.parquet"
    record(path, 60, 0)
    return load_samples(path)


def _run(samples, n=10, seed=0, loss=DEFAULT):
    tr, ev = split(samples, n, seed)
    return Run(tr, ev, loss, seed, True, "series-elastic")


def test_torques_that_fit_the_lengths_keep_the_physics(foreign):
    check = self_check(_run(foreign))
    assert check is not None and check.samples == 10
    assert check.keeps_physics and check.ratio < 0.5


def test_torques_that_do_not_fit_the_lengths_fall_back(foreign):
    """The same rows with every torque of the wrong sign (a gravity model or a loadcell
    wired backwards: every number realistic, none of them right): the torques make the
    lengths harder to predict, and the check falls back at every size it decides at."""
    decided = [n for n, t in KEEP_BELOW.items() if t < float("inf")]
    assert decided
    for n in decided:
        run = _run(foreign, n=n)
        check = self_check(replace(run, train=replace(run.train, tau=-run.train.tau)))
        assert check is not None and not check.keeps_physics
        assert check.ratio >= check.keep_below == keep_below(n)


def test_each_training_size_reads_the_ratio_with_its_own_threshold():
    """A run takes the threshold of the nearest size chosen on the development arms, the
    lower of two at equal distance; the verdict and the line follow it."""
    sizes = sorted(KEEP_BELOW)
    for n in sizes:
        assert keep_below(n) == KEEP_BELOW[n]
    assert keep_below(1) == KEEP_BELOW[sizes[0]] and keep_below(1000) == KEEP_BELOW[sizes[-1]]
    middle = (sizes[0] + sizes[1]) / 2
    assert keep_below(middle) == min(KEEP_BELOW[sizes[0]], KEEP_BELOW[sizes[1]])

    def check(ratio: float, threshold: float) -> SelfCheck:
        return SelfCheck(samples=10, with_torque=ratio, without_torque=1.0,
                         torque_noise_rms=0.01, keep_below=threshold)

    assert check(1.2, 1.5).keeps_physics and not check(1.2, 1.0).keeps_physics
    assert "kept below ×1.5" in check(1.2, 1.5).line("basic+const+pinn")
    assert check(40.0, float("inf")).keeps_physics
    assert json.loads(json.dumps(check(40.0, float("inf")).metrics(), allow_nan=False)
                      )["keep_below"] is None
    assert check(1.2, 1.5).metrics()["keep_below"] == 1.5
    assert "whatever the ratio" in check(40.0, float("inf")).line("basic+const+pinn")


def test_a_fallback_trains_exactly_what_basic_trains(foreign):
    torch.set_num_threads(1)
    run = _run(foreign)
    wrong = replace(run, train=replace(run.train, tau=-run.train.tau))
    options = TrainOptions(epochs=60, hidden=16, schedule="exp")
    checked = train_checked(wrong, options)
    basic = train(replace(wrong, loss=BASIC), options)
    m = checked.metrics()
    assert (m["loss"], m["loss_asked"]) == ("basic", "basic+const+pinn")
    assert m["self_check"]["physics_kept"] is False
    assert checked.eval_loss == pytest.approx(basic.eval_loss, rel=1e-6)


def test_the_check_applies_only_where_it_can_decide(foreign):
    assert applies(_run(foreign))
    assert not applies(_run(foreign, loss=LossConfig.parse("basic+const")))
    assert not applies(_run(foreign, n=2))


def test_pimbs_train_says_what_the_check_chose_and_paper_is_one_flag(tmp_path):
    torch.set_num_threads(1)
    data = tmp_path / "f.parquet"
    record(data, 40, 1)
    args = ["train", str(data), "--n-train", "10", "--epochs", "30", "--threads", "1"]
    out = CliRunner().invoke(main, [*args, "--json", str(tmp_path / "m.json")])
    assert out.exit_code == 0, out.output
    assert "self-check, each of 10 training samples predicted from the others" in out.output
    metrics = json.loads((tmp_path / "m.json").read_text())
    assert metrics["self_check"]["physics_kept"] == (metrics["loss"] == "basic+const+pinn")
    out = CliRunner().invoke(main, [*args, "--no-self-check"])
    assert out.exit_code == 0 and "self-check" not in out.output
    out = CliRunner().invoke(main, [*args, "--paper", "--out", str(tmp_path / "paper")])
    assert out.exit_code == 0, out.output
    meta = json.loads((tmp_path / "paper" / "model.json").read_text())
    assert meta["structure"] == "mlp" and meta["architecture"]["layers"][1:3] == [1000, 1000]
    assert meta["metrics"]["lr_schedule"] == "constant" and meta["metrics"]["alpha"] == 1e-5
    assert meta["metrics"]["self_check"] is None and "self-check" not in out.output
