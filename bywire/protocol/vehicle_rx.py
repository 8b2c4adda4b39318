"""The vehicle-CAN receiver: `VehicleRx`, the E2E monitor of every frame the ECU (or the host) hears.

DESIGN section 3: receivers reject stale, repeated, out-of-order or corrupt frames and count each
kind; section 4: the ECU engages only on fresh vehicle data, and a repeated alive counter is never
fresh. Kammel et al. 2008 (seed 000) Sec. 2.1 and 2.4: the ECU hears the drive-by-wire system, the
car's odometry and the E-stop's run/pause over CAN. The frame and counter checks are `e2e`'s, the DBC
and the typed frames `vehicle_can`'s; this module keeps the per-message state (last frame, receive
time, counters, timeouts) and never raises on bus input.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, Final

import can

from bywire.protocol.e2e import (
    COUNTER_MODULO,
    COUNTER_REJECTS,
    DEFAULT_MAX_DELTA_COUNTER,
    CounterStatus,
    RejectReason,
    check_counter,
    e2e_crc,
)
from bywire.protocol.vehicle_can import (
    CHECKSUM_E2E,
    FrameError,
    FrameKey,
    MessageInfo,
    VehicleCodec,
    VehicleFrame,
    crc_error,
)

__all__ = ["FrameMonitor", "RxMonitor", "VehicleRx"]

DEFAULT_TIMEOUT_CYCLES = 5.0  # 50 ms for 10 ms frames: the ECU's vehicle-data freshness limit
DEFAULT_MAX_AGE_CYCLES = 1.0  # a frame older than one cycle has a newer sibling on the bus
UNKNOWN_IDS_KEPT = 16  # distinct unknown ids listed in stats(); the rest only counted

_OUTCOMES: Final = ("accepted", "ignored", *(r.value for r in RejectReason))
_RESYNC: Final = CounterStatus.RESYNC
_OK: Final = CounterStatus.OK
_COUNTERS: Final = (*_OUTCOMES, "lost", "resync")


def _zero_counts() -> dict[str, int]:
    return dict.fromkeys(_COUNTERS, 0)


@dataclass(slots=True)
class _RxState:
    info: MessageInfo
    subscribed: bool
    counts: dict[str, int] = field(default_factory=_zero_counts)
    last_counter: int | None = None
    last_frame: VehicleFrame | None = None
    last_time_s: float | None = None
    error_streak: int = 0
    last_reject: tuple[str, str, float] | None = None  # (reason, detail, now_s)
    # The signal bits (all but checksum and counter) of the last payload decoded, and its frame:
    # decoding is a function of those bits alone, and most reports repeat their values.
    decoded_bits: int = -1
    decoded_frame: VehicleFrame | None = None


class RxMonitor:
    """One message's live receiver state, resolved once: the ECU reads a handful of these every
    millisecond, and a name lookup per read would cost more than the reads themselves. `state`
    is the receiver's own record (read it, never write it)."""

    __slots__ = ("state", "timeout_s")

    def __init__(self, state: _RxState, timeout_s: float) -> None:
        self.state = state
        self.timeout_s = timeout_s

    @property
    def last(self) -> VehicleFrame | None:
        return self.state.last_frame

    @property
    def error_streak(self) -> int:
        return self.state.error_streak

    def timed_out(self, now_s: float) -> bool:
        t = self.state.last_time_s
        return t is None or now_s - t > self.timeout_s


class VehicleRx:
    """A receiver's E2E monitor: `feed(msg, now_s)` returns the typed frame, or None if rejected.

    Per message (`FrameKey`: frame id, DBC name or typed-frame class) it keeps the last accepted
    frame and the receiver time `now_s` at which it was accepted, counts every outcome, and derives
    the timeout from the DBC's GenMsgCycleTime (`timeout_cycles` cycles, default 5). Check order:
    subscription (ignored) -> structure (malformed) -> CRC (corrupt) -> age (stale) -> DBC ranges
    (malformed) -> alive counter (repeated, out_of_order); each frame counts exactly one of these
    outcomes or `accepted` (accepted frames may also add to `lost` and `resync`). After a timeout the
    next frame that passes everything but the counter check is accepted as a re-sync, as AUTOSAR E2E
    does.

    Age: a frame's receive time is `rx_time_s` if given, else `msg.timestamp`, and must be on the
    same clock as `now_s` (stamp frames with `clock.now()` when sending in SIL, and keep the bus's
    timestamps, e.g. python-can virtual with `preserve_timestamps=True`). A frame older than
    `max_age_cycles` cycle times, or stamped that far in the future (a clock mismatch: its age cannot
    be known), is stale. `max_age_cycles=None` turns the age check off.

    `accept` limits the messages this receiver uses (names, ids or classes; default: all); frames of
    other DBC messages are counted as `ignored`. `VehicleRx.for_node(codec, "ECU")` accepts what the
    DBC says that node receives. Frames with unknown or extended ids are counted only in the totals.
    """

    def __init__(
        self,
        codec: VehicleCodec | None = None,
        *,
        accept: Iterable[FrameKey] | None = None,
        timeout_cycles: float = DEFAULT_TIMEOUT_CYCLES,
        max_age_cycles: float | None = DEFAULT_MAX_AGE_CYCLES,
        max_delta_counter: int = DEFAULT_MAX_DELTA_COUNTER,
    ) -> None:
        self.codec = codec if codec is not None else VehicleCodec()
        if not timeout_cycles > 0:
            raise ValueError(f"VehicleRx: timeout_cycles {timeout_cycles} must be > 0")
        if max_age_cycles is not None and not max_age_cycles > 0:
            raise ValueError(f"VehicleRx: max_age_cycles {max_age_cycles} must be > 0 or None")
        check_counter(None, 0, max_delta=max_delta_counter)  # validates max_delta
        self.timeout_cycles = timeout_cycles
        self.max_age_cycles = max_age_cycles
        self.max_delta_counter = max_delta_counter
        wanted = None if accept is None else {self.codec.info(k).frame_id for k in accept}
        self._state = {
            info.frame_id: _RxState(info, wanted is None or info.frame_id in wanted)
            for info in self.codec.messages
        }
        self._total = _zero_counts()
        self._unexpected = 0
        self._last_unexpected: str | None = None
        self._unknown_ids: dict[str, int] = {}
        self._by_key: dict[FrameKey, _RxState] = {}

    @classmethod
    def for_node(cls, codec: VehicleCodec, node: str, **kwargs: Any) -> VehicleRx:
        """A receiver accepting the messages the DBC lists `node` as a receiver of."""
        names = codec.received_by(node)
        if not names:
            raise ValueError(f"{codec.dbc_path}: node {node!r} receives no message")
        return cls(codec, accept=names, **kwargs)

    # -- receiving --

    def feed(self, msg: can.Message, now_s: float, rx_time_s: float | None = None) -> VehicleFrame | None:
        """The typed frame if `msg` is accepted, else None. Never raises on any frame content."""
        try:
            return self._feed(msg, now_s, rx_time_s)
        except Exception as exc:  # a bus frame must never take the receiver down
            self._unexpected += 1
            self._last_unexpected = f"{type(exc).__name__}: {exc}"
            self._count(None, "malformed", self._last_unexpected, now_s)
            return None

    def _feed(self, msg: can.Message, now_s: float, rx_time_s: float | None) -> VehicleFrame | None:
        frame_id = msg.arbitration_id
        state = None if msg.is_extended_id else self._state.get(frame_id)
        if state is not None and not state.subscribed:
            self._count(state, "ignored", "", now_s)
            return None
        data = msg.data
        try:
            if (
                state is None
                or msg.is_error_frame
                or msg.is_remote_frame
                or msg.is_fd
                or msg.dlc != state.info.length
                or len(data) != state.info.length
            ):
                self.codec.check_structure(msg)  # says which structural check failed (raises)
            info = state.info  # type: ignore[union-attr]  # check_structure raised if state is None
            if info.checksum == CHECKSUM_E2E:  # ours, every frame: inline
                expected = e2e_crc(frame_id, data)
                if data[0] != expected:
                    raise crc_error(info, data, expected)
            else:  # a car's checksum (profile pq), or none to check
                self.codec.check_crc(info, data)
        except FrameError as err:
            if state is None:
                self._note_unknown(msg)
            self._count(state, err.reason.value, err.detail, now_s)
            return None
        assert state is not None
        cycle_s = info.cycle_time_s
        if self.max_age_cycles is not None:
            max_age_s = self.max_age_cycles * cycle_s
            rx_s = msg.timestamp if rx_time_s is None else rx_time_s
            age_s = now_s - rx_s
            if not -max_age_s <= age_s <= max_age_s:  # NaN stamps fail too
                if age_s > 0:
                    detail = f"{info.name}: received {age_s * 1e3:.1f} ms ago, max {max_age_s * 1e3:.1f} ms"
                elif age_s < 0:
                    detail = (
                        f"{info.name}: receive time {rx_s} is {-age_s:.3g} s after now {now_s}: "
                        "frames must be stamped on the receiver's clock"
                    )
                else:
                    detail = f"{info.name}: receive time {rx_s} or now {now_s} is not a number"
                self._count(state, "stale", detail, now_s)
                return None
        payload = int.from_bytes(data, "little")
        bits = payload & info.value_mask
        counter_start = info.counter_start
        if bits == state.decoded_bits:
            frame = state.decoded_frame
            counter = (payload >> counter_start) & (COUNTER_MODULO - 1) if counter_start is not None else None
        else:
            try:
                frame, counter = self.codec.decode_payload(info, data)
            except FrameError as err:
                self._count(state, err.reason.value, err.detail, now_s)
                return None
            state.decoded_bits, state.decoded_frame = bits, frame
        timed_out = (
            state.last_time_s is not None and now_s - state.last_time_s > self.timeout_cycles * cycle_s
        )
        if counter is None:
            # A car message without an alive counter (profile pq): nothing tells a repeat from news.
            status, lost = _OK, 0
        else:
            status, lost = check_counter(
                state.last_counter, counter, timed_out=timed_out, max_delta=self.max_delta_counter
            )
        if status in COUNTER_REJECTS:
            self._count(
                state, status.value, f"{info.name}: counter {counter} after {state.last_counter}", now_s
            )
            return None
        state.last_counter = counter
        state.last_frame = frame
        state.last_time_s = now_s
        self._count(state, "accepted", "", now_s)
        if lost:
            state.counts["lost"] += lost
            self._total["lost"] += lost
        if status is _RESYNC:
            state.counts["resync"] += 1
            self._total["resync"] += 1
        return frame

    def _count(self, state: _RxState | None, outcome: str, detail: str, now_s: float) -> None:
        self._total[outcome] += 1
        if state is None:
            return
        state.counts[outcome] += 1
        if outcome == "accepted":
            state.error_streak = 0
        elif outcome != "ignored":
            state.error_streak += 1
            state.last_reject = (outcome, detail, now_s)

    def _note_unknown(self, msg: can.Message) -> None:
        key = f"{msg.arbitration_id:#x}" + ("x" if msg.is_extended_id else "")
        if key in self._unknown_ids or len(self._unknown_ids) < UNKNOWN_IDS_KEPT:
            self._unknown_ids[key] = self._unknown_ids.get(key, 0) + 1

    # -- per-message state --

    def _get(self, key: FrameKey) -> _RxState:
        # The ECU asks for the same few messages every millisecond: resolve each key once.
        state = self._by_key.get(key)
        if state is None:
            state = self._state[self.codec.info(key).frame_id]
            self._by_key[key] = state
        return state

    def monitor(self, key: FrameKey) -> RxMonitor:
        """A live read-only view of one message's receiver state, for loops that poll it every cycle."""
        return RxMonitor(self._get(key), self.timeout_cycles * self._get(key).info.cycle_time_s)

    def last(self, key: FrameKey) -> VehicleFrame | None:
        """The last accepted frame of the message, or None."""
        return self._get(key).last_frame

    def last_time_s(self, key: FrameKey) -> float | None:
        """The receiver time (`now_s` of `feed`) at which the last frame was accepted, or None."""
        return self._get(key).last_time_s

    def age_s(self, key: FrameKey, now_s: float) -> float:
        """Seconds since the last accepted frame of the message; inf if none yet."""
        t = self._get(key).last_time_s
        return math.inf if t is None else now_s - t

    def timeout_s(self, key: FrameKey) -> float:
        """The message's timeout: `timeout_cycles` x its DBC GenMsgCycleTime."""
        return self.timeout_cycles * self._get(key).info.cycle_time_s

    def timed_out(self, key: FrameKey, now_s: float) -> bool:
        """True if no frame was accepted yet, or the last one is older than `timeout_s`."""
        state = self._get(key)
        t = state.last_time_s
        return t is None or now_s - t > self.timeout_cycles * state.info.cycle_time_s

    def error_streak(self, key: FrameKey) -> int:
        """Frames of the message rejected in a row since the last accepted one (ignored ones aside)."""
        return self._get(key).error_streak

    def counts(self, key: FrameKey | None = None) -> Mapping[str, int]:
        """Counters of one message, or the totals: accepted, ignored, each RejectReason, lost, resync."""
        return dict(self._total if key is None else self._get(key).counts)

    @property
    def unexpected_exceptions(self) -> int:
        """Frames that raised inside the receiver (counted as malformed); a bug indicator, should be 0."""
        return self._unexpected

    def stats(self) -> dict[str, Any]:
        """JSON-able report: totals, per message counters and state, unknown ids seen."""
        frames = {}
        for fid in sorted(self._state):
            st = self._state[fid]
            frames[st.info.name] = {
                "frame_id": fid,
                "subscribed": st.subscribed,
                **st.counts,
                "error_streak": st.error_streak,
                "last_counter": st.last_counter,
                "last_accepted_s": st.last_time_s,
                "last_reject": None
                if st.last_reject is None
                else {"reason": st.last_reject[0], "detail": st.last_reject[1], "t_s": st.last_reject[2]},
            }
        return {
            "total": {**self._total, "unexpected_exceptions": self._unexpected},
            "last_unexpected_exception": self._last_unexpected,
            "frames": frames,
            "unknown_ids": dict(self._unknown_ids),
        }


FrameMonitor = VehicleRx
