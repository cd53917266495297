"""`pimbs simulate`: the paper's simulated data, optionally with a concealed effect."""

from __future__ import annotations

from pathlib import Path

import click

from pimbs_cli.common import (
    check_output,
    force_option,
    load_usable_arm,
    progress,
    robot_option,
    rows_as_samples,
    user_errors,
)


@click.command("simulate")
@robot_option()
@click.option("--samples", "-n", type=click.IntRange(min=1), default=1000, show_default=True,
              help="poses (rows) to simulate")
@click.option("--map", "map_kind", type=click.Choice(["al", "atl"]), default="atl",
              show_default=True, help="al: f_min = 0; atl: f_min uniform in [10, 300] N "
                                   "(at most 3/4 of the weakest muscle's f_max)")
@click.option("--seed", type=int, default=0, show_default=True,
              help="pose sequence, floors and noise; the same seed gives the poses of "
                   "`pimbs collect --seed`")
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="recording to write (Parquet)")
@click.option("--conceal", multiple=True, metavar="EFFECT[:PARAMS]",
              help="write a 'real' recording with this effect present but unlabelled: "
                   "tendon_friction, link_mass, tension_offset, tension_gain, thermal_drift, "
                   "elastic_stiffness, joint_offset, routing, joint_spring (repeatable), "
                   "e.g. tendon_friction:0.2, tension_offset:15,muscles=m1 or "
                   "joint_spring:1.5,joints=j1,rest=0.2 (N·m/rad toward 0.2 rad); aliases: "
                   "friction, mass, offset, loadcell_offset, gain, loadcell_gain, drift, "
                   "stiffness, encoder_offset, spring")
@click.option("--noise", type=click.FloatRange(min=0), default=1.0, show_default=True,
              help="sensor noise scale (0: exact data)")
@click.option("--poses-file", type=click.Path(dir_okay=False, path_type=Path),
              help="simulate these poses instead of the seeded draws (CSV: a column per "
                   "joint, optionally floor_<muscle> columns, as `pimbs diagnose --poses-out` "
                   "writes); one sample per row")
@force_option()
@user_errors
def command(robot: str, samples: int, map_kind: str, seed: int, out: Path,
            conceal: tuple[str, ...], noise: float, poses_file: Path | None,
            force: bool) -> None:
    """Simulate a body-schema recording of the robot (θ uniform in its joint range)."""
    from pimbs_arm.poses import replaced_note, scaled_note
    from pimbs_recording.format import RecordingWriteError, write_recording
    from pimbs_sim.effects import parse_effect
    from pimbs_sim.simulate import simulate

    check_output(out, force=force, what="recording")
    arm = load_usable_arm(robot)  # the checks `collect` runs too
    effects = tuple(parse_effect(spec, seed=seed) for spec in conceal)
    plan = None
    if poses_file is not None:
        from pimbs_arm.poses_file import read_pose_plan

        plan = read_pose_plan(poses_file, arm, seed, map_kind)
        samples = rows_as_samples(samples, len(plan.poses), poses_file)
    with progress("simulate", samples, "samples") as update:
        data, meta = simulate(arm, samples, map_kind, seed=seed, effects=effects,
                              noise=noise, progress=update, poses=plan)
    if poses_file is not None:
        meta["poses_file"] = str(poses_file)
    try:
        write_recording(out, data, meta)
    except RecordingWriteError as exc:  # the message names the file; simulate has no resume
        raise click.ClickException(f"{exc}; free disk space and run the same command "
                                   "again") from exc
    if meta["replaced_poses"]:
        click.echo(replaced_note(meta["replaced_poses"], samples, seed), err=True)
    if meta["scaled_floors"]:
        click.echo(scaled_note(meta["scaled_floors"], samples), err=True)
    click.echo(f"wrote {out}: {samples} samples of {arm.robot.name} "
               f"({arm.n_joints} joints, {arm.n_muscles} muscles, {map_kind.upper()}-Map, "
               f"seed {seed})")

