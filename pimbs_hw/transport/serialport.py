"""Serial transport: board frames over a USB-serial link, COBS + CRC-16 framed.

The byte stream can be a pyserial port (a device path, ``COM3``, any pyserial URL, a pty
slave path) or any object with ``read(n)``, ``write(b)``, ``close()`` (the simulated boards
use a pty master through ``PtyMaster``). A reader thread decodes frames into the queue.
"""

from __future__ import annotations

import errno
import os
import select
import threading
import time
import tty
from typing import Protocol

import serial

from pimbs_hw.errors import PortError
from pimbs_hw.host_lag import host_lag
from pimbs_hw.protocol.framing import FrameDecoder, pack_frame
from pimbs_hw.safety import LinkLost, SafetyStop
from pimbs_hw.transport.base import Frame, QueuedTransport

READ_TIMEOUT_S = 0.05
WRITE_TIMEOUT_S = 0.5  # a USB-serial buffer full this long is a lost link, a moment is not


class ByteStream(Protocol):
    def read(self, size: int = 1) -> bytes: ...
    def write(self, data: bytes) -> int | None: ...
    def close(self) -> None: ...


class PtyMaster:
    """The board end of a pseudo-terminal; ``slave_path`` is what the driver opens.

    Non-blocking writes: with nobody on the other end a board's UART just drops bytes, it
    never stalls the firmware.
    """

    def __init__(self) -> None:
        self.fd, self._slave_fd = os.openpty()
        tty.setraw(self._slave_fd)  # no echo, no newline translation: binary frames
        os.set_blocking(self.fd, False)
        self.slave_path = os.ttyname(self._slave_fd)

    def read(self, size: int = 1) -> bytes:
        ready, _, _ = select.select([self.fd], [], [], READ_TIMEOUT_S)
        if not ready:
            return b""
        try:
            return os.read(self.fd, 4096)
        except BlockingIOError:
            return b""
        except OSError as exc:  # EIO: no slave open right now; wait instead of spinning
            if exc.errno != errno.EIO:
                raise
            time.sleep(READ_TIMEOUT_S)
            return b""

    def write(self, data: bytes) -> int:
        try:
            return os.write(self.fd, data)
        except (BlockingIOError, OSError):
            return 0

    def close(self) -> None:
        for fd in (self.fd, self._slave_fd):
            try:
                os.close(fd)
            except OSError:
                pass


def _open_serial(port: str, baudrate: int, write_timeout_s: float) -> serial.SerialBase:
    try:
        stream = serial.serial_for_url(port, baudrate=baudrate, timeout=READ_TIMEOUT_S,
                                       write_timeout=write_timeout_s)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise PortError(port, f"cannot open serial port {port!r} ({exc}): is the board plugged "
                              "in (`ls /dev/ttyUSB* /dev/ttyACM*`) and are you in the dialout "
                              "group? use --port virtual for the simulated arm") from exc
    stream.reset_input_buffer()
    return stream


class SerialTransport(QueuedTransport):
    """Frames over a byte stream, received by a reader thread."""

    def __init__(self, port: str | ByteStream, *, baudrate: int = 1_000_000,
                 corrupt_per_s: int = 3, name: str | None = None,
                 send_timeout_s: float = WRITE_TIMEOUT_S) -> None:
        label = name or (port if isinstance(port, str) else repr(port))
        super().__init__(label, corrupt_per_s)
        self.stream: ByteStream = (_open_serial(port, baudrate, send_timeout_s)
                                   if isinstance(port, str) else port)
        self._decoder = FrameDecoder()
        self._write_lock = threading.Lock()
        self._thread = threading.Thread(target=self._reader, name=f"serial-rx {label}",
                                        daemon=True)
        self._thread.start()

    def _reader(self) -> None:
        try:
            while not self.closed:
                chunk = self.stream.read(256)
                if not chunk:
                    continue  # read timed out (the stream blocks for READ_TIMEOUT_S)
                now = time.monotonic()
                bad_before = self._decoder.bad_frames
                for can_id, data, is_error in self._decoder.feed(chunk):
                    self._deliver(Frame(can_id, data, now, is_error))
                for _ in range(self._decoder.bad_frames - bad_before):
                    self._count_bad("bad serial frames (CRC/COBS)")
        except Exception as exc:  # noqa: BLE001 - any reader death must reach the control loop
            if not self.closed:
                self._fail(LinkLost(f"serial reader stopped: {exc!r} (unplugged?)",
                                    port=self.port))

    def _alive(self) -> SafetyStop | None:
        if self._thread.is_alive():
            return None
        return LinkLost("serial reader thread is not running", port=self.port)

    def _write(self, frame: bytes) -> None:
        """Write one frame; a buffer that stays full for the write timeout is a lost link,
        unless this program could not run for most of that time (``HostLag``): then whoever
        reads the other end (simulated boards in this process, or this process's own reader)
        could not drain it either. That frame is lost (a board drops a torn one by its CRC)
        and the next cycle's command goes out as usual."""
        self.check()
        start = time.monotonic()
        try:
            with self._write_lock:
                self.stream.write(frame)
        except serial.SerialTimeoutException as exc:
            end = time.monotonic()
            if host_lag().starved(start, end) < 0.5 * (end - start):
                self._fail(LinkLost(f"serial write failed: {exc}", port=self.port))
                raise self._fault from exc  # type: ignore[misc]
        except (serial.SerialException, OSError) as exc:
            self._fail(LinkLost(f"serial write failed: {exc}", port=self.port))
            raise self._fault from exc  # type: ignore[misc]

    def send(self, arbitration_id: int, data: bytes) -> None:
        self._write(pack_frame(arbitration_id, data))

    def send_error(self, error_class: int) -> None:
        self._write(pack_frame(error_class, b"", is_error=True))

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self._thread.join(timeout=1.0)
        self.stream.close()
