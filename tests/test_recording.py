"""Recording format v1: round trip, crash-safe appends, and one test per kind of bad file."""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pimbs_recording.format import (
    META_KEY,
    RecordingError,
    RecordingWriter,
    make_meta,
    read_recording,
    write_recording,
)

N, M, ROWS = 2, 3, 6


def _data(rows: int = ROWS) -> dict:
    rng = np.random.default_rng(0)
    return {
        "sample": np.arange(rows),
        "time": 1.7e9 + np.arange(rows) * 2.5,
        "theta": rng.uniform(-0.5, 0.5, (rows, N)),
        "theta_command": rng.uniform(-0.5, 0.5, (rows, N)),
        "tension": rng.uniform(0, 300, (rows, M)),
        "length": rng.normal(0, 0.01, (rows, M)),
        "temperature": rng.uniform(25, 40, (rows, M)),
        "approach": rng.integers(-1, 2, (rows, M)),
        "tau_gravity": rng.normal(0, 1, (rows, N)),
    }


def _meta() -> dict:
    return make_meta(["j0", "j1"], ["m0", "m1", "m2"], "simulation", robot="toy", seed=7,
                     notes={"who": "test"})


def _good(tmp_path):
    path = tmp_path / "good.parquet"
    write_recording(path, _data(), _meta())
    return path


def test_round_trip_exact_types_values_and_metadata(tmp_path):
    data = _data()
    data["tau_gravity"][2] = np.nan  # nullable: a row without a joint model
    data["operator"] = np.array(["kim"] * ROWS)
    path = tmp_path / "r.parquet"
    write_recording(path, data, _meta())
    schema = pq.read_schema(path)
    assert schema.field("theta").type == pa.list_(pa.float64(), N)
    assert schema.field("approach").type == pa.list_(pa.int8(), M)
    assert schema.field("time").type == pa.timestamp("us", tz="UTC")
    rec = read_recording(path)
    for col in ("theta", "theta_command", "tension", "length", "temperature"):
        np.testing.assert_array_equal(rec.array(col), data[col])
    np.testing.assert_array_equal(rec.approach, data["approach"])
    assert np.isnan(rec.tau_gravity[2]).all() and rec.table.column("tau_gravity").null_count == 1
    assert rec.extra_columns == ["operator"]
    assert rec.meta["seed"] == 7 and rec.meta["notes"] == {"who": "test"}
    assert (rec.joints, rec.muscles, rec.n_rows) == (["j0", "j1"], ["m0", "m1", "m2"], ROWS)


def test_rewrite_preserves_extra_columns_and_metadata(tmp_path):
    src = tmp_path / "a.parquet"
    data = _data()
    data["lab_note"] = np.arange(ROWS) * 10
    write_recording(src, data, _meta())
    rec = read_recording(src)
    dst = tmp_path / "b.parquet"
    write_recording(dst, rec.table, rec.meta)
    again = read_recording(dst)
    assert again.table.equals(rec.table) and again.meta == rec.meta


def test_other_tool_plain_lists_and_float32_are_accepted(tmp_path):
    """A pandas-style writer uses list<float> rather than fixed_size_list: same meaning."""
    d = _data()
    cols = {"sample": pa.array(d["sample"], pa.int32()),
            "time": pa.array((d["time"] * 1e3).astype(np.int64), pa.timestamp("ms", tz="UTC"))}
    for c in ("theta", "theta_command", "tension", "length", "temperature", "tau_gravity"):
        cols[c] = pa.array([list(r) for r in d[c].astype(np.float32)], pa.list_(pa.float32()))
    cols["approach"] = pa.array([list(r) for r in d["approach"]], pa.list_(pa.int64()))
    table = pa.table(cols).replace_schema_metadata(
        {META_KEY: json.dumps({"format": 1, "joints": ["j0", "j1"],
                               "muscles": ["m0", "m1", "m2"]}).encode()})
    path = tmp_path / "other.parquet"
    pq.write_table(table, path)
    rec = read_recording(path)
    np.testing.assert_allclose(rec.tension, d["tension"], rtol=1e-6)
    assert rec.table.schema.field("theta").type == pa.list_(pa.float64(), N)


def test_writer_file_is_valid_after_every_append_and_resumes(tmp_path):
    path = tmp_path / "w.parquet"
    d = _data()
    writer = RecordingWriter(path, _meta())
    for i in range(3):
        writer.append({k: v[i] for k, v in d.items()})
        assert read_recording(path).n_rows == i + 1
    with pytest.raises(RecordingError, match="--resume"):
        RecordingWriter(path, _meta())
    resumed = RecordingWriter(path, _meta(), resume=True)
    assert resumed.n_rows == 3
    for i in range(3, ROWS):
        resumed.append({k: v[i] for k, v in d.items()})
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.tension, d["tension"])
    assert not list(tmp_path.glob("*.tmp"))


def test_writer_refuses_resume_of_other_arm(tmp_path):
    path = tmp_path / "w.parquet"
    RecordingWriter(path, _meta()).append({k: v[0] for k, v in _data().items()})
    other = make_meta(["j0", "j1"], ["a", "b", "c"], "hardware")
    with pytest.raises(RecordingError, match="muscles"):
        RecordingWriter(path, other, resume=True)


def _rewrite(path, out, mutate_table=None, meta=None):
    table = pq.read_table(path)
    raw = json.loads(table.schema.metadata[META_KEY])
    if mutate_table:
        table = mutate_table(table)
    md = {META_KEY: json.dumps(meta(raw) if meta else raw).encode()} if meta is not False else {}
    pq.write_table(table.replace_schema_metadata(md), out)
    return out


def _set(table, name, array):
    return table.set_column(table.column_names.index(name), name, array)


BAD_FILES = {
    "missing column": (lambda t: t.drop_columns(["length"]), None, "length", "missing"),
    "wrong list length": (lambda t: _set(t, "tension", pa.array(
        [[1.0, 2.0]] * ROWS, pa.list_(pa.float64(), 2))), None, "tension", "length 2"),
    "ragged list": (lambda t: _set(t, "theta", pa.array(
        [[0.0, 0.0]] * (ROWS - 1) + [[0.0]], pa.list_(pa.float64()))), None, "theta", "row 5"),
    "nan": (lambda t: _set(t, "length", pa.array(
        [[0.0, np.nan, 0.0]] * ROWS, pa.list_(pa.float64(), M))), None, "length", "NaN"),
    "inf": (lambda t: _set(t, "tau_gravity", pa.array(
        [[np.inf, 0.0]] * ROWS, pa.list_(pa.float64(), N))), None, "tau_gravity", "infinite"),
    "non-increasing sample": (lambda t: _set(t, "sample", pa.array(
        [0, 1, 2, 2, 3, 4], pa.int64())), None, "sample", "strictly increasing"),
    "null in required": (lambda t: _set(t, "tension", pa.array(
        [None] + [[1.0, 1.0, 1.0]] * (ROWS - 1), pa.list_(pa.float64(), M))), None, "tension",
        "null"),
    "string time": (lambda t: _set(t, "time", pa.array(["x"] * ROWS)), None, "time", "timestamp"),
    "bad approach": (lambda t: _set(t, "approach", pa.array(
        [[2, 0, 0]] * ROWS, pa.list_(pa.int8(), M))), None, "approach", "-1, 0 or +1"),
    "joints mismatch": (None, lambda m: {**m, "joints": ["a", "b", "c"]}, "theta", "expected 3"),
    "no format": (None, lambda m: {k: v for k, v in m.items() if k != "format"}, None, "format"),
    "bad source": (None, lambda m: {**m, "source": "dream"}, None, "source"),
    "wrong version": (None, lambda m: {**m, "format": 2}, None, "format"),
}


@pytest.mark.parametrize("kind", sorted(BAD_FILES))
def test_malformed_file_is_refused_naming_file_column_and_rule(tmp_path, kind):
    mutate, meta, column, rule = BAD_FILES[kind]
    bad = _rewrite(_good(tmp_path), tmp_path / "bad.parquet", mutate, meta)
    with pytest.raises(RecordingError) as err:
        read_recording(bad)
    msg = str(err.value)
    assert "bad.parquet" in msg and rule in msg
    if column:
        assert f"'{column}'" in msg and err.value.column == column


def test_missing_metadata_and_non_parquet_are_refused(tmp_path):
    no_meta = _rewrite(_good(tmp_path), tmp_path / "nometa.parquet", meta=False)
    with pytest.raises(RecordingError, match="no 'pimbs' key"):
        read_recording(no_meta)
    junk = tmp_path / "junk.parquet"
    junk.write_bytes(b"not parquet at all")
    with pytest.raises(RecordingError, match="junk.parquet.*Parquet"):
        read_recording(junk)
    with pytest.raises(RecordingError, match="no such file"):
        read_recording(tmp_path / "absent.parquet")
