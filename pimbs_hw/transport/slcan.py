"""python-can's ``slcan`` interface, reading what the adapter sent in one call, not per byte.

python-can's ``slcanBus._read`` (4.6) takes every byte in its own ``serial.read(1)``: a
Python call, a ``select`` and a ``read`` system call for each of the 22 bytes of an 8-byte
frame's line (``t1238DDDDDDDDDDDDDDDD`` CR). A 1 Mbit/s bus of several boards sends about a
thousand frames a second (four ODrive axes as the ``odrive-cansimple`` profile has them
configured: 880), which that alone turns into some 40 000 system calls a second and a good
part of a CPU core on the host, before any frame is used. When the host cannot keep up, the
adapter's buffer fills and the frames it drops look like a lossy bus.

``SlcanBus`` changes only how the bytes come off the serial port: everything waiting in one
``read``, split on the SLCAN terminators (CR ends a frame or an OK, BEL an error), and, on a
port the operating system can wait on, a wait for the next byte instead of python-can's
poll every millisecond (its default port timeout: some 5 % of a core while nothing comes).
Each line then goes through python-can's own parsing (``_recv_internal``); commands, version
and serial number requests, and sending are python-can's, unchanged. ``CanTransport`` uses
it whenever the interface is ``slcan`` (``benchmarks/slcan_read.py`` measures both).
"""

from __future__ import annotations

import collections
import re
import select

import serial
from can.exceptions import error_check
from can.interfaces.slcan import slcanBus

# one SLCAN line: anything up to and including its terminator (CR: frame or OK; BEL: error)
_LINE = re.compile(rb"[^\r\a]*[\r\a]")


class SlcanBus(slcanBus):
    """python-can's ``slcanBus`` with a bulk reader (see the module docstring)."""

    def __init__(self, *args, **kwargs) -> None:
        self._lines: collections.deque[bytes] = collections.deque()  # complete, not yet read
        super().__init__(*args, **kwargs)
        try:  # a port the operating system can wait on (every serial device on POSIX)
            self._fd: int | None = self.serialPortOrig.fileno()
        except (AttributeError, OSError, ValueError):  # io.UnsupportedOperation is both
            self._fd = None

    def _read(self, timeout: float | None) -> str | None:
        """The next line the adapter sent, its terminator included (as python-can's), or None
        after ``timeout`` s. An unfinished line stays in the buffer for the next call."""
        deadline = serial.Timeout(timeout)
        with error_check("Could not read from serial device"):
            while not self._lines:
                port = self.serialPortOrig
                waiting = port.in_waiting
                if not waiting and self._fd is not None:
                    # sleep until bytes arrive (python-can polls every port timeout: 1 ms)
                    select.select([self._fd], [], [], deadline.time_left())
                    waiting = port.in_waiting
                chunk = port.read(max(1, waiting))
                if chunk:
                    self._buffer += chunk
                    self._split()
                if not self._lines and deadline.expired():
                    return None
            return self._lines.popleft().decode()

    def _split(self) -> None:
        """Move the buffer's complete lines to ``_lines``; keep an unfinished one."""
        buffer = self._buffer
        end = max(buffer.rfind(b"\r"), buffer.rfind(b"\a")) + 1
        if end:
            self._lines.extend(_LINE.findall(buffer, 0, end))
            del buffer[:end]

    def flush(self) -> None:
        """Discard everything received and not yet read, as python-can's ``flush`` does."""
        self._lines.clear()
        super().flush()
