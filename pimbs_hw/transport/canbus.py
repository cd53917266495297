"""CAN transport over python-can: any interface python-can supports.

Port strings (``--port``):
  ``can0``, ``vcan1``          socketcan channel
  ``virtual`` / ``virtual:NAME``  python-can in-process virtual bus (the simulated arm)
  ``IFACE:CHANNEL[@BITRATE]``  ``pcan:PCAN_USBBUS1``, ``kvaser:0``, ``slcan:/dev/ttyACM0@1000000``
  ``IFACE``                    interface only, channel from python-can's config
  ``default`` or ``""``        everything from python-can's config file / ``CAN_*`` env vars
Only what the port names is passed to ``can.Bus``, so ``can.util.load_config`` fills in the
rest (bitrate, app name, ...) from ``~/.canrc``, ``can.ini`` or the environment.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Iterator
from typing import Any

import can
from can.broadcastmanager import ThreadBasedCyclicSendTask

from pimbs_hw.errors import PortError
from pimbs_hw.host_lag import host_lag
from pimbs_hw.safety import BusOff, LinkLost, SafetyStop
from pimbs_hw.transport.base import Frame, QueuedTransport
from pimbs_hw.transport.slcan import SlcanBus

VIRTUAL_DEFAULT_CHANNEL = "pimbs"
# a send that cannot go out this long is a lost link (a full adapter buffer for a moment is
# not: USB adapters and a busy host stall briefly); a board watchdog acts meanwhile
SEND_TIMEOUT_S = 0.5
_HINT = "use --port virtual for the simulated arm"
# python-can's interface modules log their missing vendor libraries as warnings on import
# ("Kvaser canlib is unavailable."); with no handler configured Python prints them bare on
# stderr. They belong in a log, and the one that explains a failed open goes into its message.
logging.getLogger("can").addHandler(logging.NullHandler())


class _Collect(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(" ".join(record.getMessage().split()))


@contextlib.contextmanager
def _python_can_warnings() -> Iterator[list[str]]:
    """Warnings python-can logs while an interface is imported and opened."""
    handler, logger = _Collect(), logging.getLogger("can")
    logger.addHandler(handler)
    try:
        yield handler.lines
    finally:
        logger.removeHandler(handler)


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def parse_can_port(port: str) -> dict[str, Any]:
    """``can.Bus`` keyword arguments named by a port string (see module docstring)."""
    if port in ("", "default"):
        return {}
    if port == "virtual":
        return {"interface": "virtual", "channel": VIRTUAL_DEFAULT_CHANNEL}
    iface, sep, channel = port.partition(":")
    if not sep:
        return {"interface": port} if port in can.VALID_INTERFACES else {
            "interface": "socketcan", "channel": port}
    if iface not in can.VALID_INTERFACES:
        raise PortError(port, f"unknown CAN interface {iface!r} in port {port!r}: use one of "
                              f"{', '.join(sorted(can.VALID_INTERFACES))}; {_HINT}")
    kwargs: dict[str, Any] = {"interface": iface}
    head, at, rate = channel.rpartition("@")
    if at and rate.isdigit():
        channel, kwargs["bitrate"] = head, int(rate)
    if channel:
        kwargs["channel"] = channel
    return kwargs


def open_bus(kwargs: dict[str, Any]) -> can.BusABC:
    """``can.Bus(**kwargs)``, with python-can's configuration filled in as it does; the
    ``slcan`` interface (named here or only in the configuration) opens as ``SlcanBus``,
    which reads what the adapter sent in bulk instead of one byte per call."""
    config = dict(can.util.load_config(config=kwargs))
    if config["interface"] != "slcan":
        return can.Bus(ignore_config=True, **config)
    del config["interface"]
    return SlcanBus(config.pop("channel"), **config)


def _said(exc: BaseException, logged: list[str]) -> str:
    """What python-can said: its logged warnings first (they name the missing library)."""
    return _one_line("; ".join(dict.fromkeys([*logged, f"{type(exc).__name__}: {exc}"])))


def _open_hint(port: str, kwargs: dict[str, Any], said: str, hint: str = _HINT) -> str:
    """One line: the port, what python-can said, what to do."""
    if kwargs.get("interface") == "socketcan":
        ch = kwargs.get("channel", port)
        named = "" if ch == port else f" (port {port!r})"
        # errno 97: the kernel has no SocketCAN at all (a container, WSL), so `ip link`
        # alone cannot help; an SLCAN adapter works anywhere as a serial device
        kernel = (" (this kernel has no SocketCAN: `sudo modprobe can_raw` first)"
                  if "Errno 97" in said else "")
        text = (f"no CAN interface {ch!r}{named} ({said}): plug the adapter in and bring it "
                f"up with `sudo ip link set {ch} up type can bitrate 1000000`{kernel}, or "
                f"name a serial SLCAN adapter with --port slcan:/dev/ttyACM0; {hint}")
    else:
        text = (f"cannot open CAN port {port!r} (python-can {kwargs or 'config'}: {said}): is "
                f"the adapter plugged in and its vendor driver/library installed, and is the "
                f"channel right? {hint}")
    return _one_line(text)


class _Listener(can.Listener):
    """Runs in the Notifier thread: stamp and hand over, nothing else."""

    def __init__(self, transport: CanTransport) -> None:
        self._transport = transport

    def on_message_received(self, msg: can.Message) -> None:
        self._transport._deliver(Frame(msg.arbitration_id, bytes(msg.data), time.monotonic(),
                                       msg.is_error_frame))
    # no on_error: an exception kills the Notifier thread, which ``_alive`` reports


class CanTransport(QueuedTransport):
    """Frames over python-can, received by a ``can.Notifier`` thread."""

    def __init__(self, port: str, *, corrupt_per_s: int = 3, hint: str = _HINT,
                 send_timeout_s: float = SEND_TIMEOUT_S, **bus_kwargs: Any) -> None:
        super().__init__(port or "default", corrupt_per_s)
        self.send_timeout_s = send_timeout_s
        kwargs = {**parse_can_port(port), **bus_kwargs}
        with _python_can_warnings() as logged:
            try:
                self.bus = open_bus(kwargs)
            except Exception as exc:  # noqa: BLE001 - a vendor interface fails in any way
                # (NameError from kvaser without canlib, TypeError from socketcand without a
                # host): it is the adapter's problem, not ours, and gets one line
                said = _said(exc, logged)
                raise PortError(self.port, _open_hint(self.port, kwargs, said, hint),
                                problem=said) from exc
        self._notifier = can.Notifier(self.bus, [_Listener(self)], timeout=0.05)
        # the kernel's broadcast manager times periodic frames on SocketCAN; elsewhere a
        # python-can thread does, and it must not interleave its writes with ours (SLCAN)
        self._kernel_periodic = kwargs.get("interface") == "socketcan"
        self._send_lock = threading.Lock()
        self._periodic: list[can.broadcastmanager.CyclicSendTaskABC] = []

    def _alive(self) -> SafetyStop | None:
        exc = self._notifier.exception
        if exc is not None:
            return LinkLost(f"CAN receive thread died: {exc!r}", port=self.port)
        try:
            state = self.bus.state
        except NotImplementedError:
            return None
        if state is can.BusState.ERROR:
            return BusOff("CAN controller reports bus-off; check wiring, termination and "
                          "bitrate", port=self.port)
        return None

    def _send(self, msg: can.Message) -> None:
        """Send one frame; a failure is a lost link, unless the send waited out its timeout
        while this program could not run for most of it (``HostLag``: an adapter emulated in
        this process, or this process's own I/O, could not move meanwhile). Then that frame
        is dropped, and the next cycle's command goes out as usual."""
        self.check()
        start = time.monotonic()
        try:
            with self._send_lock:
                self.bus.send(msg, timeout=self.send_timeout_s)
        except can.CanError as exc:
            end = time.monotonic()
            if end - start < 0.9 * self.send_timeout_s or host_lag().starved(start, end) < 0.5 * (
                    end - start):
                self._fail(LinkLost(f"CAN send failed: {exc}", port=self.port))
                raise self._fault from exc  # type: ignore[misc]

    def send(self, arbitration_id: int, data: bytes) -> None:
        self._send(can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False))

    def send_error(self, error_class: int) -> None:
        self._send(can.Message(arbitration_id=error_class, is_error_frame=True,
                               is_extended_id=False, dlc=0))

    def send_periodic(self, arbitration_id: int, data: bytes, period_s: float):
        """Send a frame every ``period_s`` until the returned task's ``stop()`` or ``close``
        (CANopen SYNC): by the kernel on SocketCAN, else by python-can's send thread, which
        catches up after a stall instead of skipping frames. A failed send ends it and is
        this transport's next ``LinkLost``."""
        self.check()
        msg = can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False)
        if self._kernel_periodic:
            task = self.bus.send_periodic(msg, period_s)
        else:
            def failed(exc: Exception) -> bool:
                if not self.closed:
                    self._fail(LinkLost(f"CAN send failed (frame 0x{arbitration_id:03X} every "
                                        f"{period_s * 1e3:g} ms): {exc}", port=self.port))
                return False
            task = ThreadBasedCyclicSendTask(self.bus, self._send_lock, msg, period_s,
                                             on_error=failed)
        self._periodic.append(task)
        return task

    def add_listener(self, listener: can.Listener) -> None:
        """Also hand every received frame to ``listener`` (in the receive thread): a
        request/answer stack such as canopen's SDO client waits on its own answers."""
        self._notifier.add_listener(listener)

    def remove_listener(self, listener: can.Listener) -> None:
        self._notifier.remove_listener(listener)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        for task in self._periodic:
            task.stop()
        self._notifier.stop(timeout=1.0)
        self.bus.shutdown()
