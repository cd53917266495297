"""`pimbs mockbus`: the simulated arm as a standalone process, for trying tools by hand.

`pimbs collect --port virtual` starts its own in-process simulated arm; this command is for
talking to one from another process on the same computer. Simulated boards are for one
host, so every place they can sit stays on it:

- `pty` (default): a pseudo-terminal speaking the USB-serial board framing; the driver
  opens the printed `/dev/pts/N` path.
- `slcan`: a pty behind an emulated SLCAN USB-CAN adapter; the driver opens the printed
  `slcan:/dev/pts/N` through python-can's real `slcan` interface.
- a SocketCAN virtual channel such as `vcan0` (`sudo ip link add vcan0 type vcan &&
  sudo ip link set vcan0 up`): in the kernel, never on a wire.
UDP multicast is refused: its datagrams leave the machine.
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path

import click

from pimbs_cli.common import plant_damping_option, robot_option, user_errors

DEFAULT_PORT = "pty"
_FORMS = "pty, slcan, or a SocketCAN virtual channel such as vcan0"


def check_port(port: str) -> str:
    """The link the simulated boards may sit on, or one line saying why not and what to use."""
    from pimbs_hw.transport import is_serial_port

    if port in ("pty", "slcan"):
        return port
    if is_serial_port(port):
        raise click.ClickException(
            f"--port {port}: that is a serial device; the simulated boards make their own "
            f"pseudo-terminal: use --port pty (or slcan) and pass the printed path to "
            f"`pimbs collect --port`")
    iface, sep, _ = port.partition(":")
    if port in ("virtual", "") or iface == "virtual":
        raise click.ClickException(
            f"--port {port}: python-can's virtual bus lives inside one process; for a "
            f"simulated arm in the collecting process use `pimbs collect --port virtual`, "
            f"here use {_FORMS}")
    if not sep and port.startswith("vcan"):
        return port
    why = ("udp_multicast datagrams leave the machine" if iface == "udp_multicast"
           else "a real CAN interface would put simulated boards on a real bus")
    raise click.ClickException(
        f"--port {port}: the simulated boards stay on this computer ({why}); use {_FORMS}")


@click.command("mockbus")
@robot_option()
@click.option("--port", "link", default=DEFAULT_PORT, show_default=True,
              metavar="pty|slcan|vcanN",
              help="where the simulated boards sit: a pty (serial framing), a pty behind an "
                   "emulated SLCAN adapter, or a SocketCAN virtual channel")
@click.option("--serial", is_flag=True, hidden=True, help="same as --port pty (older spelling)")
@click.option("--fault", "faults", multiple=True, metavar="KIND:MUSCLE@TRIGGER",
              help="inject a fault: @2.5s (seconds) or @300c (board cycles); @SAMPLE "
                   "triggers need an in-process collection, here only @0 fires")
@click.option("--conceal", multiple=True, metavar="EFFECT[:PARAMS]",
              help="the arm carries this unlabelled effect, e.g. tendon_friction:0.2")
@click.option("--seed", type=int, default=0, show_default=True, help="sensor noise seed")
@click.option("--speed", type=click.FloatRange(min=0, min_open=True), default=1.0,
              show_default=True, help="time speed-up of the arm's dynamics")
@click.option("--plant", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="an MJCF that MuJoCo integrates as the true arm (mj_step dynamics; may "
                   "differ from --robot, as a real arm does)")
@plant_damping_option()
@click.option("--duration", type=click.FloatRange(min=0, min_open=True), default=None,
              help="s to run [default: until Ctrl-C]")
@click.option("--verbose", is_flag=True,
              help="also print the log of the libraries underneath (canopen, python-can)")
@user_errors
def command(robot: str, link: str, serial: bool, faults: tuple[str, ...],
            conceal: tuple[str, ...], seed: int, speed: float, plant: Path | None,
            plant_damping: str, duration: float | None, verbose: bool) -> None:
    """Run simulated muscle boards of ROBOT on a pty or a local CAN channel until Ctrl-C."""
    from pimbs_calibration.description import load_robot
    from pimbs_hw.errors import PortError
    from pimbs_hw.mock import MockArm, parse_faults
    from pimbs_sim.effects import parse_effect

    link = check_port("pty" if serial else link)
    # the simulated boards' own news (a fault that fires) always; the libraries' INFO log
    # (canopen describes every PDO it maps) only when asked for
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING,
                        format="mockbus: %(message)s")
    logging.getLogger("pimbs_hw").setLevel(logging.INFO)
    description = load_robot(robot)
    muscles = tuple(m.name for m in description.muscles)
    specs = parse_faults(list(faults), muscles)
    if any(s.sample for s in specs):
        click.echo("warning: @SAMPLE triggers other than @0 never fire in a standalone mock; "
                   "use @SECONDSs or @CYCLESc", err=True)
    effects = [parse_effect(c, seed=seed) for c in conceal] or None
    notes, damping = _plant_notes(plant, description, plant_damping == "calm")
    try:
        mock = MockArm(description, link, effect=effects, faults=specs, seed=seed, speed=speed,
                       plant=plant, plant_damping=damping)
    except PortError as exc:
        raise click.ClickException(
            f"--port {link}: cannot open it ({exc.problem}); create it first "
            f"(`sudo ip link add {link} type vcan && sudo ip link set {link} up`) or use "
            f"--port pty") from exc
    boards = ", ".join(f"{m.name}=board {m.board_id}" for m in description.muscles)
    click.echo(f"simulated {description.name} ({boards}) on {mock.port}")
    if plant is not None:
        click.echo(f"the true arm: {plant}, integrated by MuJoCo")
        for note in notes:
            click.echo(note, err=True)
    click.echo(f"connect with: pimbs collect --port {mock.port} --robot {robot}", nl=True)
    with mock:
        try:
            threading.Event().wait(duration)
        except KeyboardInterrupt:
            pass
    click.echo("mockbus stopped")


def _plant_notes(plant: Path | None, description, calm: bool
                 ) -> tuple[list[str], dict[str, float]]:
    """The plant's lines to show (``plant_notes``) and the joint damping it runs with."""
    if plant is None:
        return [], {}
    from pimbs_hw.collection.settle import SettleConfig
    from pimbs_hw.mock.mujoco_plant import plant_notes

    rings, step, damping = plant_notes(plant, description, SettleConfig().timeout, calm)
    return [n for n in (rings, step) if n], damping
