"""UdpCanBus: cannelloni v2 wire format, loopback behaviour, and one back-to-back suite run against the
virtual, remote (python-can-remote) and udp transports (in the spirit of python-can's back2back_test)."""

from __future__ import annotations

import socket
import struct
import uuid
from collections.abc import Iterator

import can
import pytest
from hypothesis import given
from hypothesis import strategies as st

from bywire.protocol.bus_url import open_bus, serve_virtual_bus, stop_bus_server, wait_for_port
from bywire.protocol.udp_bus import (
    CAN_EFF_FLAG,
    CAN_RTR_FLAG,
    MalformedDatagram,
    UdpCanBus,
    decode_datagram,
    encode_datagram,
    encode_frame,
    parse_host_port,
)

FD_LENGTHS = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64]


@st.composite
def can_messages(draw: st.DrawFn) -> can.Message:
    extended = draw(st.booleans())
    arbitration_id = draw(st.integers(0, 0x1FFFFFFF if extended else 0x7FF))
    kind = draw(st.sampled_from(["data", "remote", "fd", "error"]))
    if kind == "remote":
        return can.Message(
            arbitration_id=arbitration_id,
            is_extended_id=extended,
            is_remote_frame=True,
            dlc=draw(st.integers(0, 8)),
        )
    if kind == "fd":
        data = draw(st.binary(min_size=0, max_size=64).filter(lambda b: len(b) in FD_LENGTHS))
        return can.Message(
            arbitration_id=arbitration_id,
            is_extended_id=extended,
            is_fd=True,
            data=data,
            bitrate_switch=draw(st.booleans()),
            error_state_indicator=draw(st.booleans()),
        )
    data = draw(st.binary(max_size=8))
    return can.Message(
        arbitration_id=arbitration_id, is_extended_id=extended, data=data, is_error_frame=kind == "error"
    )


def _same(a: can.Message, b: can.Message) -> bool:
    return (
        a.arbitration_id == b.arbitration_id
        and a.is_extended_id == b.is_extended_id
        and a.is_remote_frame == b.is_remote_frame
        and a.is_error_frame == b.is_error_frame
        and a.is_fd == b.is_fd
        and a.bitrate_switch == b.bitrate_switch
        and a.error_state_indicator == b.error_state_indicator
        and a.dlc == b.dlc
        and bytes(a.data or b"") == bytes(b.data or b"")
    )


# --- wire format -----------------------------------------------------------------------------


def test_known_bytes_match_cannelloni_format() -> None:
    """Hand-assembled from cannelloni doc/udp_format.md: header, one SFF frame, one EFF RTR frame."""
    msgs = [
        can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\x01\x02\x03"),
        can.Message(arbitration_id=0x1ABCDEF, is_extended_id=True, is_remote_frame=True, dlc=4),
    ]
    expected = (
        bytes([2, 0, 7])
        + struct.pack(">H", 2)
        + struct.pack(">IB", 0x123, 3)
        + b"\x01\x02\x03"
        + struct.pack(">IB", 0x1ABCDEF | CAN_EFF_FLAG | CAN_RTR_FLAG, 4)
    )
    assert encode_datagram(msgs, seq_no=7) == expected
    seq, decoded = decode_datagram(expected)
    assert seq == 7 and len(decoded) == 2
    assert all(_same(a, b) for a, b in zip(msgs, decoded, strict=True))


def test_fd_frame_carries_flags_byte() -> None:
    msg = can.Message(
        arbitration_id=0x10, is_extended_id=False, is_fd=True, bitrate_switch=True, data=bytes(12)
    )
    assert encode_frame(msg) == struct.pack(">IB", 0x10, 12 | 0x80) + b"\x01" + bytes(12)


@given(st.lists(can_messages(), max_size=20), st.integers(0, 255))
def test_datagram_round_trip(msgs: list[can.Message], seq: int) -> None:
    got_seq, decoded = decode_datagram(encode_datagram(msgs, seq))
    assert got_seq == seq
    assert len(decoded) == len(msgs)
    assert all(_same(a, b) for a, b in zip(msgs, decoded, strict=True))


@pytest.mark.parametrize(
    ("datagram", "problem"),
    [
        (b"", "shorter than the 5-byte header"),
        (bytes([1, 0, 0, 0, 0]), "version 1"),
        (bytes([2, 1, 0, 0, 0]), "op_code 1"),
        (bytes([2, 0, 0, 0, 1]) + b"\x00\x00", "header truncated"),
        (bytes([2, 0, 0, 0, 1]) + struct.pack(">IB", 0x123, 9) + bytes(9), "classic CAN length 9"),
        (bytes([2, 0, 0, 0, 1]) + struct.pack(">IB", 0x123, 4) + b"\x01", "truncated"),
        (bytes([2, 0, 0, 0, 1]) + struct.pack(">IB", 0x800, 0), "exceeds 11 bits"),
        (
            bytes([2, 0, 0, 0, 1]) + struct.pack(">IB", 0x12, 9 | 0x80) + b"\x00" + bytes(9),
            "not a CAN FD length",
        ),
        (bytes([2, 0, 0, 0, 0]) + b"\x00", "trailing"),
        (bytes([2, 0, 0, 0, 1]) + struct.pack(">IB", 0x12, 1) + b"\x00\x00", "trailing"),
    ],
)
def test_malformed_datagrams_say_why(datagram: bytes, problem: str) -> None:
    with pytest.raises(MalformedDatagram, match=problem):
        decode_datagram(datagram)


def test_empty_datagram_is_valid_and_empty() -> None:
    assert decode_datagram(bytes([2, 0, 9, 0, 0])) == (9, [])


def test_encode_refuses_what_the_wire_cannot_carry() -> None:
    with pytest.raises(ValueError, match="11 bits"):
        encode_frame(can.Message(arbitration_id=0x800, is_extended_id=False, check=False))
    with pytest.raises(ValueError, match="CAN FD length"):
        encode_frame(can.Message(arbitration_id=1, is_fd=True, data=bytes(9), check=False))
    with pytest.raises(ValueError, match="seq_no"):
        encode_datagram([], 256)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("127.0.0.1:5000", ("127.0.0.1", 5000)),
        (":7", ("127.0.0.1", 7)),
        ("[::1]:80", ("::1", 80)),
        ("localhost:0", ("localhost", 0)),
    ],
)
def test_parse_host_port(text: str, expected: tuple[str, int]) -> None:
    assert parse_host_port(text, "x") == expected


# --- the bus on loopback -----------------------------------------------------------------------


@pytest.fixture
def udp_pair() -> Iterator[tuple[UdpCanBus, UdpCanBus]]:
    a = UdpCanBus("127.0.0.1:0")
    b = UdpCanBus("127.0.0.1:0", peer=a.local_address)
    a.set_peer(b.local_address)
    yield a, b
    a.shutdown()
    b.shutdown()


def test_loopback_round_trip(udp_pair: tuple[UdpCanBus, UdpCanBus]) -> None:
    a, b = udp_pair
    sent = can.Message(arbitration_id=0x1F334455, is_extended_id=True, data=b"\xde\xad\xbe\xef")
    a.send(sent)
    got = b.recv(timeout=2.0)
    assert got is not None and _same(sent, got)
    assert got.channel == b.channel and got.timestamp > 0
    assert a.tx_frames == 1 and b.rx_frames == 1 and b.rx_errors == 0


def test_many_frames_in_order(udp_pair: tuple[UdpCanBus, UdpCanBus]) -> None:
    a, b = udp_pair
    n = 200  # a burst that fits even the kernel's default receive buffer
    for i in range(n):
        a.send(can.Message(arbitration_id=i & 0x7FF, is_extended_id=False, data=struct.pack(">H", i)))
    got = [b.recv(timeout=2.0) for _ in range(n)]
    assert [struct.unpack(">H", m.data)[0] for m in got if m is not None] == list(range(n))
    assert b.rx_seq_gaps == 0


def test_sequence_number_wraps_without_gaps(udp_pair: tuple[UdpCanBus, UdpCanBus]) -> None:
    a, b = udp_pair
    received = []
    for i in range(600):  # 8-bit sequence number wraps twice
        a.send(can.Message(arbitration_id=0x123, is_extended_id=False, data=struct.pack(">H", i)))
        msg = b.recv(timeout=2.0)
        assert msg is not None
        received.append(struct.unpack(">H", msg.data)[0])
    assert received == list(range(600))
    assert b.rx_seq_gaps == 0 and b.rx_errors == 0


def test_recv_timeout_zero_polls(udp_pair: tuple[UdpCanBus, UdpCanBus]) -> None:
    _, b = udp_pair
    assert b.recv(timeout=0) is None
    assert b.recv(timeout=0.01) is None


def test_two_buses_talk_both_ways(udp_pair: tuple[UdpCanBus, UdpCanBus]) -> None:
    a, b = udp_pair
    for i in range(50):
        a.send(can.Message(arbitration_id=0x100, is_extended_id=False, data=bytes([i])))
        b.send(can.Message(arbitration_id=0x200, is_extended_id=False, data=bytes([i])))
    from_a = [b.recv(timeout=2.0) for _ in range(50)]
    from_b = [a.recv(timeout=2.0) for _ in range(50)]
    assert [(m.arbitration_id, m.data[0]) for m in from_a if m] == [(0x100, i) for i in range(50)]
    assert [(m.arbitration_id, m.data[0]) for m in from_b if m] == [(0x200, i) for i in range(50)]


def test_garbage_datagrams_are_dropped_and_counted() -> None:
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", 0))
    bus = UdpCanBus("127.0.0.1:0", peer=peer.getsockname())
    try:
        valid = [
            encode_datagram([can.Message(arbitration_id=i, is_extended_id=False, data=[i])], i)
            for i in range(3)
        ]
        garbage = [b"", b"\x02", b"hello world", bytes([2, 0, 0, 0, 5]), bytes([3, 0, 0, 0, 0])]
        for datagram in [
            garbage[0],
            valid[0],
            garbage[1],
            garbage[2],
            valid[1],
            garbage[3],
            garbage[4],
            valid[2],
        ]:
            peer.sendto(datagram, bus.local_address)
        got = [bus.recv(timeout=2.0) for _ in range(3)]
        assert [m.arbitration_id for m in got if m is not None] == [0, 1, 2]
        assert bus.recv(timeout=0.05) is None
        assert bus.rx_errors == len(garbage)
        assert bus.rx_frames == 3
    finally:
        bus.shutdown()
        peer.close()


def test_datagrams_from_a_foreign_address_are_dropped() -> None:
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", 0))
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    bus = UdpCanBus("127.0.0.1:0", peer=peer.getsockname())
    try:
        datagram = encode_datagram([can.Message(arbitration_id=1, is_extended_id=False)], 0)
        stranger.sendto(datagram, bus.local_address)
        peer.sendto(datagram, bus.local_address)
        assert bus.recv(timeout=2.0) is not None
        assert bus.recv(timeout=0.05) is None
        assert bus.rx_foreign == 1 and bus.rx_errors == 0
    finally:
        bus.shutdown()
        peer.close()
        stranger.close()


def test_sequence_gaps_are_counted_not_dropped() -> None:
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", 0))
    bus = UdpCanBus("127.0.0.1:0", peer=peer.getsockname())
    try:
        for seq in (0, 1, 5, 6):
            peer.sendto(
                encode_datagram([can.Message(arbitration_id=seq, is_extended_id=False)], seq),
                bus.local_address,
            )
        assert len([bus.recv(timeout=2.0) for _ in range(4)]) == 4
        assert bus.rx_seq_gaps == 1
    finally:
        bus.shutdown()
        peer.close()


def test_several_frames_in_one_datagram_are_all_delivered() -> None:
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", 0))
    bus = UdpCanBus("127.0.0.1:0", peer=peer.getsockname())
    try:
        msgs = [can.Message(arbitration_id=i, is_extended_id=False, data=[i]) for i in range(10)]
        peer.sendto(encode_datagram(msgs, 0), bus.local_address)
        got = [bus.recv(timeout=2.0) for _ in range(10)]
        assert [m.arbitration_id for m in got if m is not None] == list(range(10))
    finally:
        bus.shutdown()
        peer.close()


def test_receive_own_messages_and_no_peer() -> None:
    bus = UdpCanBus("127.0.0.1:0", receive_own_messages=True)
    try:
        with pytest.raises(can.CanOperationError, match="no peer"):
            bus.send(can.Message(arbitration_id=1, is_extended_id=False))
        bus.set_peer(bus.local_address)  # talk to itself: own copy plus the looped-back datagram
        bus.send(can.Message(arbitration_id=2, is_extended_id=False, data=b"\x09"))
        first, second = bus.recv(timeout=2.0), bus.recv(timeout=2.0)
        assert first is not None and not first.is_rx and first.data == b"\x09"
        assert second is not None and second.is_rx and second.data == b"\x09"
    finally:
        bus.shutdown()


def test_filters_apply() -> None:
    a = UdpCanBus("127.0.0.1:0")
    b = UdpCanBus("127.0.0.1:0", peer=a.local_address, can_filters=[{"can_id": 0x10, "can_mask": 0x7FF}])
    a.set_peer(b.local_address)
    try:
        a.send(can.Message(arbitration_id=0x11, is_extended_id=False))
        a.send(can.Message(arbitration_id=0x10, is_extended_id=False))
        got = b.recv(timeout=2.0)
        assert got is not None and got.arbitration_id == 0x10
    finally:
        a.shutdown()
        b.shutdown()


def test_python_can_entry_point() -> None:
    bus = can.Bus(interface="bywire_udp", channel="127.0.0.1:0", peer="127.0.0.1:9")
    try:
        assert isinstance(bus, UdpCanBus) and bus.peer == ("127.0.0.1", 9)
    finally:
        bus.shutdown()


def test_bad_bind_address_is_a_clear_error() -> None:
    with pytest.raises(can.CanInitializationError, match="not HOST:PORT"):
        UdpCanBus("nonsense")


# --- back to back: the same behaviour on every transport -----------------------------------------


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def remote_server() -> Iterator[int]:
    server, thread = serve_virtual_bus(0, f"b2b-{uuid.uuid4().hex}")
    wait_for_port("127.0.0.1", server.server_port, timeout_s=5.0)
    yield server.server_port
    stop_bus_server(server, thread)


@pytest.fixture(params=["virtual", "remote", "udp"])
def bus_pair(request: pytest.FixtureRequest, remote_server: int) -> Iterator[tuple[can.BusABC, can.BusABC]]:
    if request.param == "virtual":
        name = f"b2b-{uuid.uuid4().hex}"
        urls = (f"virtual:{name}", f"virtual:{name}")
    elif request.param == "remote":
        urls = (f"remote:ws://127.0.0.1:{remote_server}",) * 2
    else:
        pa, pb = _free_port(), _free_port()
        urls = (f"udp://127.0.0.1:{pa}?peer=127.0.0.1:{pb}", f"udp://127.0.0.1:{pb}?peer=127.0.0.1:{pa}")
    a, b = open_bus(urls[0]), open_bus(urls[1])
    yield a, b
    a.shutdown()
    b.shutdown()


def _check_received(sent: can.Message, bus: can.BusABC) -> None:
    got = bus.recv(timeout=5.0)
    assert got is not None, f"{sent} not received"
    assert _same(sent, got), f"sent {sent}, got {got}"


class TestBackToBack:
    def test_no_message(self, bus_pair: tuple[can.BusABC, can.BusABC]) -> None:
        a, b = bus_pair
        assert a.recv(timeout=0.05) is None
        assert b.recv(timeout=0) is None

    def test_standard_and_extended(self, bus_pair: tuple[can.BusABC, can.BusABC]) -> None:
        a, b = bus_pair
        for msg in (
            can.Message(arbitration_id=0x7FF, is_extended_id=False, data=b"\x01\x02\x03\x04\x05\x06\x07\x08"),
            can.Message(arbitration_id=0x1FFFFFFF, is_extended_id=True, data=b"\xff"),
            can.Message(arbitration_id=0x000, is_extended_id=False, data=b""),
        ):
            a.send(msg)
            _check_received(msg, b)

    def test_remote_frame(self, bus_pair: tuple[can.BusABC, can.BusABC]) -> None:
        a, b = bus_pair
        msg = can.Message(arbitration_id=0x710, is_extended_id=False, is_remote_frame=True, dlc=1)
        a.send(msg)
        _check_received(msg, b)

    def test_both_directions(self, bus_pair: tuple[can.BusABC, can.BusABC]) -> None:
        a, b = bus_pair
        ma = can.Message(arbitration_id=0x190, is_extended_id=False, data=b"a")
        mb = can.Message(arbitration_id=0x210, is_extended_id=False, data=b"b")
        a.send(ma)
        b.send(mb)
        _check_received(ma, b)
        _check_received(mb, a)

    def test_order_is_kept(self, bus_pair: tuple[can.BusABC, can.BusABC]) -> None:
        a, b = bus_pair
        sent = [
            can.Message(arbitration_id=0x300, is_extended_id=False, data=struct.pack("<H", i))
            for i in range(300)
        ]
        for msg in sent:
            a.send(msg)
        for msg in sent:
            _check_received(msg, b)

    def test_sender_does_not_hear_itself(self, bus_pair: tuple[can.BusABC, can.BusABC]) -> None:
        a, b = bus_pair
        a.send(can.Message(arbitration_id=0x1, is_extended_id=False))
        assert b.recv(timeout=5.0) is not None
        assert a.recv(timeout=0.05) is None
