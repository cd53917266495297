"""The bulk SLCAN reader yields exactly the lines, and so the messages, of python-can's own
one-byte-at-a-time reader, however the adapter's bytes are cut into reads.

A pty delivers what one side writes to the other asynchronously (the kernel pushes it in a
work item), so nothing here waits a fixed time for bytes to arrive: every read that must
find a line may wait seconds (it returns as soon as the line is there), and a read that must
find nothing is made only when no byte still on its way could complete a line.
"""

from __future__ import annotations

import os
import time

import can
import pytest
from can.interfaces.slcan import slcanBus

from pimbs_hw.transport import CanTransport, PtyMaster
from pimbs_hw.transport.slcan import SlcanBus

FRAMES = (b"t1238DEADBEEF01020304\r", b"t0000\r", b"T1ABCDEF02A55A\r", b"r7FF3\r",
          b"R000001234\r", b"d123900112233445566778899AABB\r")
ERROR = b"\a"  # what an adapter answers a command it refused
ARRIVES_S = 10.0  # how long a read waits for bytes already written (a loaded machine)


@pytest.fixture
def adapter():
    """The adapter's end of a pty: what the test writes there, the bus reads."""
    master = PtyMaster()
    yield master
    master.close()


def _take(master: PtyMaster, expected: bytes) -> bytes:
    """What the bus wrote to the adapter, once ``len(expected)`` bytes have come."""
    got, deadline = b"", time.monotonic() + ARRIVES_S
    while len(got) < len(expected) and time.monotonic() < deadline:
        got += master.read()
    return got


def _open(cls, master: PtyMaster) -> slcanBus:
    bus = cls(master.slave_path, sleep_after_open=0)
    assert _take(master, b"O\r") == b"O\r"  # the bus opened the channel
    return bus


def _close(bus: slcanBus, master: PtyMaster) -> None:
    bus.shutdown()
    assert _take(master, b"C\r") == b"C\r"  # and closed it: the pty is clean for the next


def _lines(cls, master: PtyMaster, pieces: list[bytes]) -> list[str | None]:
    """Write each piece and take the lines it completes, then one more read, which must
    time out (None): an unfinished line never comes out before its end has arrived."""
    bus = _open(cls, master)
    out: list[str | None] = []
    written = b""
    try:
        for piece in pieces:
            os.write(master.fd, piece)
            written += piece
            complete = written.count(b"\r") + written.count(b"\a")
            while len(out) - out.count(None) < complete:
                line = bus._read(ARRIVES_S)
                assert line is not None, f"{cls.__name__}: a complete line did not come"
                out.append(line)
            out.append(bus._read(0.01))
    finally:
        _close(bus, master)
    return out


STREAM = b"".join(FRAMES[:3]) + ERROR + b"".join(FRAMES[3:])
CUTS = {
    "several frames in one read": [STREAM],
    "frames split across reads": [STREAM[:7], STREAM[7:30], STREAM[30:31], STREAM[31:]],
    "a byte at a time": [STREAM[i:i + 1] for i in range(len(FRAMES[0]) + 2)],
    "error bell between frames, partial frame at the end": [
        FRAMES[0] + ERROR + FRAMES[1][:3], FRAMES[1][3:] + FRAMES[2][:-1], b"\r"],
}


@pytest.mark.parametrize("pieces", CUTS.values(), ids=CUTS.keys())
def test_bulk_reader_yields_python_cans_own_lines(adapter, pieces):
    ours = _lines(SlcanBus, adapter, pieces)
    assert ours == _lines(slcanBus, adapter, pieces)
    lines = [line for line in ours if line is not None]
    sent = b"".join(pieces)
    assert "".join(lines).encode() == sent[:max(sent.rfind(b"\r"), sent.rfind(b"\a")) + 1]
    assert ours.count(None) == len(pieces)  # each piece's unfinished rest waited for its end


def test_error_bell_is_a_line_of_its_own(adapter):
    assert _lines(SlcanBus, adapter, [FRAMES[0] + ERROR + FRAMES[1][:3], FRAMES[1][3:]]) == [
        FRAMES[0].decode(), "\a", None, FRAMES[1].decode(), None]


def _messages(cls, master: PtyMaster, data: bytes, n: int) -> list[can.Message]:
    bus = _open(cls, master)
    try:
        os.write(master.fd, data)
        out = [bus.recv(ARRIVES_S) for _ in range(n)]
        assert bus.recv(0.01) is None
        return out
    finally:
        _close(bus, master)


def _fields(msg: can.Message) -> tuple:
    return (msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, msg.is_fd, msg.dlc,
            bytes(msg.data))


def test_bulk_reader_gives_python_cans_messages(adapter):
    ours = _messages(SlcanBus, adapter, STREAM, len(FRAMES))  # the bell is no message
    theirs = _messages(slcanBus, adapter, STREAM, len(FRAMES))
    assert [_fields(m) for m in ours] == [_fields(m) for m in theirs]
    assert _fields(ours[0]) == (0x123, False, False, False, 8, bytes.fromhex("DEADBEEF01020304"))
    assert _fields(ours[2]) == (0x1ABCDEF0, True, False, False, 2, b"\xa5\x5a")
    assert _fields(ours[5])[:5] == (0x123, False, False, True, 12)


def test_frames_read_with_a_version_answer_stay_in_order(adapter):
    """python-can's version request sets aside the frames that come before its answer; the
    frames read in the same chunk after it come next, in the order the adapter sent them."""
    bus = _open(SlcanBus, adapter)
    try:
        os.write(adapter.fd, FRAMES[0] + b"V1013\r" + FRAMES[1])
        assert bus.get_version(ARRIVES_S) == (10, 13)
        assert _take(adapter, b"V\r") == b"V\r"
        got = [bus.recv(ARRIVES_S), bus.recv(ARRIVES_S)]
        assert [m.arbitration_id for m in got] == [0x123, 0x000] and bus.recv(0.01) is None
    finally:
        _close(bus, adapter)


def test_flush_discards_lines_read_but_not_yet_taken(adapter):
    bus = _open(SlcanBus, adapter)
    try:
        # one write reaches the bus whole: the second frame and the rest are read with the first
        os.write(adapter.fd, FRAMES[0] + FRAMES[1] + b"t12")
        assert bus._read(ARRIVES_S) == FRAMES[0].decode()
        bus.flush()
        os.write(adapter.fd, FRAMES[2])
        assert _fields(bus.recv(ARRIVES_S))[0] == 0x1ABCDEF0  # nothing older survived
    finally:
        _close(bus, adapter)


def test_can_transport_opens_slcan_with_the_bulk_reader(adapter, monkeypatch):
    for var in ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_BITRATE", "CAN_CONFIG"):
        monkeypatch.delenv(var, raising=False)
    transport = CanTransport(f"slcan:{adapter.slave_path}@1000000", sleep_after_open=0)
    try:
        assert type(transport.bus) is SlcanBus
        # python-can's own opening: bitrate code between a close and an open, then open
        opening = b"C\rS8\r\rO\rO\r"
        assert _take(adapter, opening) == opening
        os.write(adapter.fd, FRAMES[0])
        frame = transport.recv(ARRIVES_S)
        assert frame is not None and (frame.arbitration_id, frame.data) == (
            0x123, bytes.fromhex("DEADBEEF01020304"))
    finally:
        transport.close()
