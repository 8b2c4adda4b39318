"""python-can's `virtual` bus, tuned for lockstep SIL.

The stock VirtualBus deep-copies every frame for every receiver and stamps it with wall time; in a
lockstep simulation that is both the largest cost per simulated millisecond and the wrong clock. This
subclass keeps python-can's channel registry and queues (so stock `virtual` buses on the same channel,
a recorder for example, still see every frame) but hands receivers a cheap copy stamped with the
simulated time, applies a receiver's CAN filters before queueing (a host that only wants the radar
frame does not pay for the rest of vehicle CAN), and gives `recv(timeout=0)` a lock-light fast path.
"""

from __future__ import annotations

from typing import Any, ClassVar

import can
from can.interfaces.virtual import VirtualBus

from bywire.clock import Clock


def received_copy(
    msg: can.Message, timestamp_s: float, channel: can.typechecking.Channel | None
) -> can.Message:
    """A frame as a receiver sees it: the same content, a new receive time and channel."""
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


class SimVirtualBus(VirtualBus):
    """A `virtual` bus whose frames carry simulated receive timestamps; for single-threaded lockstep use."""

    _by_queue: ClassVar[dict[int, SimVirtualBus]] = {}

    def __init__(self, channel: str, clock: Clock, **kwargs: Any) -> None:
        super().__init__(channel=channel, receive_own_messages=False, preserve_timestamps=True, **kwargs)
        self._clock = clock
        SimVirtualBus._by_queue[id(self.queue)] = self

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        # One received copy shared by every receiver: receivers treat frames as read-only.
        rx = received_copy(msg, self._clock.now(), self.channel_id)
        by_queue = SimVirtualBus._by_queue
        for bus_queue in self.channel:
            if bus_queue is self.queue:
                continue
            receiver = by_queue.get(id(bus_queue))
            if receiver is None:
                bus_queue.put_nowait(rx)  # a stock bus (a recorder, say) may block on its queue
            elif not receiver.filters or receiver._matches_filters(rx):
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
