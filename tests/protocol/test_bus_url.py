"""Bus URLs (DESIGN section 3): parsing, clear errors, and opening virtual, remote and udp buses."""

from __future__ import annotations

import logging
import os
import signal
import socket
import subprocess
import sys
import time
import uuid
from typing import Any

import can
import pytest
from hypothesis import given
from hypothesis import strategies as st

from bywire.protocol import bus_url
from bywire.protocol.bus_url import (
    BusSpec,
    BusUrlError,
    coerce_value,
    open_bus,
    parse_bus_url,
    serve_virtual_bus,
    stop_bus_server,
    wait_for_port,
)
from bywire.protocol.udp_bus import UdpCanBus


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.parametrize(
    ("url", "spec"),
    [
        ("virtual:sil", BusSpec("virtual", "sil", {})),
        ("virtual:sil?receive_own_messages=true", BusSpec("virtual", "sil", {"receive_own_messages": True})),
        ("socketcan:vcan0", BusSpec("socketcan", "vcan0", {})),
        (
            "socketcan:can0?fd=on&bitrate=500000",
            BusSpec("socketcan", "can0", {"fd": True, "bitrate": 500000}),
        ),
        ("remote:ws://127.0.0.1:54701", BusSpec("remote", "ws://127.0.0.1:54701", {})),
        (
            "remote:ws://127.0.0.1:54701/?bitrate=500000",
            BusSpec("remote", "ws://127.0.0.1:54701/", {"bitrate": 500000}),
        ),
        (
            "udp://127.0.0.1:5000?peer=127.0.0.1:5001",
            BusSpec("bywire_udp", "127.0.0.1:5000", {"peer": "127.0.0.1:5001"}),
        ),
        ("udp://:5000?peer=:5001", BusSpec("bywire_udp", "127.0.0.1:5000", {"peer": "127.0.0.1:5001"})),
        (
            "UDP://127.0.0.1:0?peer=127.0.0.1:9&receive_own_messages=yes",
            BusSpec("bywire_udp", "127.0.0.1:0", {"peer": "127.0.0.1:9", "receive_own_messages": True}),
        ),
        (
            "pcan:PCAN_USBBUS1?bitrate=500000&data_bitrate=2e6&fd=false&serial=0x1F",
            BusSpec(
                "pcan", "PCAN_USBBUS1", {"bitrate": 500000, "data_bitrate": 2e6, "fd": False, "serial": 31}
            ),
        ),
        ("kvaser:0", BusSpec("kvaser", "0", {})),
    ],
)
def test_parse_accepted_forms(url: str, spec: BusSpec) -> None:
    assert parse_bus_url(url) == spec


@pytest.mark.parametrize(
    ("url", "problem"),
    [
        ("", "empty"),
        ("vcan0", "no 'INTERFACE:' prefix"),
        ("virtual:", "no channel"),
        ("nosuchbus:x", "unknown python-can interface 'nosuchbus'"),
        ("udp_multicast:239.0.0.1", "IGMP"),
        ("udp:127.0.0.1:5000", "udp://"),
        ("udp://127.0.0.1:5000", "?peer=HOST:PORT"),
        ("udp://127.0.0.1:5000?peer=127.0.0.1", "not HOST:PORT"),
        ("udp://127.0.0.1:99999?peer=127.0.0.1:1", "outside 0..65535"),
        ("udp://127.0.0.1:5000?peer=127.0.0.1:0", "peer port 0"),
        ("udp://127.0.0.1:x?peer=127.0.0.1:1", "not an integer"),
        ("udp://127.0.0.1:5000/path?peer=127.0.0.1:1", "no path"),
        ("remote:http://127.0.0.1:1", "ws://"),
        ("remote:ws://127.0.0.1", "host and port"),
        ("virtual:x?a=1&a=2", "twice"),
        ("virtual:x?bad key=1", "not a valid keyword"),
        ("virtual:x?novalue", "key=value"),
    ],
)
def test_bad_urls_say_what_and_list_accepted_forms(url: str, problem: str) -> None:
    with pytest.raises(BusUrlError) as info:
        parse_bus_url(url)
    message = str(info.value)
    assert problem in message
    assert "accepted forms" in message and "remote:ws://127.0.0.1:PORT" in message
    assert isinstance(info.value, ValueError)


def test_socketcan_kwargs_reach_python_can(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[dict[str, Any]] = []

    def fake_bus(**kwargs: Any) -> str:
        calls.append(kwargs)
        return "bus"

    monkeypatch.setattr(bus_url.can, "Bus", fake_bus)
    assert open_bus("socketcan:vcan0?fd=true", receive_own_messages=False) == "bus"
    assert open_bus("socketcan:can0") == "bus"
    assert calls == [
        {"interface": "socketcan", "channel": "vcan0", "fd": True, "receive_own_messages": False},
        {"interface": "socketcan", "channel": "can0"},
    ]


def test_keyword_given_twice_is_an_error() -> None:
    with pytest.raises(BusUrlError, match="both in the URL and as keyword"):
        open_bus("virtual:x?receive_own_messages=true", receive_own_messages=False)


@given(st.integers(min_value=-(2**63), max_value=2**63))
def test_coerce_int(value: int) -> None:
    assert coerce_value(str(value)) == value
    assert coerce_value(hex(value)) == value


@given(st.floats(allow_nan=False, allow_infinity=False))
def test_coerce_float(value: float) -> None:
    coerced = coerce_value(repr(value))
    assert coerced == value
    assert not isinstance(coerced, bool)


@pytest.mark.parametrize(
    ("text", "value"),
    [
        ("true", True),
        ("On", True),
        ("YES", True),
        ("false", False),
        ("off", False),
        ("no", False),
        ("can0", "can0"),
        ("1", 1),
    ],
)
def test_coerce_bool_and_str(text: str, value: object) -> None:
    coerced = coerce_value(text)
    assert coerced == value and type(coerced) is type(value)


def test_open_virtual_bus_pair() -> None:
    name = f"url-{uuid.uuid4().hex}"
    with open_bus(f"virtual:{name}") as a, open_bus(f"virtual:{name}") as b:
        a.send(can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False))
        msg = b.recv(timeout=1.0)
        assert msg is not None and msg.arbitration_id == 0x123 and msg.data == b"\x01\x02"


def test_open_udp_bus_pair_on_loopback() -> None:
    port_a, port_b = _free_port(), _free_port()
    a = open_bus(f"udp://127.0.0.1:{port_a}?peer=127.0.0.1:{port_b}")
    b = open_bus(f"udp://127.0.0.1:{port_b}?peer=127.0.0.1:{port_a}")
    try:
        assert isinstance(a, UdpCanBus) and a.peer == ("127.0.0.1", port_b)
        b.send(can.Message(arbitration_id=0x7FF, data=b"x", is_extended_id=False))
        msg = a.recv(timeout=2.0)
        assert msg is not None and msg.arbitration_id == 0x7FF
    finally:
        a.shutdown()
        b.shutdown()


def test_remote_bus_between_two_clients_and_quiet_logging() -> None:
    logging.getLogger("can_remote").setLevel(logging.DEBUG)
    server, thread = serve_virtual_bus(0, f"remote-{uuid.uuid4().hex}")
    try:
        assert logging.getLogger("can_remote").level == logging.WARNING
        port = server.server_port
        wait_for_port("127.0.0.1", port, timeout_s=5.0)
        a = open_bus(f"remote:ws://127.0.0.1:{port}")
        b = open_bus(f"remote:ws://127.0.0.1:{port}")
        try:
            for i in range(20):
                a.send(can.Message(arbitration_id=0x100 + i, data=bytes([i]), is_extended_id=False))
            got = [b.recv(timeout=5.0) for _ in range(20)]
            assert [m.arbitration_id for m in got if m is not None] == [0x100 + i for i in range(20)]
            assert a.recv(timeout=0.05) is None  # a virtual bus does not echo to the sender
        finally:
            a.shutdown()
            b.shutdown()
    finally:
        stop_bus_server(server, thread)
    assert not thread.is_alive()


def test_wait_for_port_times_out_on_a_closed_port() -> None:
    port = _free_port()
    with pytest.raises(TimeoutError, match=f"127.0.0.1:{port}"):
        wait_for_port("127.0.0.1", port, timeout_s=0.2)


@pytest.mark.parametrize("inherited", ["blocked", "ignored"])
def test_a_bus_server_stops_on_sigint_whatever_it_inherited(inherited: str) -> None:
    """The HIL runner stops its children with SIGINT; one started by a parent that blocks or ignores
    SIGINT inherits that, and must stop all the same."""
    port = _free_port()
    code = f"from bywire.protocol.bus_url import run_bus_server; run_bus_server({port}, 'inh')"

    def inherit() -> None:
        if inherited == "blocked":
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        else:
            signal.signal(signal.SIGINT, signal.SIG_IGN)

    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, preexec_fn=inherit
    )
    try:
        wait_for_port("127.0.0.1", port, timeout_s=20.0)
        os.kill(proc.pid, signal.SIGINT)
        proc.communicate(timeout=10)
        assert proc.returncode == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_run_bus_server_serves_until_interrupted() -> None:
    """`bywire bus serve` path: a separate process serves the bus, two clients talk through it."""
    port = _free_port()
    code = f"from bywire.protocol.bus_url import run_bus_server; run_bus_server({port}, 'cli')"
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        wait_for_port("127.0.0.1", port, timeout_s=20.0)
        a = open_bus(f"remote:ws://127.0.0.1:{port}")
        b = open_bus(f"remote:ws://127.0.0.1:{port}")
        try:
            a.send(can.Message(arbitration_id=0x42, data=b"hi", is_extended_id=False))
            msg = b.recv(timeout=5.0)
            assert msg is not None and msg.data == b"hi"
        finally:
            a.shutdown()
            b.shutdown()
        os.kill(proc.pid, signal.SIGINT)
        try:
            _, stderr = proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            # seen once in the full suite on a loaded machine, never alone: keep the evidence
            os.kill(proc.pid, signal.SIGUSR1)
            time.sleep(1.0)
            proc.kill()
            _, stderr = proc.communicate(timeout=10)
            raise AssertionError(
                f"the bus server did not stop on SIGINT; its threads:\n{stderr.decode()}"
            ) from None
        assert proc.returncode == 0, stderr.decode()
        # Quiet: one line saying where it serves, no per-connection DEBUG/INFO chatter.
        assert stderr.decode().count("\n") <= 2, stderr.decode()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
