"""`pimbs diagnose`: locate the sim-to-real mismatch, name the missing physics, show the fit."""

from __future__ import annotations

import json
import os

# The fits solve thousands of small systems: BLAS threads only contend (measured 10x slower
# with two threads on a 2-core machine). Must be set before numpy loads its BLAS.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
from pathlib import Path

import click

from pimbs_cli.common import check_output, force_option, user_errors


@click.command("diagnose")
@click.argument("real", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--reference", type=click.Path(dir_okay=False, path_type=Path),
              help="simulated recording of the same commanded poses (pairs by `sample`)")
@click.option("--robot", help="robot description (name or .muscles.yaml) — instead of, or "
                              "with, --reference")
@click.option("--json", "json_out", type=click.Path(dir_okay=False, path_type=Path),
              help="write the full result as JSON")
@click.option("--plots", type=click.Path(file_okay=False, path_type=Path),
              help="directory for PNG plots")
@click.option("--corrected", type=click.Path(dir_okay=False, path_type=Path),
              help="write the real recording with the named effects undone")
@force_option()
@user_errors
def command(real: Path, reference: Path | None, robot: str | None, json_out: Path | None,
            plots: Path | None, corrected: Path | None, force: bool) -> None:
    """Why does REAL disagree with the simulation? Name the physics the model left out."""
    if json_out:  # refused before the work, not after it
        check_output(json_out, force=force, what="file", option="--json")
    if corrected:
        check_output(corrected, force=force, what="recording", option="--corrected")
    from pimbs_learn.diagnosis.report import text_report
    from pimbs_learn.diagnosis.run import diagnose, write_corrected

    result, internals = diagnose(
        real, reference, robot, progress=lambda e: click.echo(f"  testing {e} …", err=True))
    click.echo(text_report(result))
    if json_out:
        json_out.write_text(json.dumps(result, indent=2))
        click.echo(f"\nJSON: {json_out}")
    if plots:
        from pimbs_learn.diagnosis.plots import write_plots

        for path in write_plots(result, internals, plots):
            click.echo(f"plot: {path}")
    if corrected:
        write_corrected(internals, corrected)
        click.echo(f"corrected recording: {corrected}")
