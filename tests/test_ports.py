"""Every port a user can name opens or fails in one line; mockbus stays on this computer;
a real python-can interface (slcan, emulated on a pty) carries the simulated boards."""

from __future__ import annotations

import can
import numpy as np
import pytest
from click.testing import CliRunner

from pimbs_cli.main import main
from pimbs_hw import PortError, open_arm
from pimbs_hw.connect import SIMULATED_LIMITS
from pimbs_hw.mock.slcan import format_frame, parse_frame
from pimbs_hw.transport import CanTransport
from pimbs_hw.transport.slcan import SlcanBus

ROBOT = "two-link-4-muscle"


@pytest.fixture
def no_can_config(tmp_path, monkeypatch):
    """No user python-can config or CAN_* environment: only what the port names counts."""
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.chdir(tmp_path)
    for var in ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_BITRATE", "CAN_CONFIG"):
        monkeypatch.delenv(var, raising=False)


@pytest.mark.parametrize("iface", sorted(set(can.VALID_INTERFACES) - {"udp_multicast",
                                                                       "socketcand"}))
@pytest.mark.parametrize("form", ["{}:0", "{}"])
def test_every_python_can_interface_opens_or_fails_in_one_line(iface, form, no_can_config,
                                                               capfd):
    port = form.format(iface)
    try:
        transport = CanTransport(port)
    except PortError as exc:
        message = str(exc)
        assert "\n" not in message and port in message
        assert "installed" in message or "ip link set" in message
        assert exc.port == port
    else:
        transport.close()  # opened (the in-process virtual bus): nothing was sent
    out, err = capfd.readouterr()
    assert out == "" and err == "", "python-can printed around the one line"


@pytest.mark.parametrize("port", ["udp_multicast:239.74.163.2", "socketcand:localhost"])
def test_network_interfaces_fail_in_one_line_without_sending(port, no_can_config):
    """udp_multicast without its optional msgpack, socketcand without host and port."""
    try:
        transport = CanTransport(port)
    except PortError as exc:
        assert "\n" not in str(exc) and port in str(exc)
    else:  # msgpack installed: it opens; nothing is ever sent by opening
        transport.close()


def test_collect_on_an_adapter_without_its_driver_is_one_line(tmp_path, no_can_config):
    out = tmp_path / "k.parquet"
    res = CliRunner().invoke(main, ["collect", "--port", "kvaser:0", "--samples", "1",
                                    "--out", str(out)])
    assert res.exit_code == 1 and res.output.count("\n") == 1, res.output
    assert "kvaser:0" in res.output and "Traceback" not in res.output
    assert not out.exists()


@pytest.mark.parametrize("args, says", [
    (["--port", "/dev/ttyUSB7"], "serial device; the simulated boards make their own"),
    (["--port", "udp_multicast:239.74.163.2"], "datagrams leave the machine"),
    (["--port", "virtual"], "use `pimbs collect --port virtual`"),
    (["--port", "can0"], "would put simulated boards on a real bus"),
    (["--port", "pimbsnovcan7"], "use pty, slcan, or a SocketCAN virtual channel"),
])
def test_mockbus_refuses_links_that_leave_the_process_host_in_one_line(args, says):
    res = CliRunner().invoke(main, ["mockbus", *args, "--duration", "0.1"])
    assert res.exit_code == 1 and res.output.count("\n") == 1, res.output
    assert says in res.output and "Error: --port" in res.output


def test_mockbus_missing_vcan_says_how_to_create_it():
    res = CliRunner().invoke(main, ["mockbus", "--port", "vcan97", "--duration", "0.1"])
    assert res.exit_code == 1 and res.output.count("\n") == 1, res.output
    assert "ip link add vcan97 type vcan" in res.output and "--port pty" in res.output


@pytest.mark.parametrize("args, port", [([], "/dev/"), (["--port", "slcan"], "slcan:/dev/")])
def test_mockbus_default_and_slcan_run_with_declared_dependencies(args, port):
    res = CliRunner().invoke(main, ["mockbus", *args, "--duration", "0.2"])
    assert res.exit_code == 0, res.output
    assert f"connect with: pimbs collect --port {port}" in res.output
    assert "mockbus stopped" in res.output


def test_slcan_line_format_round_trips():
    line = format_frame(0x203, bytes([1, 2, 0xAB]))
    assert line == b"t20330102AB\r"
    assert parse_frame(line.decode()[:-1]) == (0x203, bytes([1, 2, 0xAB]))
    assert parse_frame("T0000020328899") == (0x203, bytes([0x88, 0x99]))
    assert parse_frame("t2033010") is None and parse_frame("t20") is None


def test_driver_through_python_can_slcan_interface():
    with open_arm("slcan-pty", ROBOT, speed=10.0, seed=1, limits=SIMULATED_LIMITS) as (
            driver, mock):
        # python-can's slcan interface, with the bulk reader of pimbs_hw.transport.slcan
        assert mock.port.startswith("slcan:/dev/") and type(driver.transport.bus) is SlcanBus
        driver.command("tension", [30.0, 40.0, 30.0, 40.0])
        state = driver.dwell(0.3)
        assert state.tension == pytest.approx([30, 40, 30, 40], abs=1.5)
        assert np.abs(state.length - mock.snapshot().length).max() <= 1.5 / 108650
    assert mock.snapshot().modes == ("relax",) * 4  # the close relaxed every board
