"""The ``Transport`` interface and the receive-side supervision every transport shares.

A transport moves protocol frames. Reception runs in its own thread (python-can Notifier,
or a serial reader) so a slow control loop never loses frames; frames wait in a queue.
Problems the receive side sees (error frames, bus-off, undecodable serial frames, a dead
thread) are stored and raised, naming the port, by the next ``recv`` of the control loop.
"""

from __future__ import annotations

import collections
import queue
import threading
import time
from abc import ABC, abstractmethod
from typing import NamedTuple

from pimbs_hw.safety import BusOff, CorruptFrames, SafetyStop

# SocketCAN error classes carried in an error frame's id (linux/can/error.h)
CAN_ERR_BUSOFF = 0x40
CAN_ERR_RESTARTED = 0x100


class Frame(NamedTuple):
    arbitration_id: int
    data: bytes
    timestamp: float  # time.monotonic() when the receive thread got it
    is_error: bool = False


class Transport(ABC):
    """Send and receive protocol frames on one port."""

    port: str

    @abstractmethod
    def send(self, arbitration_id: int, data: bytes) -> None:
        """Queue one frame for transmission."""

    @abstractmethod
    def send_error(self, error_class: int) -> None:
        """Emit an error frame (simulated boards use it to fake bus problems)."""

    @abstractmethod
    def recv(self, timeout: float | None = 0.0) -> Frame | None:
        """Next received frame, or None after ``timeout`` s; raises SafetyStop on link faults."""

    @abstractmethod
    def close(self) -> None:
        """Stop the receive thread and release the port (idempotent)."""

    def __enter__(self) -> Transport:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class QueuedTransport(Transport):
    """Queue + supervision shared by the CAN and serial transports.

    Subclasses call ``_deliver`` from their receive thread, ``_fail`` when it dies or the
    port breaks, ``_count_bad`` for an undecodable frame, and implement ``_alive``.
    """

    def __init__(self, port: str, corrupt_per_s: int = 3) -> None:
        self.port = port
        self._queue: queue.SimpleQueue[Frame | None] = queue.SimpleQueue()
        self._fault: SafetyStop | None = None
        self._corrupt_per_s = corrupt_per_s
        self._bad_times: collections.deque[float] = collections.deque()
        self._lock = threading.Lock()
        self._bypass = False
        self.closed = False

    # -- receive thread side ---------------------------------------------------------------
    def _deliver(self, frame: Frame) -> None:
        if not frame.is_error:
            self._queue.put(frame)
        elif frame.arbitration_id & CAN_ERR_BUSOFF:
            self._fail(BusOff("CAN controller is bus-off (error frame); check wiring, "
                              "termination (120 ohm at both ends) and bitrate", port=self.port))
        elif not frame.arbitration_id & CAN_ERR_RESTARTED:
            self._count_bad("CAN error frames")

    def _count_bad(self, what: str) -> None:
        now = time.monotonic()
        with self._lock:
            self._bad_times.append(now)
            while self._bad_times and now - self._bad_times[0] > 1.0:
                self._bad_times.popleft()
            too_many = len(self._bad_times) > self._corrupt_per_s
        if too_many:
            self._fail(CorruptFrames(f"more than {self._corrupt_per_s} {what} in 1 s; "
                                     "check wiring, termination and bitrate", port=self.port))

    def _fail(self, fault: SafetyStop) -> None:
        if self._fault is None:
            self._fault = fault
            self._queue.put(None)  # wake a blocked recv

    # -- control loop side -----------------------------------------------------------------
    @abstractmethod
    def _alive(self) -> SafetyStop | None:
        """None while the receive side is healthy, else the stop describing why not."""

    def check(self) -> None:
        """Raise the pending link fault, if any."""
        if self._bypass:
            return
        if self._fault is None and not self.closed:
            problem = self._alive()
            if problem is not None:
                self._fail(problem)
        if self._fault is not None:
            raise self._fault

    def usable(self) -> bool:
        """Whether frames can still go out: after a bad-frame storm they can (the stop is
        about trusting what comes in); after bus-off or a lost link they cannot."""
        return not self.closed and (self._fault is None
                                    or isinstance(self._fault, CorruptFrames))

    def send_despite_fault(self, arbitration_id: int, data: bytes) -> None:
        """Send although a stop is pending (the driver's last relax after a stop)."""
        self._bypass = True
        try:
            self.send(arbitration_id, data)
        finally:
            self._bypass = False

    def recv(self, timeout: float | None = 0.0) -> Frame | None:
        self.check()
        try:
            if timeout is not None and timeout <= 0:
                frame = self._queue.get_nowait()
            else:
                frame = self._queue.get(timeout=timeout)
        except queue.Empty:
            return None
        if frame is None:
            self.check()
        return frame
