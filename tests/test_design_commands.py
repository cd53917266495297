"""The command lines the design shows run as written (only a small --epochs added)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pimbs_cli.main import main


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file()}


@pytest.fixture
def data(tmp_path, monkeypatch) -> Path:
    """`data.parquet` in the working directory: a simulated recording of 30 samples."""
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(main, ["simulate", "--samples", "30", "--out", "data.parquet"])
    assert res.exit_code == 0, res.output
    return tmp_path / "data.parquet"


def test_train_data_alpha_as_the_design_writes_it(data) -> None:
    """`pimbs train data.parquet --alpha 1e-7`: a seeded 80/20 split, its rows named."""
    runner = CliRunner()
    before = _files(data.parent)
    runs = [runner.invoke(main, ["train", "data.parquet", "--alpha", "1e-7", "--epochs", "2"])
            for _ in range(2)]
    assert _files(data.parent) == before  # no --out: the recording untouched, nothing saved
    for res in runs:
        assert res.exit_code == 0, res.output
    line = [x for x in runs[0].output.splitlines() if x.startswith("note: no --n-train")]
    assert len(line) == 1, runs[0].output
    assert "training on 24 of 30 rows" in line[0] and "evaluating on the other 6" in line[0]
    named = re.search(r"rows ([\d, ]+) \(0-based\)", line[0])
    assert named, line[0]
    rows = [int(r) for r in named.group(1).split(",")]
    # the rows named are those the seeded draw leaves out of training: checkable by anyone
    assert rows == sorted(np.random.default_rng(0).permutation(30)[24:].tolist())
    assert "24 training / 6 evaluation samples" in runs[0].output
    # reproducible: the same split and the same result the second time
    assert line[0] in runs[1].output.splitlines()
    metrics = [json.loads(r.output.strip().splitlines()[-1]) for r in runs]
    assert metrics[0]["eval_loss"] == metrics[1]["eval_loss"]
    # another --seed draws other rows
    other = runner.invoke(main, ["train", "data.parquet", "--alpha", "1e-7", "--epochs", "1",
                                 "--seed", "1"])
    assert other.exit_code == 0 and line[0] not in other.output.splitlines(), other.output


@pytest.mark.skipif(Path("/sys/class/net/can0").exists(), reason="this machine has a can0")
def test_collect_on_can0_without_can0_says_how_to_bring_it_up(tmp_path, monkeypatch) -> None:
    """`pimbs collect --port can0 --samples 496` where there is no can0: one line, no file."""
    monkeypatch.chdir(tmp_path)
    before = _files(tmp_path)
    res = CliRunner().invoke(main, ["collect", "--port", "can0", "--samples", "496"])
    assert res.exit_code == 1, res.output
    assert res.output.count("\n") == 1 and res.output.startswith("Error: "), res.output
    assert "'can0'" in res.output
    assert "`sudo ip link set can0 up type can bitrate 1000000`" in res.output
    assert "--port slcan:" in res.output and "--port virtual" in res.output
    assert _files(tmp_path) == before  # no recording started, nothing written
