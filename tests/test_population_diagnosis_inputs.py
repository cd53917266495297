"""The population diagnosis benchmark refuses a wrong folder in one line, before writing."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

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
