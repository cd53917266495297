"""A new user's first hour (issue 14): every wrong input ends in one line naming the thing
and what to do, with exit status 1 (a bad option too), nothing on disk changed or lost;
logged runs show progress; the diagnosis figure shows the fit improve.

Runs are tiny (a few samples, a few hundred epochs) so the file adds seconds, and nothing
depends on how fast the machine is.
"""

from __future__ import annotations

import errno
import hashlib
import io
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pimbs_arm.model import ArmModel
from pimbs_cli.main import main
from pimbs_recording.format import read_recording, write_recording
from pimbs_sim.effects import ALIASES, EFFECT_NAMES, MAGNITUDE_RANGE
from pimbs_sim.simulate import simulate


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load("two-link-4-muscle")


def _sim(path: Path, arm: ArmModel, n: int, seed: int = 0, effects=()) -> Path:
    data, meta = simulate(arm, n, "atl", seed=seed, effects=effects)
    write_recording(path, data, meta)
    return path


def _tree(root: Path) -> dict[str, str]:
    """Every file under ``root`` with its SHA-256: what 'nothing on disk changed' means."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def _run(*args: object) -> tuple[int, str]:
    res = CliRunner().invoke(main, [str(a) for a in args])
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        raise res.exception  # our bug: keep its traceback
    assert "Traceback" not in res.output, res.output
    return res.exit_code, res.output


def _one_error_line(output: str) -> str:
    lines = [ln for ln in output.splitlines() if ln.startswith("Error")]
    assert len(lines) == 1, output
    return lines[0]


# -- simulate ----------------------------------------------------------------------------

def test_simulate_does_not_overwrite_or_create_directories(tmp_path, arm):
    rec = _sim(tmp_path / "x.parquet", arm, 5)
    before = _tree(tmp_path)
    code, out = _run("simulate", "--samples", 3, "--out", rec)
    line = _one_error_line(out)
    assert code == 1 and str(rec) in line and "--force" in line
    code, out = _run("simulate", "--samples", 3, "--out", tmp_path / "no" / "such" / "x.pq")
    assert code == 1 and "does not exist" in _one_error_line(out)
    assert _tree(tmp_path) == before and not (tmp_path / "no").exists()
    code, out = _run("simulate", "--samples", 3, "--out", rec, "--force")
    assert code == 0, out
    assert read_recording(rec).n_rows == 3


@pytest.mark.parametrize("effect", sorted(MAGNITUDE_RANGE))
def test_simulate_refuses_an_effect_magnitude_outside_its_range(tmp_path, effect):
    _, lo, hi, _ = MAGNITUDE_RANGE[effect]
    bad = lo - 1 if effect in ("link_mass", "elastic_stiffness", "tendon_friction",
                               "routing") else hi * 2
    out_file = tmp_path / "x.parquet"
    code, out = _run("simulate", "--samples", 3, "--conceal", f"{effect}:{bad:g}",
                     "--out", out_file)
    line = _one_error_line(out)
    assert code == 1 and effect in line and f"{hi:g}]" in line, line
    assert "inertia" not in out and not out_file.exists()


def test_every_effect_name_and_alias_is_in_the_help():
    code, out = _run("simulate", "--help")
    text = " ".join(out.split())  # help is wrapped
    assert code == 0
    for name in (*EFFECT_NAMES, *ALIASES):
        assert re.search(rf"\b{name}\b", text), name


def test_simulate_on_a_full_disk_keeps_the_old_file_and_says_what_to_do(tmp_path, arm,
                                                                       monkeypatch):
    import pyarrow.parquet as pq

    rec = _sim(tmp_path / "x.parquet", arm, 5)
    before = _tree(tmp_path)
    real_write = pq.write_table

    def full_disk(table, where, **kw):
        real_write(table.slice(0, 1), where, **kw)  # part of it reaches the disk
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(pq, "write_table", full_disk)
    code, out = _run("simulate", "--samples", 4, "--out", rec, "--force")
    line = _one_error_line(out)
    assert code == 1 and str(rec) in line and "No space left" in line
    assert "--resume" not in line and "run the same command again" in line
    assert _tree(tmp_path) == before  # the old recording intact, no temporary file left


# -- train -------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def recording(tmp_path_factory, arm) -> Path:
    return _sim(tmp_path_factory.mktemp("train") / "rec.parquet", arm, 12, seed=2)


def test_train_does_not_overwrite_a_model_or_json(tmp_path, recording):
    model = tmp_path / "model"
    code, out = _run("train", recording, "--n-train", 8, "--epochs", 2, "--out", model,
                     "--json", tmp_path / "m.json")
    assert code == 0, out
    before = _tree(tmp_path)
    code, out = _run("train", recording, "--n-train", 8, "--epochs", 2, "--out", model)
    line = _one_error_line(out)
    assert code == 1 and "--out" in line and "--force" in line and "training" not in out
    code, out = _run("train", recording, "--n-train", 8, "--epochs", 2, "--out",
                     tmp_path / "other", "--json", tmp_path / "m.json")
    assert code == 1 and "--json" in _one_error_line(out)
    code, out = _run("train", recording, "--n-train", 8, "--epochs", 2, "--out",
                     tmp_path / "no" / "model")
    assert code == 1 and "does not exist" in _one_error_line(out)
    assert _tree(tmp_path) == before
    code, out = _run("train", recording, "--n-train", 8, "--epochs", 2, "--out", model,
                     "--force")
    assert code == 0, out


def test_train_checks_robot_and_never_ignores_it(recording):
    code, out = _run("train", recording, "--n-train", 8, "--epochs", 2, "--robot", "nope")
    assert code == 1 and "'nope'" in _one_error_line(out)
    code, out = _run("train", recording, "--n-train", 8, "--epochs", 2,
                     "--robot", "left-arm-5dof")
    assert code == 1 and "joints" in _one_error_line(out)
    code, out = _run("train", recording, "--n-train", 8, "--epochs", 2,
                     "--robot", "two-link-4-muscle")
    assert code == 0 and "prior two-link-4-muscle" in out  # the default uses it as prior
    code, out = _run("train", recording, "--n-train", 8, "--epochs", 2, "--no-prior",
                     "--robot", "two-link-4-muscle")
    assert code == 0 and "not used: DATA has tau_gravity in every row" in out


def test_train_without_out_says_so_before_training_and_logs_progress(recording):
    code, out = _run("train", recording, "--n-train", 8, "--epochs", 200)
    assert code == 0, out
    lines = out.splitlines()
    warn = next(i for i, ln in enumerate(lines) if "will not be saved" in ln)
    progress = [i for i, ln in enumerate(lines) if ln.startswith("training: ")]
    assert progress and warn < progress[0]
    # output is not a terminal: plain lines with count, rate and ETA, no bar, no \r
    assert re.match(r"training: 100/200 epochs, .* epochs/s, elapsed \d+:\d\d, ETA ",
                    lines[progress[0]])
    assert lines[progress[-1]].startswith("training: 200/200 epochs")
    assert "\r" not in out and "━" not in out and out.endswith("\n")


# -- experiment --------------------------------------------------------------------------

def test_experiment_blames_the_right_option(tmp_path):
    code, out = _run("experiment", "--n-train", 7, "--out", tmp_path / "e")
    assert code == 1 and "--n-train" in out and "--tables" not in out
    assert "7" in out and "table 1: 3, 5, 10;" in out
    code, out = _run("experiment", "--tables", "4", "--out", tmp_path / "e")
    assert code == 1 and "--tables" in out
    assert not (tmp_path / "e").exists()


def test_experiment_logs_progress_and_keeps_earlier_results(tmp_path):
    out_dir = tmp_path / "e"
    args = ("experiment", "--quick", "--tables", "1", "--n-train", 3, "--seeds", 1,
            "--epochs", 100, "--threads", 1, "--out", out_dir)
    code, out = _run(*args)
    assert code == 0, out
    assert re.search(r"^training: \d+/400 epochs, .*table1$", out, re.M)
    assert (out_dir / "tables.md").exists() and (out_dir / "table1-curves.png").exists()
    before = _tree(tmp_path)
    code, out = _run(*args)
    line = _one_error_line(out)
    assert code == 1 and "tables.md" in line and "--force" in line
    assert _tree(tmp_path) == before


# -- collect -----------------------------------------------------------------------------

def test_collect_resume_of_a_simulated_file_says_what_it_is(tmp_path, arm):
    rec = _sim(tmp_path / "sim.parquet", arm, 5)
    before = _tree(tmp_path)
    code, out = _run("collect", "--port", "virtual", "--samples", 5, "--out", rec,
                     "--resume")
    line = _one_error_line(out)
    assert code == 1 and "pimbs simulate" in line and "None" not in line
    code, out = _run("collect", "--port", "virtual", "--samples", 5,
                     "--out", tmp_path / "no" / "x.parquet")
    assert code == 1 and "does not exist" in _one_error_line(out)
    assert _tree(tmp_path) == before


def test_collect_log_lines_show_how_far_it_got():
    from rich.console import Console

    from pimbs_hw.collection.progress import LogReporter
    from pimbs_hw.collection.routine import Summary

    buf = io.StringIO()
    s = Summary(path="x.parquet", total=40, start=0)
    with LogReporter(Console(file=buf, width=40), every_s=1e9) as rep:
        for i in range(3):
            s.next_sample, s.written = i + 1, i + 1
            s.tension_range, s.temperature_max = (10.0, 200.0), 30.0
            rep.sample(s, {"sample": i})
        rep.warn(s, "m1 (board 2) did not settle at sample 2")
    lines = buf.getvalue().splitlines()
    assert buf.getvalue().endswith("\n")
    assert lines[0].startswith("collect: 1/40 samples,") and "ETA" in lines[0]
    assert lines[1] == "warning: m1 (board 2) did not settle at sample 2"
    assert lines[2].startswith("collect: 3/40 samples,")  # the last state, at the end
    assert len(lines) == 3


# -- diagnose ----------------------------------------------------------------------------

def test_diagnose_names_the_sample_minimum_not_the_seed(tmp_path, arm):
    ref = _sim(tmp_path / "ref.parquet", arm, 10, seed=1)
    real = _sim(tmp_path / "real.parquet", arm, 10, seed=1)
    code, out = _run("diagnose", real, "--reference", ref)
    line = _one_error_line(out)
    assert code == 1 and "10 samples" in line and "at least 30" in line
    assert "same seed" not in line


@pytest.fixture(scope="module")
def friction_pair(tmp_path_factory, arm) -> tuple[Path, Path]:
    from pimbs_sim.effects import parse_effect

    d = tmp_path_factory.mktemp("diag")
    return (_sim(d / "real.parquet", arm, 60, seed=3,
                 effects=(parse_effect("tendon_friction:0.15"),)),
            _sim(d / "ref.parquet", arm, 60, seed=3))


def test_diagnose_on_a_full_disk_names_the_file_and_leaves_no_truncated_png(
        tmp_path, friction_pair, monkeypatch):
    from matplotlib.figure import Figure

    real, ref = friction_pair
    plots = tmp_path / "plots"
    plots.mkdir()
    (plots / "fit_before_after.png").write_bytes(b"an earlier result")
    before = _tree(tmp_path)

    def full_disk(self, fh, **kw):
        fh.write(b"\x89PNG\r\n\x1a\n partial")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Figure, "savefig", full_disk)
    code, out = _run("diagnose", real, "--reference", ref, "--plots", plots, "--force")
    line = _one_error_line(out)
    assert code == 1 and "mismatch_by_joint.png" in line and "No space left" in line
    assert _tree(tmp_path) == before  # the earlier PNG intact, no partial or temp file


def test_diagnose_refuses_to_overwrite_its_outputs(tmp_path, friction_pair):
    real, ref = friction_pair
    (tmp_path / "d.json").write_text("{}")
    (tmp_path / "fixed.parquet").write_bytes(b"a recording")
    before = _tree(tmp_path)
    for option, name in (("--json", "d.json"), ("--corrected", "fixed.parquet")):
        code, out = _run("diagnose", real, "--reference", ref, option, tmp_path / name)
        line = _one_error_line(out)
        assert code == 1 and option in line and "--force" in line
    assert _tree(tmp_path) == before


def test_fit_figure_shows_the_improvement(tmp_path):
    """The 'with effects' bar is drawn in every panel even when it is 500× smaller, and the
    values are printed (log scale) — counted in the PNG's pixels, as a reader sees it."""
    from matplotlib.image import imread

    from pimbs_learn.diagnosis.plots import _fit_before_after

    fit = {"before": 1.0, "after": 0.002, "torque_rms_Nm": {"before": 2.2, "after": 0.0165},
           "length_rms_m": {"before": 7.1e-5, "after": 3.8e-6}}
    path = _fit_before_after(fit, "tendon_friction", tmp_path / "fit.png")
    img = imread(path)[..., :3]
    green = np.all(np.abs(img - np.array([0.173, 0.627, 0.173])) < 0.05, axis=-1)
    third = img.shape[1] // 3
    for k in range(3):
        # a visible bar: thousands of pixels (a 0.2 %-high bar on a linear axis has ~0)
        assert green[:, k * third:(k + 1) * third].sum() > 2000, k
