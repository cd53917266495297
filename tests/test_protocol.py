"""Board protocol: DBC, codec round trips and edges, serial framing, bus-load arithmetic."""

from __future__ import annotations

import dataclasses
import random

import cantools
import pytest

from pimbs_hw.protocol import codec
from pimbs_hw.protocol.busload import frame_bits, stuff_bits
from pimbs_hw.protocol.codec import (
    MESSAGE_TYPES,
    CodecError,
    Fault,
    JointStatus,
    PositionCommand,
    Relax,
    SetLimits,
    Status,
    Stop,
    TensionCommand,
    decode,
    encode,
    signal_range,
)
from pimbs_hw.protocol.crc import crc8_j1850, crc16_ccitt
from pimbs_hw.protocol.framing import (
    FrameDecoder,
    FramingError,
    cobs_decode,
    cobs_encode,
    pack_frame,
    unpack_frame,
)


def test_dbc_loads_in_cantools_and_matches_dataclasses():
    db = cantools.database.load_file(str(codec.DBC_PATH))
    assert {m.name for m in db.messages} == {cls.MESSAGE for cls in MESSAGE_TYPES}
    for cls in MESSAGE_TYPES:
        signals = {s.name for s in db.get_message_by_name(cls.MESSAGE).signals}
        fields = {f.name for f in dataclasses.fields(cls)} - {"board_id", "faults"}
        fault_signals = {f"fault_{f.name.lower()}" for f in Fault} if cls is Status else set()
        assert signals == fields | {"crc"} | fault_signals
    status = db.get_message_by_name("STATUS")
    bits = [status.get_signal_by_name(f"fault_{f.name.lower()}").start for f in Fault]
    assert bits == sorted(bits) and [1 << (b - bits[0]) for b in bits] == [f.value for f in Fault]


def test_crc_check_values():
    assert crc8_j1850(b"123456789") == 0x4B
    assert crc16_ccitt(b"123456789") == 0x29B1


def _edges(cls, name):
    lo, hi = signal_range(cls, name)
    return [lo, hi, 0] if lo <= 0 <= hi else [lo, hi]


def _samples():
    yield Stop(0, 0)
    yield Relax(31, 15)
    for v in _edges(PositionCommand, "position_counts"):
        yield PositionCommand(5, 3, int(v))
    for v in _edges(TensionCommand, "loadcell_raw"):
        yield TensionCommand(7, 9, int(v))
    for wd in (0.0, 0.25, 4.095):
        yield SetLimits(1, 2, wd, 32767, -32768, 87.5)
    yield SetLimits(1, 2, 0.1, 4448, 2088, -40.0)
    for pos, raw, temp, faults in [(-524288, -32768, -40.0, Fault(0)),
                                   (524287, 32767, 87.5, Fault(255)),
                                   (1234, 2048, 25.5, Fault.OVERHEAT | Fault.WATCHDOG)]:
        yield Status(4, 15, pos, raw, temp, faults)
    for angle in (*_edges(JointStatus, "angle_rad"), 1.23456):
        yield JointStatus(1, 4, angle)


@pytest.mark.parametrize("msg", list(_samples()), ids=repr)
def test_round_trip_every_message(msg):
    fid, data = encode(msg)
    assert codec.board_of(fid) == msg.board_id
    back = decode(fid, data)
    assert type(back) is type(msg)
    for f in dataclasses.fields(msg):
        want = getattr(msg, f.name)
        assert getattr(back, f.name) == (want if isinstance(want, int) else pytest.approx(want))


def test_ids_are_base_plus_board():
    assert encode(Status(3, 0, 0, 0, 20.0, Fault(0)))[0] == 0x200 + 3
    assert encode(Stop(31, 0))[0] == 0x80 + 31
    with pytest.raises(ValueError, match="board_id"):
        encode(Stop(32, 0))


def test_out_of_range_value_refused():
    with pytest.raises(CodecError):
        encode(PositionCommand(1, 0, 1 << 20))


def test_counter_wraps_to_4_bits():
    fid, data = encode(Relax(2, 17))
    assert decode(fid, data).counter == 1


def test_corruption_and_misattribution_detected():
    fid, data = encode(Status(2, 1, 100, 2100, 30.0, Fault(0)))
    rng = random.Random(0)
    for _ in range(50):
        bad = bytearray(data)
        bad[rng.randrange(8)] ^= 1 << rng.randrange(8)
        with pytest.raises(CodecError, match="CRC"):
            decode(fid, bytes(bad))
    with pytest.raises(CodecError, match="CRC"):
        decode(fid + 1, data)  # same payload under another board's id
    with pytest.raises(CodecError, match="bytes"):
        decode(fid, data[:7])
    with pytest.raises(CodecError, match="not a PIMBS"):
        decode(0x7FF, data)


@pytest.mark.parametrize("n", [0, 1, 253, 254, 255, 600])
def test_cobs_round_trip(n):
    rng = random.Random(n)
    for payload in (bytes(n), bytes(rng.randrange(256) for _ in range(n)), b"\x01" * n):
        enc = cobs_encode(payload)
        assert 0 not in enc and cobs_decode(enc) == payload


def test_serial_frame_round_trip_and_crc():
    enc = pack_frame(0x203, b"\x00\x01\x00\xff")
    assert enc[0] == 0 and enc[-1] == 0 and 0 not in enc[1:-1]
    assert unpack_frame(enc[1:-1]) == (0x203, b"\x00\x01\x00\xff", False)
    assert unpack_frame(pack_frame(0x40, b"", is_error=True)[1:-1]) == (0x40, b"", True)
    for i in range(1, len(enc) - 1):
        bad = bytearray(enc[1:-1])
        bad[i - 1] ^= 0x10
        if 0 in bad:
            continue
        with pytest.raises(FramingError):
            unpack_frame(bytes(bad))


def test_decoder_resyncs_after_garbage_and_split_reads():
    frames = [(0x200 + i, bytes([i, 0, 255, i])) for i in range(5)]
    stream = b"\xaa\x55 line noise" + pack_frame(*frames[0]) + b"\x13\x37"
    stream += b"".join(pack_frame(*f) for f in frames[1:])
    corrupt = bytearray(pack_frame(0x211, b"\x01\x02"))
    corrupt[3] ^= 0x40
    stream += bytes(corrupt) + pack_frame(0x212, b"ok")
    dec = FrameDecoder()
    got = []
    for i in range(0, len(stream), 3):  # arbitrary chunking, as a UART read returns
        got += dec.feed(stream[i:i + 3])
    assert [(i, d) for i, d, _ in got] == frames + [(0x212, b"ok")]
    assert dec.bad_frames == 3  # leading noise, the 2 stray bytes, the corrupt frame
    assert dec.feed(b"\x07" * 5000) == [] and dec.bad_frames == 4  # no delimiter: dropped
    assert [i for i, _, _ in dec.feed(pack_frame(0x201, b"x"))] == [0x201]


def test_frame_bits_include_stuffing():
    assert stuff_bits([0] * 5) == 1 and stuff_bits([0, 1] * 10) == 0
    base = 1 + 11 + 3 + 4 + 64 + 15 + 13  # unstuffed 8-byte standard frame
    bits = frame_bits(*encode(Status(1, 0, 0, 2048, 25.0, Fault(0))))
    assert base <= bits <= base + 24
    assert frame_bits(0x80, b"\x00\x00") > 1 + 11 + 3 + 4 + 16 + 15 + 13
