"""`pimbs scan --canopen`: which CANopen nodes answer, with identity and CiA 402 state.

Asks every node id 1..127 for its device type (0x1000, an SDO upload, canopen's node
scanner), then reads from each node that answered: the identity object 0x1018 (vendor,
product, revision), the producer heartbeat time 0x1017 and, for CiA 402 devices (profile
402 in 0x1000), the statusword 0x6041. Only reads: nothing on a node is written.
The NMT state is the one the node's own heartbeat reports, if it sends one.
"""

from __future__ import annotations

import struct
import time
from dataclasses import dataclass

import canopen
from canopen.nmt import NMT_STATES
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from pimbs_hw.protocol.canopen_link import attached
from pimbs_hw.protocol.cia402_states import state_name


@dataclass
class NodeSeen:
    node_id: int
    device_type: int
    identity: tuple[int | None, int | None, int | None]  # vendor, product, revision
    heartbeat_ms: int | None
    cia402_state: str | None = None
    nmt_state: str | None = None  # from a heartbeat, None when none was heard

    def line(self) -> str:
        ids = " ".join(f"{name} " + ("-" if v is None else f"0x{v:08X}")
                       for name, v in zip(("vendor", "product", "revision"), self.identity,
                                          strict=True))
        profile = self.device_type & 0xFFFF
        state = (f"CiA 402 '{self.cia402_state}'" if self.cia402_state is not None
                 else f"profile {profile}")
        nmt = (f"NMT {self.nmt_state}" if self.nmt_state is not None else
               "no heartbeat" + ("" if self.heartbeat_ms is None
                                 else f" (0x1017 = {self.heartbeat_ms} ms)"))
        return f"CANopen node {self.node_id}  {ids}  {state}  {nmt}"


def _upload(node, index: int, subindex: int, fmt: str) -> int | None:
    try:
        data = node.sdo.upload(index, subindex)
        return struct.unpack_from(fmt, data.ljust(struct.calcsize(fmt), b"\0"))[0]
    except (SdoAbortedError, SdoCommunicationError, struct.error):
        return None


def scan_canopen(transport, seconds: float = 0.5, sdo_timeout_s: float = 0.3
                 ) -> list[NodeSeen]:
    """Every node that answers an SDO read of 0x1000 within ``seconds``."""
    heard: dict[int, int] = {}
    with attached(transport) as network:
        for node_id in range(1, 128):
            network.subscribe(0x700 + node_id,
                              lambda can_id, data, ts: heard.__setitem__(can_id & 0x7F, data[0]))
        network.scanner.search()
        time.sleep(seconds)
        seen = []
        for node_id in sorted(set(network.scanner.nodes)):
            node = canopen.RemoteNode(node_id, canopen.ObjectDictionary())
            network.add_node(node)
            node.sdo.RESPONSE_TIMEOUT = sdo_timeout_s
            device_type = _upload(node, 0x1000, 0, "<I")
            if device_type is None:
                continue  # not a CANopen node: its frame only looked like one
            identity = tuple(_upload(node, 0x1018, s, "<I") for s in (1, 2, 3))
            state = None
            if device_type & 0xFFFF == 402:
                word = _upload(node, 0x6041, 0, "<H")
                state = None if word is None else state_name(word)
            seen.append(NodeSeen(node_id, device_type, identity,  # type: ignore[arg-type]
                                 _upload(node, 0x1017, 0, "<H"), state))
        time.sleep(0.1)
    for node in seen:
        if node.node_id in heard:
            code = heard[node.node_id] & 0x7F
            node.nmt_state = NMT_STATES.get(code, f"0x{code:02X}")
    return seen
