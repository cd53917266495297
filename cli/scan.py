"""`pimbs scan`: which boards answer on a port — protocol, firmware, temperature, faults, load.

Only listens (sends nothing), so it is safe next to a running arm; with `--canopen` (on by
itself for a robot with CiA 402 drives) it also asks every CANopen node for its identity and
state, by SDO reads only. For the simulated ports
(`virtual`, `pty`, `slcan-pty`) it starts the simulated boards of `--robot` first.
"""

from __future__ import annotations

import click

from pimbs_cli.common import robot_option, user_errors


@click.command("scan")
@click.option("--port", required=True,
              help="can0, pcan:PCAN_USBBUS1, slcan:/dev/ttyACM0, /dev/ttyUSB0, or virtual / "
                   "slcan-pty for the simulated arm")
@robot_option(default=None)
@click.option("--seconds", type=click.FloatRange(min=0.1, max=60), default=1.0,
              show_default=True, help="how long to listen")
@click.option("--bitrate", type=click.IntRange(min=10_000), default=1_000_000,
              show_default=True, help="bit/s of the bus, for the load figure")
@click.option("--canopen", "canopen_nodes", is_flag=True,
              help="also list CANopen nodes: identity (0x1018) and CiA 402 state, by SDO "
                   "reads (on by itself when --robot has CiA 402 drives)")
@user_errors
def command(port: str, robot: str | None, seconds: float, bitrate: int,
            canopen_nodes: bool) -> None:
    """List every board heard on PORT, with its protocol, firmware, temperature and faults."""
    import contextlib

    from pimbs_calibration.description import load_robot
    from pimbs_hw.connect import SIMULATED_PORTS, is_simulated, mock_link
    from pimbs_hw.mock import MockArm
    from pimbs_hw.scan import fault_names, scan_bus
    from pimbs_hw.transport import open_transport

    description = load_robot(robot or "two-link-4-muscle") if robot or is_simulated(
        port) else None
    if description is not None:
        from pimbs_hw.protocol.profiles import protocols_for

        protocols_for(description)  # refuses boards whose CAN ids collide, in one line
    with contextlib.ExitStack() as stack:
        kwargs = {}
        if is_simulated(port):
            mock = stack.enter_context(MockArm(description, mock_link(port)))
            click.echo(f"simulated {description.name} on {mock.port} "
                       f"(--port {'|'.join(SIMULATED_PORTS)} starts one)")
            port = mock.port
            if port.startswith("slcan:"):
                kwargs["sleep_after_open"] = 0
        transport = stack.enter_context(open_transport(port, **kwargs))
        result = scan_bus(transport, seconds, description)
        nodes = None
        if canopen_nodes or _has_cia402(description):
            from pimbs_hw.canopen_scan import scan_canopen

            nodes = scan_canopen(transport, min(seconds, 0.5))
    boards = sorted(result.boards.values(), key=lambda b: (b.board_id, b.protocol))
    click.echo(f"port {result.port}: {len(boards)} board(s) in {seconds:g} s, "
               f"{result.frames} frames ({result.joint_frames} from joint encoders, "
               f"{result.unknown_frames} not understood), bus load "
               f"{100 * result.bus_load(bitrate):.1f} % of {bitrate / 1e6:g} Mbit/s")
    if nodes is not None:
        click.echo(f"{len(nodes)} CANopen node(s) answered an SDO read of 0x1000 (device type)")
        for node in nodes:
            click.echo(node.line())
    if not boards:
        if not nodes:
            click.echo("no board answered: is the arm powered, the port right (and the "
                       "bitrate)?")
        return
    click.echo(f"{'board':>5}  {'protocol':<18} {'muscle':<7} {'firmware':<9} {'temp °C':>7}  "
               f"{'frames/s':>8}  faults")
    for b in boards:
        temp = "-" if b.temperature_c is None else f"{b.temperature_c:.1f}"
        bad = f" ({b.bad_frames} failed CRC)" if b.bad_frames else ""
        click.echo(f"{b.board_id:>5}  {b.protocol:<18} {b.muscle or '-':<7} "
                   f"{b.version or '-':<9} {temp:>7}  {b.frames / seconds:>8.0f}  "
                   f"{fault_names(b.faults)}{bad}")


def _has_cia402(description) -> bool:
    from pimbs_hw.protocol.profiles import is_cia402, muscle_protocol

    return description is not None and any(is_cia402(muscle_protocol(m))
                                           for m in description.muscles)
