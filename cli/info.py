"""`pimbs info FILE`: a short summary of any valid recording; a clean refusal otherwise."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from pimbs_cli.common import USER_ERRORS, user_errors


def _range(values: np.ndarray) -> str:
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return "—"
    return f"{finite.min():.4g} … {finite.max():.4g}"


def summary(path: Path) -> str:
    """Human-readable summary of a recording (raises RecordingError if invalid)."""
    from pimbs_recording.format import read_recording

    rec = read_recording(path)
    t = rec.time
    lines = [
        f"{path}",
        f"  robot    {rec.robot or '(not named)'}   source {rec.source or '(not given)'}   "
        f"format {rec.meta['format']}",
        f"  rows     {rec.n_rows}   samples {int(rec.sample[0]) if rec.n_rows else '-'}"
        f"…{int(rec.sample[-1]) if rec.n_rows else '-'}",
    ]
    if rec.n_rows:
        span = (t[-1] - t[0]).astype("timedelta64[ms]").astype(float) / 1e3
        lines.append(f"  time     {t[0]} … {t[-1]} UTC ({span:.1f} s)")
    lines.append(f"  joints   {rec.n_joints}: {', '.join(rec.joints)}")
    lines.append(f"  muscles  {rec.n_muscles}: {', '.join(rec.muscles)}")
    if rec.n_rows:
        tau = rec.tau_gravity
        missing = int(np.isnan(tau).all(axis=1).sum())
        lines += [
            f"  theta        [rad]  {_range(rec.theta)}",
            f"  tension      [N]    {_range(rec.tension)}",
            f"  length       [m]    {_range(rec.length)}",
            f"  temperature  [°C]   {_range(rec.temperature)}",
            f"  tau_gravity  [N·m]  {_range(tau)}"
            + (f"   ({missing} rows without)" if missing else ""),
        ]
        lines += pose_accuracy(rec)
    if rec.extra_columns:
        lines.append(f"  extra columns: {', '.join(rec.extra_columns)}")
    other = sorted(k for k in rec.meta if k not in ("format", "robot", "joints", "muscles",
                                                     "source"))
    if other:
        lines.append(f"  metadata: {', '.join(other)}")
    return "\n".join(lines)


def pose_accuracy(rec) -> list[str]:
    """rms of θ − θ_command per joint in degrees: how well the commands reach their poses.

    Only meaningful where θ is measured (joint encoders); otherwise θ is itself a model
    estimate, which the line says. A log has no commands: its ``theta_command`` is the
    measured pose itself, and an accuracy of 0° would be a claim nobody measured.
    """
    if rec.source == "import" or "theta_command" in rec.meta:
        note = rec.meta.get("theta_command")
        why = f"theta_command holds {note}" if note else "an imported log records no commands"
        return [f"  pose accuracy  none: no commanded poses ({why})"]
    err = rec.theta - rec.theta_command
    ok = np.isfinite(err).all(axis=1)
    if not ok.any():
        return []
    rms = np.degrees(np.sqrt(np.mean(err[ok] ** 2, axis=0)))
    per_joint = ", ".join(f"{j} {r:.3g}°" for j, r in zip(rec.joints, rms, strict=True))
    source = rec.meta.get("theta_source")
    note = "   (θ estimated by the model, not measured)" if source == "model" else ""
    schema = rec.meta.get("schema")
    by = ""
    if schema:
        kinds, counts = np.unique(np.asarray(rec.array("commanded_by"), str), return_counts=True)
        split = ", ".join(f"{c} {k}" for k, c in zip(kinds, counts, strict=True))
        by = f"   [commanded with body schema {schema}: {split}]"
    return [f"  pose accuracy rms(θ − θ_command)  {per_joint}{by}{note}"]


@click.command("info")
@click.argument("files", nargs=-1, required=True,
                type=click.Path(dir_okay=False, path_type=Path))
@click.option("--adopt-metadata", "source", metavar="FROM",
              type=click.Path(dir_okay=False, path_type=Path),
              help="give FILE the 'pimbs' metadata of the recording FROM (for a file that "
                   "pandas or polars wrote without it): checked against FILE's columns, then "
                   "FILE is rewritten atomically")
@click.option("--force", is_flag=True,
              help="with --adopt-metadata: replace the 'pimbs' metadata FILE already has")
@user_errors
def command(files: tuple[Path, ...], source: Path | None, force: bool) -> None:
    """Summarise recordings (robot, joints, muscles, rows, source, value ranges).

    Every valid FILE is summarised; each one that is not is refused in one line, and the
    exit status is then 1.

    With --adopt-metadata FROM, first give the one FILE the metadata of FROM, the recording
    its rows came from (pandas and polars drop it unless told to keep it)."""
    if source is not None:
        from pimbs_recording.adopt import adopt_metadata

        if len(files) != 1:
            raise click.UsageError("--adopt-metadata takes one FILE")
        adopt_metadata(files[0], source, force=force)
        click.echo(f"adopted the metadata of {source} into {files[0]}")
    elif force:
        raise click.UsageError("--force only goes with --adopt-metadata")
    refused = shown = 0
    for path in files:  # a bad file does not hide the good ones after it
        try:
            text = summary(path)
        except USER_ERRORS as exc:
            click.echo(f"Error: {exc}", err=True)
            refused += 1
            continue
        click.echo(f"\n{text}" if shown else text)
        shown += 1
    if refused:
        raise SystemExit(1)  # each refusal has had its line
