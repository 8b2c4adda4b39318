"""What `bywire bench runtime` sends and what carries it: the two objects (a small one and a LIDAR
scan) and every candidate transport as a sender and a receiver (pyzmq, iceoryx2, eclipse-zenoh,
`multiprocessing.Queue`, and the runtime's own store-to-store transport).

The runtime relays time-stamped objects between processes as KogMo-RTDB did (seed 000 section 3);
these are the ways to do it that `runtime.py`'s rows compare, measured by `runtime_phases`.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import os
import queue
import secrets
import struct
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from bywire.host.runtime import transport
from bywire.host.runtime.store import ObjectStore, Subscription

SCAN_POINTS = 130_000
SCAN_HISTORY = 8  # scans a store keeps (0.8 s of a 10 Hz LIDAR)


@dataclass(frozen=True, slots=True)
class SmallSample:
    """The small object: about the size of a pose or an ECU status (ten floats and a stamp)."""

    t_s: float
    sent_ns: int
    warm: bool = False
    x_m: float = 1.0
    y_m: float = 2.0
    z_m: float = 3.0
    roll_rad: float = 0.1
    pitch_rad: float = 0.2
    yaw_rad: float = 0.3
    vx_mps: float = 4.0
    vy_mps: float = 5.0
    vz_mps: float = 6.0


@dataclass(frozen=True, slots=True)
class ScanSample:
    """The scan-sized object: one Velodyne HDL-64 revolution, x/y/z/intensity as float32."""

    t_s: float
    sent_ns: int
    points: np.ndarray
    warm: bool = False


KINDS = ("small", "scan")
TOPICS = {"small": "/bench/small", "scan": "/bench/scan"}


def _scan_points() -> np.ndarray:
    return np.random.default_rng(0).random((SCAN_POINTS, 4), dtype=np.float32)


def object_bytes(kind: str) -> int:
    if kind == "scan":
        return SCAN_POINTS * 4 * 4
    return sum(len(p) for p in transport.encode(TOPICS[kind], SmallSample(0.0, 0)))


class Factory:
    """Makes the objects of one kind; stamps the send time at the last moment."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self._points = _scan_points() if kind == "scan" else None

    def make(self, warm: bool = False) -> SmallSample | ScanSample:
        if self._points is not None:
            return ScanSample(time.monotonic(), time.perf_counter_ns(), self._points, warm)
        return SmallSample(time.monotonic(), time.perf_counter_ns(), warm)


# -- across processes: the candidates -----------------------------------------------------------------


class Sender(Protocol):
    def send(self, topic: str, obj: Any) -> None: ...
    def close(self) -> None: ...


class Receiver(Protocol):
    def close(self) -> None: ...


OnObject = Callable[[Any], None]


class _ZmqSender:
    """pyzmq as the transport uses it (a PUSH socket connecting, same options), without the store."""

    def __init__(self, endpoint: str) -> None:
        import zmq

        self._zmq = zmq
        self._sock = transport._ctx().socket(zmq.PUSH)
        self._sock.setsockopt(zmq.SNDHWM, transport.SEND_QUEUE)
        self._sock.setsockopt(zmq.LINGER, transport.LINGER_MS)
        self._sock.setsockopt(zmq.RECONNECT_IVL, transport.RECONNECT_MS)
        self._sock.setsockopt(zmq.RECONNECT_IVL_MAX, 0)
        self._sock.connect(endpoint)

    def send(self, topic: str, obj: Any) -> None:
        with contextlib.suppress(self._zmq.Again):
            self._sock.send_multipart(transport.encode(topic, obj), flags=self._zmq.NOBLOCK, copy=False)

    def close(self) -> None:
        self._sock.close()


class _ZmqReceiver:
    """A PULL socket bound at the endpoint; its thread polls it and a pipe that close() writes to."""

    def __init__(self, endpoint: str, on_object: OnObject) -> None:
        import zmq

        self._zmq = zmq
        self._sock = transport._ctx().socket(zmq.PULL)
        self._sock.setsockopt(zmq.RCVHWM, transport.RECEIVE_QUEUE)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.bind(endpoint)
        self._wake_r, self._wake_w = os.pipe()
        self._stop = False
        self._on_object = on_object
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        zmq = self._zmq
        poller = zmq.Poller()
        poller.register(self._sock, zmq.POLLIN)
        poller.register(self._wake_r, zmq.POLLIN)
        while not self._stop:
            if self._sock in dict(poller.poll(500)):
                while not self._stop:
                    try:
                        frames = self._sock.recv_multipart(zmq.NOBLOCK, copy=False)
                    except zmq.Again:
                        break
                    self._on_object(transport.decode(frames)[1])

    def close(self) -> None:
        self._stop = True
        os.write(self._wake_w, b"x")
        self._thread.join(1.0)
        self._sock.close(0)
        os.close(self._wake_r)
        os.close(self._wake_w)


# iceoryx2 as the transport used it before pyzmq: one publish-subscribe service (a slice of bytes
# per object) and one event service (the wake-ups) per endpoint, one node per sender or receiver.
IOX_BUFFER = 128  # unread samples per subscriber
IOX_INITIAL_SAMPLE_BYTES = 4096  # grows (powers of two) with the largest object sent
IOX_ALIGN = 64
_IOX_HEADER = struct.Struct("<4sI")  # magic, number of frames; then one little-endian u64 length each
_IOX_MAGIC = b"BWT1"


def _iox_node() -> Any:
    import iceoryx2 as iox2

    iox2.set_log_level_from_env_or(iox2.LogLevel.Error)  # else: "no config file was loaded"
    return (
        iox2.NodeBuilder.new()
        .signal_handling_mode(iox2.SignalHandlingMode.Disabled)  # else it takes SIGINT/SIGTERM
        .create(iox2.ServiceType.Ipc)
    )


def _iox_services(node: Any, endpoint: str) -> tuple[Any, Any]:
    import iceoryx2 as iox2

    name = iox2.ServiceName.new(endpoint)
    pubsub = (
        node.service_builder(name)
        .publish_subscribe(iox2.Slice[ctypes.c_uint8])
        .max_publishers(2)
        .max_subscribers(8)
        .subscriber_max_buffer_size(IOX_BUFFER)
        .history_size(0)
        .enable_safe_overflow(False)
        .open_or_create()
    )
    event = node.service_builder(name).event().open_or_create()
    return pubsub, event


def _iox_layout(lengths: Sequence[int]) -> tuple[list[int], int]:
    """Offsets of the frames after the header (each 64-byte aligned), and the total size."""

    def aligned(n: int) -> int:
        return -(-n // IOX_ALIGN) * IOX_ALIGN

    offset = aligned(_IOX_HEADER.size + 8 * len(lengths))
    offsets = []
    for n in lengths:
        offsets.append(offset)
        offset = aligned(offset + n)
    return offsets, offset


def _iox_pack_into(dest: np.ndarray, frames: Sequence[memoryview]) -> None:
    lengths = [f.nbytes for f in frames]
    offsets, _ = _iox_layout(lengths)
    dest[: _IOX_HEADER.size] = np.frombuffer(_IOX_HEADER.pack(_IOX_MAGIC, len(frames)), dtype=np.uint8)
    table = np.asarray(lengths, dtype="<u8").view(np.uint8)
    dest[_IOX_HEADER.size : _IOX_HEADER.size + table.nbytes] = table
    for frame, offset in zip(frames, offsets, strict=True):
        dest[offset : offset + frame.nbytes] = np.frombuffer(frame, dtype=np.uint8)


def _iox_unpack(data: np.ndarray) -> list[memoryview]:
    magic, count = _IOX_HEADER.unpack_from(data.data, 0)
    if magic != _IOX_MAGIC:
        raise ValueError(f"not a bywire sample (magic {magic!r})")
    lengths = data[_IOX_HEADER.size : _IOX_HEADER.size + 8 * count].view("<u8").tolist()
    offsets, _ = _iox_layout(lengths)
    view = data.data.toreadonly()
    return [view[o : o + n] for o, n in zip(offsets, lengths, strict=True)]


class _IoxSender:
    def __init__(self, endpoint: str) -> None:
        import iceoryx2 as iox2

        self._node = _iox_node()
        self._pubsub, event = _iox_services(self._node, endpoint)
        self._pub = (
            self._pubsub.publisher_builder()
            .initial_max_slice_len(IOX_INITIAL_SAMPLE_BYTES)
            .allocation_strategy(iox2.AllocationStrategy.PowerOfTwo)
            .backpressure_strategy(iox2.BackpressureStrategy.DiscardData)
            .create()
        )
        self._notifier = event.notifier_builder().create()

    def send(self, topic: str, obj: Any) -> None:
        frames = [memoryview(f).cast("B") for f in transport.encode(topic, obj)]
        size = _iox_layout([f.nbytes for f in frames])[1]
        sample = self._pub.loan_slice_uninit(size)
        _iox_pack_into(
            np.ctypeslib.as_array((ctypes.c_uint8 * size).from_address(sample.payload_ptr)), frames
        )
        sample.assume_init().send()
        self._notifier.notify()

    def close(self) -> None:
        self._pub.delete()
        self._notifier.delete()
        self._pubsub = self._node = None  # the node and its services go with the last reference


class _IoxReceiver:
    """Takes samples until none is left, then waits for an event; close() sends it one to wake it
    (the listener's only wake-up, hence a notifier of its own)."""

    def __init__(self, endpoint: str, on_object: OnObject) -> None:
        import iceoryx2 as iox2

        self._node = _iox_node()
        self._pubsub, self._event = _iox_services(self._node, endpoint)
        self._sub = self._pubsub.subscriber_builder().create()
        self._listener = self._event.listener_builder().create()
        self._waker = self._event.notifier_builder().create()
        self._timeout = iox2.Duration.from_millis(500)
        self._stop = False
        self._on_object = on_object
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _take(self) -> bool:
        sample = self._sub.receive()
        if sample is None:
            return False
        data = np.frombuffer(sample.payload().as_memory_view(), dtype=np.uint8).copy()
        sample.delete()
        self._on_object(transport.decode(_iox_unpack(data))[1])
        return True

    def _run(self) -> None:
        while not self._stop:
            if not self._take():
                self._listener.timed_wait(self._timeout)

    def close(self) -> None:
        self._stop = True
        self._waker.notify()
        self._thread.join(1.0)
        self._sub.delete()
        self._listener.delete()
        self._waker.delete()
        self._pubsub = self._event = self._node = None


def _zenoh_session(endpoint: str, role: str) -> Any:
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    # Off: from Python every payload would be copied into and out of it, and each session leaves a
    # 16 MB segment in /dev/shm behind when its process is killed.
    conf.insert_json5("transport/shared_memory/enabled", "false")
    key = "listen/endpoints" if role == "listen" else "connect/endpoints"
    conf.insert_json5(key, json.dumps([f"unixsock-stream/{endpoint}"]))
    return zenoh.open(conf)


class _ZenohSender:
    def __init__(self, endpoint: str) -> None:
        import zenoh

        self._session = _zenoh_session(endpoint, "listen")
        self._pub = self._session.declare_publisher(
            "bywire/bench", congestion_control=zenoh.CongestionControl.DROP, express=True
        )

    def send(self, topic: str, obj: Any) -> None:
        parts = [memoryview(p).cast("B") for p in transport.encode(topic, obj)]
        table = np.array([len(parts), *(p.nbytes for p in parts)], dtype="<u8").tobytes()
        self._pub.put(b"".join([table, *parts]))

    def close(self) -> None:
        self._pub.undeclare()
        self._session.close()


class _ZenohReceiver:
    def __init__(self, endpoint: str, on_object: OnObject) -> None:
        self._session = _zenoh_session(endpoint, "connect")
        self._on_object = on_object
        self._sub = self._session.declare_subscriber("bywire/bench", self._callback)

    def _callback(self, sample: Any) -> None:
        data = sample.payload.to_bytes()
        (n,) = np.frombuffer(data, dtype="<u8", count=1)
        lengths = np.frombuffer(data, dtype="<u8", count=int(n), offset=8).tolist()
        view, offset, parts = memoryview(data), 8 * (int(n) + 1), []
        for length in lengths:
            parts.append(view[offset : offset + length])
            offset += length
        self._on_object(transport.decode(parts)[1])

    def close(self) -> None:
        self._sub.undeclare()
        self._session.close()


class _MpQueueSender:
    def __init__(self, q: Any) -> None:
        self._q = q

    def send(self, topic: str, obj: Any) -> None:
        self._q.put(obj)

    def close(self) -> None:
        self._q.close()


class _MpQueueReceiver:
    """Gets with a timeout; close() puts a sentinel (None) to wake it at once."""

    def __init__(self, q: Any, on_object: OnObject) -> None:
        self._q = q
        self._stop = False
        self._on_object = on_object
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop:
            try:
                obj = self._q.get(timeout=0.5)
            except queue.Empty:
                continue
            if obj is not None:
                self._on_object(obj)

    def close(self) -> None:
        self._stop = True
        self._q.put(None)
        self._thread.join(1.0)


class _StoreSender:
    """The chosen transport as a module uses it: publish into a store, its tap sends."""

    def __init__(self, endpoint: str) -> None:
        self.store = ObjectStore()
        self.pub = transport.TopicPublisher(endpoint)
        self.pub.attach(self.store, TOPICS.values())

    def send(self, topic: str, obj: Any) -> None:
        self.store.publish(topic, obj)

    def close(self) -> None:
        self.pub.close()


class _StoreReceiver:
    """Into the receiving process's store, read by a subscription per topic, each in its thread."""

    def __init__(self, endpoint: str, on_object: OnObject) -> None:
        self.store = ObjectStore()
        # A store keeps every object of its history alive: a scan topic's must be short, or each
        # received scan lands in fresh memory (page faults: ~1 ms per scan on this VM).
        self.store.declare(TOPICS["scan"], ScanSample, history=SCAN_HISTORY)
        subs = [self.store.subscribe(t) for t in TOPICS.values()]
        self.sub = transport.TopicSubscriber(endpoint, self.store)
        self._stop = False
        self._on_object = on_object
        self._threads = [threading.Thread(target=self._run, args=(s,), daemon=True) for s in subs]
        for thread in self._threads:
            thread.start()

    def _run(self, sub: Subscription[Any]) -> None:
        while not self._stop:
            obj = sub.wait(0.05)
            if obj is not None:
                self._on_object(obj)

    def close(self) -> None:
        self._stop = True
        for thread in self._threads:
            thread.join(1.0)
        self.sub.close()


CANDIDATES = ("transport", "mp_queue", "zmq", "iceoryx2", "zenoh")


def make_sender(name: str, endpoint: Any) -> Sender:
    makers: dict[str, Callable[[Any], Sender]] = {
        "transport": _StoreSender,
        "mp_queue": _MpQueueSender,
        "zmq": _ZmqSender,
        "iceoryx2": _IoxSender,
        "zenoh": _ZenohSender,
    }
    return makers[name](endpoint)


def make_receiver(name: str, endpoint: Any, on_object: OnObject) -> Receiver:
    makers: dict[str, Callable[[Any, OnObject], Receiver]] = {
        "transport": _StoreReceiver,
        "mp_queue": _MpQueueReceiver,
        "zmq": _ZmqReceiver,
        "iceoryx2": _IoxReceiver,
        "zenoh": _ZenohReceiver,
    }
    return makers[name](endpoint, on_object)


def make_endpoint(name: str, tmp: str, ctx: Any, tag: str = "") -> Any:
    if name == "transport":
        return transport.new_endpoint(f"bench-store{tag}")
    if name == "mp_queue":
        return ctx.Queue(1000)
    if name == "zmq":
        return f"ipc://{tmp}/zmq{tag}"
    if name == "iceoryx2":
        return f"bywire/bench-{os.getpid()}-{secrets.token_hex(4)}/raw{tag}"
    return f"{tmp}/zenoh{tag}.sock"
