"""The link that carries LIDAR revolutions (`scan_message`) from the sensor to the host.

A revolution is 1.6 MB ten times a second: too big for a datagram, and worthless once the next one is
there. So the link is a queue of whole messages that keeps only the newest few (`KEEP`): a host that
falls behind reads the latest revolution, never a backlog, and the sensor never blocks on it.

- `mem://NAME`: in process (SIL), deterministic: `receive` returns what `send` put in, in order.
- `tcp://127.0.0.1:PORT`: between processes (HIL), a ZeroMQ PUSH (sensor, connects) / PULL (host, binds)
  pair, the host runtime's own transport (`host.runtime.transport`, where the choice of ZeroMQ for
  2 MB scans is measured). Sends never block (`NOBLOCK`, high-water mark `KEEP`): a revolution that
  finds the queue full or no host listening is dropped and counted, as a real sensor's UDP packets
  would be.
"""

from __future__ import annotations

from typing import Any
from urllib.parse import urlparse

from bywire.protocol.objects import MemObjectLink

KEEP = 2  # revolutions queued at most: the one being read and the next


class MemScanLink(MemObjectLink):
    """In-process channel (SIL): the newest `KEEP` messages, in order (`MemObjectLink`'s channel, counted)."""

    def __init__(self, name: str, keep: int = KEEP) -> None:
        super().__init__(name, maxlen=keep)
        self.sent = 0
        self.dropped = 0

    def send(self, data: bytes) -> None:
        if len(self._q) == self._q.maxlen:
            self.dropped += 1
        super().send(data)
        self.sent += 1


class ZmqScanLink:
    """Loopback ZeroMQ PUSH/PULL (HIL): `receiver=True` binds and reads without blocking."""

    def __init__(self, host: str, port: int, receiver: bool, keep: int = KEEP) -> None:
        import zmq

        if host not in ("127.0.0.1", "localhost"):
            raise ValueError(f"tcp scan link: loopback only (127.0.0.1), got {host!r}")
        self._zmq = zmq
        self._ctx: Any = zmq.Context.instance()
        self.receiver = receiver
        self.sock = self._ctx.socket(zmq.PULL if receiver else zmq.PUSH)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.RCVHWM if receiver else zmq.SNDHWM, keep)
        endpoint = f"tcp://127.0.0.1:{port}"
        if receiver:
            self.sock.bind(endpoint)
        else:
            self.sock.connect(endpoint)
        self.sent = 0
        self.dropped = 0

    def send(self, data: bytes) -> None:
        try:
            self.sock.send(data, self._zmq.NOBLOCK, copy=False)
            self.sent += 1
        except self._zmq.Again:
            self.dropped += 1  # the host is not reading, or not there yet

    def receive(self) -> list[bytes]:
        out: list[bytes] = []
        while True:
            try:
                out.append(self.sock.recv(self._zmq.NOBLOCK, copy=True))
            except self._zmq.Again:
                return out

    def close(self) -> None:
        self.sock.close(0)


def open_scan_link(url: str, receiver: bool) -> MemScanLink | ZmqScanLink:
    """`mem://NAME` or `tcp://127.0.0.1:PORT`; ValueError naming the URL otherwise."""
    u = urlparse(url)
    if u.scheme == "mem" and (u.netloc or u.path):
        return MemScanLink(u.netloc + u.path)
    if u.scheme == "tcp" and u.hostname and u.port:
        return ZmqScanLink(u.hostname, u.port, receiver)
    raise ValueError(f"scan link {url!r}: expected mem://NAME or tcp://127.0.0.1:PORT")


__all__ = ["KEEP", "MemScanLink", "ZmqScanLink", "open_scan_link"]
