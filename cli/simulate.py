"""`pimbs simulate`: the paper's simulated data, optionally with a concealed effect."""

from __future__ import annotations

from pathlib import Path

import click

from pimbs_cli.common import check_output, force_option, progress, robot_option, user_errors


@click.command("simulate")
@robot_option()
@click.option("--samples", "-n", type=click.IntRange(min=1), default=1000, show_default=True)
@click.option("--map", "map_kind", type=click.Choice(["al", "atl"]), default="atl",
              show_default=True, help="al: f_min = 0; atl: f_min uniform in [10, 300] N "
                                   "(at most 3/4 of the weakest muscle's f_max)")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), required=True)
@click.option("--conceal", multiple=True, metavar="EFFECT[:PARAMS]",
              help="write a 'real' recording with this effect present but unlabelled: "
                   "tendon_friction, link_mass, tension_offset, tension_gain, thermal_drift, "
                   "elastic_stiffness, joint_offset, routing (repeatable), e.g. "
                   "tendon_friction:0.2 or tension_offset:15,muscles=m1; aliases: "
                   "friction, mass, offset, loadcell_offset, gain, loadcell_gain, drift, "
                   "stiffness, encoder_offset")
@click.option("--noise", type=click.FloatRange(min=0), default=1.0, show_default=True,
              help="sensor noise scale (0: exact data)")
@force_option()
@user_errors
def command(robot: str, samples: int, map_kind: str, seed: int, out: Path,
            conceal: tuple[str, ...], noise: float, force: bool) -> None:
    """Simulate a body-schema recording of the robot (θ uniform in its joint range)."""
    from pimbs_arm.model import ArmModel
    from pimbs_arm.poses import replaced_note, scaled_note
    from pimbs_recording.format import RecordingWriteError, write_recording
    from pimbs_sim.effects import parse_effect
    from pimbs_sim.simulate import simulate

    check_output(out, force=force, what="recording")
    arm = ArmModel.load(robot)
    _refuse_one_sided(arm, robot)
    effects = tuple(parse_effect(spec, seed=seed) for spec in conceal)
    with progress("simulate", samples, "samples") as update:
        data, meta = simulate(arm, samples, map_kind, seed=seed, effects=effects,
                              noise=noise, progress=update)
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


def _refuse_one_sided(arm, robot: str) -> None:
    """Refuse, as `pimbs robot` does, an arm whose muscles cannot turn a joint both ways
    somewhere in its range: its recording would hold poses no real arm of that routing
    can be held in against gravity, with nothing in the file to say so."""
    from pimbs_arm.routing import BOTH_WAYS_FIX, both_ways_problem, check_poses, routing_report

    problem = both_ways_problem(arm, routing_report(arm, check_poses(arm)))
    if problem:
        raise click.ClickException(
            f"{arm.robot.muscle_path}: some driven joints cannot be turned both ways "
            f"({problem}), as `pimbs robot {robot}` shows with the poses; {BOTH_WAYS_FIX}")
