"""The link pumped, not threaded: a canopen network without its threads, drained and stepped by its owner.

DESIGN section 4: the ECU's cyclic executive runs at 1 kHz and every time it judges must be its own.
Both ends of the host <-> ECU link run WITHOUT canopen's can.Notifier thread and without python-can
periodic send tasks: the owner pumps `poll(now_s)` (drain the bus with recv(timeout=0) and call
network.notify, `drain`) and `tick(now_s)` (heartbeat producer, PDO event timers, timeouts,
`EventTimer`). So the link steps deterministically in lockstep SIL on a SimClock, and every receive
time is on the pump's clock, never a frame's wall-clock timestamp.
"""

from __future__ import annotations

import logging
import math

import can
import canopen

from bywire.protocol.timebase import data_frame, rx_time_s

log = logging.getLogger(__name__)

DEFAULT_MAX_FRAMES_PER_POLL = 256


def to_us(t_s: float) -> int:
    # Integer microseconds make timer and timeout boundaries exact on a SimClock stepped in ms.
    return round(t_s * 1_000_000)


class EventTimer:
    """A period on the pump's clock: `due(now_s)` is True once per period, without drift.

    `early_ms`: how early a call may find it due. A timer polled once per period by a loop of the
    same period (the host's heartbeat, sent with each 20 ms request) would otherwise alias with the
    loop's jitter: a call 0.1 ms before the instant finds it not due, and the next is a period later,
    a double gap. Polled at 1 kHz (the ECU) it needs none."""

    def __init__(self, period_ms: int, early_ms: float = 0.0) -> None:
        self.period_ms = period_ms
        self._early_us = int(early_ms * 1000)
        self._next_us: int | None = None

    @property
    def period_ms(self) -> int:
        return self._period_us // 1000

    @period_ms.setter
    def period_ms(self, period_ms: int) -> None:
        if period_ms < 1:
            raise ValueError(f"event timer period {period_ms} ms must be >= 1 ms")
        self._period_us = period_ms * 1000

    def reset(self) -> None:
        """Make the next `due` fire at once."""
        self._next_us = None

    def next_s(self) -> float:
        """Before this instant `due` is surely False (a microsecond early; -inf: due at once)."""
        return -math.inf if self._next_us is None else (self._next_us - self._early_us - 1) * 1e-6

    def due(self, now_s: float) -> bool:
        next_us = self._next_us
        if next_us is not None and now_s * 1e6 < next_us - self._early_us - 1:
            return False  # clearly not yet: spares the exact integer conversion on most calls
        now_us = to_us(now_s)
        if self._next_us is None:
            self._next_us = now_us + self._period_us
            return True
        if now_us < self._next_us - self._early_us:
            return False
        self._next_us += self._period_us
        if self._next_us <= now_us:
            # More than a period behind (pump stalled): resynchronise instead of sending a burst.
            self._next_us = now_us + self._period_us
        return True


def drain(
    bus: can.BusABC,
    network: canopen.Network,
    first_timeout_s: float,
    max_frames: int,
    now_s: float | None = None,
) -> tuple[int, int]:
    """Feed up to max_frames frames from the bus to the network; returns (frames, handler errors).

    With `now_s`, each handler gets the frame's receive time on the clock of `now_s` (the bus's
    stamp, never later than `now_s`), so a frame that waited in the queue while the owner stalled is
    judged by when it arrived, not by when it was polled."""
    frames = errors = 0
    timeout = first_timeout_s
    while frames < max_frames:
        msg = bus.recv(timeout=timeout)
        timeout = 0.0
        if msg is None:
            break
        frames += 1
        # CANopen speaks 11-bit data frames; 29-bit ids with the same number belong to someone else.
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            continue
        if now_s is None:
            stamp = msg.timestamp
        else:
            stamp = rx_time_s(msg, now_s)
            if not stamp <= now_s:  # a stamp from the future (or NaN) cannot be trusted
                stamp = now_s
        try:
            network.notify(msg.arbitration_id, msg.data, stamp)
        except Exception:
            # A handler bug must not stop the cyclic executive: counted and logged, frame dropped.
            errors += 1
            log.exception(
                "CANopen handler failed on frame 0x%03X %s", msg.arbitration_id, bytes(msg.data).hex()
            )
    return frames, errors


def send_frame(network: canopen.Network, cob_id: int, data: bytes) -> None:
    """`network.send_message(cob_id, data)` without its generic parts: an 11-bit data frame,
    under the network's send lock; there is no Notifier thread whose error `check` could raise."""
    msg = data_frame(cob_id, bytearray(data))
    bus = network.bus
    assert bus is not None, "a CANopen network without a bus"
    with network.send_lock:
        bus.send(msg)


def network_without_threads(bus: can.BusABC) -> canopen.Network:
    network = canopen.Network(bus)  # no connect(): no can.Notifier thread
    # LSS is not used; its handler queues every 0x7E4 frame forever.
    network.unsubscribe(network.lss.LSS_RX_COBID)
    return network
