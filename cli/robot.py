"""`pimbs robot`: what a robot description means, and a picture of its routing."""

from __future__ import annotations

from pathlib import Path

import click

from pimbs_cli.common import check_output, force_option, user_errors


def _parse_pose(text: str, joints: tuple[str, ...]) -> list[float]:
    """``0.1,-0.3,0.2`` (every driven joint in order) or ``elbow=-0.5,shoulder=0.2``
    (the others at 0)."""
    parts = [p.strip() for p in text.split(",") if p.strip()]
    if all("=" in p for p in parts):
        pose = dict.fromkeys(joints, 0.0)
        for part in parts:
            name, _, value = part.partition("=")
            if name.strip() not in pose:
                raise click.BadParameter(f"'{name.strip()}' is not a driven joint "
                                         f"({', '.join(joints)})", param_hint="--pose")
            pose[name.strip()] = _float(value)
        return list(pose.values())
    if len(parts) != len(joints):
        raise click.BadParameter(f"give {len(joints)} angles in rad ({', '.join(joints)}) or "
                                 "name=value pairs", param_hint="--pose")
    return [_float(p) for p in parts]


def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise click.BadParameter(f"'{text}' is not a number (rad)", param_hint="--pose") from None


@click.command("robot")
@click.argument("robot")
@click.option("--plot", "plot", type=click.Path(dir_okay=False, path_type=Path),
              help="draw the arm at the home pose (and --pose) with every muscle's path (PNG)")
@click.option("--pose", help="another pose to draw: angles of the driven joints in order "
                             "(0.1,-0.3,0.2) or name=value pairs (rad)")
@click.option("--poses", "n_poses", type=click.IntRange(min=0), default=200, show_default=True,
              help="random poses (besides centre and corners) for the moment-arm ranges and "
                   "the both-ways check")
@click.option("--package-path", "package_path", multiple=True,
              type=click.Path(file_okay=False, path_type=Path),
              help="where a 'urdf: package://...' is looked for (repeatable; also the muscle "
                   "file's package_path and ROS_PACKAGE_PATH)")
@click.option("--poses-file", "poses_file", type=click.Path(dir_okay=False, path_type=Path),
              help="CSV of poses (a header naming the driven joints, one pose in rad a row): "
                   "write every muscle's length and Jacobian at them to --json instead of "
                   "explaining")
@click.option("--json", "json_out", type=click.Path(dir_okay=False, path_type=Path),
              help="with --poses-file: the JSON to write (joints, muscles, theta, length, "
                   "h_geom, jacobian [pose][muscle][joint])")
@force_option()
@user_errors
def command(robot: str, plot: Path | None, pose: str | None, n_poses: int,
            package_path: tuple[Path, ...], poses_file: Path | None, json_out: Path | None,
            force: bool) -> None:
    """Explain ROBOT (a built-in name, a .muscles.yaml or an MJCF .xml): joints driven and
    locked, muscles and boards, moment arms over the joint ranges, and whether every driven
    joint can be turned both ways at every checked pose. With --poses-file and --json: the
    muscle lengths and Jacobians at given poses. A description that fails a check is still
    explained, drawn and exported, the check marked where it fails; the exit status is then
    1, with one line saying what failed (`simulate` and `collect` refuse it)."""
    import numpy as np

    from pimbs_arm.explain import describe
    from pimbs_arm.model import ArmModel
    from pimbs_arm.routing import check_poses, routing_report, usable_problem
    from pimbs_calibration.description import load_robot

    if (poses_file is None) != (json_out is None):
        raise click.UsageError("--poses-file and --json go together: the poses to read and "
                               "the JSON to write")
    if json_out is not None:
        check_output(json_out, force=force, what="JSON file", option="--json")
    if plot is not None:
        check_output(plot, force=force, what="picture", option="--plot")
    # checked below, after everything is shown: a failing description is explained too
    arm = ArmModel(load_robot(robot, package_path), check=False)
    other = None if pose is None else np.array(_parse_pose(pose, arm.joints))
    report = routing_report(arm, check_poses(arm, n_poses))
    if poses_file is not None:
        _write_geometry(arm, poses_file, json_out)
    else:
        for line in describe(arm, report):
            click.echo(line)
        if plot is not None:
            from pimbs_arm.picture import plot_routing

            home = np.clip(np.zeros(arm.n_joints), arm.joint_limits[:, 0],
                           arm.joint_limits[:, 1])
            panels = [("home pose", home)] + ([] if other is None else [("given pose", other)])
            plot_routing(arm, plot, panels)
            click.echo(f"\nwrote {plot}")
    problem = usable_problem(arm, report)
    if problem:
        raise click.ClickException(f"{arm.robot.muscle_path}: {problem}; until then `pimbs "
                                   "simulate` and `pimbs collect` refuse this description")


def _write_geometry(arm, poses_file: Path, json_out: Path) -> None:
    """``--poses-file`` + ``--json``: lengths and Jacobians at the CSV's poses, one JSON."""
    import json

    import numpy as np

    from pimbs_arm.geometry_table import geometry_table, read_poses_csv
    from pimbs_recording.atomic import write_text_atomic

    theta, ignored = read_poses_csv(poses_file, arm.joints)
    if ignored:
        click.echo(f"{poses_file}: column(s) {', '.join(ignored)} name no driven joint of "
                   f"{arm.robot.name}; ignored", err=True)
    lo, hi = arm.joint_limits[:, 0], arm.joint_limits[:, 1]
    outside = np.flatnonzero(((theta < lo) | (theta > hi)).any(axis=1))
    if len(outside):
        rows = ", ".join(str(i + 1) for i in outside[:10])
        click.echo(f"{poses_file}: {len(outside)} pose(s) lie outside the joint limits (rows "
                   f"{rows}{', ...' if len(outside) > 10 else ''}); their geometry is written "
                   "as asked", err=True)
    write_text_atomic(json_out, json.dumps(geometry_table(arm, theta)) + "\n")
    click.echo(f"wrote {json_out}: lengths and Jacobians of {arm.n_muscles} muscles over "
               f"{arm.n_joints} joints at {len(theta)} poses")
