"""The SIL bus's shortcuts against python-can's own behaviour: frames built slot by slot
(`protocol.timebase.data_frame`, `hil.sil_bus.received_copy`) equal the constructor's, and the
precompiled filters accept exactly what `BusABC._matches_filters` accepts."""

from __future__ import annotations

import can
from hypothesis import given
from hypothesis import strategies as st

from bywire.clock import SimClock
from bywire.hil.sil_bus import SimVirtualBus, compile_filters, filters_accept, received_copy
from bywire.protocol.timebase import SLOT_LAYOUT_KNOWN, data_frame

_FIELDS = (
    "timestamp",
    "arbitration_id",
    "is_extended_id",
    "is_remote_frame",
    "is_error_frame",
    "channel",
    "dlc",
    "data",
    "is_fd",
    "is_rx",
    "bitrate_switch",
    "error_state_indicator",
)


def _fields(msg: can.Message) -> dict[str, object]:
    return {name: getattr(msg, name) for name in _FIELDS}


def test_the_installed_python_can_has_the_slot_layout_the_shortcuts_were_written_for() -> None:
    # Not a precondition of correctness (the shortcuts fall back to the constructor), but a
    # python-can upgrade that changes can.Message should be noticed, not silently cost speed.
    assert SLOT_LAYOUT_KNOWN, sorted(can.Message.__slots__)


@given(
    arbitration_id=st.integers(0, 0x7FF),
    data=st.binary(max_size=8),
    timestamp=st.floats(0.0, 1e6, allow_nan=False),
)
def test_data_frame_equals_the_constructors_frame(arbitration_id: int, data: bytes, timestamp: float) -> None:
    ours = data_frame(arbitration_id, bytearray(data), timestamp)
    theirs = can.Message(
        timestamp=timestamp, arbitration_id=arbitration_id, is_extended_id=False, data=bytearray(data)
    )
    assert _fields(ours) == _fields(theirs)
    assert ours.equals(theirs)


@given(
    extended=st.booleans(),
    ident=st.integers(0, 0x1FFFFFFF),
    data=st.binary(max_size=8),
    remote=st.booleans(),
    rx_time=st.floats(0.0, 1e6, allow_nan=False),
)
def test_received_copy_equals_the_constructors_copy(
    extended: bool, ident: int, data: bytes, remote: bool, rx_time: float
) -> None:
    ident = ident if extended else ident & 0x7FF
    sent = can.Message(
        arbitration_id=ident,
        is_extended_id=extended,
        is_remote_frame=remote,
        data=None if remote else data,
        dlc=len(data),
    )
    ours = received_copy(sent, rx_time, "ch")
    theirs = can.Message(
        timestamp=rx_time,
        arbitration_id=sent.arbitration_id,
        is_extended_id=sent.is_extended_id,
        is_remote_frame=sent.is_remote_frame,
        is_error_frame=sent.is_error_frame,
        dlc=sent.dlc,
        data=bytes(sent.data),
        is_fd=sent.is_fd,
        channel="ch",
        is_rx=True,
    )
    assert _fields(ours) == _fields(theirs)
    assert ours.data is not sent.data  # a receiver never shares the sender's buffer


_FILTER = st.fixed_dictionaries(
    {"can_id": st.integers(0, 0x1FFFFFFF), "can_mask": st.integers(0, 0x1FFFFFFF)},
    optional={"extended": st.booleans()},
)


@given(
    filters=st.lists(_FILTER, max_size=4),
    ident=st.integers(0, 0x1FFFFFFF),
    extended=st.booleans(),
)
def test_compiled_filters_accept_what_python_can_accepts(
    filters: list[can.typechecking.CanFilter], ident: int, extended: bool
) -> None:
    ident = ident if extended else ident & 0x7FF
    msg = can.Message(arbitration_id=ident, is_extended_id=extended)
    bus = SimVirtualBus(channel="filters-oracle", clock=SimClock(0.0), can_filters=filters or None)
    try:
        expected = bus._matches_filters(msg)
        compiled = compile_filters(filters)
        assert (compiled is None or filters_accept(compiled, msg)) == expected
        assert bus.accepts(msg) == expected
    finally:
        bus.shutdown()


def test_a_filtered_receiver_only_queues_what_its_filters_accept() -> None:
    clock = SimClock(1.5)
    tx = SimVirtualBus(channel="filters-e2e", clock=clock)
    rx = SimVirtualBus(
        channel="filters-e2e",
        clock=clock,
        can_filters=[{"can_id": 0x300, "can_mask": 0x7FF, "extended": False}],
    )
    try:
        for ident in (0x120, 0x300, 0x301):
            tx.send(data_frame(ident, bytearray(b"\x01\x02")))
        got = rx.recv(timeout=0)
        assert got is not None and got.arbitration_id == 0x300 and got.timestamp == 1.5
        assert rx.recv(timeout=0) is None
    finally:
        tx.shutdown()
        rx.shutdown()
