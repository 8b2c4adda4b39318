"""The object-list datagram: the ego pose and the tracked objects, plant -> host (urban driving).

A stand-in while the host has no perception of its own (seed 000 sections 4-6 are not built): the
plant's urban world sends ground truth (optionally noisy) the way a tracker and an RTK GPS/INS would,
and the host's `urban_io` module reads it. One datagram per cycle, little-endian, fixed layout:

    header  "<4sBBHdI"   magic b"BWOL", version 1, flags (bit 0: pose valid; bit 1: the object list is
                          included, else a pose-only update), object count n (<= 256),
                          t_s (scenario time of the snapshot, s), sequence number
    pose    "<5d"         rear axle x_m, y_m (local metres of the road network), heading_rad (ENU, CCW
                          from east), speed_mps (signed), yaw_rate_radps
    n x     "<I2d4f"      object id, x_m, y_m (its centre), heading_rad, speed_mps (>= 0 along the
                          heading), length_m, width_m

`decode` refuses anything else with `ObjectListError` naming the field; it never raises another
exception (fuzzed in tests/protocol/test_urban_objects.py).

Transports (`open_object_link`): `mem://NAME` in one process (SIL: a deterministic in-process queue) and
`udp://127.0.0.1:PORT` between processes (HIL: loopback only; the receiver binds, the sender sends).
"""

from __future__ import annotations

import math
import socket
import struct
from collections import deque
from dataclasses import dataclass
from typing import ClassVar
from urllib.parse import urlparse

MAGIC = b"BWOL"
VERSION = 1
MAX_OBJECTS = 256
FLAG_POSE = 0x01
FLAG_OBJECTS = 0x02  # the object list is part of this datagram (else: a pose-only update)
_HEADER = struct.Struct("<4sBBHdI")
_POSE = struct.Struct("<5d")
_OBJECT = struct.Struct("<I2d4f")
MAX_DATAGRAM = _HEADER.size + _POSE.size + MAX_OBJECTS * _OBJECT.size


class ObjectListError(ValueError):
    """A datagram that is not a valid object list; the message names the field."""


@dataclass(frozen=True)
class EgoPoseRecord:
    x_m: float
    y_m: float
    heading_rad: float
    speed_mps: float
    yaw_rate_radps: float


@dataclass(frozen=True)
class ObjectRecord:
    object_id: int
    x_m: float
    y_m: float
    heading_rad: float
    speed_mps: float
    length_m: float
    width_m: float


@dataclass(frozen=True)
class ObjectList:
    t_s: float
    seq: int
    pose: EgoPoseRecord | None
    objects: tuple[ObjectRecord, ...]
    has_objects: bool = True  # False: a pose-only update, the last object list still stands


def encode(msg: ObjectList) -> bytes:
    if len(msg.objects) > MAX_OBJECTS:
        raise ObjectListError(f"objects: {len(msg.objects)} objects, at most {MAX_OBJECTS}")
    flags = (FLAG_POSE if msg.pose is not None else 0) | (FLAG_OBJECTS if msg.has_objects else 0)
    if not msg.has_objects and msg.objects:
        raise ObjectListError("objects: a pose-only update carries no objects")
    p = msg.pose or EgoPoseRecord(0.0, 0.0, 0.0, 0.0, 0.0)
    parts = [
        _HEADER.pack(MAGIC, VERSION, flags, len(msg.objects), msg.t_s, msg.seq & 0xFFFFFFFF),
        _POSE.pack(p.x_m, p.y_m, p.heading_rad, p.speed_mps, p.yaw_rate_radps),
    ]
    for o in msg.objects:
        parts.append(
            _OBJECT.pack(
                o.object_id & 0xFFFFFFFF, o.x_m, o.y_m, o.heading_rad, o.speed_mps, o.length_m, o.width_m
            )
        )
    return b"".join(parts)


def decode(data: bytes) -> ObjectList:
    """The datagram as an `ObjectList`, or `ObjectListError` saying what is wrong where."""
    if len(data) < _HEADER.size + _POSE.size:
        raise ObjectListError(f"header: {len(data)} bytes, need at least {_HEADER.size + _POSE.size}")
    magic, version, flags, n, t_s, seq = _HEADER.unpack_from(data, 0)
    if magic != MAGIC:
        raise ObjectListError(f"magic: {magic!r}, expected {MAGIC!r}")
    if version != VERSION:
        raise ObjectListError(f"version: {version}, this decoder reads {VERSION}")
    if flags & ~(FLAG_POSE | FLAG_OBJECTS):
        raise ObjectListError(f"flags: unknown bits 0x{flags:02x}")
    if n > MAX_OBJECTS:
        raise ObjectListError(f"count: {n} objects, at most {MAX_OBJECTS}")
    if n and not flags & FLAG_OBJECTS:
        raise ObjectListError(f"count: {n} objects in a pose-only update (flags 0x{flags:02x})")
    want = _HEADER.size + _POSE.size + n * _OBJECT.size
    if len(data) != want:
        raise ObjectListError(f"length: {len(data)} bytes for {n} objects, expected {want}")
    if not math.isfinite(t_s):
        raise ObjectListError(f"t_s: {t_s} is not finite")
    pose_values = _POSE.unpack_from(data, _HEADER.size)
    pose = None
    if flags & FLAG_POSE:
        for name, v in zip(
            ("x_m", "y_m", "heading_rad", "speed_mps", "yaw_rate_radps"), pose_values, strict=True
        ):
            if not math.isfinite(v):
                raise ObjectListError(f"pose.{name}: {v} is not finite")
        pose = EgoPoseRecord(*pose_values)
    objects = []
    off = _HEADER.size + _POSE.size
    for i in range(n):
        oid, x, y, h, v, length, width = _OBJECT.unpack_from(data, off)
        off += _OBJECT.size
        for name, val in (("x_m", x), ("y_m", y), ("heading_rad", h), ("speed_mps", v)):
            if not math.isfinite(val):
                raise ObjectListError(f"objects[{i}].{name}: {val} is not finite")
        if v < 0.0:
            raise ObjectListError(f"objects[{i}].speed_mps: {v} < 0 (a speed along the heading)")
        for name, val in (("length_m", length), ("width_m", width)):
            if not (math.isfinite(val) and 0.0 < val <= 100.0):
                raise ObjectListError(f"objects[{i}].{name}: {val} is not within (0, 100] m")
        objects.append(ObjectRecord(oid, x, y, h, v, length, width))
    return ObjectList(t_s, seq, pose, tuple(objects), bool(flags & FLAG_OBJECTS))


class MemObjectLink:
    """In-process channel (SIL): what `send` puts in, `receive` takes out, in order; bounded."""

    _channels: ClassVar[dict[str, deque[bytes]]] = {}

    def __init__(self, name: str, maxlen: int = 1024) -> None:
        self.name = name
        self._q = MemObjectLink._channels.setdefault(name, deque(maxlen=maxlen))

    def send(self, data: bytes) -> None:
        self._q.append(bytes(data))

    def receive(self) -> list[bytes]:
        out = list(self._q)
        self._q.clear()
        return out

    def close(self) -> None:
        MemObjectLink._channels.pop(self.name, None)


class UdpObjectLink:
    """Loopback UDP (HIL). `receiver=True` binds the port and reads without blocking; otherwise sends."""

    def __init__(self, host: str, port: int, receiver: bool) -> None:
        if host not in ("127.0.0.1", "localhost"):
            raise ValueError(f"udp object link: loopback only (127.0.0.1), got {host!r}")
        self.addr = ("127.0.0.1", port)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.receiver = receiver
        self.dropped = 0
        if receiver:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
            self.sock.bind(self.addr)
        self.sock.setblocking(False)

    def send(self, data: bytes) -> None:
        try:
            self.sock.sendto(data, self.addr)
        except OSError:
            self.dropped += 1  # nobody listening yet / buffer full: a lost datagram, like on a radio

    def receive(self) -> list[bytes]:
        out: list[bytes] = []
        while True:
            try:
                data, _ = self.sock.recvfrom(MAX_DATAGRAM + 64)
            except (BlockingIOError, InterruptedError):
                return out
            except OSError:
                return out
            out.append(data)

    def close(self) -> None:
        self.sock.close()


def open_object_link(url: str, receiver: bool) -> MemObjectLink | UdpObjectLink:
    """`mem://NAME` or `udp://127.0.0.1:PORT`; ValueError naming the URL otherwise."""
    u = urlparse(url)
    if u.scheme == "mem" and (u.netloc or u.path):
        return MemObjectLink(u.netloc + u.path)
    if u.scheme == "udp" and u.hostname and u.port:
        return UdpObjectLink(u.hostname, u.port, receiver)
    raise ValueError(f"object link {url!r}: expected mem://NAME or udp://127.0.0.1:PORT")


__all__ = [
    "EgoPoseRecord",
    "MemObjectLink",
    "ObjectList",
    "ObjectListError",
    "ObjectRecord",
    "UdpObjectLink",
    "decode",
    "encode",
    "open_object_link",
]
