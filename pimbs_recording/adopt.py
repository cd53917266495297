"""Giving a file back the metadata it lost: ``pimbs info FILE --adopt-metadata FROM``.

pandas (``df.to_parquet``) and polars (``write_parquet``) write a new Parquet file without the
key-value metadata of the file they read, so a recording filtered or edited there comes back
without its ``pimbs`` key, and every command refuses it: without ``joints`` and ``muscles``
nobody can tell which list element is which joint. The recording the rows came from still has
the key; this copies it over, after checking that it fits the file (required columns, list
widths, values), and rewrites the file atomically with the contract's exact column types.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pimbs_recording.format import (
    META_KEY,
    Recording,
    RecordingError,
    read_parquet,
    read_recording,
    validate_table,
    write_recording,
)

ADOPTED_KEY = "metadata_adopted_from"  # file name of FROM, so the history stays visible


def adopt_metadata(path: str | Path, source: str | Path, *, force: bool = False) -> Recording:
    """Write ``source``'s ``pimbs`` metadata into ``path`` and return the recording it makes.

    Refused, with ``path`` unchanged, when ``path`` already has ``pimbs`` metadata (unless
    ``force``), when ``source`` is not a valid recording, or when the metadata does not fit
    ``path``'s columns (another robot, a dropped column, a list of another width)."""
    path, source = Path(path), Path(source)
    origin = read_recording(source)
    if not path.is_file():
        raise RecordingError(path, "no such file", hint="check the path")
    table, raw, _ = read_parquet(path)
    if META_KEY in raw and not force:
        raise RecordingError(path, "already has 'pimbs' metadata",
                             hint=f"pass --force to replace it with that of {source}")
    meta: dict[str, Any] = {**origin.meta, ADOPTED_KEY: source.name}
    try:
        validate_table(table, meta, path)
    except RecordingError as exc:
        raise RecordingError(
            path, f"cannot take the metadata of {source}: {exc.rule}", exc.column,
            hint=f"{source} has joints {origin.joints} and muscles {origin.muscles}; adopt the "
                 "metadata of the recording these rows came from, and keep its required "
                 "columns and its sample order") from None
    write_recording(path, table, meta)
    return read_recording(path)
