"""Time-stamped, typed, immutable objects on named topics, with a bounded history per topic.

What KogMo-RTDB gave AnnieWAY (seed 000 section 3: "all data within the RTDB are represented as
time-stamped objects"; seed 003 section II-c: synchronous and asynchronous queries): a module
publishes frozen dataclass instances that carry their own time `t_s` (the time the data is valid
for, on the shared `Clock`, not the time of publishing), and any other module reads the latest one,
the one valid at or before a time, an interpolation between two when the type says it may be
interpolated, or waits for the next one.

Objects are immutable once published: only frozen dataclasses are accepted, so a reader can never
change what another reader sees. A topic's type is fixed by its first publication (or by
`declare`); another type on the same topic is refused, naming both.

Reads never block unless asked to: `Subscription.poll()` returns the next unread object or None,
`Subscription.wait(timeout_s)` blocks on a condition variable (wall time; in lockstep SIL nothing
else can publish while a reader waits, so SIL uses `poll`).
"""

from __future__ import annotations

import bisect
import builtins
import dataclasses
import math
import threading
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar, runtime_checkable

DEFAULT_HISTORY = 256  # objects per topic: 25 s of a 10 Hz topic, 2.5 s of a 100 Hz one


@runtime_checkable
class Interpolatable(Protocol):
    """A type that may be interpolated declares how (positions yes, discrete states no)."""

    @classmethod
    def interpolate(cls, before: Any, after: Any, t_s: float) -> Any: ...


class StoreError(ValueError):
    """A publication or query the store refuses, naming the topic and what was wrong."""


T = TypeVar("T")


def _check_object(topic: str, obj: object) -> float:
    if not dataclasses.is_dataclass(obj) or isinstance(obj, type):
        raise StoreError(
            f"topic {topic!r}: only dataclass instances can be published, got {type(obj).__name__}"
        )
    if not type(obj).__dataclass_params__.frozen:  # type: ignore[attr-defined]
        raise StoreError(
            f"topic {topic!r}: {type(obj).__name__} must be a frozen dataclass (objects are immutable)"
        )
    t_s = getattr(obj, "t_s", None)
    if isinstance(t_s, bool) or not isinstance(t_s, int | float) or not math.isfinite(t_s):
        raise StoreError(
            f"topic {topic!r}: {type(obj).__name__}.t_s must be a finite time in seconds, got {t_s!r}"
        )
    return float(t_s)


@dataclass
class _Topic:
    type: builtins.type
    history: int
    times: deque[float]
    objects: deque[Any]
    published: int = 0  # sequence number of the last publication (1-based)
    # The store-wide publication number of each object held: increasing along the deque, so the
    # objects published up to a given number are always a prefix of the history.
    store_seqs: deque[int] = dataclasses.field(default_factory=deque)

    @classmethod
    def empty(cls, obj_type: builtins.type, history: int) -> _Topic:
        return cls(obj_type, history, deque(maxlen=history), deque(maxlen=history), 0, deque(maxlen=history))

    def held_as_of(self, as_of: int | None) -> int:
        """How many of the held objects (oldest first) were published at or before store number `as_of`."""
        n = len(self.objects)
        if as_of is None or n == 0 or self.store_seqs[-1] <= as_of:
            return n
        return bisect.bisect_right(self.store_seqs, as_of)


class ObjectStore:
    """In-process object store; thread-safe (a lock per store, held only for O(1)..O(log n) work)."""

    def __init__(self, default_history: int = DEFAULT_HISTORY) -> None:
        if default_history < 1:
            raise ValueError(f"history must hold at least one object, not {default_history}")
        self._default_history = default_history
        self._topics: dict[str, _Topic] = {}
        self._lock = threading.Lock()
        self._published = threading.Condition(self._lock)
        self._taps: list[Callable[[str, Any], None]] = []
        self._seq = 0  # publications so far, store-wide (see `seq`)

    def add_tap(self, tap: Callable[[str, Any], None]) -> None:
        """Call `tap(topic, obj)` after every publication (recorders, live views, bridges).

        Taps run in the publisher's thread, outside the store's lock, in publication order per
        topic; a tap that raises is the tap's bug and propagates to the publisher.
        """
        self._taps.append(tap)

    # -- writing ------------------------------------------------------------------------------------

    def declare(self, topic: str, obj_type: type, history: int | None = None) -> None:
        """Fix a topic's type and history length before anything is published on it."""
        if not dataclasses.is_dataclass(obj_type) or not obj_type.__dataclass_params__.frozen:  # type: ignore[attr-defined]
            raise StoreError(f"topic {topic!r}: {obj_type.__name__} must be a frozen dataclass")
        n = self._default_history if history is None else history
        if n < 1:
            raise StoreError(f"topic {topic!r}: history must hold at least one object, not {n}")
        with self._lock:
            known = self._topics.get(topic)
            if known is not None and known.type is not obj_type:
                raise StoreError(f"topic {topic!r} carries {known.type.__name__}, not {obj_type.__name__}")
            if known is None:
                self._topics[topic] = _Topic.empty(obj_type, n)

    def publish(self, topic: str, obj: object) -> int:
        """Publish `obj` (a frozen dataclass with `t_s`); returns its sequence number on the topic.

        Objects must arrive in time order per topic: one older than the newest is refused, since
        time queries would silently answer with the wrong object otherwise.
        """
        t_s = _check_object(topic, obj)
        with self._lock:
            entry = self._topics.get(topic)
            if entry is None:
                entry = self._topics[topic] = _Topic.empty(type(obj), self._default_history)
            elif type(obj) is not entry.type:
                raise StoreError(f"topic {topic!r} carries {entry.type.__name__}, not {type(obj).__name__}")
            if entry.times and t_s < entry.times[-1]:
                raise StoreError(
                    f"topic {topic!r}: t_s {t_s} is older than the newest object ({entry.times[-1]})"
                )
            entry.times.append(t_s)
            entry.objects.append(obj)
            entry.published += 1
            self._seq += 1
            entry.store_seqs.append(self._seq)
            seq = entry.published
            self._published.notify_all()
        for tap in self._taps:
            tap(topic, obj)
        return seq

    # -- reading ------------------------------------------------------------------------------------

    def topics(self) -> dict[str, type]:
        with self._lock:
            return {name: entry.type for name, entry in self._topics.items()}

    @property
    def seq(self) -> int:
        """The number of publications so far, store-wide. Reads given `as_of=store.seq` see the store
        as it is now, whatever is published later: what a module released now may read (see
        `ModuleContext`), so that a module that runs late still computes on its release's data."""
        return self._seq

    def latest(self, topic: str, as_of: int | None = None) -> Any | None:
        with self._lock:
            entry = self._topics.get(topic)
            if entry is None:
                return None
            n = entry.held_as_of(as_of)
            return entry.objects[n - 1] if n else None

    def at_or_before(self, topic: str, t_s: float, as_of: int | None = None) -> Any | None:
        """The newest object valid at or before `t_s` still in the history; None if there is none."""
        with self._lock:
            entry = self._topics.get(topic)
            if entry is None:
                return None
            i = bisect.bisect_right(entry.times, t_s, 0, entry.held_as_of(as_of))
            return entry.objects[i - 1] if i > 0 else None

    def interpolated(self, topic: str, t_s: float, as_of: int | None = None) -> Any | None:
        """The object at `t_s` interpolated between its neighbours, for types that allow it.

        Outside the history's span there is nothing to interpolate between: None before the oldest
        object, the newest object after it (extrapolation is the reader's decision, not the store's).
        """
        with self._lock:
            entry = self._topics.get(topic)
            if entry is None or not entry.objects:
                return None
            if not isinstance(entry.type, type) or not issubclass(entry.type, Interpolatable):
                raise StoreError(f"topic {topic!r}: {entry.type.__name__} does not define interpolate()")
            n = entry.held_as_of(as_of)
            i = bisect.bisect_right(entry.times, t_s, 0, n)
            if i == 0:
                return None
            before = entry.objects[i - 1]
            if i == n or entry.times[i - 1] == t_s:
                return before
            after = entry.objects[i]
        return entry.type.interpolate(before, after, t_s)

    def history(self, topic: str, since_s: float = -math.inf) -> list[Any]:
        """The objects still held with t_s >= since_s, oldest first."""
        with self._lock:
            entry = self._topics.get(topic)
            if entry is None:
                return []
            i = bisect.bisect_left(entry.times, since_s)
            return list(entry.objects)[i:]

    def subscribe(self, topic: str) -> Subscription[Any]:
        """A reader that sees every object published on `topic` from now on (or what history still holds)."""
        with self._lock:
            entry = self._topics.get(topic)
            seen = entry.published if entry is not None else 0
        return Subscription(self, topic, seen)

    # -- for Subscription ------------------------------------------------------------------------------

    def _next_after(
        self, topic: str, seen: int, as_of: int | None = None
    ) -> tuple[Any | None, int, int, int]:
        """(next object after topic sequence `seen` published at or before store number `as_of`,
        its topic sequence, objects lost to the bounded history, its store number)."""
        entry = self._topics.get(topic)
        if entry is None or entry.published <= seen:
            return None, seen, 0, 0
        oldest = entry.published - len(entry.objects) + 1
        lost = max(0, oldest - (seen + 1))
        nxt = max(seen + 1, oldest)
        store_seq = entry.store_seqs[nxt - oldest]
        if as_of is not None and store_seq > as_of:
            return None, seen, 0, 0
        return entry.objects[nxt - oldest], nxt, lost, store_seq


class Subscription(Generic[T]):
    """One reader's position on a topic: `poll()` (non-blocking), `wait(timeout_s)` (blocking), `lost`."""

    def __init__(self, store: ObjectStore, topic: str, seen: int) -> None:
        self._store = store
        self.topic = topic
        self._seen = seen
        self.lost = 0  # objects that left the bounded history before this reader got to them
        self.last_store_seq = 0  # the store-wide publication number of the last object taken

    def poll(self, as_of: int | None = None) -> T | None:
        """The next unread object (published at or before store number `as_of`), or None."""
        with self._store._lock:
            return self._take(as_of)

    def wait(self, timeout_s: float | None = None) -> T | None:
        with self._store._published:
            obj = self._take()
            if obj is None:
                self._store._published.wait_for(lambda: self._peek(), timeout=timeout_s)
                obj = self._take()
            return obj

    def __iter__(self) -> Iterator[T]:
        """Everything available now, without blocking."""
        while (obj := self.poll()) is not None:
            yield obj

    def _peek(self) -> bool:
        return self._store._next_after(self.topic, self._seen)[0] is not None

    def _take(self, as_of: int | None = None) -> T | None:
        obj, seq, lost, store_seq = self._store._next_after(self.topic, self._seen, as_of)
        if obj is not None:
            self._seen = seq
            self.lost += lost
            self.last_store_seq = store_seq
        return obj


def linear_interpolation(*fields: str) -> Callable[[type[T]], type[T]]:
    """Class decorator: `interpolate` linearly in the named numeric fields; the rest (and `t_s`'s
    neighbours' other fields) are taken from the earlier object."""

    def decorate(cls: type[T]) -> type[T]:
        def interpolate(klass: type[T], before: Any, after: Any, t_s: float) -> T:
            span = after.t_s - before.t_s
            alpha = 0.0 if span <= 0 else (t_s - before.t_s) / span
            changes = {
                f: getattr(before, f) + alpha * (getattr(after, f) - getattr(before, f)) for f in fields
            }
            return dataclasses.replace(before, t_s=t_s, **changes)  # type: ignore[type-var]

        cls.interpolate = classmethod(interpolate)  # type: ignore[attr-defined]
        return cls

    return decorate
