"""Transports: port parsing, CAN (virtual bus) and serial (pty) links, and their supervision."""

from __future__ import annotations

import time
import uuid

import pytest

from pimbs_hw.errors import PortError
from pimbs_hw.safety import BusOff, CorruptFrames, LinkLost
from pimbs_hw.transport import (
    CanTransport,
    PtyMaster,
    SerialTransport,
    is_serial_port,
    open_transport,
    parse_can_port,
)
from pimbs_hw.transport.base import CAN_ERR_BUSOFF


def _channel() -> str:
    return f"virtual:test-{uuid.uuid4().hex}"


def _recv(transport, timeout=1.0):
    frame = transport.recv(timeout)
    assert frame is not None, "no frame arrived"
    return frame


@pytest.mark.parametrize("port, kwargs", [
    ("can0", {"interface": "socketcan", "channel": "can0"}),
    ("virtual", {"interface": "virtual", "channel": "pimbs"}),
    ("virtual:arm7", {"interface": "virtual", "channel": "arm7"}),
    ("pcan:PCAN_USBBUS1", {"interface": "pcan", "channel": "PCAN_USBBUS1"}),
    ("slcan:/dev/ttyACM0@500000",
     {"interface": "slcan", "channel": "/dev/ttyACM0", "bitrate": 500000}),
    ("kvaser", {"interface": "kvaser"}),
    ("default", {}),
])
def test_parse_can_port(port, kwargs):
    assert parse_can_port(port) == kwargs


def test_serial_or_can_by_port_name():
    assert is_serial_port("/dev/ttyUSB0") and is_serial_port("/dev/pts/3")
    assert is_serial_port("serial:/dev/x") and not is_serial_port("can0")


def test_unknown_interface_is_a_clear_error():
    with pytest.raises(PortError, match="unknown CAN interface 'nosuch'.*--port virtual"):
        parse_can_port("nosuch:0")


def test_missing_socketcan_interface_names_port_and_fix():
    with pytest.raises(PortError) as err:
        CanTransport("pimbsnocan9")
    msg = str(err.value)
    assert "'pimbsnocan9'" in msg and "ip link set pimbsnocan9 up" in msg
    assert "--port virtual" in msg


def test_missing_serial_port_names_port_and_fix():
    with pytest.raises(PortError, match=r"/dev/ttyPIMBS9.*plugged in.*--port virtual"):
        open_transport("/dev/ttyPIMBS9")


def test_python_can_config_from_environment(monkeypatch):
    channel = f"env-{uuid.uuid4().hex}"
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    monkeypatch.setenv("CAN_CHANNEL", channel)
    with CanTransport("default") as a, CanTransport(f"virtual:{channel}") as b:
        a.send(0x201, b"\x01\x02")
        assert _recv(b)[:2] == (0x201, b"\x01\x02")


def test_virtual_can_round_trip_and_no_cross_talk():
    port = _channel()
    with CanTransport(port) as a, CanTransport(port) as b, CanTransport(_channel()) as other:
        for i in range(20):
            a.send(0x200 + (i % 8), bytes([i] * 8))
        got = [_recv(b) for _ in range(20)]
        assert [f.data[0] for f in got] == list(range(20))
        assert all(f.timestamp <= time.monotonic() for f in got)
        assert b.recv(0.0) is None and other.recv(0.05) is None


def test_bus_off_error_frame_raises_naming_port():
    port = _channel()
    with CanTransport(port) as host, CanTransport(port) as boards:
        boards.send_error(CAN_ERR_BUSOFF)
        with pytest.raises(BusOff, match=port):
            host.recv(1.0)
        with pytest.raises(BusOff):  # sticky: every later call reports it too
            host.send(0x80, b"\x00\x00")


def test_error_frame_storm_raises_corrupt_frames():
    port = _channel()
    with CanTransport(port) as host, CanTransport(port) as boards:
        for _ in range(10):
            boards.send_error(0x08)  # protocol violation class
        with pytest.raises(CorruptFrames, match=port):
            for _ in range(20):
                host.recv(0.1)


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_dead_receive_thread_is_reported():
    with CanTransport(_channel()) as host:
        def broken(timeout=None):
            raise OSError("adapter unplugged")
        host.bus.recv = broken
        deadline = time.monotonic() + 2.0
        with pytest.raises(LinkLost, match="receive thread died"):
            while time.monotonic() < deadline:
                host.recv(0.05)


@pytest.fixture
def pty_pair():
    master = PtyMaster()
    boards = SerialTransport(master, name="pty-boards")
    host = SerialTransport(master.slave_path)
    yield host, boards, master
    host.close()
    boards.close()


def test_serial_pty_round_trip_both_ways(pty_pair):
    host, boards, _ = pty_pair
    host.send(0x101, b"\x00\x10\x00\x00")
    assert _recv(boards)[:2] == (0x101, b"\x00\x10\x00\x00")
    for i in range(30):
        boards.send(0x201, bytes([i, 0, 0, 0, 0, 0, 0, 0]))
    assert [_recv(host).data[0] for _ in range(30)] == list(range(30))


def test_serial_resyncs_after_garbage_then_reports_a_storm(pty_pair):
    host, boards, master = pty_pair
    master.write(b"\x17\x42 boot banner \xff")
    boards.send(0x202, b"\x05" * 8)
    assert _recv(host)[:2] == (0x202, b"\x05" * 8)
    for _ in range(6):
        master.write(b"\x00\x99\x98\x97\x00")
    with pytest.raises(CorruptFrames, match="bad serial frames"):
        for _ in range(20):
            host.recv(0.1)


def test_serial_carries_error_frames(pty_pair):
    host, boards, _ = pty_pair
    boards.send_error(CAN_ERR_BUSOFF)
    with pytest.raises(BusOff, match=host.port):
        host.recv(1.0)


def test_serial_unplugged_is_reported():
    master = PtyMaster()
    host = SerialTransport(master.slave_path)
    try:
        master.close()  # the USB adapter goes away
        with pytest.raises(LinkLost, match="serial reader stopped"):
            for _ in range(20):
                host.recv(0.1)
    finally:
        host.close()
