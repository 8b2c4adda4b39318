"""The host runtime's object store: typed, time-stamped, immutable objects with time queries."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import pytest
from hypothesis import given
from hypothesis import strategies as st

from bywire.host.runtime.store import ObjectStore, StoreError, linear_interpolation


@linear_interpolation("x_m", "v_mps")
@dataclass(frozen=True, slots=True)
class Pose:
    t_s: float
    x_m: float
    v_mps: float = 0.0
    source: str = "gps"


@dataclass(frozen=True)
class Mode:
    t_s: float
    name: str


@dataclass
class Mutable:
    t_s: float


def test_latest_and_at_or_before() -> None:
    store = ObjectStore()
    assert store.latest("pose") is None and store.at_or_before("pose", 1.0) is None
    for k in range(5):
        store.publish("pose", Pose(t_s=float(k), x_m=10.0 * k))
    assert store.latest("pose") == Pose(4.0, 40.0)
    assert store.at_or_before("pose", 2.5) == Pose(2.0, 20.0)
    assert store.at_or_before("pose", 2.0) == Pose(2.0, 20.0)
    assert store.at_or_before("pose", -0.1) is None
    assert [p.t_s for p in store.history("pose", since_s=3.0)] == [3.0, 4.0]
    assert store.topics() == {"pose": Pose}


def test_interpolation_only_where_the_type_allows_it() -> None:
    store = ObjectStore()
    store.publish("pose", Pose(1.0, 10.0, 1.0))
    store.publish("pose", Pose(2.0, 20.0, 3.0))
    mid = store.interpolated("pose", 1.25)
    assert mid == Pose(1.25, 12.5, 1.5)
    assert store.interpolated("pose", 0.5) is None  # before the history: nothing to interpolate
    assert store.interpolated("pose", 5.0) == Pose(2.0, 20.0, 3.0)  # after: the newest, not extrapolated
    store.publish("mode", Mode(1.0, "drive"))
    with pytest.raises(StoreError, match="'mode': Mode does not define interpolate"):
        store.interpolated("mode", 1.0)


@pytest.mark.parametrize(
    ("obj", "words"),
    [
        (Mutable(1.0), "must be a frozen dataclass"),
        ({"t_s": 1.0}, "only dataclass instances"),
        (Mode(float("nan"), "x"), "finite time"),
        (Pose, "only dataclass instances"),
    ],
)
def test_refused_publications_name_topic_and_reason(obj: object, words: str) -> None:
    with pytest.raises(StoreError, match=f"topic 'x'.*{words}"):
        ObjectStore().publish("x", obj)


def test_one_type_per_topic_and_time_order() -> None:
    store = ObjectStore()
    store.publish("pose", Pose(1.0, 0.0))
    with pytest.raises(StoreError, match="carries Pose, not Mode"):
        store.publish("pose", Mode(2.0, "x"))
    with pytest.raises(StoreError, match="older than the newest"):
        store.publish("pose", Pose(0.5, 0.0))
    store.declare("mode", Mode, history=2)
    with pytest.raises(StoreError, match="carries Mode, not Pose"):
        store.declare("mode", Pose)


def test_published_objects_cannot_be_changed() -> None:
    store = ObjectStore()
    store.publish("pose", Pose(1.0, 0.0))
    with pytest.raises(AttributeError):
        store.latest("pose").x_m = 5.0  # type: ignore[misc]


def test_subscription_sees_everything_once_and_counts_what_history_dropped() -> None:
    store = ObjectStore()
    store.declare("pose", Pose, history=3)
    store.publish("pose", Pose(0.0, 0.0))  # before subscribing: not seen
    sub = store.subscribe("pose")
    assert sub.poll() is None
    for k in range(1, 3):
        store.publish("pose", Pose(float(k), 0.0))
    assert [p.t_s for p in sub] == [1.0, 2.0]
    for k in range(3, 9):
        store.publish("pose", Pose(float(k), 0.0))
    assert [p.t_s for p in sub] == [6.0, 7.0, 8.0]
    assert sub.lost == 3  # 3, 4, 5 left the 3-deep history unread


def test_blocking_wait_returns_the_next_object_or_none_on_timeout() -> None:
    store = ObjectStore()
    sub = store.subscribe("mode")
    t0 = time.monotonic()
    assert sub.wait(0.05) is None
    assert time.monotonic() - t0 >= 0.04

    def later() -> None:
        time.sleep(0.05)
        store.publish("mode", Mode(1.0, "drive"))

    threading.Thread(target=later).start()
    assert sub.wait(5.0) == Mode(1.0, "drive")


@given(
    st.lists(st.floats(0.0, 100.0, allow_nan=False), min_size=1, max_size=40),
    st.floats(-1.0, 101.0),
    st.integers(1, 10),
)
def test_time_queries_match_a_brute_force_reference(times: list[float], query: float, depth: int) -> None:
    store = ObjectStore(default_history=depth)
    times = sorted(times)
    for k, t in enumerate(times):
        store.publish("pose", Pose(t, float(k)))
    held = [Pose(t, float(k)) for k, t in enumerate(times)][-depth:]
    expected = [p for p in held if p.t_s <= query]
    assert store.at_or_before("pose", query) == (expected[-1] if expected else None)
    assert store.latest("pose") == held[-1]


def test_reads_as_of_a_publication_count_see_the_store_as_it_was() -> None:
    """What a late module sees (ModuleContext.as_of): nothing published after its release."""
    store = ObjectStore()
    store.publish("pose", Pose(t_s=0.0, x_m=0.0, v_mps=1.0))
    store.publish("mode", Mode(t_s=0.0, name="a"))
    store.publish("pose", Pose(t_s=1.0, x_m=10.0, v_mps=1.0))
    sub = store.subscribe("mode")
    as_of = store.seq
    assert as_of == 3
    store.publish("pose", Pose(t_s=2.0, x_m=20.0, v_mps=1.0))
    store.publish("mode", Mode(t_s=0.5, name="b"))
    assert store.latest("pose", as_of).x_m == 10.0 and store.latest("pose").x_m == 20.0
    assert store.latest("mode", as_of).name == "a" and store.latest("mode").name == "b"
    assert store.at_or_before("pose", 5.0, as_of).x_m == 10.0
    assert store.at_or_before("pose", 0.5, as_of).x_m == 0.0
    # Interpolation stops at the view's newest object instead of using the later one.
    assert store.interpolated("pose", 1.5, as_of).x_m == 10.0
    assert store.interpolated("pose", 1.5).x_m == pytest.approx(15.0)
    assert sub.poll(as_of) is None  # "b" came later
    assert sub.poll().name == "b" and sub.last_store_seq == 5
    assert store.latest("pose", 0) is None and store.latest("nothing", as_of) is None


@given(st.lists(st.sampled_from(["p", "q"]), min_size=1, max_size=40), st.data())
def test_as_of_reads_match_a_store_that_stopped_there(topics: list[str], data: st.DataObject) -> None:
    cut = data.draw(st.integers(0, len(topics)))
    full, stopped = ObjectStore(default_history=8), ObjectStore(default_history=8)
    for i, topic in enumerate(topics):
        obj = Pose(t_s=float(i), x_m=float(i))
        full.publish(topic, obj)
        if i < cut:
            stopped.publish(topic, obj)
    for topic in ("p", "q"):
        for t in (-1.0, cut / 2, float(len(topics))):
            # (history is bounded: what the stopped store still holds, the full one may have dropped)
            mine = full.at_or_before(topic, t, cut)
            theirs = stopped.at_or_before(topic, t)
            assert mine is None or mine == theirs
        assert full.latest(topic, cut) in (stopped.latest(topic), None)
