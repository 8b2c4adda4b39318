"""Object types and child-process bodies for the transport tests, importable by spawned processes.

A "spawn" child imports its target by module name, so everything a child runs or receives lives
here rather than in the test module.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from multiprocessing.connection import Connection

import numpy as np

from bywire.host.runtime.store import ObjectStore
from bywire.host.runtime.transport import TopicPublisher, TopicSubscriber, new_endpoint

ECHO_PREFIX = "echo"


@dataclass(frozen=True)
class Ping:
    t_s: float
    n: int


@dataclass(frozen=True)
class Cloud:
    t_s: float
    frame: str
    points: np.ndarray


def echo_child(in_endpoint: str, out_endpoint: str, seconds: float) -> None:
    """Sends back everything it receives, on `echo/<topic>`, until killed or `seconds` pass."""
    store = ObjectStore()
    pub = TopicPublisher(out_endpoint)
    store.add_tap(lambda topic, obj: pub.send(f"{ECHO_PREFIX}/{topic}", obj))
    sub = TopicSubscriber(in_endpoint, store)
    time.sleep(seconds)
    sub.close()
    pub.close()


def ping_child(endpoint: str, period_s: float, seconds: float) -> None:
    """Publishes a `Ping` on "ping" every `period_s` (t_s on the machine's monotonic clock, so a
    restarted publisher continues in order) until killed or `seconds` pass."""
    pub = TopicPublisher(endpoint)
    end = time.monotonic() + seconds
    n = 0
    while time.monotonic() < end:
        pub.send("ping", Ping(time.monotonic(), n))
        n += 1
        time.sleep(period_s)
    pub.close()


def endpoint_child(conn: Connection, seconds: float) -> None:
    """Makes an endpoint, sends its address back, then ends after `seconds` (unless killed)."""
    conn.send(new_endpoint("owned by a child"))
    time.sleep(seconds)
