"""Stacked training of many arms: arms of one shape stack whatever their names, stacking
changes no run's result, and the population runner resumes instead of training again."""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from pimbs_arm.model import ArmModel
from pimbs_learn.data import LearnError, Samples, split
from pimbs_learn.method_spec import parse_method
from pimbs_learn.run import Run, TrainOptions
from pimbs_learn.train import train_runs
from pimbs_recording.format import write_recording
from pimbs_sim.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]
OPTIONS = TrainOptions(epochs=150, hidden=24, schedule="exp")


def _samples(seed: int, rename: str = "") -> Samples:
    data, meta = simulate(ArmModel.load("two-link-4-muscle"), 40, "atl", seed=seed)
    return Samples(theta=data["theta"], tension=data["tension"], length=data["length"],
                   tau=data["tau_gravity"],
                   joints=tuple(rename + j for j in meta["joints"]),
                   muscles=tuple(rename + m for m in meta["muscles"]))


def test_split_caps_the_evaluation_rows_and_keeps_the_training_rows():
    s = _samples(0)
    train, evaluate = split(s, 10, 3)
    capped_train, capped = split(s, 10, 3, max_eval=7)
    np.testing.assert_array_equal(train.theta, capped_train.theta)
    assert capped.n_samples == 7
    assert {tuple(r) for r in capped.theta} <= {tuple(r) for r in evaluate.theta}


def test_runs_of_differently_named_arms_of_one_shape_stack_as_if_run_apart():
    torch.set_num_threads(1)
    a, b = _samples(1), _samples(2, rename="other_")
    runs = []
    for spec, samples, n_eval in (("se:basic+const+pinn@auto~exp", a, 25),
                                  ("se:basic~exp", b, 18),  # evaluation sizes differ too
                                  ("se:basic~exp", a, 25)):
        m = parse_method(spec)
        tr, ev = split(samples, 8, 5, max_eval=n_eval)
        runs.append(Run(tr, ev, m.loss, 5, True, m.structure))
    together = train_runs(runs, OPTIONS)
    apart = [train_runs([r], OPTIONS)[0] for r in runs]
    for t, s in zip(together, apart, strict=True):
        assert t.run.eval.n_samples == s.run.eval.n_samples
        assert t.best_epoch == s.best_epoch
        assert t.eval_loss == pytest.approx(s.eval_loss, rel=1e-4)
        assert t.train_loss == pytest.approx(s.train_loss, rel=1e-4, abs=1e-12)
    assert together[0].torque_noise_rms is not None  # the automatic weight's own floor
    assert together[0].eval_loss != pytest.approx(together[2].eval_loss, rel=1e-3)


def test_runs_of_different_shapes_are_refused_in_one_batch():
    a = _samples(1)
    fewer = replace(a, tension=a.tension[:, :3], length=a.length[:, :3],
                    muscles=a.muscles[:3])
    runs = [Run(*split(s, 8, 0)) for s in (a, fewer)]
    with pytest.raises(LearnError, match="numbers of joints and muscles"):
        train_runs(runs, OPTIONS)


def _runner():
    spec = importlib.util.spec_from_file_location(
        "population_runner", ROOT / "benchmarks" / "population_runner.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look themselves up there
    spec.loader.exec_module(module)
    return module


def test_population_runner_stacks_one_shape_and_resumes(tmp_path, capsys):
    arm = ArmModel.load("two-link-4-muscle")
    lines = []
    for seed in (1, 3):  # two judging arms of one shape
        data, meta = simulate(arm, 30, "atl", seed=seed)
        rec = tmp_path / f"arm{seed}.parquet"
        write_recording(rec, data, meta)
        lines.append({"arm": f"arm{seed:03d}", "seed": seed, "split": "judge",
                      "family": "viapoint", "simulator": "ours", "dof": 2, "n_muscles": 4,
                      "rows": 30, "recording": rec.name,
                      "truth": {"effects": [{"name": "tension_offset"}] if seed == 3 else []}})
    manifest = tmp_path / "manifest.jsonl"
    manifest.write_text("".join(json.dumps(d) + "\n" for d in lines))
    out = tmp_path / "runs.jsonl"
    runner = _runner()
    args = argparse.Namespace(
        manifest=manifest, split="judge", arms=None, n=[5], seeds=2, seed0=0,
        methods=["se:basic+const~exp", "se:basic~exp"], hidden=16, epochs=40,
        lr=1e-3, device="cpu", threads=1, jobs=1, max_eval=20, max_batch=64, out=out)
    runner.run(args)
    rows = [json.loads(t) for t in out.read_text().splitlines()]
    assert len(rows) == 2 * 2 * 2  # arms x seeds x methods, one batch
    assert {r["batch_runs"] for r in rows} == {8}
    assert {r["n_eval"] for r in rows} == {20}
    assert {(r["arm"], tuple(r["effects"])) for r in rows} == {
        ("arm001", ()), ("arm003", ("tension_offset",))}
    assert all(r["eval"] > 0 and r["hidden"] == 16 for r in rows)
    capsys.readouterr()
    runner.run(args)  # everything is there: nothing trains, nothing is appended
    assert "0 runs to train" in capsys.readouterr().out
    assert len(out.read_text().splitlines()) == len(rows)
    args.n, args.jobs = [5, 8], 2  # a new N trains only what is new (here in a worker)
    runner.run(args)
    assert len(out.read_text().splitlines()) == 2 * len(rows)
    text = "\n".join(runner.summary(out, "se:basic~exp", "se:basic+const~exp"))
    assert "viapoint on ours" in text and "N=5" in text and "2 arms" in text


def _count_training(monkeypatch) -> list[int]:
    """The number of networks in each ``train_runs`` call from now on."""
    import pimbs_learn.train as train_module

    trained: list[int] = []

    def counting(runs, options):
        trained.append(len(runs))
        return train_runs(runs, options)

    monkeypatch.setattr(train_module, "train_runs", counting)
    return trained


def test_a_default_that_falls_back_shares_basics_run(monkeypatch):
    """A checked default that falls back trains what Basic trains on the same cell: the batch
    trains it once and both lines carry the same result."""
    runner = _runner()
    trained = _count_training(monkeypatch)
    arm = {"arm": "arm001", "dof": 2, "n_muscles": 4}
    checked = parse_method("se:basic+const+pinn@auto~exp!check")
    basic = parse_method("se:basic~exp")
    jobs = [runner.Job(arm, 8, 0, checked), runner.Job(arm, 8, 0, basic),
            runner.Job(arm, 8, 1, basic)]
    tr, ev = split(_samples(1), 8, 0)
    fell_back = Run(tr, ev, basic.loss, 0, True, basic.structure)  # what the check trains
    other = Run(*split(_samples(1), 8, 1), basic.loss, 1, True, basic.structure)
    results = runner._train_once(jobs, [[fell_back], [fell_back], [other]], OPTIONS)
    assert trained == [2]
    assert results[0].eval_loss == results[1].eval_loss != results[2].eval_loss


def test_members_jobs_train_their_networks_once_and_merge(monkeypatch):
    """With the ``members`` flag a run of few samples is the mean of its networks: the
    physics networks train in one stack, the Basic ones in another (they skip the torque
    balance's matmuls), each distinct network once in the batch (a plain Basic run of the
    same cell is Basic's first network), and the line's L_eval is the merged network's."""
    from pimbs_learn.ensemble import member_runs

    runner = _runner()
    trained = _count_training(monkeypatch)
    arm = {"arm": "arm001", "dof": 2, "n_muscles": 4}
    default = parse_method("se:basic+const+pinn@auto~exp!sensors,members")
    basic = parse_method("se:basic~exp!members")
    plain = parse_method("se:basic~exp")
    assert basic.members and not plain.members
    jobs = [runner.Job(arm, 10, 0, default), runner.Job(arm, 10, 0, basic),
            runner.Job(arm, 10, 0, plain)]
    rows = split(_samples(1), 10, 0)
    physics = member_runs(Run(*rows, default.loss, 0, True, default.structure), 2)
    basics = member_runs(Run(*rows, basic.loss, 0, True, basic.structure), 2)
    results = runner._train_once(jobs, [physics, basics, basics[:1]], OPTIONS)
    assert trained == [2, 2]  # the two physics networks, then the two Basic ones
    assert [m["loss"] for m in results[0].members] == ["basic+const+pinn", "basic+pinn"]
    assert results[2].eval_loss == results[1].members[0]["eval_loss"]
    assert results[0].eval_loss != results[1].eval_loss
    assert results[1].eval_loss not in {m["eval_loss"] for m in results[1].members}
    # at 5 samples the physics network's partner is Basic: the same network as Basic's
    # second, trained once
    trained.clear()
    rows = split(_samples(1), 5, 0)
    physics = member_runs(Run(*rows, default.loss, 0, True, default.structure), 2)
    basics = member_runs(Run(*rows, basic.loss, 0, True, basic.structure), 2)
    five = [runner.Job(arm, 5, 0, default), runner.Job(arm, 5, 0, basic)]
    results = runner._train_once(five, [physics, basics], OPTIONS)
    assert trained == [1, 2]
    assert results[0].members[1]["eval_loss"] == results[1].members[1]["eval_loss"]
