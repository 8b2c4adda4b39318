"""One reader of a CAN bus, several consumers: each `BusView` sees the frames of its ids, in order.

The HIL host reads vehicle CAN through one python-can-remote connection (every frame crosses a loopback
websocket and is decoded in Python: a second connection would double that work in the host process).
The radar adapter and the odometry adapter each get a view; a view's `recv(timeout=0)` first moves
whatever the shared bus has into every view's queue (frames filtered by id when the view has ids), then
returns its own oldest frame. Views are bounded (`max_frames`, oldest dropped and counted), so a
consumer that stops reading cannot make the host's memory grow. Thread-safe (the modules run in their
own threads).
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Iterable

import can

MAX_VIEW_FRAMES = 2000  # 2 s of the radar or 10 s of one odometry frame at their cycle times


class FanoutBus:
    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self._views: list[BusView] = []
        self._lock = threading.Lock()

    def view(self, ids: Iterable[int] | None = None, max_frames: int = MAX_VIEW_FRAMES) -> BusView:
        v = BusView(self, None if ids is None else frozenset(ids), max_frames)
        with self._lock:
            self._views.append(v)
        return v

    def _pump(self) -> None:
        while True:
            msg = self.bus.recv(timeout=0)
            if msg is None:
                return
            for v in self._views:
                if v.ids is None or msg.arbitration_id in v.ids:
                    if len(v.frames) == v.frames.maxlen:
                        v.dropped += 1
                    v.frames.append(msg)

    def recv_for(self, view: BusView) -> can.Message | None:
        with self._lock:
            self._pump()
            return view.frames.popleft() if view.frames else None

    def shutdown(self) -> None:
        self.bus.shutdown()


class BusView:
    """The part of `can.BusABC` the adapters use: `recv(timeout=0)` (non-blocking only) and `shutdown`."""

    def __init__(self, parent: FanoutBus, ids: frozenset[int] | None, max_frames: int) -> None:
        self.parent = parent
        self.ids = ids
        self.frames: deque[can.Message] = deque(maxlen=max_frames)
        self.dropped = 0

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if timeout not in (0, 0.0):
            raise ValueError("a BusView is polled (recv(timeout=0)); it does not block")
        return self.parent.recv_for(self)

    def shutdown(self) -> None:
        """The shared bus is shut down by its owner (`FanoutBus.shutdown`)."""


__all__ = ["BusView", "FanoutBus"]
