"""Serial framing: the same CAN frames over a USB-serial byte stream.

Wire format of one frame (COBS-encoded, between 0x00 delimiters)::

    flags:u8 | can_id:u32 LE | data[0..64] | crc16:u16 BE      (CRC-16/CCITT over flags..data)

flags: bit0 extended id, bit1 error frame (can_id then holds the error class, as SocketCAN),
bits 4..7 framing version (1). COBS guarantees 0x00 appears only as a delimiter, so a reader
that starts mid-stream, or meets line noise, drops at most the frame it is in and resyncs at the
next 0x00. Bad frames are counted, not raised: the transport decides when too many is a fault.
"""

from __future__ import annotations

import struct

from pimbs_hw.protocol.crc import crc16_ccitt

VERSION = 1
FLAG_EXTENDED = 0x01
FLAG_ERROR = 0x02
_HEADER = struct.Struct("<BI")
_CRC = struct.Struct(">H")
MAX_DATA = 64
MAX_ENCODED = 2 + (_HEADER.size + MAX_DATA + _CRC.size) * 255 // 254  # COBS overhead bound


class FramingError(ValueError):
    """One undecodable serial frame (COBS, CRC, header)."""


def cobs_encode(data: bytes) -> bytes:
    """Consistent Overhead Byte Stuffing: output contains no 0x00."""
    out = bytearray()
    block = bytearray()
    for byte in data:
        if byte == 0:
            out.append(len(block) + 1)
            out += block
            block.clear()
        else:
            block.append(byte)
            if len(block) == 254:
                out.append(255)
                out += block
                block.clear()
    out.append(len(block) + 1)
    out += block
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Inverse of cobs_encode; raises FramingError on a malformed block."""
    out = bytearray()
    i = 0
    n = len(data)
    while i < n:
        code = data[i]
        if code == 0 or i + code > n:
            raise FramingError("COBS block overruns the frame")
        block = data[i + 1:i + code]
        if 0 in block:
            raise FramingError("0x00 inside a COBS block")
        out += block
        i += code
        if code < 255 and i < n:
            out.append(0)
    return bytes(out)


def pack_frame(arbitration_id: int, data: bytes, *, is_error: bool = False,
               is_extended: bool = False) -> bytes:
    """Bytes to write for one CAN frame; delimiters on both sides so garbage before it
    (a reader that just opened the port, line noise) costs no good frame."""
    if len(data) > MAX_DATA:
        raise ValueError(f"{len(data)} data bytes; at most {MAX_DATA}")
    flags = (VERSION << 4) | (FLAG_ERROR if is_error else 0) | (FLAG_EXTENDED if is_extended else 0)
    body = _HEADER.pack(flags, arbitration_id) + bytes(data)
    return b"\x00" + cobs_encode(body + _CRC.pack(crc16_ccitt(body))) + b"\x00"


def unpack_frame(encoded: bytes) -> tuple[int, bytes, bool]:
    """(can_id, data, is_error) of one delimiter-free frame; raises FramingError."""
    raw = cobs_decode(encoded)
    if len(raw) < _HEADER.size + _CRC.size:
        raise FramingError(f"frame of {len(raw)} bytes is shorter than header + CRC")
    body, (crc,) = raw[:-_CRC.size], _CRC.unpack(raw[-_CRC.size:])
    if crc16_ccitt(body) != crc:
        raise FramingError("CRC-16 mismatch")
    flags, can_id = _HEADER.unpack_from(body)
    if flags >> 4 != VERSION:
        raise FramingError(f"framing version {flags >> 4}, expected {VERSION}")
    return can_id, body[_HEADER.size:], bool(flags & FLAG_ERROR)


class FrameDecoder:
    """Incremental decoder: feed it whatever the port returned, get whole frames back."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self.bad_frames = 0  # frames dropped (CRC, COBS, oversize); read by the transport

    def feed(self, chunk: bytes) -> list[tuple[int, bytes, bool]]:
        self._buf += chunk
        frames = []
        while (end := self._buf.find(0)) >= 0:
            encoded = bytes(self._buf[:end])
            del self._buf[:end + 1]
            if not encoded:
                continue  # back-to-back delimiters: idle line / resync
            try:
                frames.append(unpack_frame(encoded))
            except FramingError:
                self.bad_frames += 1
        if len(self._buf) > MAX_ENCODED:  # garbage without a delimiter: drop it, wait for 0x00
            self._buf.clear()
            self.bad_frames += 1
        return frames
