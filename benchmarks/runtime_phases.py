"""How `bywire bench runtime` measures: what a receiver saw in a phase (latencies, throughput), the
phases in one process and across processes (candidates side by side, in interleaved rounds), and
the set-up and tear-down of a sender-receiver pair with the stall it causes in other threads.

DESIGN.md section 5: on these shared machines every figure is a distribution (p50 / p99 / max) and
every ratio is to a baseline measured in the same run, interleaved with it.
"""

from __future__ import annotations

import bisect
import contextlib
import multiprocessing as mp
import queue
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from typing import Any, Protocol

import numpy as np

from benchmarks.runtime_transports import (
    KINDS,
    TOPICS,
    Factory,
    OnObject,
    Receiver,
    Sender,
    SmallSample,
    make_endpoint,
    make_receiver,
    make_sender,
    object_bytes,
)
from bywire.host.runtime import transport
from bywire.host.runtime.store import ObjectStore

SMALL_PERIOD_S = 0.001
SCAN_PERIOD_S = 0.02
PHASE_TIMEOUT_S = 10.0  # a candidate that delivers nothing for this long is reported as failed
ROUNDS = 3  # interleaved rounds per candidate and object kind
DRAIN_S = 1.0  # after the last send, how long the receiver may still be catching up

# Objects per phase at scale 1 (the default --seconds); tuned so that a full run takes ~30 s on a
# 2-core VM, of which process start-up (spawn + numpy import) is a good part.
BASE_COUNTS = {
    ("small", "latency"): 1200,
    ("small", "burst"): 2000,
    ("scan", "latency"): 60,
    ("scan", "burst"): 25,
}


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
        "mb_per_s": None if per_s is None else round(per_s * object_bytes(kind) / 1e6, 1),
        "delivered": got,
        "sent": sent,
    }


def with_baseline(row: dict[str, Any], base: dict[str, Any]) -> dict[str, Any]:
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


def _in_process_phase(channel: _InProcess, factory: Factory, n: int, period_s: float) -> tuple[Phase, int]:
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
    factory = Factory(kind)
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
    return with_baseline(rows["store"], rows["queue"])


# -- across processes ---------------------------------------------------------------------------------


def _child(name: str, endpoint: Any, conn: Connection) -> None:
    """The receiving process: phases on command, results back over the control pipe."""
    lock = threading.Lock()
    phase = Phase()

    def on_object(obj: Any) -> None:
        with lock:
            phase.on_object(obj)

    receiver = make_receiver(name, endpoint, on_object)
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
    sender: Sender, conn: Connection, factory: Factory, n: int, period_s: float
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
    sender: Sender
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
            "mb_per_s": None if per_s is None else round(per_s * object_bytes(kind) / 1e6, 1),
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
                    endpoint = make_endpoint(name, tmp, ctx)
                    sender = make_sender(name, endpoint)
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
                factory = Factory(kind)
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


def _measure(peer: _Peer, factory: Factory, n_lat: int, n_burst: int, period_s: float) -> None:
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


def _make_pair(name: str, endpoint: Any, on_object: OnObject) -> tuple[Sender, Receiver]:
    """A sender and a receiver on one endpoint, both here; for the transport what the host makes
    for a process worker: a `TopicPublisher`, and a `TopicSubscriber` into a store."""
    if name == "transport":
        store = ObjectStore()
        store.add_tap(lambda topic, obj: on_object(obj))
        pub = transport.TopicPublisher(endpoint)
        return pub, transport.TopicSubscriber(endpoint, store)
    return make_sender(name, endpoint), make_receiver(name, endpoint, on_object)


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
    endpoint = make_endpoint(name, tmp, ctx, tag)
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
