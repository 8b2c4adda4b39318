"""`bywire bench runtime`: publish-to-receive latency and throughput of the object store, in one
process and across processes, each next to a plain-queue baseline measured in the same run.

Rows (each for a small object, ten floats in a frozen dataclass, and a scan-sized one, a
(130000, 4) float32 LIDAR scan of 2.08 MB):

- in process: `ObjectStore.publish` -> `Subscription.wait` in another thread; baseline
  `queue.Queue.put` -> `get` in another thread.
- across processes: the runtime's transport (`transport.py`: pyzmq PUSH/PULL over ipc://), measured
  end to end, from `ObjectStore.publish` in this process (the `TopicPublisher` tap sends it) to
  `Subscription.wait` in a thread of the receiving process (its `TopicSubscriber` publishes into
  that process's store); baseline `multiprocessing.Queue` (pickle in band over a pipe, what a user
  of the standard library would write). The candidates the transport was chosen from are measured
  in the same run, raw (no store on either side: from the send call to their receive thread or
  callback), all with the transport's pickle-5 encoding with out-of-band buffers: pyzmq with the
  transport's sockets (PUSH/PULL over ipc://), iceoryx2 publish-subscribe on shared memory with its
  event service to wake the reader (one sample per object, frames at 64-byte aligned offsets), and
  eclipse-zenoh peer to peer over a unix socket (its shared-memory provider works from Python but
  copies every payload into and out of it, so it is off). iceoryx2 and zenoh are optional (the
  `bench` extra): a row says so when one is missing. The candidates run side by side and take turns
  in short rounds, so that load on the (shared) machine hits all alike.

Setup (`setup` in the JSON): what it costs to set up and tear down one endpoint pair (a sender and
a receiver with its receive thread, both in this process, as the host makes one per direction for
each process-isolated module), per candidate, interleaved like the rest, after one uncounted
warm-up each (imports, a process-wide context): `create_*_ms` (making the endpoint, sender and
receiver), `first_*_ms` (from then until the first object, sent every millisecond, arrives: a
transport may connect in the background) and `close_*_ms` (closing both and dropping them), each
as p50 / p99 / max; `stall_max_ms` and `stall_p50_ms`: how late a 1 ms `time.sleep` loop in
another thread of this process woke up during the create and close operations (the largest, and
the median over operations), i.e. how long an operation kept other Python threads (the host's
scheduler) from running, mostly by holding the GIL. The `idle` row is that loop while this thread
only sleeps, in 10 ms windows between the others: the machine's own noise.

Latency: the sender stamps `time.perf_counter_ns()` (CLOCK_MONOTONIC, shared by all processes of the
machine) into the object just before publishing; the receiver subtracts it from its own clock on
receipt. Objects are paced (small at 1 kHz, scans at 50 Hz) so the numbers are latency, not queueing.
Throughput: a burst sent as fast as the sender can, objects delivered per second from the first send
to the last receipt; transports that drop rather than block report how many arrived.

Each ratio is the row's value over its baseline's (latency: > 1 is slower than the baseline;
throughput: > 1 is faster). In one process nothing is copied (both rows pass a reference), so the
scan rows' MB/s only say how many references per second. The machine matters more than anything
here: on a shared 2-core VM a thread wake-up alone costs tens to hundreds of microseconds, and
p99/max are set by the hypervisor; compare rows of one run, not runs.
"""

from __future__ import annotations

import argparse
import bisect
import contextlib
import ctypes
import json
import multiprocessing as mp
import os
import platform
import queue
import secrets
import struct
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from bywire.host.runtime import transport
from bywire.host.runtime.store import ObjectStore, Subscription

DEFAULT_SECONDS = 30.0
SCAN_POINTS = 130_000
SMALL_PERIOD_S = 0.001
SCAN_PERIOD_S = 0.02
PHASE_TIMEOUT_S = 10.0  # a candidate that delivers nothing for this long is reported as failed
ROUNDS = 3  # interleaved rounds per candidate and object kind
SCAN_HISTORY = 8  # scans a store keeps (0.8 s of a 10 Hz LIDAR)
DRAIN_S = 1.0  # after the last send, how long the receiver may still be catching up

# Objects per phase at scale 1 (the default --seconds); tuned so that a full run takes ~30 s on a
# 2-core VM, of which process start-up (spawn + numpy import) is a good part.
BASE_COUNTS = {
    ("small", "latency"): 1200,
    ("small", "burst"): 2000,
    ("scan", "latency"): 60,
    ("scan", "burst"): 25,
}


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


def _object_bytes(kind: str) -> int:
    if kind == "scan":
        return SCAN_POINTS * 4 * 4
    return sum(len(p) for p in transport.encode(TOPICS[kind], SmallSample(0.0, 0)))


class _Factory:
    """Makes the objects of one kind; stamps the send time at the last moment."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self._points = _scan_points() if kind == "scan" else None

    def make(self, warm: bool = False) -> SmallSample | ScanSample:
        if self._points is not None:
            return ScanSample(time.monotonic(), time.perf_counter_ns(), self._points, warm)
        return SmallSample(time.monotonic(), time.perf_counter_ns(), warm)


# -- results ------------------------------------------------------------------------------------------


@dataclass
class Phase:
    """What one receiver saw during one phase."""

    latencies_ns: list[int] = field(default_factory=list)
    first_recv_ns: int = 0
    last_recv_ns: int = 0
    warm: bool = False

    def on_object(self, obj: Any) -> None:
        now = time.perf_counter_ns()
        if obj.warm:
            self.warm = True
            return
        if not self.latencies_ns:
            self.first_recv_ns = now
        self.last_recv_ns = now
        self.latencies_ns.append(now - obj.sent_ns)


def _latency_row(lat_ns: Sequence[int]) -> dict[str, float | None]:
    if not lat_ns:
        return {"p50_us": None, "p99_us": None, "max_us": None}
    us = np.asarray(lat_ns, dtype=np.float64) / 1000.0
    return {
        "p50_us": round(float(np.percentile(us, 50)), 1),
        "p99_us": round(float(np.percentile(us, 99)), 1),
        "max_us": round(float(us.max()), 1),
    }


def _throughput_row(kind: str, sent: int, phase: Phase, first_send_ns: int) -> dict[str, Any]:
    got = len(phase.latencies_ns)
    span_s = (phase.last_recv_ns - first_send_ns) / 1e9
    per_s = got / span_s if got and span_s > 0 else None
    return {
        "throughput_per_s": None if per_s is None else round(per_s, 1),
        "mb_per_s": None if per_s is None else round(per_s * _object_bytes(kind) / 1e6, 1),
        "delivered": got,
        "sent": sent,
    }


def _with_baseline(row: dict[str, Any], base: dict[str, Any]) -> dict[str, Any]:
    out = dict(row)
    for key in ("p50_us", "p99_us", "max_us", "throughput_per_s", "mb_per_s"):
        out[f"baseline_{key}"] = base.get(key)
    for key in ("p50_us", "p99_us", "max_us", "throughput_per_s"):
        a, b = row.get(key), base.get(key)
        out[f"ratio_{key.removesuffix('_us')}"] = round(a / b, 2) if a is not None and b else None
    return out


# -- in process ---------------------------------------------------------------------------------------


class _InProcess(Protocol):
    def put(self, obj: Any) -> None: ...
    def get(self, timeout_s: float) -> Any | None: ...


class _StoreChannel:
    def __init__(self, topic: str, history: int) -> None:
        self.topic = topic
        self.store = ObjectStore(default_history=history)
        self.sub = self.store.subscribe(topic)

    def put(self, obj: Any) -> None:
        self.store.publish(self.topic, obj)

    def get(self, timeout_s: float) -> Any | None:
        return self.sub.wait(timeout_s)


class _QueueChannel:
    def __init__(self) -> None:
        self.q: queue.Queue[Any] = queue.Queue()

    def put(self, obj: Any) -> None:
        self.q.put(obj)

    def get(self, timeout_s: float) -> Any | None:
        try:
            return self.q.get(timeout=timeout_s)
        except queue.Empty:
            return None


def _in_process_phase(channel: _InProcess, factory: _Factory, n: int, period_s: float) -> tuple[Phase, int]:
    phase = Phase()
    done = threading.Event()

    def reader() -> None:
        while not done.is_set():
            obj = channel.get(0.05)
            if obj is not None:
                phase.on_object(obj)
                if len(phase.latencies_ns) >= n:
                    return

    thread = threading.Thread(target=reader, name="bench-reader", daemon=True)
    thread.start()
    first_send_ns = time.perf_counter_ns()
    for _ in range(n):
        channel.put(factory.make())
        if period_s:
            time.sleep(period_s)
    thread.join(timeout=PHASE_TIMEOUT_S)
    done.set()
    return phase, first_send_ns


def bench_in_process(kind: str, scale: float) -> dict[str, Any]:
    factory = _Factory(kind)
    period = SMALL_PERIOD_S if kind == "small" else SCAN_PERIOD_S
    n_lat = max(10, int(BASE_COUNTS[(kind, "latency")] * scale))
    n_burst = max(5, int(BASE_COUNTS[(kind, "burst")] * scale))
    rows = {}
    for name, make in (
        ("store", lambda n: _StoreChannel(TOPICS[kind], history=n)),
        ("queue", lambda n: _QueueChannel()),
    ):
        lat, _ = _in_process_phase(make(n_lat), factory, n_lat, period)
        burst, first = _in_process_phase(make(n_burst), factory, n_burst, 0.0)
        rows[name] = {**_latency_row(lat.latencies_ns), **_throughput_row(kind, n_burst, burst, first)}
    return _with_baseline(rows["store"], rows["queue"])


# -- across processes: the candidates -----------------------------------------------------------------


class _Sender(Protocol):
    def send(self, topic: str, obj: Any) -> None: ...
    def close(self) -> None: ...


class _Receiver(Protocol):
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


def _make_sender(name: str, endpoint: Any) -> _Sender:
    makers: dict[str, Callable[[Any], _Sender]] = {
        "transport": _StoreSender,
        "mp_queue": _MpQueueSender,
        "zmq": _ZmqSender,
        "iceoryx2": _IoxSender,
        "zenoh": _ZenohSender,
    }
    return makers[name](endpoint)


def _make_receiver(name: str, endpoint: Any, on_object: OnObject) -> _Receiver:
    makers: dict[str, Callable[[Any, OnObject], _Receiver]] = {
        "transport": _StoreReceiver,
        "mp_queue": _MpQueueReceiver,
        "zmq": _ZmqReceiver,
        "iceoryx2": _IoxReceiver,
        "zenoh": _ZenohReceiver,
    }
    return makers[name](endpoint, on_object)


def _endpoint(name: str, tmp: str, ctx: Any, tag: str = "") -> Any:
    if name == "transport":
        return transport.new_endpoint(f"bench-store{tag}")
    if name == "mp_queue":
        return ctx.Queue(1000)
    if name == "zmq":
        return f"ipc://{tmp}/zmq{tag}"
    if name == "iceoryx2":
        return f"bywire/bench-{os.getpid()}-{secrets.token_hex(4)}/raw{tag}"
    return f"{tmp}/zenoh{tag}.sock"


def _child(name: str, endpoint: Any, conn: Connection) -> None:
    """The receiving process: phases on command, results back over the control pipe."""
    lock = threading.Lock()
    phase = Phase()

    def on_object(obj: Any) -> None:
        with lock:
            phase.on_object(obj)

    receiver = _make_receiver(name, endpoint, on_object)
    conn.send("ready")
    try:
        while True:
            msg = conn.recv()
            if msg[0] == "phase":
                with lock:
                    phase = Phase()
                end = time.monotonic() + PHASE_TIMEOUT_S
                while not phase.warm and time.monotonic() < end:
                    time.sleep(0.002)
                conn.send(phase.warm)
            elif msg[0] == "collect":
                sent, last_progress, count = msg[1], time.monotonic(), -1
                while len(phase.latencies_ns) < sent and time.monotonic() - last_progress < DRAIN_S:
                    if len(phase.latencies_ns) != count:
                        count, last_progress = len(phase.latencies_ns), time.monotonic()
                    time.sleep(0.005)
                with lock:
                    conn.send(phase)
            else:
                return
    finally:
        receiver.close()


def _cross_phase(
    sender: _Sender, conn: Connection, factory: _Factory, n: int, period_s: float
) -> tuple[Phase, int] | None:
    topic = TOPICS[factory.kind]
    conn.send(("phase",))
    # Warm-up until the receiver has seen one object: connections are up (slow joiners) and the
    # scan-sized buffers are allocated before anything is measured.
    end = time.monotonic() + PHASE_TIMEOUT_S
    while not conn.poll(0.01):
        sender.send(topic, factory.make(warm=True))
        if time.monotonic() > end:
            return None
    if not conn.recv():
        return None
    time.sleep(0.05)
    first_send_ns = time.perf_counter_ns()
    for _ in range(n):
        sender.send(topic, factory.make())
        if period_s:
            time.sleep(period_s)
    conn.send(("collect", n))
    if not conn.poll(PHASE_TIMEOUT_S + DRAIN_S + 5.0):
        return None
    phase: Phase = conn.recv()
    return phase, first_send_ns


@dataclass
class _Peer:
    """One candidate: its sender here, its receiver in a process of its own, what it measured."""

    name: str
    sender: _Sender
    proc: BaseProcess
    conn: Connection
    error: str | None = None
    latencies_ns: dict[str, list[int]] = field(default_factory=lambda: {k: [] for k in KINDS})
    bursts: dict[str, list[tuple[int, int, int]]] = field(default_factory=lambda: {k: [] for k in KINDS})

    def row(self, kind: str) -> dict[str, Any]:
        if self.error is not None:
            return {"error": self.error}
        delivered = sum(b[0] for b in self.bursts[kind])
        sent = sum(b[1] for b in self.bursts[kind])
        span_s = sum(b[2] for b in self.bursts[kind]) / 1e9
        per_s = delivered / span_s if delivered and span_s > 0 else None
        return {
            **_latency_row(self.latencies_ns[kind]),
            "throughput_per_s": None if per_s is None else round(per_s, 1),
            "mb_per_s": None if per_s is None else round(per_s * _object_bytes(kind) / 1e6, 1),
            "delivered": delivered,
            "sent": sent,
        }


def bench_cross_process(
    names: Sequence[str], scale: float, rounds: int = ROUNDS
) -> dict[str, dict[str, dict[str, Any]]]:
    """Every candidate, interleaved: {kind: {candidate: row}} (row["error"] when it failed).

    All receiving processes run side by side and the candidates take turns in short rounds, each
    round in another order, so that a load spike on the machine (it is shared) falls on all of
    them alike instead of on whichever happened to be measured at the time.
    """
    ctx = mp.get_context("spawn")
    peers: list[_Peer] = []
    failed: dict[str, str] = {}
    with tempfile.TemporaryDirectory(prefix="bywire-bench-") as tmp:
        try:
            for name in names:
                try:
                    endpoint = _endpoint(name, tmp, ctx)
                    sender = _make_sender(name, endpoint)
                except Exception as exc:  # not installed, say: reported, the others still run
                    failed[name] = f"{type(exc).__name__}: {exc}"
                    continue
                parent_conn, child_conn = ctx.Pipe()
                proc = ctx.Process(target=_child, args=(name, endpoint, child_conn), daemon=True)
                peers.append(_Peer(name, sender, proc, parent_conn))
                proc.start()
            for peer in peers:
                if not peer.conn.poll(30.0) or peer.conn.recv() != "ready":
                    peer.error = "the receiving process did not start"
            for kind in KINDS:
                factory = _Factory(kind)
                period = SMALL_PERIOD_S if kind == "small" else SCAN_PERIOD_S
                n_lat = max(5, int(BASE_COUNTS[(kind, "latency")] * scale / rounds))
                n_burst = max(3, int(BASE_COUNTS[(kind, "burst")] * scale / rounds))
                for r in range(rounds):
                    for peer in peers[r % len(peers) :] + peers[: r % len(peers)]:
                        if peer.error is None:
                            _measure(peer, factory, n_lat, n_burst, period)
        finally:
            for peer in peers:
                with contextlib.suppress(OSError, ValueError):
                    peer.conn.send(("quit",))
            for peer in peers:
                if peer.proc.pid is not None:
                    peer.proc.join(3.0)
                    if peer.proc.is_alive():
                        peer.proc.kill()
                        peer.proc.join(2.0)
                peer.sender.close()
    rows = {kind: {peer.name: peer.row(kind) for peer in peers} for kind in KINDS}
    for kind in KINDS:
        rows[kind].update({name: {"error": why} for name, why in failed.items()})
    return rows


def _measure(peer: _Peer, factory: _Factory, n_lat: int, n_burst: int, period_s: float) -> None:
    kind = factory.kind
    try:
        lat = _cross_phase(peer.sender, peer.conn, factory, n_lat, period_s)
        burst = _cross_phase(peer.sender, peer.conn, factory, n_burst, 0.0)
    except Exception as exc:  # a candidate that fails is reported, the others still run
        peer.error = f"{type(exc).__name__}: {exc}"
        return
    if lat is None or burst is None:
        peer.error = "no objects arrived"
        return
    peer.latencies_ns[kind].extend(lat[0].latencies_ns)
    got = burst[0]
    peer.bursts[kind].append((len(got.latencies_ns), n_burst, max(0, got.last_recv_ns - burst[1])))


# -- setting up and tearing down a pair ----------------------------------------------------------------

SETUP_CYCLES = 30  # create / first object / close cycles per candidate at scale 1 (plus one warm-up)
SETUP_GAP_S = 0.005  # between operations, so that one operation's stall is not charged to the next
IDLE_WINDOW_S = 0.01  # the idle row's windows


class _Ticker:
    """A thread that sleeps 1 ms at a time and records every interval between its wake-ups."""

    def __init__(self) -> None:
        self.starts: list[float] = []
        self.ends: list[float] = []
        self._stop = False
        self._thread = threading.Thread(target=self._run, name="bench-ticker", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        prev = time.perf_counter()
        while not self._stop:
            time.sleep(0.001)
            now = time.perf_counter()
            self.starts.append(prev)
            self.ends.append(now)
            prev = now

    def stop(self) -> None:
        self._stop = True
        self._thread.join(1.0)

    def late_ms(self, a: float, b: float) -> float:
        """How late (beyond its 1 ms) the latest wake-up overlapping [a, b] was."""
        worst = 0.0
        i = bisect.bisect_left(self.ends, a)
        while i < len(self.ends) and self.starts[i] <= b:
            worst = max(worst, self.ends[i] - self.starts[i])
            i += 1
        return max(0.0, worst * 1000.0 - 1.0)


def _make_pair(name: str, endpoint: Any, on_object: OnObject) -> tuple[_Sender, _Receiver]:
    """A sender and a receiver on one endpoint, both here; for the transport what the host makes
    for a process worker: a `TopicPublisher`, and a `TopicSubscriber` into a store."""
    if name == "transport":
        store = ObjectStore()
        store.add_tap(lambda topic, obj: on_object(obj))
        pub = transport.TopicPublisher(endpoint)
        return pub, transport.TopicSubscriber(endpoint, store)
    return _make_sender(name, endpoint), _make_receiver(name, endpoint, on_object)


@dataclass
class _SetupRuns:
    create_s: list[float] = field(default_factory=list)
    first_s: list[float] = field(default_factory=list)
    close_s: list[float] = field(default_factory=list)
    windows: list[tuple[float, float]] = field(default_factory=list)  # create and close operations
    error: str | None = None

    def row(self, ticker: _Ticker) -> dict[str, Any]:
        if self.error is not None:
            return {"error": self.error}
        out: dict[str, Any] = {"cycles": len(self.create_s)}
        for key, values in (("create", self.create_s), ("first", self.first_s), ("close", self.close_s)):
            ms = np.asarray(values, dtype=np.float64) * 1000.0
            for stat, value in (
                ("p50", np.percentile(ms, 50)),
                ("p99", np.percentile(ms, 99)),
                ("max", ms.max()),
            ):
                out[f"{key}_{stat}_ms"] = round(float(value), 3)
        stalls = [ticker.late_ms(a, b) for a, b in self.windows]
        out["stall_max_ms"] = round(max(stalls), 2)
        out["stall_p50_ms"] = round(float(np.median(stalls)), 2)
        return out


def _setup_cycle(name: str, tmp: str, ctx: Any, tag: str, runs: _SetupRuns | None) -> None:
    got = threading.Event()
    t0 = time.perf_counter()
    endpoint = _endpoint(name, tmp, ctx, tag)
    sender, receiver = _make_pair(name, endpoint, lambda obj: got.set())
    t1 = time.perf_counter()
    obj = SmallSample(0.0, 0)
    while True:
        sender.send(TOPICS["small"], obj)
        if got.wait(0.001):
            break
        if time.perf_counter() - t1 > PHASE_TIMEOUT_S:
            receiver.close()
            sender.close()
            raise TimeoutError("no object arrived")
    t2 = time.perf_counter()
    receiver.close()
    sender.close()
    if name == "mp_queue":
        endpoint.join_thread()  # its feeder thread has flushed (the receiver took everything)
    del sender, receiver  # iceoryx2 and zenoh: the last references to nodes, services and sessions
    t3 = time.perf_counter()
    if runs is not None:
        runs.create_s.append(t1 - t0)
        runs.first_s.append(t2 - t1)
        runs.close_s.append(t3 - t2)
        runs.windows += [(t0, t1), (t2, t3)]


def bench_setup(names: Sequence[str], scale: float) -> dict[str, dict[str, Any]]:
    """Per candidate: create / first object / close of a pair and the stall of a 1 ms loop in
    another thread meanwhile, interleaved in rounds; plus the loop's stall while nothing happens."""
    ctx = mp.get_context("spawn")
    cycles = max(3, int(SETUP_CYCLES * scale))
    runs = {name: _SetupRuns() for name in names}
    idle = _SetupRuns()
    with tempfile.TemporaryDirectory(prefix="bywire-bench-") as tmp:
        for name in names:  # warm-up: imports, the process's context or runtime; not counted
            try:
                _setup_cycle(name, tmp, ctx, "-warm", None)
            except Exception as exc:  # not installed, say: reported, the others still run
                runs[name].error = f"{type(exc).__name__}: {exc}"
        ticker = _Ticker()
        try:
            live = [name for name in names if runs[name].error is None]
            for i in range(cycles):
                for name in [*live[i % len(live) :], *live[: i % len(live)], "idle"] if live else ["idle"]:
                    time.sleep(SETUP_GAP_S)
                    if name == "idle":
                        t0 = time.perf_counter()
                        time.sleep(IDLE_WINDOW_S)
                        idle.windows.append((t0, time.perf_counter()))
                    elif runs[name].error is None:
                        try:
                            _setup_cycle(name, tmp, ctx, f"-{i}", runs[name])
                        except Exception as exc:
                            runs[name].error = f"{type(exc).__name__}: {exc}"
            time.sleep(SETUP_GAP_S)
        finally:
            ticker.stop()
    rows = {name: r.row(ticker) for name, r in runs.items()}
    stalls = [ticker.late_ms(a, b) for a, b in idle.windows]
    rows["idle"] = {
        "cycles": len(stalls),
        "stall_max_ms": round(max(stalls), 2),
        "stall_p50_ms": round(float(np.median(stalls)), 2),
    }
    return rows


# -- the command ---------------------------------------------------------------------------------------


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", type=Path, help="write the results as JSON")
    p.add_argument(
        "--seconds",
        type=float,
        default=DEFAULT_SECONDS,
        help=f"roughly how long the whole run takes (default {DEFAULT_SECONDS:.0f}); scales every phase",
    )


def _fmt(value: Any, digits: int = 0) -> str:
    return "-" if value is None else f"{value:,.{digits}f}"


def _print_table(doc: dict[str, Any]) -> None:
    head = (
        f"{'':29} {'p50 us':>9} {'p99 us':>9} {'max us':>9} {'obj/s':>10} {'MB/s':>8}"
        f"   {'x base p50':>10} {'x base p99':>10} {'x base obj/s':>12}"
    )
    for kind in KINDS:
        print(f"\n{kind} objects ({_object_bytes(kind):,} bytes encoded)")
        print(head)

        def line(label: str, row: dict[str, Any]) -> None:
            if "error" in row:
                print(f"  {label:27} failed: {row['error']}")
                return
            lost = "" if row.get("delivered") == row.get("sent") else f"  ({row['delivered']}/{row['sent']})"
            ratios = ""
            if "ratio_p50" in row:
                ratios = (
                    f"   {_fmt(row['ratio_p50'], 2):>10} {_fmt(row['ratio_p99'], 2):>10} "
                    f"{_fmt(row['ratio_throughput_per_s'], 2):>12}"
                )
            print(
                f"  {label:27} {_fmt(row['p50_us']):>9} {_fmt(row['p99_us']):>9} {_fmt(row['max_us']):>9} "
                f"{_fmt(row['throughput_per_s']):>10} {_fmt(row['mb_per_s'], 1):>8}{ratios}{lost}"
            )

        ip = doc["in_process"][kind]
        line("in process: store", ip)
        line(
            "in process: queue.Queue", {k.removeprefix("baseline_"): v for k, v in ip.items() if "base" in k}
        )
        for name, row in doc["candidates"][kind].items():
            label = {"transport": "x-proc: transport, store-store", "mp_queue": "x-proc: mp.Queue"}.get(
                name, f"x-proc: {name} (raw)"
            )
            line(label, row)
    _print_setup(doc["setup"])


def _print_setup(setup: dict[str, dict[str, Any]]) -> None:
    print(
        "\nsetting up and tearing down a pair (ms; stall: how late a 1 ms sleep loop in another thread woke)"
    )
    print(
        f"  {'':12} {'create p50':>10} {'p99':>7} {'max':>7}   {'first p50':>9} {'max':>7}   "
        f"{'close p50':>9} {'p99':>7} {'max':>7}   {'stall p50':>9} {'max':>7}"
    )
    for name, row in setup.items():
        if "error" in row:
            print(f"  {name:12} failed: {row['error']}")
        elif name == "idle":
            print(
                f"  {name:12} {'':>79}   {_fmt(row['stall_p50_ms'], 2):>9} {_fmt(row['stall_max_ms'], 2):>7}"
            )
        else:
            print(
                f"  {name:12} {_fmt(row['create_p50_ms'], 2):>10} {_fmt(row['create_p99_ms'], 2):>7} "
                f"{_fmt(row['create_max_ms'], 2):>7}   {_fmt(row['first_p50_ms'], 2):>9} "
                f"{_fmt(row['first_max_ms'], 2):>7}   {_fmt(row['close_p50_ms'], 2):>9} "
                f"{_fmt(row['close_p99_ms'], 2):>7} {_fmt(row['close_max_ms'], 2):>7}   "
                f"{_fmt(row['stall_p50_ms'], 2):>9} {_fmt(row['stall_max_ms'], 2):>7}"
            )


def run(seconds: float = DEFAULT_SECONDS, candidates: Sequence[str] = CANDIDATES) -> dict[str, Any]:
    scale = max(0.01, seconds / DEFAULT_SECONDS)
    doc: dict[str, Any] = {
        "seconds": seconds,
        "choice": transport.CHOICE,
        "machine": {
            "cpus": os.cpu_count(),
            "platform": platform.platform(),
            "python": platform.python_version(),
        },
        "object_bytes": {kind: _object_bytes(kind) for kind in KINDS},
        "measured_to": {
            "in_process": "Subscription.wait in another thread",
            "cross_process": "Subscription.wait on the receiving process's store (transport row); "
            "the receive thread or callback (raw candidates)",
        },
        "in_process": {},
        "cross_process": {},
        "candidates": {kind: {} for kind in KINDS},
        "setup": {},
    }
    for kind in KINDS:
        print(f"in process, {kind} objects ...", flush=True)
        doc["in_process"][kind] = bench_in_process(kind, scale)
    print(f"setting up and tearing down pairs, interleaved: {', '.join(candidates)} ...", flush=True)
    doc["setup"] = bench_setup(candidates, scale)
    print(f"across processes, interleaved: {', '.join(candidates)} ...", flush=True)
    doc["candidates"] = bench_cross_process(candidates, scale)
    for kind in KINDS:
        base = doc["candidates"][kind].get("mp_queue", {})
        for name, row in doc["candidates"][kind].items():
            if name != "mp_queue" and "error" not in row and "error" not in base:
                doc["candidates"][kind][name] = _with_baseline(row, base)
        chosen = doc["candidates"][kind].get("transport")
        if chosen is not None:
            doc["cross_process"][kind] = chosen
    return doc


def main(args: argparse.Namespace) -> int:
    doc = run(DEFAULT_SECONDS if args.seconds is None else args.seconds)  # the CLI's default is None
    _print_table(doc)
    print(f"\ncross-process transport: {doc['choice']}")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    failed = [k for k in KINDS if "error" in doc["cross_process"].get(k, {"error": 1})]
    return 1 if failed else 0
