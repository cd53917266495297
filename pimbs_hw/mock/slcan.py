"""An SLCAN (Lawicel ASCII) USB-CAN adapter emulated on a pty, for the simulated boards.

python-can's ``virtual`` bus skips every real interface. This adapter lets the driver open
the simulated arm through python-can's real ``slcan`` interface (``slcan:/dev/pts/N``), so
its serial framing, its open/close handshake, and its timing and losses are exercised the
way a CANable or USBtin on a USB port would exercise them.

Lawicel commands understood (each ends with CR; the reply is CR for OK, BEL for an error):
``Sn`` bitrate code, ``O``/``L`` open (listen-only), ``C`` close, ``V``/``v``/``N`` version
and serial number, ``F`` status flags, ``tIIILDD..`` / ``TIIIIIIIILDD..`` a frame to send.
Frames from the bus reach the host as ``tIIILDD..CR`` only while the channel is open.
SLCAN has no error-frame format: a bus-off on this adapter is seen by the host as every
board falling silent, as with most USB adapters.
"""

from __future__ import annotations

import os
import select
import threading
import time

from pimbs_hw.host_lag import host_lag
from pimbs_hw.safety import LinkLost, SafetyStop
from pimbs_hw.transport.base import Frame, QueuedTransport
from pimbs_hw.transport.serialport import PtyMaster

OK, ERROR = b"\r", b"\a"
VERSION = b"V1013\r"  # hardware 1.0, software 1.3, as a USBtin answers
SERIAL_NUMBER = b"NPIMB\r"
FLOW_WAIT_S = 1.0


def format_frame(arbitration_id: int, data: bytes, extended: bool = False) -> bytes:
    """The ASCII line an adapter sends for a received frame."""
    head = f"T{arbitration_id:08X}" if extended else f"t{arbitration_id:03X}"
    return f"{head}{len(data):d}{bytes(data).hex().upper()}\r".encode()


def parse_frame(line: str) -> tuple[int, bytes] | None:
    """``(id, data)`` of a ``t``/``T`` line (without CR), None if malformed."""
    try:
        width = 3 if line[0] == "t" else 8
        arbitration_id = int(line[1:1 + width], 16)
        dlc = int(line[1 + width])
        data = bytes.fromhex(line[2 + width:2 + width + 2 * dlc])
    except (IndexError, ValueError):
        return None
    if len(data) != dlc or dlc > 8 or len(line) != 2 + width + 2 * dlc:
        return None
    return arbitration_id, data


class SlcanAdapter(QueuedTransport):
    """The bus side of an emulated adapter: the simulated boards ``send``/``recv`` frames.

    ``port`` is the python-can port string the host opens (``slcan:/dev/pts/N``).
    """

    def __init__(self) -> None:
        self._pty = PtyMaster()
        super().__init__(f"slcan:{self._pty.slave_path}")
        self.is_open = False
        self.bitrate_code: str | None = None
        self._thread = threading.Thread(target=self._reader, daemon=True,
                                        name=f"slcan-adapter {self.port}")
        self._thread.start()

    # -- host side (the pty) ---------------------------------------------------------------
    def _reader(self) -> None:
        pending = b""
        try:
            while not self.closed:
                chunk = self._pty.read(256)
                if not chunk:
                    continue
                pending += chunk
                *lines, pending = pending.split(b"\r")
                now = time.monotonic()
                for raw in lines:
                    reply = self._command(raw.decode("ascii", "replace").strip("\n"), now)
                    if reply:
                        self._pty.write(reply)
        except Exception as exc:  # noqa: BLE001 - the boards' side must learn of it
            if not self.closed:
                self._fail(LinkLost(f"SLCAN adapter stopped: {exc!r}", port=self.port))

    def _command(self, line: str, now: float) -> bytes:
        if not line:
            return b""
        code = line[0]
        if code in "tT":
            frame = parse_frame(line)
            if frame is None or not self.is_open:
                return ERROR
            self._deliver(Frame(frame[0], frame[1], now))
            return b""  # python-can neither expects nor needs a per-frame acknowledgement
        if code == "S" and line[1:].isdigit() and int(line[1:]) <= 8:
            self.bitrate_code = line[1:]
            return OK
        if code in "OL":
            self.is_open = True
            return OK
        if code == "C":
            self.is_open = False
            return OK
        if code in "Vv":
            return VERSION
        if code == "N":
            return SERIAL_NUMBER
        if code == "F":
            return b"F00\r"
        return ERROR

    # -- bus side (the simulated boards) ----------------------------------------------------
    def send(self, arbitration_id: int, data: bytes) -> None:
        """Queue a bus frame for the host. USB is flow-controlled: when the host reads late
        the adapter waits (up to ``FLOW_WAIT_S``, not counting the time this process could
        not run: the host and this emulated adapter share it) instead of dropping, as its
        buffer would."""
        if not self.is_open or self.closed:
            return
        line = format_frame(arbitration_id, data)
        start = time.monotonic()
        while line and not self.closed:
            try:
                line = line[os.write(self._pty.fd, line):]
            except BlockingIOError:
                now = time.monotonic()
                if now - start > FLOW_WAIT_S and (
                        now - start - host_lag().starved(start, now) > FLOW_WAIT_S):
                    return  # the host stopped reading: the adapter's buffer overflows
                select.select([], [self._pty.fd], [], 0.01)
            except OSError:
                return  # nobody has the port open

    def send_error(self, error_class: int) -> None:
        """SLCAN cannot carry error frames: nothing reaches the host."""

    def _alive(self) -> SafetyStop | None:
        return None if self._thread.is_alive() else LinkLost("SLCAN adapter thread ended",
                                                             port=self.port)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self._thread.join(timeout=1.0)
        self._pty.close()
