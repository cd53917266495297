"""Checksums of the board protocol, kept in one place so boards, driver and framing agree.

- CRC-8/SAE-J1850 protects each CAN payload end to end (catches corruption that the CAN
  controller cannot see: a gateway, a USB-serial adapter, a firmware bug writing the wrong
  buffer). It covers the frame id too, so a frame that arrives under another board's id fails.
- CRC-16/CCITT-FALSE protects each serial frame (``binascii.crc_hqx`` is C, so it is cheap).
"""

from __future__ import annotations

import binascii


def _crc8_table(poly: int) -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_J1850 = _crc8_table(0x1D)


def crc8_j1850(data: bytes) -> int:
    """CRC-8/SAE-J1850 (poly 0x1D, init 0xFF, xorout 0xFF); check("123456789") == 0x4B."""
    crc = 0xFF
    for byte in data:
        crc = _J1850[crc ^ byte]
    return crc ^ 0xFF


def crc16_ccitt(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF); check("123456789") == 0x29B1."""
    return binascii.crc_hqx(data, 0xFFFF)
