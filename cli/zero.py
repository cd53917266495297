"""`pimbs zero`: guided encoder zeroing at the home pose, written to the calibration file.

The person at the arm holds it at its home pose (every joint at 0 rad) with the wires on
their pulleys; PIMBS holds each muscle at its low pre-tension, reads every encoder, removes
the stretch that tension causes and writes the zero to `<robot>.calibration.yaml`, which
`pimbs collect` then applies. On the simulated ports the simulation holds the arm at home.
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

from pimbs_cli.common import check_output, force_option, robot_option, user_errors


@click.command("zero")
@click.option("--port", required=True,
              help="where the boards are (can0, slcan:/dev/ttyACM0, /dev/ttyUSB0, ...), or "
                   "virtual for the simulated arm")
@robot_option()
@click.option("--calibration", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="file to write [default: ROBOT.calibration.yaml beside the robot file, or "
                   "in this directory for a built-in robot]")
@click.option("--yes", is_flag=True, help="the arm is already at its home pose: do not ask")
@force_option()
@user_errors
def command(port: str, robot: str, calibration: Path | None, yes: bool, force: bool) -> None:
    """Zero every motor encoder at the home pose (all joints 0 rad, wires on their pulleys)."""

    from pimbs_arm.model import ArmModel
    from pimbs_calibration.zeroing import default_path, save
    from pimbs_hw import is_simulated, open_arm
    from pimbs_hw.zeroing import measure_zero

    model = ArmModel.load(robot)
    path = check_output(calibration or default_path(model.robot), force=force,
                        what="calibration", option="--calibration")
    joints = ", ".join(model.joints)
    click.echo(f"Zeroing {model.robot.name}: hold the arm at its home pose ({joints} all at "
               "0 rad), every wire on its pulleys. Each muscle will be held at its low "
               "pre-tension (f_floor), never slack.")
    if not yes:
        if not sys.stdin.isatty():
            raise click.ClickException("the arm must be at its home pose before zeroing: "
                                       "run at a terminal, or pass --yes when it is")
        click.confirm("Is the arm at its home pose?", abort=True)
    with open_arm(port, model.robot, seed=0) as (driver, mock):
        if mock is not None:
            mock.hold_home()  # the simulation's stand-in for the hands holding the arm
        zero_m, tension = measure_zero(driver, model)
    save(path, model.robot, zero_m, tension, port)
    for name, z, f in zip(model.muscles, zero_m, tension, strict=True):
        click.echo(f"  {name}: encoder zero {1e3 * z:+9.3f} mm (held at {f:5.1f} N)")
    click.echo(f"wrote {path}; `pimbs collect --robot {robot}` applies it"
               + ("" if path == default_path(model.robot) else f" with --calibration {path}"))
    if is_simulated(port):
        click.echo("(simulated arm: its encoders start at zero, so the zeros are ~0)")
