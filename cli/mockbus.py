"""`pimbs mockbus`: the simulated arm as a standalone process, for trying tools by hand.

`pimbs collect --port virtual` starts its own in-process simulated arm; this command is for
talking to one from another process: over a pty (`--serial`, the driver opens the printed
path) or over a CAN port both processes can reach (`udp_multicast:GROUP` needs the optional
`msgpack` package; `vcan0` needs `sudo ip link add vcan0 type vcan && sudo ip link set vcan0 up`).
The python-can `virtual` bus lives inside one process, so it is useless here.
"""

from __future__ import annotations

import logging
import threading

import click

from pimbs_cli.common import robot_option, user_errors

DEFAULT_CHANNEL = "udp_multicast:239.74.163.2"


@click.command("mockbus")
@robot_option()
@click.option("--channel", default=DEFAULT_CHANNEL, show_default=True,
              help="CAN port the simulated boards sit on (udp_multicast:GROUP, vcan0, ...)")
@click.option("--serial", is_flag=True, help="boards behind a pty instead (prints its path)")
@click.option("--fault", "faults", multiple=True, metavar="KIND:MUSCLE@TRIGGER",
              help="inject a fault: @2.5s (seconds) or @300c (board cycles); @SAMPLE "
                   "triggers need an in-process collection, here only @0 fires")
@click.option("--conceal", multiple=True, metavar="EFFECT[:PARAMS]",
              help="the arm carries this unlabelled effect, e.g. tendon_friction:0.2")
@click.option("--seed", type=int, default=0, show_default=True, help="sensor noise seed")
@click.option("--speed", type=click.FloatRange(min=0, min_open=True), default=1.0,
              show_default=True, help="time speed-up of the arm's dynamics")
@click.option("--duration", type=click.FloatRange(min=0, min_open=True), default=None,
              help="s to run [default: until Ctrl-C]")
@user_errors
def command(robot: str, channel: str, serial: bool, faults: tuple[str, ...],
            conceal: tuple[str, ...], seed: int, speed: float, duration: float | None) -> None:
    """Run simulated muscle boards of ROBOT on a CAN port or a pty until Ctrl-C."""
    from pimbs_calibration.description import load_robot
    from pimbs_calibration.effects import parse_effect
    from pimbs_hw.mock import MockArm, parse_faults

    logging.basicConfig(level=logging.INFO, format="mockbus: %(message)s")
    description = load_robot(robot)
    muscles = tuple(m.name for m in description.muscles)
    specs = parse_faults(list(faults), muscles)
    if any(s.sample for s in specs):
        click.echo("warning: @SAMPLE triggers other than @0 never fire in a standalone mock; "
                   "use @SECONDSs or @CYCLESc", err=True)
    effects = [parse_effect(c, seed=seed) for c in conceal] or None
    mock = MockArm(description, "pty" if serial else channel, effect=effects, faults=specs,
                   seed=seed, speed=speed)
    boards = ", ".join(f"{m.name}=board {m.board_id}" for m in description.muscles)
    click.echo(f"simulated {description.name} ({boards}) on {mock.port}")
    click.echo(f"connect with: pimbs collect --port {mock.port} --robot {robot}")
    with mock:
        try:
            threading.Event().wait(duration)
        except KeyboardInterrupt:
            pass
    click.echo("mockbus stopped")
