"""A service tool on the host link, for scenarios: the DISABLE unlatch as an SDO write, non-blocking.

What `bywire ecu unlatch` does (an SDO expedited download of 1 into 0x2300sub1, CiA 301), split into
a send and a poll so that it runs inside SIL's lockstep loop and beside HIL's supervisor without a
thread: the frame goes out at the scenario's instant, the ECU's answer (acknowledged, or aborted
with a code and the reason in 0x2400) is collected whenever it arrives. Any node on the host link
can send this frame, which is why the ECU never takes it as a re-arm by itself (ecu.safety).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import can

from bywire.protocol.canopen_link.dictionary import COMMAND_INDEX, ECU_NODE_ID, UNLATCH_SUB
from bywire.protocol.timebase import data_frame

SDO_RX_BASE = 0x600  # client -> server, + node id (CiA 301 default SDO COB-IDs)
SDO_TX_BASE = 0x580  # server -> client
_EXPEDITED_1_BYTE = 0x2F  # initiate download, expedited, size indicated, 3 bytes unused
_DOWNLOAD_ACK = 0x60
_ABORT = 0x80


@dataclass
class ServiceAction:
    t_s: float  # when the request went out (scenario time)
    what: str
    result: str = "no answer"  # "acknowledged", "aborted 0x08000022", or "no answer"
    answered_t_s: float | None = None


class ServiceTool:
    """Sends the unlatch on `bus` and matches the ECU's SDO answers to it."""

    def __init__(self, bus: can.BusABC, ecu_node_id: int = ECU_NODE_ID) -> None:
        self.bus = bus
        self._rx_cob = SDO_RX_BASE + ecu_node_id
        self._tx_cob = SDO_TX_BASE + ecu_node_id
        self.actions: list[ServiceAction] = []

    def send_unlatch(self, t_s: float) -> None:
        data = struct.pack("<BHBB3x", _EXPEDITED_1_BYTE, COMMAND_INDEX, UNLATCH_SUB, 1)
        self.bus.send(data_frame(self._rx_cob, bytearray(data)))
        self.actions.append(ServiceAction(t_s, "unlatch"))

    def poll(self, t_s: float) -> None:
        while (msg := self.bus.recv(timeout=0)) is not None:
            if msg.arbitration_id != self._tx_cob or len(msg.data) != 8 or msg.is_extended_id:
                continue
            pending = next((a for a in self.actions if a.answered_t_s is None), None)
            if pending is None:
                continue
            command, index, sub, code = struct.unpack("<BHBL", bytes(msg.data))
            if (index, sub) != (COMMAND_INDEX, UNLATCH_SUB):
                continue
            pending.answered_t_s = t_s
            pending.result = "acknowledged" if command == _DOWNLOAD_ACK else f"aborted 0x{code:08X}"

    def summary(self) -> list[dict[str, object]]:
        return [
            {"t_s": round(a.t_s, 3), "what": a.what, "result": a.result, "answered_t_s": a.answered_t_s}
            for a in self.actions
        ]
