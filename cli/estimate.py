"""`pimbs estimate MODEL DATA`: joint angles from muscle lengths and tensions alone.

What a robot without joint encoders would do with its body schema. Where the recording has
θ (joint encoders, or a simulation), the error per joint is reported in degrees, beside the
geometric model's estimate of the same samples: what learning bought.
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from pimbs_cli.common import check_output, force_option, user_errors


@click.command("estimate")
@click.argument("model", type=click.Path(file_okay=False, path_type=Path))
@click.argument("data", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--robot", default=None,
              help="robot NAME|PATH of the geometric model to compare with and whose joint "
                   "limits bound the search [default: the model's robot]")
@click.option("--starts", type=click.IntRange(min=1), default=5, show_default=True,
              help="start poses per sample (range centre + seeded draws)")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, path_type=Path),
              default=None, help="write rms_error_deg (one per joint) and the estimates here")
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False, path_type=Path),
              default=None, help="write a figure of estimated against measured angles")
@force_option()
@user_errors
def command(model: Path, data: Path, robot: str | None, starts: int, json_path: Path | None,
            plot_path: Path | None, force: bool) -> None:
    """Estimate the joint angles of every sample in DATA from its lengths and tensions."""
    import numpy as np
    import torch

    from pimbs_learn import load_body_schema
    from pimbs_learn.data import LearnError, load_samples
    from pimbs_learn.estimate import joint_angle_report
    from pimbs_recording.atomic import write_text_atomic

    for path, option in ((json_path, "--json"), (plot_path, "--plot")):
        if path is not None:
            check_output(path, force=force, what="file", option=option)
    torch.set_num_threads(1)
    schema = load_body_schema(model)
    samples = load_samples(data)
    if list(samples.joints) != schema.joints or list(samples.muscles) != schema.muscles:
        raise LearnError(f"{data}: joints {list(samples.joints)} / muscles "
                         f"{list(samples.muscles)} differ from the model's {schema.joints} / "
                         f"{schema.muscles}; estimate with a model of this arm")
    report = joint_angle_report(schema, samples.theta, samples.tension, samples.length,
                                robot=robot, starts=starts)
    measured = bool(np.isfinite(samples.theta).all())
    click.echo(f"{samples.n_samples} samples, search within the {report.range_source}; "
               f"length residual {1e3 * np.sqrt(np.mean(report.residual_m ** 2)):.3g} mm rms")
    if report.geometric_theta is None:
        click.echo("no geometric model to compare with (pass --robot NAME|PATH)")
    if measured:
        click.echo(f"joint-angle error, rms: {report.line()}")
    if json_path is not None:
        out = {"model": str(model), "data": str(data), "n_samples": samples.n_samples,
               **report.to_json()}
        write_text_atomic(json_path, json.dumps(out, indent=2) + "\n")
        click.echo(f"wrote {json_path}: every sample's estimate"
                   + (" and the rms error per joint (rms_error_deg)" if measured else ""))
    if plot_path is not None:
        from pimbs_learn.estimate_plot import estimate_figure

        estimate_figure(report, samples.theta, plot_path)
        click.echo(f"wrote {plot_path}: estimated against measured joint angles")
