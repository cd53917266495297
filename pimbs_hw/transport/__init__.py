"""Transports: how protocol frames reach the boards (CAN via python-can, or USB-serial)."""

from __future__ import annotations

from pimbs_hw.transport.base import Frame, Transport
from pimbs_hw.transport.canbus import CanTransport, parse_can_port
from pimbs_hw.transport.serialport import PtyMaster, SerialTransport

_SERIAL_PREFIXES = ("/dev/tty", "/dev/pts/", "/dev/cu.", "COM", "serial:", "loop://", "socket://",
                    "rfc2217://")


def is_serial_port(port: str) -> bool:
    """Serial devices, pty paths and pyserial URLs; everything else is a CAN port."""
    return port.startswith(_SERIAL_PREFIXES)


def open_transport(port: str, **kwargs) -> Transport:
    """Transport for a ``--port`` string: ``serial:/dev/x`` forces serial."""
    if is_serial_port(port):
        return SerialTransport(port.removeprefix("serial:"), **kwargs)
    return CanTransport(port, **kwargs)


__all__ = ["CanTransport", "Frame", "PtyMaster", "SerialTransport", "Transport",
           "is_serial_port", "open_transport", "parse_can_port"]
