"""A ``canopen.Network`` on one of our CAN transports, for request/answer services (SDO).

canopen sends through the transport (with its link supervision) and hears every received
frame through a listener on the transport's receive thread, only while ``attached``: the
cyclic traffic goes through the board-protocol seam like every protocol's.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import canopen

from pimbs_hw.protocol.cia402_config import DriveFileError


class TransportNetwork(canopen.Network):
    """A canopen network that sends through ``transport``."""

    def __init__(self, transport) -> None:
        super().__init__()
        self._transport = transport

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        self._transport.send(can_id, bytes(data))


@contextmanager
def attached(transport) -> Iterator[TransportNetwork]:
    """A network that hears ``transport``'s frames until the block ends."""
    add = getattr(transport, "add_listener", None)
    if add is None:
        raise DriveFileError(f"port {transport.port}: CANopen needs a CAN port (socketcan, an "
                             "SLCAN adapter, --port virtual), not a serial link")
    network = TransportNetwork(transport)
    listener = canopen.network.MessageListener(network)
    add(listener)
    try:
        yield network
    finally:
        transport.remove_listener(listener)
