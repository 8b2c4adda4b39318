"""The LIDAR's scan link: newest revolutions only, never blocking the sensor, in process and between
processes (ZeroMQ over loopback TCP, as the HIL plant and host use it)."""

from __future__ import annotations

import time

import pytest

from bywire.hil.runner import free_port
from bywire.protocol.lidar.scan_link import KEEP, MemScanLink, ZmqScanLink, open_scan_link


def test_mem_link_keeps_the_newest_revolutions_in_order() -> None:
    sender = open_scan_link("mem://scans-test-order", receiver=False)
    receiver = open_scan_link("mem://scans-test-order", receiver=True)
    try:
        for i in range(5):
            sender.send(bytes([i]))
        assert receiver.receive() == [bytes([i]) for i in range(5 - KEEP, 5)]
        assert receiver.receive() == []
        assert isinstance(sender, MemScanLink) and sender.dropped == 5 - KEEP
    finally:
        receiver.close()


def test_tcp_link_carries_a_whole_revolution_and_never_blocks_the_sender() -> None:
    url = f"tcp://127.0.0.1:{free_port()}"
    sender = open_scan_link(url, receiver=False)
    try:
        # nobody listening: a send never waits for a receiver; what cannot be queued is dropped, counted
        for _ in range(10):
            sender.send(b"x" * 1_600_000)
        assert isinstance(sender, ZmqScanLink) and sender.dropped > 0
        receiver = open_scan_link(url, receiver=True)
        try:
            payload = bytes(range(256)) * 6250  # 1.6 MB
            got: list[bytes] = []
            deadline = time.monotonic() + 10.0
            while not any(g == payload for g in got) and time.monotonic() < deadline:
                sender.send(payload)
                time.sleep(0.05)
                got += receiver.receive()
            assert payload in got
        finally:
            receiver.close()
    finally:
        sender.close()


@pytest.mark.parametrize("url", ["udp://127.0.0.1:5", "tcp://10.0.0.1:5000", "mem://", "scans"])
def test_a_link_that_is_not_one_is_refused_naming_it(url: str) -> None:
    with pytest.raises(ValueError, match=r"scan link|loopback"):
        open_scan_link(url, receiver=True)
