"""NMT states and commands (CiA 301 section 7.2.8) and the heartbeat consumer both ends run.

Kammel et al. 2008 (seed 000) Sec. 12: a hung process that its watchdog could not see stopped the
car in the final, so liveness on the host <-> ECU link is explicit both ways. DESIGN section 3: NMT
state and heartbeat producer/consumer are the watchdog's input. The `canopen` package has no
heartbeat consumer with a timeout; `HeartbeatConsumer` is one. The ECU counts the host as alive only
while its heartbeat is fresh AND reports OPERATIONAL (the host reports PRE-OPERATIONAL while starting
up or when its supervisor takes it out of the loop, and that must stop the car just like silence);
the host counts the ECU as alive on any fresh heartbeat and reads its NMT state separately.
"""

from __future__ import annotations

from enum import IntEnum

from bywire.protocol.canopen_link.pump import to_us

NMT_COB_ID = 0x000
HEARTBEAT_COB_BASE = 0x700


class NmtState(IntEnum):
    """NMT states as carried in heartbeat frames (CiA 301 table 51)."""

    INITIALISING = 0  # the boot-up frame
    STOPPED = 4
    OPERATIONAL = 5
    PRE_OPERATIONAL = 127


# Heartbeats arrive every few ms on both sides: a dict lookup instead of NmtState(byte)'s enum call.
_NMT_STATES: dict[int, NmtState] = {int(m): m for m in NmtState}


class NmtCommand(IntEnum):
    """NMT command specifiers (CiA 301 section 7.2.8.3.1)."""

    START = 1
    STOP = 2
    ENTER_PRE_OPERATIONAL = 128
    RESET_NODE = 129
    RESET_COMMUNICATION = 130


def parse_heartbeat(data: bytes | bytearray) -> NmtState:
    """Heartbeat data -> NMT state; ValueError for a wrong length or an undefined state."""
    if len(data) != 1:
        raise ValueError(f"heartbeat has {len(data)} data bytes, expected 1")
    state = _NMT_STATES.get(data[0])
    if state is None:
        raise ValueError(f"heartbeat state 0x{data[0]:02X} is not an NMT state")
    return state


class HeartbeatConsumer:
    """Watches one node's heartbeat (CiA 301 section 7.2.8.3.2.2): fresh for timeout_ms after a frame.

    Fresh means `now - last_rx <= timeout`, in integer microseconds: with a 100 ms consumer time a
    heartbeat at t is still fresh at exactly t + 100 ms and stale from t + 100.001 ms.
    """

    def __init__(self, node_id: int, timeout_ms: int) -> None:
        self.node_id = node_id
        self.timeout_ms = timeout_ms
        self.state: NmtState | None = None
        self.last_rx_s: float | None = None
        self.received = 0
        self.rejected = 0  # wrong length or undefined state byte
        self.bootups = 0
        self.timeouts = 0  # fresh -> stale transitions seen by update()
        self._was_fresh = False
        self._last_rx_us = 0

    @property
    def cob_id(self) -> int:
        return HEARTBEAT_COB_BASE + self.node_id

    def on_frame(self, data: bytes | bytearray, now_s: float) -> bool:
        try:
            state = parse_heartbeat(data)
        except ValueError:
            self.rejected += 1
            return False
        self.received += 1
        if state is NmtState.INITIALISING:
            self.bootups += 1
        self.state = state
        self.last_rx_s = now_s
        self._last_rx_us = to_us(now_s)
        return True

    def fresh(self, now_s: float) -> bool:
        if self.last_rx_s is None:
            return False
        return to_us(now_s) - self._last_rx_us <= self.timeout_ms * 1000

    def alive(self, now_s: float, states: tuple[NmtState, ...] | None = None) -> bool:
        """Fresh, and (if `states` is given) last reporting one of `states`."""
        return self.fresh(now_s) and (states is None or self.state in states)

    def update(self, now_s: float) -> None:
        fresh = self.fresh(now_s)
        if self._was_fresh and not fresh:
            self.timeouts += 1
        self._was_fresh = fresh
