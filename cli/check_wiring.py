"""`pimbs check-wiring`: pull each muscle gently and confirm its winding direction.

A muscle's `direction` in the robot file says which way its motor turns to reel the wire in
(+1: a positive turn). A wrong sign makes every length and tension command act the other
way, so it is checked on the arm before the first collection: each muscle in turn is pulled
to a gentle tension above its holding floor while the others stay relaxed; its tension must
rise while its length shortens and the motor must come to rest against the wire. Every muscle
gets one line; a wrong sign is named with what to change.
"""

from __future__ import annotations

import click

from pimbs_cli.common import robot_option, user_errors


def _winding(text: str | None) -> list[int] | None:
    if text is None:
        return None
    try:
        values = [int(v) for v in text.split(",")]
    except ValueError:
        values = []
    if not values or any(v not in (1, -1) for v in values):
        raise click.BadParameter(f"{text!r}: give one 1 or -1 per muscle, e.g. 1,-1,1,1",
                                 param_hint="--mock-winding")
    return values


@click.command("check-wiring")
@click.option("--port", required=True,
              help="where the boards are (can0, slcan:/dev/ttyACM0, /dev/ttyUSB0, ...), or "
                   "virtual for the simulated arm")
@robot_option()
@click.option("--pull", type=click.FloatRange(min=0.5, max=50.0), default=None,
              help="tension step above the holding floor, N [default: a tenth of each "
                   "muscle's range, 2-20 N]")
@click.option("--mock-speed", type=click.FloatRange(min=0, min_open=True), default=1.0,
              show_default=True, help="simulated arm only: time speed-up of its dynamics")
@click.option("--mock-winding", default=None,
              help="simulated arm only: how its wires are really wound, one 1 or -1 per "
                   "muscle [default: as the robot file says]")
@user_errors
def command(port: str, robot: str, pull: float | None, mock_speed: float,
            mock_winding: str | None) -> None:
    """Pull each muscle gently: tension must rise while the length shortens."""
    from pimbs_calibration.description import load_robot
    from pimbs_hw import is_simulated, open_arm
    from pimbs_hw.wiring import check_wiring

    description = load_robot(robot)
    winding = _winding(mock_winding)
    if winding is not None and not is_simulated(port):
        raise click.BadParameter("only the simulated arm can be wound on the command line",
                                 param_hint="--mock-winding")
    if winding is not None and len(winding) != len(description.muscles):
        raise click.BadParameter(f"{len(winding)} values for {len(description.muscles)} "
                                 "muscles", param_hint="--mock-winding")
    click.echo(f"Checking the winding of {description.name}: each muscle in turn is pulled "
               "gently above its holding floor, the others stay relaxed.")
    options = {"winding": winding} if winding is not None else None
    with open_arm(port, description, speed=mock_speed, mock_options=options) as (driver, _):
        results = check_wiring(driver, pull)
    for r in results:
        click.echo(f"  {r.line}")
    wrong = [r.muscle for r in results if not r.ok]
    if wrong:
        raise click.ClickException(f"{len(wrong)} muscle(s) failed the check: "
                                   f"{', '.join(wrong)} (see above); fix the robot file or the "
                                   "wiring and run `pimbs check-wiring` again")
    click.echo("every muscle: tension rises while its length shortens; directions are right")
