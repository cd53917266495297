"""``canopen`` on one of our CAN transports: request/answer services (SDO) and the SYNC.

canopen sends through the transport (with its link supervision) and hears every received
frame through a listener on the transport's receive thread, only while ``attached``: the
cyclic traffic goes through the board-protocol seam like every protocol's.

SYNC (CiA 301) has one producer per bus: ``start_sync`` hands every drive file on a
transport the same producer, which the transport times (the kernel on SocketCAN, a
python-can thread elsewhere), so a slow control loop does not slow the drives' cycle.
"""

from __future__ import annotations

import weakref
from collections.abc import Iterator
from contextlib import contextmanager

import canopen

from pimbs_hw.protocol.cia402_config import DriveFileError

SYNC_ID = 0x080  # COB-ID of SYNC (0x1005's default, CiA 301 predefined connection set)


class TransportNetwork(canopen.Network):
    """A canopen network that sends through ``transport``."""

    def __init__(self, transport) -> None:
        super().__init__()
        self._transport = transport

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        self._transport.send(can_id, bytes(data))


def _can_port(transport) -> None:
    if getattr(transport, "add_listener", None) is None:
        raise DriveFileError(f"port {transport.port}: CANopen needs a CAN port (socketcan, an "
                             "SLCAN adapter, --port virtual), not a serial link")


@contextmanager
def attached(transport) -> Iterator[TransportNetwork]:
    """A network that hears ``transport``'s frames until the block ends."""
    _can_port(transport)
    network = TransportNetwork(transport)
    listener = canopen.network.MessageListener(network)
    transport.add_listener(listener)
    try:
        yield network
    finally:
        transport.remove_listener(listener)


class SyncProducer:
    """The bus's SYNC every ``period_us`` µs, sent by the transport until ``stop``."""

    def __init__(self, transport, period_us: int, owner: str) -> None:
        self.transport, self.period_us, self.owner = transport, period_us, owner
        self._task = transport.send_periodic(SYNC_ID, b"", period_us / 1e6)
        self.running = True

    def stop(self) -> None:
        """Stop the periodic SYNC, then send one more: RPDOs of a synchronous transmission
        type take effect at the next SYNC, so the host's last command (its relax) must be
        followed by one. The drives then see SYNC stop, as at any other end of the host."""
        if not self.running:
            return
        self.running = False
        self._task.stop()
        send = getattr(self.transport, "send_despite_fault", self.transport.send)
        usable = getattr(self.transport, "usable", lambda: True)
        if usable():
            try:
                send(SYNC_ID, b"")
            except Exception:  # noqa: BLE001 - a link that failed now: the drives' SYNC
                pass  # supervision takes them out of operation, as documented


_PRODUCERS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def start_sync(transport, period_us: int, owner: str) -> SyncProducer:
    """The SYNC producer of ``transport``, started at ``period_us`` µs if it is not running.

    Drive files on one bus share it; two that ask for different periods are refused (a
    CANopen network has one SYNC producer, and one cycle)."""
    _can_port(transport)
    running = _PRODUCERS.get(transport)
    if running is not None and running.running:
        if running.period_us != period_us:
            raise DriveFileError(f"{owner}: sync_period_us {period_us} differs from "
                                 f"{running.owner}'s {running.period_us} on the same bus; a "
                                 "CANopen bus has one SYNC: give both drive files the same "
                                 "sync_period_us")
        return running
    producer = SyncProducer(transport, period_us, owner)
    _PRODUCERS[transport] = producer
    return producer
