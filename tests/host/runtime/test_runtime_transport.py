"""The object store across processes (`transport`): round trips between real processes, order,
garbage, peers killed with SIGKILL on either side, one subscriber per endpoint, prompt close, the
private endpoint directory; and the runtime benchmark's JSON."""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import pickle
import signal
import socket
import stat
import time
from collections.abc import Callable, Iterator
from multiprocessing.process import BaseProcess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zmq
from runtime_types import Cloud, Ping, echo_child, endpoint_child, ping_child

from bywire.cli import benchmark
from bywire.host.runtime import transport
from bywire.host.runtime.store import ObjectStore
from bywire.host.runtime.transport import (
    SEND_QUEUE,
    EndpointInUse,
    TopicPublisher,
    TopicSubscriber,
    new_endpoint,
)

bench = benchmark("runtime")

CTX = mp.get_context("spawn")
CHILD_S = 30.0  # children end by themselves after this, should a test fail to kill them
Spawn = Callable[..., BaseProcess]


@pytest.fixture
def spawn() -> Iterator[Spawn]:
    procs: list[BaseProcess] = []

    def start(target: Callable[..., None], *args: Any) -> BaseProcess:
        proc = CTX.Process(target=target, args=args, daemon=True)
        proc.start()
        procs.append(proc)
        return proc

    yield start
    for proc in procs:
        if proc.is_alive():
            proc.kill()
        proc.join(5.0)


def wait_for(condition: Callable[[], bool], timeout_s: float = 20.0) -> None:
    end = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > end:
            raise AssertionError("condition not met in time")
        time.sleep(0.005)


def wait_quiet(value: Callable[[], Any], quiet_s: float = 0.2, timeout_s: float = 10.0) -> None:
    """Until `value()` has not changed for `quiet_s` (what was in flight has arrived)."""
    end = time.monotonic() + timeout_s
    last, since = value(), time.monotonic()
    while time.monotonic() - since < quiet_s:
        assert time.monotonic() < end, "never settled"
        time.sleep(0.01)
        now = value()
        if now != last:
            last, since = now, time.monotonic()


def handshake(pub: TopicPublisher, back: ObjectStore) -> None:
    """Send hellos until one comes back echoed: both directions are connected (no slow joiner)."""
    echoed = back.subscribe("echo/hello")
    end = time.monotonic() + 20.0
    while time.monotonic() < end:
        pub.send("hello", Ping(time.monotonic(), 0))
        if echoed.wait(0.02) is not None:
            return
    raise AssertionError("no echo from the child")


def test_small_and_numpy_objects_round_trip_in_order(spawn: Spawn) -> None:
    to_child, from_child = new_endpoint("to child"), new_endpoint("from child")
    back = ObjectStore(default_history=1000)
    arrivals: list[str] = []
    back.add_tap(lambda topic, obj: arrivals.append(topic))
    sub = TopicSubscriber(from_child, back)  # before the child's publisher exists
    pub = TopicPublisher(to_child)
    spawn(echo_child, to_child, from_child, CHILD_S)
    handshake(pub, back)
    arrivals.clear()

    rng = np.random.default_rng(1)
    sent_topics, clouds = [], []
    for i in range(60):
        pub.send("ping", Ping(float(i), i))
        sent_topics.append("echo/ping")
        if i % 10 == 0:
            clouds.append(Cloud(float(i), f"lidar{i}", rng.random((1000, 4), dtype=np.float32)))
            pub.send("cloud", clouds[-1])
            sent_topics.append("echo/cloud")
    clouds.append(Cloud(100.0, "velodyne", rng.random((130_000, 4), dtype=np.float32)))  # 2 MB
    pub.send("cloud", clouds[-1])
    sent_topics.append("echo/cloud")
    wait_for(lambda: len(back.history("echo/cloud")) == len(clouds))

    assert [p.n for p in back.history("echo/ping")] == list(range(60))
    got = back.history("echo/cloud")
    assert [c.frame for c in got] == [c.frame for c in clouds]
    for mine, theirs in zip(clouds, got, strict=True):
        assert theirs.points.dtype == np.float32 and theirs.points.shape == mine.points.shape
        np.testing.assert_array_equal(theirs.points, mine.points)
        assert not theirs.points.flags.writeable  # received objects are as immutable as sent ones
    assert [t for t in arrivals if t != "echo/hello"] == sent_topics  # one ordered stream
    assert pub.dropped == 0 and sub.errors == 0
    sub.close()
    pub.close()


def test_garbage_and_refused_objects_are_counted_never_raised() -> None:
    ep = new_endpoint("garbage")
    store = ObjectStore()
    sub = TopicSubscriber(ep, store)
    # Not ZeroMQ at all: ZeroMQ hangs up on it (nothing to count), the subscriber carries on.
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as raw:
        raw.connect(ep.removeprefix("ipc://"))
        raw.sendall(b"\xff" * 64 + b"definitely not ZMTP" * 100)
    rogue = zmq.Context.instance().socket(zmq.PUSH)  # a broken or foreign publisher
    rogue.setsockopt(zmq.LINGER, 0)
    rogue.connect(ep)
    try:
        good = pickle.dumps(Ping(1.0, 1))
        oob: list[pickle.PickleBuffer] = []
        needs_buffer = pickle.dumps(Cloud(1.0, "x", np.zeros(4)), protocol=5, buffer_callback=oob.append)
        bad = [
            [b"only one frame"],
            [b""],
            [b"ping", b"not a pickle"],
            [b"\xff\xfe", good],  # topic is not UTF-8
            [b"ping", b"cno_such_module_for_bywire\nThing\n."],  # a type we cannot import
            [b"ping", good[: len(good) // 2]],  # truncated
            [b"cloud", needs_buffer],  # its out-of-band buffer is missing
            [b"ping", pickle.dumps({"not": "a dataclass"})],  # refused by the store
            [b"ping", pickle.dumps(Ping(5.0, 5))],
            [b"ping", pickle.dumps(Ping(1.0, 6))],  # older than the newest: refused by the store
            [b"ping", pickle.dumps(Ping(9.0, 9))],
        ]
        for frames in bad:
            rogue.send_multipart(frames)
        wait_for(lambda: sub.errors + sub.received == len(bad))
        assert [p.n for p in store.history("ping")] == [5, 9]
        assert sub.errors == len(bad) - 2
        assert sub.last_error is not None and "older than the newest" in sub.last_error
        assert sub._thread.is_alive()
        pub = TopicPublisher(ep)  # and a proper publisher still gets through
        pub.send("ping", Ping(10.0, 10))
        wait_for(lambda: sub.received == 3)
        pub.close()
    finally:
        rogue.close(0)
        sub.close()


def test_subscriber_outlives_a_killed_publisher_and_takes_its_restart(spawn: Spawn) -> None:
    ep = new_endpoint("pings")
    store = ObjectStore()
    sub = TopicSubscriber(ep, store)
    first = spawn(ping_child, ep, 0.005, CHILD_S)
    wait_for(lambda: sub.received >= 5)
    os.kill(first.pid or 0, signal.SIGKILL)
    first.join(5.0)
    wait_quiet(lambda: sub.received)
    last_s, count = sub.last_receive_s, sub.received
    time.sleep(0.3)
    assert sub.last_receive_s == last_s and sub.received == count  # liveness stops advancing
    assert sub._thread.is_alive() and sub.errors == 0

    spawn(ping_child, ep, 0.005, CHILD_S)  # same endpoint: the restart takes it over
    wait_for(lambda: sub.received >= count + 5)
    assert sub.errors == 0 and (sub.last_receive_s or 0.0) > (last_s or 0.0)
    sub.close()


def test_publisher_outlives_a_killed_subscriber_and_serves_its_restart(spawn: Spawn) -> None:
    to_child, from_child = new_endpoint("to child"), new_endpoint("from child")
    back = ObjectStore()
    sub = TopicSubscriber(from_child, back)
    pub = TopicPublisher(to_child)
    child = spawn(echo_child, to_child, from_child, CHILD_S)
    handshake(pub, back)
    os.kill(child.pid or 0, signal.SIGKILL)
    child.join(5.0)
    sent_before, dropped_before = pub.sent, pub.dropped
    for i in range(1000):  # never blocks, whatever state the dead peer's socket is in
        pub.send("ping", Ping(time.monotonic(), i))
    assert (pub.sent - sent_before) + (pub.dropped - dropped_before) == 1000

    spawn(echo_child, to_child, from_child, CHILD_S)
    handshake(pub, back)
    assert sub.errors == 0
    sub.close()
    pub.close()


def test_publisher_never_waits_for_a_stopped_subscriber(spawn: Spawn) -> None:
    to_child, from_child = new_endpoint("to child"), new_endpoint("from child")
    back = ObjectStore()
    sub = TopicSubscriber(from_child, back)
    pub = TopicPublisher(to_child)
    child = spawn(echo_child, to_child, from_child, CHILD_S)
    handshake(pub, back)
    os.kill(child.pid or 0, signal.SIGSTOP)
    try:
        # Fills the kernel's socket buffers (a few thousand pings), then the queue, then drops
        # (and counts). A send that waited for the stopped reader would never return: reaching the
        # drops at all is the proof (how fast each send returns is `bywire bench runtime`'s).
        dropped, sent = pub.dropped, 0
        while pub.dropped - dropped < SEND_QUEUE:
            pub.send("ping", Ping(time.monotonic(), sent))
            sent += 1
            assert sent < 200_000, "never dropped"
    finally:
        os.kill(child.pid or 0, signal.SIGCONT)
    handshake(pub, back)  # once it reads again, it gets what is sent
    sub.close()
    pub.close()


def test_close_is_prompt_and_final() -> None:
    ep = new_endpoint("close")
    store = ObjectStore()
    sub = TopicSubscriber(ep, store)
    pub = TopicPublisher(ep)
    wait_for(lambda: (pub.send("ping", Ping(time.monotonic(), 0)), sub.received > 0)[1])
    sub.close()
    assert not sub._thread.is_alive()  # close() returned with its thread ended: nothing left behind
    count = sub.received
    for i in range(10):
        pub.send("ping", Ping(time.monotonic(), i))
    time.sleep(0.1)
    assert sub.received == count  # nothing reaches the store after close()

    pub.close()
    dropped = pub.dropped
    pub.send("ping", Ping(time.monotonic(), 99))  # after close: counted, not raised
    assert pub.dropped == dropped + 1

    lonely = TopicSubscriber(new_endpoint("nobody"), ObjectStore())  # no publisher ever
    lonely.close()
    assert not lonely._thread.is_alive() and lonely.last_receive_s is None


def test_one_subscriber_per_endpoint_and_a_restart_takes_over() -> None:
    ep = new_endpoint("twice")
    first_store, second_store = ObjectStore(), ObjectStore()
    first = TopicSubscriber(ep, first_store)
    with pytest.raises(EndpointInUse):
        TopicSubscriber(ep, ObjectStore())  # an error, not objects dealt out between the two
    pub = TopicPublisher(ep)
    wait_for(lambda: (pub.send("ping", Ping(time.monotonic(), 0)), first.received > 0)[1])
    first.close()
    assert not os.path.exists(ep.removeprefix("ipc://"))
    second = TopicSubscriber(ep, second_store)  # the endpoint is free again; the publisher reconnects
    pub.send("ping", Ping(time.monotonic(), 1))
    wait_for(lambda: second.received >= 1)
    assert (second_store.latest("ping") or Ping(0.0, 0)).n == 1
    second.close()
    pub.close()


def test_endpoints_live_in_a_private_directory_removed_with_its_process(spawn: Spawn) -> None:
    mine = Path(new_endpoint("mine").removeprefix("ipc://")).parent
    assert stat.S_IMODE(mine.stat().st_mode) == 0o700 and mine.stat().st_uid == os.getuid()

    conn, child_conn = CTX.Pipe()
    proc = spawn(endpoint_child, child_conn, 0.0)  # ends normally: its directory goes with it
    ended = Path(conn.recv().removeprefix("ipc://")).parent
    proc.join(10.0)
    assert proc.exitcode == 0 and not ended.exists()

    conn, child_conn = CTX.Pipe()
    proc = spawn(endpoint_child, child_conn, CHILD_S)
    killed = Path(conn.recv().removeprefix("ipc://")).parent
    transport._sweep(killed.parent)
    assert killed.exists()  # its owner is alive
    os.kill(proc.pid or 0, signal.SIGKILL)
    proc.join(5.0)
    assert killed.exists()
    transport._sweep(killed.parent)  # what the next process making endpoints does
    assert not killed.exists() and mine.exists()


def test_attach_sends_only_the_named_topics() -> None:
    ep = new_endpoint("attach")
    here, there = ObjectStore(), ObjectStore()
    sub = TopicSubscriber(ep, there)
    pub = TopicPublisher(ep)
    pub.attach(here, ["ping"])
    wait_for(lambda: (here.publish("ping", Ping(time.monotonic(), 0)), sub.received > 0)[1])
    here.publish("private", Ping(time.monotonic(), 1))
    here.publish("ping", Ping(time.monotonic(), 2))
    wait_for(lambda: (there.latest("ping") or Ping(0.0, 0)).n == 2)
    assert "private" not in there.topics()
    sub.close()
    pub.close()


def test_no_slow_joiner_either_way_round() -> None:
    """The first object sent after both ends exist arrives, whichever end was made first."""
    for publisher_first in (True, False):
        ep = new_endpoint("joiner")
        store = ObjectStore()
        if publisher_first:
            pub = TopicPublisher(ep)
            sub = TopicSubscriber(ep, store)
        else:
            sub = TopicSubscriber(ep, store)
            pub = TopicPublisher(ep)
        pub.send("ping", Ping(1.0, 1))
        wait_for(lambda: sub.received == 1)  # noqa: B023 (called before the loop moves on)
        assert pub.sent == 1 and pub.dropped == 0
        sub.close()
        pub.close()


def test_bench_runtime_writes_every_key(tmp_path: Path) -> None:
    parser = argparse.ArgumentParser()
    bench.add_arguments(parser)
    out = tmp_path / "runtime.json"
    args = parser.parse_args(["--json", str(out), "--seconds", "0.2"])
    assert bench.main(args) == 0
    doc = json.loads(out.read_text(encoding="utf-8"))
    assert doc["choice"]
    keys = {"p50_us", "p99_us", "max_us", "throughput_per_s", "mb_per_s"}
    for section in ("in_process", "cross_process"):
        for kind in ("small", "scan"):
            row = doc[section][kind]
            assert keys <= row.keys()
            assert {f"baseline_{k}" for k in keys} <= row.keys()
            assert {"ratio_p50", "ratio_p99", "ratio_max", "ratio_throughput_per_s"} <= row.keys()
            assert row["p50_us"] is not None and row["throughput_per_s"] is not None
    assert set(doc["candidates"]["scan"]) == set(bench.CANDIDATES)
    setup = doc["setup"]
    assert set(setup) == {*bench.CANDIDATES, "idle"}
    timing = {f"{op}_{stat}_ms" for op in ("create", "first", "close") for stat in ("p50", "p99", "max")}
    for name in ("transport", "zmq", "mp_queue"):  # always installed
        assert timing | {"stall_max_ms", "stall_p50_ms", "cycles"} <= setup[name].keys()
        assert setup[name]["create_max_ms"] >= setup[name]["create_p50_ms"] > 0
    assert {"stall_max_ms", "stall_p50_ms"} <= setup["idle"].keys()
