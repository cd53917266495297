"""`pimbs import`: a ROS bag (ROS 1 .bag, ROS 2 directory) -> a PIMBS recording."""

from __future__ import annotations

from pathlib import Path

import click

from pimbs_cli.common import check_output, force_option, progress, robot_option, user_errors


@click.command("import")
@click.argument("log", type=click.Path(exists=True, path_type=Path))
@robot_option(default=None)
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="recording to write (.parquet)")
@click.option("--map", "map_path", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="YAML mapping other topics, types, fields, orders, scales, offsets "
                   "(docs/recording-format.md)")
@force_option()
@user_errors
def command(log: Path, robot: str | None, out: Path, map_path: Path | None,
            force: bool) -> None:
    """Turn LOG (a ROS 1 .bag file or a ROS 2 bag directory), a continuous log of the arm
    moving between held poses, into a recording with one row per held pose (ramps dropped),
    ready for train and diagnose."""
    if robot is None:
        raise click.UsageError("--robot is required: the log's joints and muscles are matched "
                               "to it by name")
    from pimbs_calibration.arm_model import ArmModel
    from pimbs_calibration.recording import write_recording
    from pimbs_import.convert import import_log
    from pimbs_import.mapping import load_mapping

    check_output(out, force=force, what="recording")
    arm = ArmModel.load(robot)
    mapping = load_mapping(map_path)
    with progress(f"reading {log.name}", None, "messages") as update:
        data, meta = import_log(log, arm, mapping,
                                lambda done, total: update(done, f"of {total}"))
    write_recording(out, data, meta)
    click.echo(f"wrote {out}: {len(data['sample'])} held poses of {arm.robot.name} from "
               f"{log.name} ({meta['log_span_s']:.0f} s of log); temperature: "
               f"{meta['temperature']}")
