"""The population diagnosis benchmark refuses a wrong folder in one line, before writing, and
scores a recording on the poses it holds."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from benchmarks.population_diagnosis import StaleRecording, check_poses_match
from pimbs_arm.model import ArmModel
from pimbs_recording.format import read_recording, write_recording
from pimbs_sim.simulate import simulate

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "population_diagnosis.py"


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True,
                          timeout=120)


def test_a_folder_without_a_population_is_refused_and_nothing_is_written(tmp_path):
    out = tmp_path / "out"
    r = _run("--population", str(tmp_path / "missing"), "--split", "dev", "--out", str(out))
    assert r.returncode == 2 and "no manifest.jsonl" in r.stderr and "population.py" in r.stderr
    assert not out.exists()


def test_a_population_without_arms_of_the_split_says_which_seeds_the_split_has(tmp_path):
    (tmp_path / "manifest.jsonl").write_text('{"arm": "arm200"}\n')
    r = _run("--population", str(tmp_path), "--split", "dev", "--out", str(tmp_path / "out"))
    assert r.returncode == 2 and "no arm of the dev split (seeds 0-38)" in r.stderr


def test_a_missing_results_file_is_refused(tmp_path):
    r = _run("--summary", str(tmp_path / "none.jsonl"))
    assert r.returncode == 2 and "no such results file" in r.stderr


def test_a_recording_holding_fewer_poses_is_scored_and_a_moved_pose_is_not(tmp_path):
    """A plant that could not hold some planned poses leaves a recording with fewer rows:
    it is paired with its reference by sample id, as ``pimbs diagnose`` pairs it, and
    scored. A recording that commands a pose its seed's plan no longer draws is refused,
    naming the sample."""
    data, meta = simulate(ArmModel.load("two-link-4-muscle"), 12, "atl", seed=3)
    reference = tmp_path / "reference.parquet"
    write_recording(reference, data, meta)
    table = read_recording(reference).table
    held = tmp_path / "held.parquet"
    keep = np.ones(12, bool)
    keep[[4, 9]] = False  # two poses the plant could not hold
    write_recording(held, table.filter(pa.array(keep)), meta)
    check_poses_match(held, reference)
    moved = tmp_path / "moved.parquet"
    command = np.stack(table.column("theta_command").to_pylist())
    command[7, 0] += 0.05
    column = pa.FixedSizeListArray.from_arrays(pa.array(command.ravel()), command.shape[1])
    write_recording(moved, table.set_column(table.column_names.index("theta_command"),
                                            "theta_command", column), meta)
    with pytest.raises(StaleRecording, match="at sample 7"):
        check_poses_match(moved, reference)
