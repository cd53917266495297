"""The PIMBS recording format, version 1: one place that writes, reads and validates it.

The format (``docs/recording-format.md``) is a contract with other tools, so this module
is strict about meaning and lenient only about lossless representation: a file whose list
columns are plain ``list<double>`` of the right length, or ``float32`` values, is read;
a missing column, a wrong list length, a NaN, a null where none is allowed or a
non-increasing ``sample`` is refused with a :class:`RecordingError` naming the file, the
column and the rule. Writing always produces the exact types of the contract.

Files on disk are replaced atomically (temporary file, fsync, rename), so a crash or a full
disk never leaves a half-written recording where a valid one used to be.
"""

from __future__ import annotations

import datetime as dt
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pimbs_recording.atomic import AtomicWriteError, atomic_file

FORMAT_VERSION = 1
META_KEY = b"pimbs"
SOURCES = ("simulation", "hardware", "import")

# column -> (width: "N" joints | "M" muscles | None scalar, nullable)
JOINT_COLUMNS = ("theta", "theta_command", "tau_gravity")
MUSCLE_COLUMNS = ("tension", "length", "temperature", "approach")
REQUIRED_COLUMNS = ("sample", "time", *JOINT_COLUMNS[:2], *MUSCLE_COLUMNS, "tau_gravity")
NULLABLE_COLUMNS = frozenset({"tau_gravity"})


class RecordingError(ValueError):
    """A recording that cannot be read or breaks the format.

    The message always names the file and, where one is at fault, the column and the rule,
    so that someone can fix the file (or the tool that wrote it) without reading our code.
    """

    def __init__(self, path: str | Path | None, rule: str, column: str | None = None,
                 hint: str = "") -> None:
        self.path = None if path is None else Path(path)
        self.column = column
        self.rule = rule
        where = f"{self.path}" if self.path is not None else "<recording>"
        col = f": column '{column}'" if column else ""
        msg = f"{where}{col}: {rule}"
        if hint:
            msg += f" ({hint})"
        super().__init__(msg)


class RecordingWriteError(OSError):
    """Writing failed (disk full, permission...); the file on disk is left as it was."""


@dataclass
class Recording:
    """A validated recording: the Arrow table (extra columns kept) and its metadata."""

    table: pa.Table
    meta: dict[str, Any]
    path: Path | None = None

    @property
    def joints(self) -> list[str]:
        return list(self.meta["joints"])

    @property
    def muscles(self) -> list[str]:
        return list(self.meta["muscles"])

    @property
    def n_joints(self) -> int:
        return len(self.meta["joints"])

    @property
    def n_muscles(self) -> int:
        return len(self.meta["muscles"])

    @property
    def robot(self) -> str | None:
        return self.meta.get("robot")

    @property
    def source(self) -> str | None:
        return self.meta.get("source")

    @property
    def n_rows(self) -> int:
        return self.table.num_rows

    def array(self, column: str) -> np.ndarray:
        """A column as numpy: (rows, width) float64 for list columns, (rows,) for scalars.

        Null lists (only allowed in ``tau_gravity``) become rows of NaN.
        """
        if column not in self.table.column_names:
            raise RecordingError(self.path, "column not in this recording", column)
        return _to_numpy(self.table.column(column))

    @property
    def sample(self) -> np.ndarray:
        return self.array("sample").astype(np.int64)

    @property
    def time(self) -> np.ndarray:
        """Sample times as numpy datetime64[us] (UTC)."""
        col = self.table.column("time").cast(pa.timestamp("us", tz="UTC"))
        return col.to_numpy().astype("datetime64[us]")

    @property
    def theta(self) -> np.ndarray:
        return self.array("theta")

    @property
    def theta_command(self) -> np.ndarray:
        return self.array("theta_command")

    @property
    def tension(self) -> np.ndarray:
        return self.array("tension")

    @property
    def length(self) -> np.ndarray:
        return self.array("length")

    @property
    def temperature(self) -> np.ndarray:
        return self.array("temperature")

    @property
    def approach(self) -> np.ndarray:
        return self.array("approach").astype(np.int8)

    @property
    def tau_gravity(self) -> np.ndarray:
        """(rows, N); NaN rows where the writer had no joint model."""
        return self.array("tau_gravity")

    @property
    def extra_columns(self) -> list[str]:
        return [c for c in self.table.column_names if c not in REQUIRED_COLUMNS]


def _to_numpy(col: pa.ChunkedArray | pa.Array) -> np.ndarray:
    if isinstance(col, pa.ChunkedArray):
        col = col.combine_chunks() if col.num_chunks != 1 else col.chunk(0)
    t = col.type
    if pa.types.is_fixed_size_list(t) or pa.types.is_list(t) or pa.types.is_large_list(t):
        n = len(col)
        if n == 0:
            width = t.list_size if pa.types.is_fixed_size_list(t) else 0
            return np.zeros((0, width))
        valid = np.asarray(col.is_valid().to_numpy(zero_copy_only=False), dtype=bool)
        if pa.types.is_fixed_size_list(t):
            width = t.list_size
        else:
            lens = col.value_lengths().to_numpy(zero_copy_only=False)
            width = int(np.max(np.where(valid, lens, 0))) if valid.any() else 0
        out = np.full((n, width), np.nan)
        if valid.any():
            filled = col.filter(pa.array(valid))
            flat = filled.flatten().cast(pa.float64()).to_numpy(zero_copy_only=False)
            out[valid] = flat.reshape(-1, width)
        return out
    return col.to_numpy(zero_copy_only=False)


# ----------------------------------------------------------------------------- reading


def read_recording(path: str | Path) -> Recording:
    """Read and validate a recording; raises :class:`RecordingError` on any violation."""
    path = Path(path)
    if not path.exists():
        raise RecordingError(path, "no such file", hint="check the path")
    if path.is_dir():
        raise RecordingError(path, "is a directory, not a Parquet recording")
    table, raw_meta, writer = read_parquet(path)
    meta = _parse_meta(path, raw_meta, writer)
    table = validate_table(table, meta, path)
    return Recording(table=table, meta=meta, path=path)


def read_parquet(path: Path) -> tuple[pa.Table, dict[bytes, bytes], str]:
    """(table, key-value metadata, the writing library's name) of any Parquet file; a
    :class:`RecordingError` naming the file if it is not one."""
    try:
        pf = pq.ParquetFile(path)
        table = pf.read()
        # the Parquet footer's key-value metadata: pyarrow also copies it into the Arrow
        # schema, but polars (write_parquet(metadata=...)) writes it only to the footer
        raw_meta = {**(pf.schema_arrow.metadata or {}), **(pf.metadata.metadata or {})}
        writer = pf.metadata.created_by or ""
    except (pa.ArrowInvalid, OSError) as exc:
        raise RecordingError(
            path, f"not a readable Parquet file ({exc})",
            hint="a recording is one Apache Parquet file; was the copy truncated?") from exc
    return table, raw_meta, writer


def _parse_meta(path: Path | None, raw: Mapping[bytes, bytes],
                writer: str = "") -> dict[str, Any]:
    if META_KEY not in raw:
        raise RecordingError(path, "file metadata has no 'pimbs' key",
                             hint=_lost_meta_hint(path, raw, writer))
    try:
        meta = json.loads(raw[META_KEY])
    except (ValueError, UnicodeDecodeError) as exc:
        raise RecordingError(path, f"metadata 'pimbs' is not valid JSON ({exc})") from exc
    if not isinstance(meta, dict):
        raise RecordingError(path, "metadata 'pimbs' must be a JSON object")
    _check_meta(path, meta)
    return meta


def _lost_meta_hint(path: Path | None, raw: Mapping[bytes, bytes], writer: str) -> str:
    """How to get the metadata back: pandas and polars write Parquet without the keys of
    the file they read unless told to keep them (docs/recording-format.md)."""
    by = ("written by pandas, which drops it unless told to keep it; "
          if b"pandas" in raw else "written by polars, which drops it unless told to keep it; "
          if writer.lower().startswith("polars") else "")
    name = path if path is not None else "FILE"
    return (f"{by}restore it from the recording these rows came from with `pimbs info {name} "
            "--adopt-metadata ORIGINAL.parquet`; docs/recording-format.md shows how to keep "
            "it when writing from pandas or polars")


def _check_meta(path: Path | None, meta: Mapping[str, Any]) -> None:
    for key in ("format", "joints", "muscles"):
        if key not in meta:
            raise RecordingError(path, f"metadata 'pimbs' lacks required key '{key}'")
    if meta["format"] != FORMAT_VERSION or isinstance(meta["format"], bool):
        raise RecordingError(path, f"metadata format is {meta['format']!r}; this PIMBS reads "
                                   f"format {FORMAT_VERSION}")
    for key in ("joints", "muscles"):
        names = meta[key]
        if (not isinstance(names, list) or not names
                or not all(isinstance(n, str) and n for n in names)):
            raise RecordingError(path, f"metadata '{key}' must be a non-empty list of names")
        if len(set(names)) != len(names):
            raise RecordingError(path, f"metadata '{key}' has duplicate names")
    if "source" in meta and meta["source"] not in SOURCES:
        raise RecordingError(path, f"metadata source {meta['source']!r} is not one of "
                                   f"{', '.join(SOURCES)}")


def validate_table(table: pa.Table, meta: Mapping[str, Any],
                   path: Path | None = None) -> pa.Table:
    """Check a table against the format; return it with required columns in exact types."""
    n_joints, n_muscles = len(meta["joints"]), len(meta["muscles"])
    names = table.column_names
    for col in REQUIRED_COLUMNS:
        if col not in names:
            raise RecordingError(path, "required column is missing", col)
    if len(set(names)) != len(names):
        raise RecordingError(path, "duplicate column names")

    sample = table.column("sample")
    if not pa.types.is_integer(sample.type):
        raise RecordingError(path, f"must be int64, found {sample.type}", "sample")
    if sample.null_count:
        raise RecordingError(path, "must not contain nulls", "sample")
    s = sample.to_numpy().astype(np.int64)
    if s.size and (s[0] < 0 or np.any(np.diff(s) <= 0)):
        bad = int(np.argmax(np.diff(s) <= 0)) + 1 if s.size > 1 and np.any(np.diff(s) <= 0) else 0
        raise RecordingError(path, f"must be non-negative and strictly increasing "
                                   f"(row {bad}: {s[bad]})", "sample")

    time = table.column("time")
    if not pa.types.is_timestamp(time.type):
        raise RecordingError(path, f"must be timestamp[us, tz=UTC], found {time.type}", "time")
    if time.type.tz not in (None, "UTC", "utc", "Etc/UTC", "+00:00"):
        raise RecordingError(path, f"timestamps must be in UTC, found tz={time.type.tz}", "time")
    if time.null_count:
        raise RecordingError(path, "must not contain nulls", "time")

    columns: dict[str, pa.Array] = {
        "sample": sample.cast(pa.int64()),
        "time": time.cast(pa.timestamp("us", tz="UTC")),
    }
    for col in REQUIRED_COLUMNS[2:]:
        width = n_joints if col in JOINT_COLUMNS else n_muscles
        columns[col] = _validated_list(table.column(col), col, width, path,
                                       int8=(col == "approach"))
    fixed = [columns[c] if c in columns else table.column(c) for c in names]
    return pa.table(dict(zip(names, fixed, strict=True)))


def _validated_list(col: pa.ChunkedArray, name: str, width: int, path: Path | None,
                    int8: bool = False) -> pa.ChunkedArray:
    t = col.type
    if not (pa.types.is_fixed_size_list(t) or pa.types.is_list(t) or pa.types.is_large_list(t)):
        raise RecordingError(path, f"must be fixed_size_list<{'int8' if int8 else 'float64'}>"
                                   f"[{width}], found {t}", name)
    vt = t.value_type
    if not (pa.types.is_floating(vt) or pa.types.is_integer(vt)):
        raise RecordingError(path, f"list values must be numbers, found {vt}", name)
    nullable = name in NULLABLE_COLUMNS
    if col.null_count and not nullable:
        raise RecordingError(path, "must not contain null rows", name)
    arr = col.combine_chunks() if col.num_chunks != 1 else col.chunk(0)
    if pa.types.is_fixed_size_list(t):
        if t.list_size != width:
            raise RecordingError(path, f"lists have length {t.list_size}, expected {width} "
                                       f"(len of metadata "
                                       f"{'joints' if name in JOINT_COLUMNS else 'muscles'})",
                                 name)
    else:
        lens = arr.value_lengths().to_numpy(zero_copy_only=False)
        valid = arr.is_valid().to_numpy(zero_copy_only=False)
        bad = np.flatnonzero(valid & (lens != width))
        if bad.size:
            raise RecordingError(path, f"row {int(bad[0])} has a list of length "
                                       f"{int(lens[bad[0]])}, expected {width}", name)
    values = arr.filter(arr.is_valid()).flatten() if arr.null_count else arr.flatten()
    if values.null_count:
        raise RecordingError(path, "lists must not contain null values", name)
    v = values.cast(pa.float64()).to_numpy(zero_copy_only=False)
    if not np.all(np.isfinite(v)):
        raise RecordingError(path, "contains NaN or infinite values", name)
    if int8:
        if np.any((v != -1) & (v != 0) & (v != 1)):
            raise RecordingError(path, "values must be -1, 0 or +1", name)
        target = pa.list_(pa.int8(), width)
    else:
        target = pa.list_(pa.float64(), width)
    return pa.chunked_array([_as_fixed_list(arr, target, width)], type=target)


def _as_fixed_list(arr: pa.Array, target: pa.DataType, width: int) -> pa.Array:
    """Cast a (possibly variable) list array to the exact fixed-size list type."""
    value_type = target.value_type
    valid = arr.is_valid()
    flat = arr.fill_null([0] * width) if arr.null_count else arr
    values = flat.flatten().cast(value_type)
    return pa.FixedSizeListArray.from_arrays(values, width, mask=pa.compute.invert(valid))


# ----------------------------------------------------------------------------- writing


def make_meta(joints: list[str], muscles: list[str], source: str, robot: str | None = None,
              **extra: Any) -> dict[str, Any]:
    """The ``pimbs`` metadata object with required keys first, extra keys preserved."""
    meta: dict[str, Any] = {"format": FORMAT_VERSION, "robot": robot, "joints": list(joints),
                            "muscles": list(muscles), "source": source,
                            "created": dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")}
    if robot is None:
        del meta["robot"]
    meta.update(extra)
    return meta


def build_table(data: Mapping[str, Any], meta: Mapping[str, Any]) -> pa.Table:
    """Build a format-exact table from numpy arrays (or Arrow arrays); extra keys become
    extra columns as they are."""
    _check_meta(None, meta)
    n_joints, n_muscles = len(meta["joints"]), len(meta["muscles"])
    cols: dict[str, pa.Array] = {}
    for name in REQUIRED_COLUMNS:
        if name not in data:
            raise RecordingError(None, "required column is missing", name)
    cols["sample"] = pa.array(np.asarray(data["sample"], dtype=np.int64), type=pa.int64())
    cols["time"] = _time_array(data["time"])
    for name in REQUIRED_COLUMNS[2:]:
        width = n_joints if name in JOINT_COLUMNS else n_muscles
        cols[name] = _list_array(data[name], width, name)
    for name, value in data.items():
        if name not in cols:
            cols[name] = value if isinstance(value, pa.Array | pa.ChunkedArray) else pa.array(
                list(value) if isinstance(value, np.ndarray) and value.ndim > 1 else value)
    table = pa.table(cols)
    return table.replace_schema_metadata({META_KEY: json.dumps(dict(meta)).encode()})


def _time_array(value: Any) -> pa.Array:
    if isinstance(value, pa.Array | pa.ChunkedArray):
        return value.cast(pa.timestamp("us", tz="UTC"))
    arr = np.asarray(value)
    if np.issubdtype(arr.dtype, np.datetime64):
        arr = arr.astype("datetime64[us]").astype(np.int64)
    elif arr.dtype == object:
        arr = np.array([int(t.timestamp() * 1e6) for t in arr], dtype=np.int64)
    else:  # seconds since the epoch
        arr = np.round(arr.astype(np.float64) * 1e6).astype(np.int64)
    return pa.array(arr, type=pa.timestamp("us", tz="UTC"))


def _list_array(value: Any, width: int, name: str) -> pa.Array:
    if isinstance(value, pa.Array | pa.ChunkedArray):
        return value
    int8 = name == "approach"
    dtype = np.int8 if int8 else np.float64
    if name in NULLABLE_COLUMNS:
        rows = np.asarray(value, dtype=np.float64).reshape(-1, width)
        missing = np.all(np.isnan(rows), axis=1)
        flat = pa.array(np.nan_to_num(rows).ravel(), type=pa.float64())
        return pa.FixedSizeListArray.from_arrays(flat, width, mask=pa.array(missing))
    rows = np.asarray(value, dtype=dtype).reshape(-1, width)
    return pa.FixedSizeListArray.from_arrays(pa.array(rows.ravel()), width)


def write_recording(path: str | Path, data: Mapping[str, Any] | pa.Table,
                    meta: Mapping[str, Any]) -> None:
    """Validate and write a recording atomically (a reader never sees a partial file)."""
    table = data if isinstance(data, pa.Table) else build_table(data, meta)
    table = validate_table(table, meta, Path(path))
    table = table.replace_schema_metadata({META_KEY: json.dumps(dict(meta)).encode()})
    _atomic_write(table, Path(path))


def _atomic_write(table: pa.Table, path: Path) -> None:
    try:
        with atomic_file(path) as fh:
            pq.write_table(table, fh, compression="zstd")
    except AtomicWriteError as exc:
        # what to do next depends on the command (collect resumes, simulate reruns)
        raise RecordingWriteError(
            exc.errno, f"could not write {path}: {exc.reason}; the recording already on "
                       "disk is unchanged") from exc.__cause__


class RecordingWriter:
    """Append samples one at a time; after every append the file is a valid recording.

    Each append rewrites the whole (small) file atomically. For the few thousand samples a
    body-schema collection takes this costs milliseconds, and in exchange a ``kill -9``,
    power cut or full disk loses at most the sample in progress.
    """

    def __init__(self, path: str | Path, meta: Mapping[str, Any], resume: bool = False) -> None:
        self.path = Path(path)
        self.meta = dict(meta)
        self._table: pa.Table | None = None
        if resume and self.path.exists():
            existing = read_recording(self.path)
            for key in ("joints", "muscles"):
                if existing.meta[key] != self.meta[key]:
                    raise RecordingError(self.path, f"cannot resume: recorded {key} "
                                                    f"{existing.meta[key]} differ from "
                                                    f"{self.meta[key]}")
            self.meta = {**self.meta, **existing.meta}
            self._table = existing.table
        elif self.path.exists():
            raise RecordingError(self.path, "file exists",
                                 hint="use --resume to continue it or choose another --out")

    @property
    def n_rows(self) -> int:
        return 0 if self._table is None else self._table.num_rows

    @property
    def recording(self) -> Recording | None:
        if self._table is None:
            return None
        return Recording(self._table, self.meta, self.path)

    def append(self, row: Mapping[str, Any]) -> None:
        """Add one sample (values for one row, lists as 1-D arrays) and persist it."""
        data = {k: (np.asarray(v)[None] if k in REQUIRED_COLUMNS[2:] else [v])
                for k, v in row.items()}
        new = build_table(data, self.meta)
        table = new if self._table is None else pa.concat_tables(
            [self._table.replace_schema_metadata(None), new.replace_schema_metadata(None)]
        ).combine_chunks()  # one chunk: writing 1000 one-row chunks costs 10x more
        table = table.replace_schema_metadata({META_KEY: json.dumps(self.meta).encode()})
        _atomic_write(table, self.path)
        self._table = table

    def update_meta(self, **keys: Any) -> None:
        """Change metadata (e.g. a summary at the end) and persist it."""
        self.meta.update(keys)
        if self._table is not None:
            self._table = self._table.replace_schema_metadata(
                {META_KEY: json.dumps(self.meta).encode()})
            _atomic_write(self._table, self.path)
