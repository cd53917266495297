"""`pimbs import`: a ROS bag (ROS 1 .bag, ROS 2 directory) -> a PIMBS recording."""

from __future__ import annotations

from pathlib import Path

import click

from pimbs_cli.common import check_output, force_option, progress, robot_option, user_errors


@click.command("import")
@click.argument("log", type=click.Path(exists=True, path_type=Path))
@robot_option(default=None)
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path),
              help="recording to write (.parquet)")
@click.option("--map", "map_path", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="YAML mapping other topics, types, fields, orders, scales, offsets "
                   "(docs/recording-format.md)")
@click.option("--list-topics", is_flag=True,
              help="print every topic of LOG with its type and message count, and exit")
@click.option("--keep-out-of-range", is_flag=True,
              help="import held poses with a joint outside its URDF limits or a negative "
                   "tension, NaN/infinite readings (dropped) and backward times (sorted) "
                   "instead of refusing the log; the counts go into the metadata")
@click.option("--msg-dir", "msg_dirs", multiple=True,
              type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="folder with PKG/msg/NAME.msg definitions of message types a ROS 2 bag "
                   "recorded before Iron does not hold (repeatable)")
@force_option()
@user_errors
def command(log: Path, robot: str | None, out: Path | None, map_path: Path | None,
            list_topics: bool, keep_out_of_range: bool, msg_dirs: tuple[Path, ...],
            force: bool) -> None:
    """Turn LOG (a ROS 1 .bag file or a ROS 2 bag directory), a continuous log of the arm
    moving between held poses, into a recording with one row per held pose (ramps dropped),
    ready for train and diagnose."""
    if list_topics:
        from pimbs_import.bagopen import describe_topics, open_log

        reader = open_log(log)
        try:
            for line in describe_topics(reader.topics):
                click.echo(line)
        finally:
            reader.close()
        return
    if robot is None:
        raise click.UsageError("--robot is required: the log's joints and muscles are matched "
                               "to it by name")
    if out is None:
        raise click.UsageError("--out is required: the recording to write (.parquet)")
    from pimbs_arm.model import ArmModel
    from pimbs_import.convert import import_log
    from pimbs_import.mapping import load_mapping
    from pimbs_recording.format import write_recording

    check_output(out, force=force, what="recording")
    arm = ArmModel.load(robot)
    mapping = load_mapping(map_path)
    with progress(f"reading {log.name}", None, "messages") as update:
        data, meta = import_log(log, arm, mapping,
                                lambda done, total: update(done, f"of {total}"),
                                keep_out_of_range=keep_out_of_range, msg_dirs=msg_dirs)
    write_recording(out, data, meta)
    click.echo(f"wrote {out}: {len(data['sample'])} held poses of {arm.robot.name} from "
               f"{log.name} ({meta['log_span_s']:.0f} s of log); temperature: "
               f"{meta['temperature']}")
    flags = meta.get("import_flags")
    if flags:
        click.echo(f"Warning: kept readings and poses out of range ({flags}); they are "
                   "counted in the metadata key import_flags", err=True)
