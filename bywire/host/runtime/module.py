"""Host modules: what each one reads, writes, how often it runs, its deadline, and what to do when it fails.

A module is the unit the scheduler runs and the supervisor watches (seed 000 section 3:
"the software is organized in modules that communicate through the real-time database", seed 003
section II-c). It declares its inputs and outputs by topic, so the runtime knows the data flow
without reading the code: the supervisor restarts a failed module's dependants in dependency order,
and refuses a publication on a topic the module did not declare (a wiring mistake would otherwise
show up as a mysteriously stale topic elsewhere).

A module may also sample topics (`sampled`): read their newest object when it runs, without being
part of their data flow. A sampled topic does not place the module after its producer in the chain,
never holds its release while the producer computes, and does not make the module a dependant that
is restarted with the producer: a sender on its own rhythm (the V2X link's CAM) takes what a
controller said last and is never delayed by it.

A module is run either periodically (`period_s`) or on a trigger topic (every new object on it),
and every release must complete within `deadline_s`. The `FailurePolicy` says what the supervisor
does when it does not: restart (with back-off, then escalate), degrade (a speed limit for the
rest of the run), or ask the ECU for a controlled stop.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

from bywire.host.runtime.store import ObjectStore, StoreError, Subscription

Action = Literal["restart", "degrade", "stop"]
ACTIONS: tuple[Action, ...] = ("restart", "degrade", "stop")
Isolation = Literal["thread", "process"]


@dataclass(frozen=True)
class FailurePolicy:
    """How the supervisor reacts to this module failing, and how quickly it must notice.

    `hang_after_s` bounds detection of a hung or deadlocked release; `slow_misses` deadline misses
    within the last `slow_window` releases make the module "slow"; `silent_releases` completed
    releases in a row without a publication make it "stale" (counted in releases, not seconds, so a
    late scheduler cannot make its modules look silent). Restarts back off exponentially from
    `backoff_s`; after `max_restarts` within `restart_window_s` the supervisor escalates to
    `escalate_to`.
    """

    action: Action = "restart"
    on_slow: Action | None = None  # a different reaction to "slow" (a late module still works)
    escalate_to: Action = "stop"
    max_restarts: int = 3
    restart_window_s: float = 30.0
    backoff_s: float = 0.0
    backoff_max_s: float = 2.0
    hang_after_s: float | None = None  # default: max(3 deadlines, 2 periods)
    slow_misses: int = 3
    slow_window: int = 10
    silent_releases: int = 3
    degrade_speed_mps: float = 5.0  # the speed limit a "degrade" imposes
    # Restart this module when a module it consumes from is restarted (its state derives from the
    # producer's outputs). A stateless sink such as the ECU link's sender says no: restarting it would
    # only reset its alive counter.
    restart_as_dependant: bool = True

    def __post_init__(self) -> None:
        if (
            self.action not in ACTIONS
            or self.escalate_to not in ACTIONS
            or self.on_slow not in (*ACTIONS, None)
        ):
            raise ValueError(f"policy actions must be one of {ACTIONS}, got {self.action}/{self.escalate_to}")
        if self.escalate_to == "restart":
            raise ValueError("escalate_to cannot be restart: escalation is what happens when restarts fail")
        if self.max_restarts < 0 or self.slow_misses < 1 or self.slow_window < self.slow_misses:
            raise ValueError("need max_restarts >= 0 and 1 <= slow_misses <= slow_window")
        if self.silent_releases < 1:
            raise ValueError("silent_releases must be at least 1")


@dataclass(frozen=True)
class ModuleSpec:
    """A module's declaration: the scheduler's and the supervisor's whole knowledge of it."""

    name: str
    inputs: tuple[str, ...] = ()
    outputs: tuple[str, ...] = ()
    # Read by their newest object only (`ModuleContext.latest`), outside the data flow (module docstring).
    sampled: tuple[str, ...] = ()
    period_s: float | None = None
    trigger: str | None = None  # run on every new object on this input topic instead of periodically
    deadline_s: float = 0.010
    policy: FailurePolicy = field(default_factory=FailurePolicy)
    isolation: Isolation = "thread"
    # Released every period even when a module it consumes from is late in this cycle's chain: a sink
    # that keeps a link alive (the ECU link's heartbeat and requests) and judges its inputs' age itself.
    # Other consumers of a late producer wait for the next cycle rather than run on stale data.
    always_release: bool = False

    def __post_init__(self) -> None:
        if not self.name or not self.name.replace("_", "").isalnum():
            raise ValueError(f"module name must be letters, digits and '_', got {self.name!r}")
        if (self.period_s is None) == (self.trigger is None):
            raise ValueError(f"module {self.name}: give exactly one of period_s and trigger")
        if self.period_s is not None and not (math.isfinite(self.period_s) and self.period_s > 0):
            raise ValueError(f"module {self.name}: period_s must be > 0, got {self.period_s}")
        if self.trigger is not None and self.trigger not in self.inputs:
            raise ValueError(f"module {self.name}: trigger {self.trigger!r} must be one of its inputs")
        both = sorted(set(self.sampled) & set(self.inputs))
        if both:
            raise ValueError(f"module {self.name}: {both} are both inputs and sampled; name each once")
        if not (math.isfinite(self.deadline_s) and self.deadline_s > 0):
            raise ValueError(f"module {self.name}: deadline_s must be > 0, got {self.deadline_s}")

    @property
    def hang_after_s(self) -> float:
        if self.policy.hang_after_s is not None:
            return self.policy.hang_after_s
        return max(3.0 * self.deadline_s, 2.0 * (self.period_s or 0.0))


class ModuleContext:
    """What a module sees of the runtime during a release: the time, its inputs, its outputs, its params.

    A release sees the store as it was when it was released (`as_of`, set by the worker): a module
    that runs late, on a busy machine or because it is slow, computes on its release's inputs, not on
    objects other modules published meanwhile. Its outputs are then the same as on time, which is
    what a replay of the run reproduces.

    Publications are fenced by generation: once the supervisor has given up on an instance (hung,
    deadlocked), anything that instance still publishes is dropped, so a zombie can never overwrite
    the outputs of its replacement.
    """

    def __init__(
        self, spec: ModuleSpec, store: ObjectStore, params: Mapping[str, Any], generation: int
    ) -> None:
        self.spec = spec
        self.store = store
        self.params = params
        self.generation = generation
        self.fenced = False
        self.now_s = 0.0  # the release time on the runtime's clock
        self.as_of: int | None = None  # the store's publication count at the release (None: now)
        self.published = 0
        self._subs: dict[str, Subscription[Any]] = {}

    def release(self, now_s: float) -> None:
        """Called by the worker as it releases a step: the time, and the store as of now."""
        self.now_s = now_s
        self.as_of = self.store.seq

    def latest(self, topic: str) -> Any | None:
        """The newest object on an input or sampled topic, as of the release."""
        if topic not in self.spec.sampled:
            self._check_input(topic)
        return self.store.latest(topic, self.as_of)

    def at_or_before(self, topic: str, t_s: float) -> Any | None:
        self._check_input(topic)
        return self.store.at_or_before(topic, t_s, self.as_of)

    def interpolated(self, topic: str, t_s: float) -> Any | None:
        self._check_input(topic)
        return self.store.interpolated(topic, t_s, self.as_of)

    def new(self, topic: str) -> list[Any]:
        """Every object on `topic` since this module instance last asked (non-blocking), up to the
        release's view of the store."""
        self._check_input(topic)
        sub = self._subs.get(topic)
        if sub is None:
            sub = self._subs[topic] = self.store.subscribe(topic)
        out = []
        while (obj := sub.poll(self.as_of)) is not None:
            out.append(obj)
        return out

    def publish(self, topic: str, obj: object) -> None:
        if topic not in self.spec.outputs:
            raise StoreError(f"module {self.spec.name} publishes {topic!r}, which is not among its outputs")
        if self.fenced:
            return
        self.store.publish(topic, obj)
        self.published += 1

    def _check_input(self, topic: str) -> None:
        if topic not in self.spec.inputs:
            raise StoreError(f"module {self.spec.name} reads {topic!r}, which is not among its inputs")


class Module:
    """Base class: override `step`; `start` runs once per instance before the first release.

    A module keeps its state in the instance; a restart builds a fresh instance from the same
    factory, so nothing of a failed instance's state survives into its replacement.
    """

    def start(self, ctx: ModuleContext) -> None:
        """Called once in the worker before the first step (open files, warm caches)."""

    def step(self, ctx: ModuleContext) -> None:
        raise NotImplementedError

    def close(self) -> None:
        """Called when the instance is retired normally (not when it was abandoned as hung)."""


def dependency_order(specs: list[ModuleSpec]) -> list[ModuleSpec]:
    """Producers before consumers (a topological sort of the data flow), stable in declaration order.

    Cycles are allowed (a feedback loop through the store is legitimate, e.g. control -> ECU link ->
    status -> control): within a cycle the declaration order decides.
    """
    import networkx as nx

    producers: dict[str, str] = {}
    for s in specs:
        for topic in s.outputs:
            if topic in producers:
                raise ValueError(f"topic {topic!r} is an output of both {producers[topic]} and {s.name}")
            producers[topic] = s.name
    graph = nx.DiGraph()
    order = {s.name: i for i, s in enumerate(specs)}
    graph.add_nodes_from(order)
    for s in specs:
        for topic in s.inputs:
            src = producers.get(topic)
            if src is not None and src != s.name:
                graph.add_edge(src, s.name)
    condensed = nx.condensation(graph)
    members = condensed.graph["mapping"]
    groups: dict[int, list[str]] = {}
    for name, comp in members.items():
        groups.setdefault(comp, []).append(name)
    names: list[str] = []
    for comp in nx.lexicographical_topological_sort(
        condensed, key=lambda c: min(order[n] for n in groups[c])
    ):
        names.extend(sorted(groups[comp], key=order.__getitem__))
    by_name = {s.name: s for s in specs}
    return [by_name[n] for n in names]


def dependants(specs: list[ModuleSpec], name: str) -> list[str]:
    """Modules whose inputs derive from `name`'s outputs, in dependency order (without `name`).

    Data flow is followed downstream, except between partners in a feedback loop (control -> ECU
    link -> status -> odometry -> control): restarting the ECU link because the controller restarted
    would only interrupt the link, while a consumer outside the loop (a logger of the requests) is a
    dependant.
    """
    import networkx as nx

    graph = nx.DiGraph()
    graph.add_nodes_from(s.name for s in specs)
    for a in specs:
        for b in specs:
            if a.name != b.name and set(a.outputs) & set(b.inputs):
                graph.add_edge(a.name, b.name)
    loop_of = nx.condensation(graph).graph["mapping"]
    downstream = nx.DiGraph((a, b) for a, b in graph.edges if loop_of[a] != loop_of[b])
    downstream.add_nodes_from(graph)
    affected = nx.descendants(downstream, name)
    return [s.name for s in dependency_order(specs) if s.name in affected]
