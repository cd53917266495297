"""On-wire size of a classic CAN frame, for bus-load estimates.

Counts the exact bits of a CAN 2.0A data frame including bit stuffing (computed on the real
bit sequence with its CRC-15), so a bus-load figure reflects the payloads we actually send.
"""

from __future__ import annotations

_TRAILER_BITS = 1 + 1 + 1 + 7 + 3  # CRC delimiter, ACK slot, ACK delimiter, EOF, intermission


def _bits(value: int, width: int) -> list[int]:
    return [(value >> (width - 1 - i)) & 1 for i in range(width)]


def _crc15(bits: list[int]) -> int:
    crc = 0
    for bit in bits:
        feedback = bit ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if feedback:
            crc ^= 0x4599
    return crc


def stuff_bits(bits: list[int]) -> int:
    """Number of stuff bits a transmitter inserts into ``bits`` (5 equal bits -> 1 stuff bit)."""
    count, run, last = 0, 0, None
    for bit in bits:
        if bit == last:
            run += 1
        else:
            run, last = 1, bit
        if run == 5:
            count += 1
            run, last = 1, 1 - bit  # the stuff bit starts the next run
    return count


def frame_bits(arbitration_id: int, data: bytes) -> int:
    """Bits a standard-id data frame occupies on the bus, stuffing and intermission included."""
    if not 0 <= arbitration_id < 0x800 or len(data) > 8:
        raise ValueError("classic CAN 2.0A: 11-bit id, at most 8 data bytes")
    head = [0] + _bits(arbitration_id, 11) + [0, 0, 0] + _bits(len(data), 4)
    for byte in data:
        head += _bits(byte, 8)
    stuffed = head + _bits(_crc15(head), 15)
    return len(stuffed) + stuff_bits(stuffed) + _TRAILER_BITS


def bus_load(frames_per_s: float, bits_per_frame: float, bitrate: float = 1_000_000) -> float:
    """Fraction of the bus a traffic of ``frames_per_s`` frames of that size occupies."""
    return frames_per_s * bits_per_frame / bitrate
