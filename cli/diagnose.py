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
@click.argument("real", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--reference", multiple=True, type=click.Path(dir_okay=False, path_type=Path),
              help="simulated recording of the same commanded poses (pairs by `sample`); "
                   "one per REAL recording, in the same order")
@click.option("--robot", help="robot description (name or .muscles.yaml) — instead of, or "
                              "with, --reference")
@click.option("--json", "json_out", type=click.Path(dir_okay=False, path_type=Path),
              help="write the full result as JSON")
@click.option("--plots", type=click.Path(file_okay=False, path_type=Path),
              help="directory for PNG plots (its parent must exist)")
@click.option("--corrected", type=click.Path(dir_okay=False, path_type=Path),
              help="write the real recording with the identified effects undone (not those "
                   "it cannot tell apart)")
@click.option("--poses-out", type=click.Path(dir_okay=False, path_type=Path),
              help="with --robot: write the poses that would tell apart what this recording "
                   "cannot, as a CSV for `pimbs collect --poses-file`")
@click.option("--design-poses", type=click.IntRange(min=1), default=None,
              help="how many such poses to propose [default: 30, a few minutes on an arm]")
@force_option()
@user_errors
def command(real: tuple[Path, ...], reference: tuple[Path, ...], robot: str | None,
            json_out: Path | None, plots: Path | None, corrected: Path | None,
            poses_out: Path | None, design_poses: int | None, force: bool) -> None:
    """Why does REAL disagree with the simulation? Name the physics the model left out.

    Several REAL recordings of one arm (a session and the poses collected to settle what it
    could not tell apart) are diagnosed together, each paired with its --reference."""
    from pimbs_learn.diagnosis.design import design_csv
    from pimbs_learn.diagnosis.plots import PLOT_FILES
    from pimbs_learn.diagnosis.report import text_report
    from pimbs_learn.diagnosis.run import diagnose, write_corrected
    from pimbs_recording.atomic import write_text_atomic

    _check_outputs(json_out, plots, corrected, force, PLOT_FILES)
    if poses_out:
        if robot is None:
            raise click.UsageError("--poses-out needs --robot: the poses are planned on the "
                                   "robot description")
        check_output(poses_out, force=force, option="--poses-out")
    if corrected and len(real) > 1:
        raise click.UsageError("--corrected writes one recording: diagnose it alone, or leave "
                               "--corrected out")
    result, internals = diagnose(
        list(real), list(reference), robot,
        progress=lambda e: click.echo(f"  testing {e} …", err=True),
        **({} if design_poses is None else {"design_poses": design_poses}))
    click.echo(text_report(result))
    text, count = design_csv(result)
    if poses_out and count:
        write_text_atomic(poses_out, text)
        click.echo(f"\nposes to collect next: {poses_out} ({count} poses; collect "
                   f"them with `pimbs collect --poses-file {poses_out}`, simulate their "
                   f"reference with `pimbs simulate --poses-file {poses_out}`)")
    elif poses_out:
        click.echo(f"\n{poses_out} not written: nothing here asks for more poses")
    if json_out:
        write_text_atomic(json_out, json.dumps(result, indent=2) + "\n")
        click.echo(f"\nJSON: {json_out}")
    if plots:
        from pimbs_learn.diagnosis.plots import write_plots

        for path in write_plots(result, internals, plots):
            click.echo(f"plot: {path}")
    if corrected:
        write_corrected(internals, corrected)
        click.echo(f"corrected recording: {corrected}")


def _check_outputs(json_out: Path | None, plots: Path | None, corrected: Path | None,
                   force: bool, plot_files: tuple[str, ...]) -> None:
    """Refuse before the diagnosis runs: an output that exists (without --force) or whose
    directory does not."""
    if json_out:
        check_output(json_out, force=force, option="--json")
    if corrected:
        check_output(corrected, force=force, what="recording", option="--corrected")
    if plots:
        check_output(plots, force=True, option="--plots")  # its parent must exist
        for name in plot_files if plots.is_dir() else ():
            check_output(plots / name, force=force, what="plot", option="--plots")
