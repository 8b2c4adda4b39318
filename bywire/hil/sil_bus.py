"""python-can's `virtual` bus, tuned for lockstep SIL.

The stock VirtualBus deep-copies every frame for every receiver and stamps it with wall time; in a
lockstep simulation that is both the largest cost per simulated millisecond and the wrong clock. This
subclass keeps python-can's channel registry and queues (so stock `virtual` buses on the same channel,
a recorder for example, still see every frame) but hands receivers a cheap copy stamped with the
simulated time, applies a receiver's CAN filters before queueing (a host that only wants the radar
frame does not pay for the rest of vehicle CAN), and gives `recv(timeout=0)` a lock-light fast path.

The copy is made slot by slot rather than through `can.Message(...)`, whose keyword handling cost
more than the rest of a send (as `protocol.timebase.data_frame` does); the filters are python-can's,
precompiled into tuples. Both are checked against python-can's own behaviour in tests/hil/test_sil_bus.py.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import can
from can.interfaces.virtual import VirtualBus

from bywire.clock import Clock
from bywire.protocol.timebase import SLOT_LAYOUT_KNOWN

_new_message = object.__new__
_ANY_ID_KIND = object()  # a filter without "extended": matches 11- and 29-bit ids alike

CompiledFilters = tuple[tuple[int, int, object], ...]


def received_copy(
    msg: can.Message, timestamp_s: float, channel: can.typechecking.Channel | None
) -> can.Message:
    """A frame as a receiver sees it: the same content, a new receive time and channel.

    What `can.Message(timestamp=timestamp_s, arbitration_id=..., is_extended_id=...,
    is_remote_frame=..., is_error_frame=..., dlc=msg.dlc, data=bytes(msg.data), is_fd=...,
    channel=channel, is_rx=True)` builds, without the constructor's argument handling."""
    if not SLOT_LAYOUT_KNOWN:
        return can.Message(
            timestamp=timestamp_s,
            arbitration_id=msg.arbitration_id,
            is_extended_id=msg.is_extended_id,
            is_remote_frame=msg.is_remote_frame,
            is_error_frame=msg.is_error_frame,
            dlc=msg.dlc,
            data=bytes(msg.data),
            is_fd=msg.is_fd,
            channel=channel,
            is_rx=True,
        )
    rx: can.Message = _new_message(can.Message)
    rx.timestamp = timestamp_s
    rx.arbitration_id = msg.arbitration_id
    rx.is_extended_id = msg.is_extended_id
    rx.is_remote_frame = msg.is_remote_frame
    rx.is_error_frame = msg.is_error_frame
    rx.channel = channel
    rx.is_fd = msg.is_fd
    rx.is_rx = True
    rx.bitrate_switch = False
    rx.error_state_indicator = False
    rx.data = bytearray() if msg.is_remote_frame else bytearray(msg.data)
    rx.dlc = msg.dlc if msg.dlc is not None else len(rx.data)
    return rx


def compile_filters(filters: Sequence[can.typechecking.CanFilter] | None) -> CompiledFilters | None:
    """python-can filter dicts as (can_id, can_mask, extended) tuples (None: accept everything)."""
    if not filters:
        return None
    return tuple((f["can_id"], f["can_mask"], f.get("extended", _ANY_ID_KIND)) for f in filters)


def filters_accept(filters: CompiledFilters, msg: can.Message) -> bool:
    """`BusABC._matches_filters` on compiled filters: some filter matches id, mask and id kind."""
    arbitration_id = msg.arbitration_id
    for can_id, can_mask, extended in filters:
        if extended is not _ANY_ID_KIND and extended != msg.is_extended_id:
            continue
        if (can_id ^ arbitration_id) & can_mask == 0:
            return True
    return False


class SimVirtualBus(VirtualBus):
    """A `virtual` bus whose frames carry simulated receive timestamps; for single-threaded lockstep use."""

    _by_queue: ClassVar[dict[int, SimVirtualBus]] = {}

    def __init__(self, channel: str, clock: Clock, **kwargs: Any) -> None:
        self._compiled_from: object = None
        self._compiled: CompiledFilters | None = None
        super().__init__(channel=channel, receive_own_messages=False, preserve_timestamps=True, **kwargs)
        self._clock = clock
        SimVirtualBus._by_queue[id(self.queue)] = self

    def accepts(self, msg: can.Message) -> bool:
        """Whether this bus's filters let `msg` in (compiled again whenever they are replaced)."""
        filters = self._filters
        if filters is None:
            return True
        if filters is not self._compiled_from:
            self._compiled_from, self._compiled = filters, compile_filters(filters)
        return self._compiled is None or filters_accept(self._compiled, msg)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if not self._open:
            self._check_if_open()  # raises
        # One received copy shared by every receiver: receivers treat frames as read-only.
        rx = received_copy(msg, self._clock.now(), self.channel_id)
        by_queue = SimVirtualBus._by_queue
        own = self.queue
        for bus_queue in self.channel:
            if bus_queue is own:
                continue
            receiver = by_queue.get(id(bus_queue))
            if receiver is None:
                bus_queue.put_nowait(rx)  # a stock bus (a recorder, say) may block on its queue
            elif receiver._filters is None or receiver.accepts(rx):
                bus_queue.queue.append(rx)  # single-threaded lockstep: no lock, no one to wake

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if timeout == 0:
            # Frames were filtered when queued; the Queue's deque is ours alone single-threaded.
            frames = self.queue.queue
            return frames.popleft() if frames else None
        return super().recv(timeout)

    def shutdown(self) -> None:
        SimVirtualBus._by_queue.pop(id(self.queue), None)
        super().shutdown()
