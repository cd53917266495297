"""Recordings edited in pandas, polars or plain pyarrow: a file that lost the `pimbs` key is
refused with the way to restore it, `pimbs info FILE --adopt-metadata FROM` restores it (and
refuses metadata that does not fit, leaving the file as it was), and the examples in
docs/recording-format.md keep the key (run here as written, where pandas or polars is
installed)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from pimbs_cli.main import main
from pimbs_recording.format import make_meta, read_recording, write_recording

DOC = Path(__file__).resolve().parents[1] / "docs" / "recording-format.md"
JOINTS, MUSCLES = ["shoulder_pitch", "elbow_pitch"], ["m0", "m1", "m2", "m3"]


def _recording(path: Path, n: int = 12, joints=JOINTS, muscles=MUSCLES) -> None:
    rng = np.random.default_rng(4)
    N, M = len(joints), len(muscles)
    data = {"sample": np.arange(n),
            "time": np.datetime64("2026-01-01T09:00:00", "us") + np.arange(n) * 1_000_000,
            "theta": rng.uniform(-0.5, 0.5, (n, N)), "theta_command": rng.uniform(-.5, .5, (n, N)),
            "tension": rng.uniform(10, 300, (n, M)), "length": rng.normal(0, 0.01, (n, M)),
            "temperature": rng.uniform(25, 30, (n, M)),
            "approach": rng.integers(-1, 2, (n, M)).astype(np.int8),
            "tau_gravity": rng.normal(0, 1, (n, N)), "settle_s": rng.uniform(0.1, 1, n)}
    write_recording(path, data, make_meta(joints, muscles, "simulation", robot="test-arm",
                                          seed=3, samples=n))


def _info(*args: str):
    return CliRunner().invoke(main, ["info", *map(str, args)])


def _one_error(res) -> str:
    assert res.exit_code == 1, res.output
    assert isinstance(res.exception, SystemExit), repr(res.exception)  # no escaped exception
    assert "Traceback" not in res.output
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), res.output
    return lines[0]


def _stripped_filter(src: Path, dst: Path) -> pa.Table:
    """What any tool that rebuilds the table does: rows filtered, schema metadata gone."""
    table = pq.read_table(src)
    part = table.filter(pa.compute.less(table["sample"], 8))
    part = pa.table({name: part[name] for name in part.column_names})  # no metadata
    assert part.schema.metadata is None
    pq.write_table(part, dst)
    return part


def test_a_file_without_the_key_says_how_to_restore_it(tmp_path):
    rec = tmp_path / "rec.parquet"
    _recording(rec)
    part = tmp_path / "part.parquet"
    _stripped_filter(rec, part)
    before = part.read_bytes()
    line = _one_error(_info(part))
    assert f"{part}: file metadata has no 'pimbs' key" in line
    assert f"pimbs info {part} --adopt-metadata ORIGINAL.parquet" in line
    assert "docs/recording-format.md" in line
    assert part.read_bytes() == before


def test_adopt_metadata_restores_a_filtered_file(tmp_path):
    rec = tmp_path / "rec.parquet"
    _recording(rec)
    part = tmp_path / "part.parquet"
    stripped = _stripped_filter(rec, part)
    res = _info(part, "--adopt-metadata", rec)
    assert res.exit_code == 0, res.output
    assert f"adopted the metadata of {rec} into {part}" in res.output
    assert "rows     8" in res.output
    restored, original = read_recording(part), read_recording(rec)
    assert restored.meta == {**original.meta, "metadata_adopted_from": "rec.parquet"}
    assert restored.table.schema.equals(original.table.schema)  # the contract's exact types
    for column in stripped.column_names:  # every value kept, the extra column too
        assert restored.table[column].to_pylist() == stripped[column].to_pylist()
    assert not list(tmp_path.glob("*.tmp*")) and sorted(p.name for p in tmp_path.iterdir()) == [
        "part.parquet", "rec.parquet"]


@pytest.mark.parametrize("case", ["other robot", "rows sorted", "not a recording",
                                  "already has it"])
def test_adopt_refusals_leave_the_file_as_it_was(tmp_path, case):
    rec = tmp_path / "rec.parquet"
    _recording(rec)
    part = tmp_path / "part.parquet"
    _stripped_filter(rec, part)
    if case == "other robot":
        source = tmp_path / "five.parquet"
        _recording(source, joints=["a", "b", "c", "d", "e"], muscles=MUSCLES)
        expect = [f"{part}: column 'theta': cannot take the metadata of {source}: lists have "
                  "length 2, expected 5", "adopt the metadata of the recording these rows "
                  "came from"]
    elif case == "rows sorted":
        table = pq.read_table(part)
        pq.write_table(table.sort_by([("settle_s", "ascending")]), part)  # meta dropped
        source = rec
        expect = [f"{part}: column 'sample': cannot take the metadata of {source}: must be "
                  "non-negative and strictly increasing", "keep its required columns and its "
                  "sample order"]
    elif case == "not a recording":
        source = tmp_path / "stripped_too.parquet"
        _stripped_filter(rec, source)
        expect = [f"{source}: file metadata has no 'pimbs' key"]
    else:
        _info(part, "--adopt-metadata", rec)
        source = rec
        expect = [f"{part}: already has 'pimbs' metadata", "--force"]
    before = part.read_bytes()
    line = _one_error(_info(part, "--adopt-metadata", source))
    for text in expect:
        assert text in line
    assert part.read_bytes() == before
    if case == "already has it":
        assert _info(part, "--adopt-metadata", source, "--force").exit_code == 0


# --- the documented pandas and polars examples, run as written ---------------------------

def _doc_example(marker: str) -> str:
    blocks = re.findall(r"```python\n(.*?)```", DOC.read_text(), flags=re.S)
    (code,) = [b for b in blocks if b.startswith(f"# {marker}")]
    return code


def _run_example(tmp_path: Path, monkeypatch, marker: str) -> Path:
    """Runs the example in ``tmp_path``, which holds ``rec.parquet``."""
    monkeypatch.chdir(tmp_path)
    exec(compile(_doc_example(marker), f"{DOC.name}: {marker}", "exec"), {})
    return tmp_path / "part.parquet"


def test_pandas_drops_the_key_and_the_documented_examples_keep_it(tmp_path, monkeypatch):
    pd = pytest.importorskip("pandas")
    rec = tmp_path / "rec.parquet"
    _recording(rec, n=600)
    plain = tmp_path / "plain.parquet"
    df = pd.read_parquet(rec)
    df[df["sample"] < 500].to_parquet(plain)
    assert "written by pandas" in _one_error(_info(plain))
    part = _run_example(tmp_path, monkeypatch, "pandas: schema=")
    got, original = read_recording(part), read_recording(rec)
    assert got.meta == original.meta and got.n_rows == 500
    np.testing.assert_array_equal(got.tension, original.tension[:500])
    part.unlink()
    part = _run_example(tmp_path, monkeypatch, "pandas with a new column")
    got = read_recording(part)
    assert got.meta == original.meta and got.array("operator").tolist() == ["ab"] * 600
    assert _info(plain, "--adopt-metadata", rec).exit_code == 0
    assert read_recording(plain).n_rows == 500


def test_polars_drops_the_key_and_the_documented_example_keeps_it(tmp_path, monkeypatch):
    pl = pytest.importorskip("polars")
    rec = tmp_path / "rec.parquet"
    _recording(rec, n=600)
    plain = tmp_path / "plain.parquet"
    pl.read_parquet(rec).filter(pl.col("sample") < 500).write_parquet(plain)
    assert "written by polars" in _one_error(_info(plain))
    part = _run_example(tmp_path, monkeypatch, "polars:")
    got, original = read_recording(part), read_recording(rec)
    assert got.meta == original.meta and got.n_rows == 500
    np.testing.assert_array_equal(got.theta, original.theta[:500])
    assert _info(plain, "--adopt-metadata", rec).exit_code == 0
