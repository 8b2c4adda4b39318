"""A small hierarchical state machine (statechart) core: the planner of seed 000 Sec. 8 runs on it.

Sec. 8: "The maneuver planner is implemented as a hierarchical state machine (HSM), with every state
representing a driving behavior. [...] a substate is a specialization of its parent state, and only
extensions to the more general behavior of the parent state have to be modeled explicitly." AnnieWAY
built theirs on boost::statechart; nothing of the kind is installed here, so this is our own, with
exactly what the planner needs and nothing it does not:

- `State`: a name, children (then it is composite and names its `initial` child), `entry` / `exit`
  actions, an `activity` run every cycle while the state is active, guarded `Transition`s, and an
  optional `NoProgress` timer. Names are unique in a machine; a state is addressed by its name.
- Transitions are evaluated **top-down**: the active states from the root to the leaf, each state's
  no-progress timer first, then its transitions in the order declared; the first enabled one fires.
  So a family's rule (its recovery, leaving the family) preempts whatever its substates would do.
- Firing is the UML "external" transition: the domain is the least common ancestor of the declaring
  state and the target (its parent when one contains the other, so a state can re-enter itself or
  its family); the active states below the domain exit innermost first, the transition's action
  runs, the states down to the target enter outermost first, then the target's initial chain.
- Run to completion: after a transition the new configuration is evaluated again, at most
  `max_microsteps` times per cycle. More means two guards contradict each other (a livelock):
  `HsmLivelockError` names the chain. (AnnieWAY's code had the same bound, 16, but could not act on
  it; seed 000 Sec. 12's lesson is that a planner must never hang silently - see `Behaviour`.)
- `NoProgress(timeout_s, recovery, excused)`: while the state is active, progress is `progress_m` of
  travel (the odometer the caller passes each cycle) or, if given, `excused(ctx)` (e.g. we wait on
  moving traffic); when none has been made for `timeout_s`, the machine transits to `recovery`
  ("Most states implement a recovery state that is activated whenever the car makes no progress at
  all for a certain amount of time", Sec. 8). The timer rests while `recovery` is active (a family's
  recovery state lives inside it); a recovery state's own timer escalates to the global recovery.
- `force(target)`: an external jump (a fault handler's way into the global recovery). Exceptions of
  the exit actions on the way out are collected and returned, not raised: the jump must land.

Time is an argument (seconds on one monotonic clock, which the caller may stop while the vehicle is
paused), there is no randomness and no iteration over unordered sets: the same inputs give the same
sequence of states. Pure Python, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Generic, TypeVar

__all__ = [
    "Fired",
    "HsmDefinitionError",
    "HsmLivelockError",
    "Machine",
    "NoProgress",
    "State",
    "Transition",
]

C = TypeVar("C")


class HsmDefinitionError(ValueError):
    """The state tree is malformed (duplicate name, unknown target, composite without initial, ...)."""


class HsmLivelockError(RuntimeError):
    """More transitions in one cycle than `max_microsteps`: the guards contradict each other."""


@dataclass(frozen=True)
class Transition(Generic[C]):
    """Go to `target` when `guard(ctx)`; `label` says why (diagrams, logs); `action` runs in between."""

    target: str
    guard: Callable[[C], bool]
    label: str
    action: Callable[[C], None] | None = None


@dataclass(frozen=True)
class NoProgress(Generic[C]):
    """Transit to `recovery` after `timeout_s` without progress (travel, or `excused(ctx)`)."""

    timeout_s: float
    recovery: str
    excused: Callable[[C], bool] | None = None

    @property
    def label(self) -> str:
        return f"no progress for {self.timeout_s:g} s"


class State(Generic[C]):
    """One state of the chart; composite when it has children (then `initial` names the entry child)."""

    def __init__(
        self,
        name: str,
        *,
        doc: str = "",
        children: Sequence[State[C]] = (),
        initial: str | None = None,
        transitions: Sequence[Transition[C]] = (),
        entry: Callable[[C], None] | None = None,
        exit: Callable[[C], None] | None = None,
        activity: Callable[[C], None] | None = None,
        no_progress: NoProgress[C] | None = None,
    ) -> None:
        self.name = name
        self.doc = doc
        self.children: tuple[State[C], ...] = tuple(children)
        self.initial = initial
        self.transitions: tuple[Transition[C], ...] = tuple(transitions)
        self.entry = entry
        self.exit = exit
        self.activity = activity
        self.no_progress = no_progress
        self.parent: State[C] | None = None

    @property
    def is_composite(self) -> bool:
        return bool(self.children)

    def walk(self) -> Iterator[State[C]]:
        """This state and all below it, depth first, in declaration order."""
        yield self
        for child in self.children:
            yield from child.walk()

    def __repr__(self) -> str:
        return f"State({self.name!r})"


@dataclass(frozen=True)
class Fired:
    """One transition taken: declared on `source`, from the leaf `leaf`, to `target`, because `label`."""

    source: str
    leaf: str
    target: str
    label: str


@dataclass
class _Mark:
    entered_s: float
    progress_s: float  # when progress was last seen
    odometer_m: float  # the odometer then


class Machine(Generic[C]):
    """Runs a `State` tree. Call `start` once, then `step` every cycle and `run_activities` after it."""

    def __init__(self, root: State[C], *, max_microsteps: int = 16, progress_m: float = 0.5) -> None:
        if max_microsteps < 1:
            raise HsmDefinitionError(f"max_microsteps = {max_microsteps}: must be >= 1")
        if not (math.isfinite(progress_m) and progress_m > 0.0):
            raise HsmDefinitionError(f"progress_m = {progress_m}: must be finite and > 0")
        self.root = root
        self.max_microsteps = max_microsteps
        self.progress_m = progress_m
        self.states: dict[str, State[C]] = {}
        for state in root.walk():
            if state.name in self.states:
                raise HsmDefinitionError(f"state name {state.name!r} used twice")
            self.states[state.name] = state
            for child in state.children:
                child.parent = state
        self._check_definition()
        self._active: list[State[C]] = []
        self._marks: dict[str, _Mark] = {}

    # ------------------------------------------------------------------------------- definition

    def _check_definition(self) -> None:
        for state in self.states.values():
            if state.is_composite:
                names = [c.name for c in state.children]
                if state.initial not in names:
                    raise HsmDefinitionError(
                        f"composite state {state.name!r}: initial {state.initial!r} is not one of {names}"
                    )
            elif state.initial is not None:
                raise HsmDefinitionError(f"state {state.name!r} has an initial state but no children")
            for tr in state.transitions:
                if tr.target not in self.states:
                    raise HsmDefinitionError(
                        f"state {state.name!r}: transition {tr.label!r} targets unknown state {tr.target!r}"
                    )
                if tr.target == self.root.name:
                    raise HsmDefinitionError(f"state {state.name!r}: the root cannot be a target")
            np_ = state.no_progress
            if np_ is not None:
                if np_.recovery not in self.states or np_.recovery == self.root.name:
                    raise HsmDefinitionError(
                        f"state {state.name!r}: no-progress recovery {np_.recovery!r} is not a state"
                    )
                if not (math.isfinite(np_.timeout_s) and np_.timeout_s > 0.0):
                    raise HsmDefinitionError(f"state {state.name!r}: no-progress timeout must be > 0")

    def transitions(self) -> Iterator[tuple[State[C], Transition[C] | NoProgress[C]]]:
        """Every declared transition and no-progress timer with its declaring state (for diagrams)."""
        for state in self.root.walk():
            if state.no_progress is not None:
                yield state, state.no_progress
            for tr in state.transitions:
                yield state, tr

    def ancestors(self, name: str) -> list[State[C]]:
        """The root ... the state `name` itself."""
        chain: list[State[C]] = []
        node: State[C] | None = self.states[name]
        while node is not None:
            chain.append(node)
            node = node.parent
        return chain[::-1]

    # ------------------------------------------------------------------------------- configuration

    @property
    def started(self) -> bool:
        return bool(self._active)

    @property
    def active(self) -> tuple[State[C], ...]:
        """The active states, root first."""
        return tuple(self._active)

    @property
    def leaf(self) -> str:
        return self._active[-1].name

    @property
    def path(self) -> str:
        """The active states below the root joined by '/', e.g. 'Intersection/IntersectionWait'."""
        return "/".join(s.name for s in self._active[1:])

    def is_active(self, name: str) -> bool:
        return name in self._marks

    def time_in(self, name: str, t_s: float) -> float:
        """Seconds since the active state `name` was entered (KeyError if it is not active)."""
        return t_s - self._marks[name].entered_s

    def idle_s(self, name: str, t_s: float) -> float:
        """Seconds since the active state `name` last saw progress (its no-progress timer)."""
        return t_s - self._marks[name].progress_s

    # ------------------------------------------------------------------------------- running

    def start(self, ctx: C, t_s: float, odometer_m: float = 0.0) -> None:
        """Enter the root and its initial chain (entry actions outermost first)."""
        if self._active:
            raise RuntimeError("Machine.start: already started")
        self._enter_down(self.root, ctx, t_s, odometer_m)

    def step(self, ctx: C, t_s: float, odometer_m: float) -> tuple[Fired, ...]:
        """Update the no-progress timers, then fire enabled transitions until none is (run to completion).

        Returns the transitions taken, in order. Raises `HsmLivelockError` after `max_microsteps`.
        """
        if not self._active:
            raise RuntimeError("Machine.step: call start() first")
        self._update_progress(ctx, t_s, odometer_m)
        fired: list[Fired] = []
        for _ in range(self.max_microsteps):
            found = self._enabled(ctx, t_s)
            if found is None:
                return tuple(fired)
            source, target, label, action = found
            fired.append(self._fire(source, target, label, action, ctx, t_s, odometer_m))
        if self._enabled(ctx, t_s) is None:
            return tuple(fired)
        chain = " -> ".join([fired[0].leaf] + [f.target for f in fired])
        raise HsmLivelockError(
            f"more than {self.max_microsteps} transitions in one cycle at t = {t_s:.3f} s: {chain}"
        )

    def run_activities(self, ctx: C) -> None:
        """Every active state's activity, root first (a family prepares, the leaf decides)."""
        for state in tuple(self._active):
            if state.activity is not None:
                state.activity(ctx)

    def force(
        self, target: str, ctx: C, t_s: float, odometer_m: float, label: str
    ) -> tuple[Fired, list[BaseException]]:
        """Jump to `target` from wherever the machine is; exit-action errors are returned, not raised."""
        if target not in self.states or target == self.root.name:
            raise KeyError(f"Machine.force: unknown target state {target!r}")
        errors: list[BaseException] = []
        fired = self._fire(self._active[-1], self.states[target], label, None, ctx, t_s, odometer_m, errors)
        return fired, errors

    # ------------------------------------------------------------------------------- internals

    def _update_progress(self, ctx: C, t_s: float, odometer_m: float) -> None:
        for state in self._active:
            np_ = state.no_progress
            if np_ is None:
                continue
            mark = self._marks[state.name]
            moved = abs(odometer_m - mark.odometer_m) >= self.progress_m
            if moved or (np_.excused is not None and np_.excused(ctx)):
                mark.progress_s = t_s
                mark.odometer_m = odometer_m

    def _enabled(
        self, ctx: C, t_s: float
    ) -> tuple[State[C], State[C], str, Callable[[C], None] | None] | None:
        for state in tuple(self._active):
            np_ = state.no_progress
            if (
                np_ is not None
                and not self.is_active(np_.recovery)
                and t_s - self._marks[state.name].progress_s >= np_.timeout_s
            ):
                return state, self.states[np_.recovery], np_.label, None
            for tr in state.transitions:
                if tr.guard(ctx):
                    return state, self.states[tr.target], tr.label, tr.action
        return None

    def _fire(
        self,
        source: State[C],
        target: State[C],
        label: str,
        action: Callable[[C], None] | None,
        ctx: C,
        t_s: float,
        odometer_m: float,
        errors: list[BaseException] | None = None,
    ) -> Fired:
        leaf = self._active[-1].name
        src_chain = self.ancestors(source.name)
        tgt_chain = self.ancestors(target.name)
        common = 0
        while common < min(len(src_chain), len(tgt_chain)) and src_chain[common] is tgt_chain[common]:
            common += 1
        domain = src_chain[common - 1]
        if (domain is source or domain is target) and common >= 2:
            domain = src_chain[common - 2]  # external: leave and re-enter the containing state
        depth = self._active.index(domain)
        while len(self._active) > depth + 1:
            state = self._active.pop()
            del self._marks[state.name]
            if state.exit is not None:
                if errors is None:
                    state.exit(ctx)
                else:
                    try:
                        state.exit(ctx)
                    except Exception as exc:  # a forced jump must land; the caller reports these
                        errors.append(exc)
        if action is not None:
            action(ctx)
        below = tgt_chain[tgt_chain.index(domain) + 1 :]
        for state in below[:-1]:
            self._enter_one(state, ctx, t_s, odometer_m)
        self._enter_down(below[-1], ctx, t_s, odometer_m)
        return Fired(source.name, leaf, target.name, label)

    def _enter_one(self, state: State[C], ctx: C, t_s: float, odometer_m: float) -> None:
        self._active.append(state)
        self._marks[state.name] = _Mark(t_s, t_s, odometer_m)
        if state.entry is not None:
            state.entry(ctx)

    def _enter_down(self, state: State[C], ctx: C, t_s: float, odometer_m: float) -> None:
        node: State[C] | None = state
        while node is not None:
            self._enter_one(node, ctx, t_s, odometer_m)
            node = self.states[node.initial] if node.initial is not None else None
