"""The statechart core (host/behaviour/hsm.py): hierarchy, entry/exit order, top-down guards, external
transitions, run to completion with its livelock bound, no-progress timers and their escalation, the
forced jump, definition errors, determinism."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.host.behaviour.hsm import (
    HsmDefinitionError,
    HsmLivelockError,
    Machine,
    NoProgress,
    State,
    Transition,
)


@dataclass
class Ctx:
    log: list[str] = field(default_factory=list)
    flags: set[str] = field(default_factory=set)
    traffic: bool = False

    def on(self, flag: str) -> bool:
        return flag in self.flags


def logged(name: str) -> dict[str, object]:
    return {
        "entry": lambda c, n=name: c.log.append(f"enter {n}"),
        "exit": lambda c, n=name: c.log.append(f"exit {n}"),
        "activity": lambda c, n=name: c.log.append(f"do {n}"),
    }


def tree() -> State[Ctx]:
    """Root -> A (A1 -> A1a, A1b; A2), B; timers on A (-> A2) and A2 (-> B)."""
    return State(
        "Root",
        initial="A",
        children=(
            State(
                "A",
                initial="A1",
                no_progress=NoProgress(10.0, "A2", lambda c: c.traffic),
                transitions=(Transition("B", lambda c: c.on("a->b"), "A to B"),),
                children=(
                    State(
                        "A1",
                        initial="A1a",
                        children=(
                            State(
                                "A1a",
                                transitions=(
                                    Transition("A1b", lambda c: c.on("a1a->a1b"), "sibling"),
                                    Transition("B", lambda c: c.on("a->b"), "never reached: A decides first"),
                                ),
                                **logged("A1a"),  # type: ignore[arg-type]
                            ),
                            State(
                                "A1b",
                                transitions=(Transition("A1", lambda c: c.on("reenter"), "re-enter parent"),),
                                **logged("A1b"),  # type: ignore[arg-type]
                            ),
                        ),
                        **logged("A1"),  # type: ignore[arg-type]
                    ),
                    State(
                        "A2",
                        no_progress=NoProgress(5.0, "B"),
                        transitions=(Transition("A2", lambda c: c.on("self"), "self"),),
                        **logged("A2"),  # type: ignore[arg-type]
                    ),
                ),
                **logged("A"),  # type: ignore[arg-type]
            ),
            State("B", transitions=(Transition("A1b", lambda c: c.on("b->a1b"), "deep"),), **logged("B")),  # type: ignore[arg-type]
        ),
    )


def started(ctx: Ctx) -> Machine[Ctx]:
    m = Machine(tree(), max_microsteps=4, progress_m=0.5)
    m.start(ctx, 0.0, 0.0)
    return m


def test_start_enters_the_initial_chain_outermost_first() -> None:
    ctx = Ctx()
    m = started(ctx)
    assert m.path == "A/A1/A1a" and m.leaf == "A1a"
    assert ctx.log == ["enter A", "enter A1", "enter A1a"]
    m.run_activities(ctx)
    assert ctx.log[-3:] == ["do A", "do A1", "do A1a"]  # root first: a family prepares, the leaf decides
    with pytest.raises(RuntimeError):
        m.start(ctx, 0.0)


def test_transitions_exit_innermost_first_and_enter_outermost_first() -> None:
    ctx = Ctx()
    m = started(ctx)
    ctx.log.clear()
    ctx.flags = {"a1a->a1b"}
    fired = m.step(ctx, 1.0, 0.0)
    assert [f.target for f in fired] == ["A1b"] and m.path == "A/A1/A1b"
    assert ctx.log == ["exit A1a", "enter A1b"]  # siblings: the parent A1 stays
    ctx.log.clear()
    ctx.flags = {"b->a1b"}
    m2 = started(Ctx())
    c2 = Ctx(flags={"a->b"})
    m2.step(c2, 1.0, 0.0)
    assert m2.path == "B" and c2.log == ["exit A1a", "exit A1", "exit A", "enter B"]
    c2.log.clear()
    c2.flags = {"b->a1b"}
    m2.step(c2, 2.0, 0.0)  # a deep target: its ancestors enter first, no initial detour
    assert m2.path == "A/A1/A1b" and c2.log == ["exit B", "enter A", "enter A1", "enter A1b"]


def test_guards_are_evaluated_top_down() -> None:
    ctx = Ctx(flags={"a->b", "a1a->a1b"})
    m = started(ctx)
    fired = m.step(ctx, 1.0, 0.0)
    assert fired[0].source == "A" and fired[0].label == "A to B" and m.path == "B"


def test_external_transitions_reenter() -> None:
    ctx = Ctx(flags={"a1a->a1b"})
    m = started(ctx)
    m.step(ctx, 1.0, 0.0)
    ctx.log.clear()
    ctx.flags = {"reenter"}  # A1b -> A1, its parent: leave A1 and enter it again, through its initial
    m.step(ctx, 2.0, 0.0)
    assert m.path == "A/A1/A1a" and ctx.log == ["exit A1b", "exit A1", "enter A1", "enter A1a"]
    m.force("A2", ctx, 3.0, 0.0, "jump")
    ctx.log.clear()
    ctx.flags = {"self"}  # a self-transition exits and re-enters (and here loops: see the next test)
    with pytest.raises(HsmLivelockError):
        m.step(ctx, 4.0, 0.0)
    assert ctx.log[:2] == ["exit A2", "enter A2"]


def test_livelock_is_bounded_and_named() -> None:
    ctx = Ctx()
    m = started(ctx)
    m.force("A2", ctx, 0.0, 0.0, "jump")
    ctx.flags = {"self"}
    with pytest.raises(HsmLivelockError, match=r"more than 4 transitions .* A2 -> A2"):
        m.step(ctx, 1.0, 0.0)


def test_no_progress_timer_fires_rests_and_escalates() -> None:
    ctx = Ctx()
    m = started(ctx)
    # progress by travel: moving 0.5 m every 4 s keeps A's 10 s timer from firing
    for k in range(1, 8):
        assert m.step(ctx, 4.0 * k, 0.5 * k) == ()
    assert m.path == "A/A1/A1a"
    # then standing: after 10 s without progress A goes to its recovery A2 ...
    t0 = 28.0
    assert m.step(ctx, t0 + 9.9, 3.5) == ()
    fired = m.step(ctx, t0 + 10.0, 3.5)
    assert [(f.source, f.target, f.label) for f in fired] == [("A", "A2", "no progress for 10 s")]
    # ... A's timer rests while A2 is active, A2's own 5 s escalate to B
    assert m.step(ctx, t0 + 14.9, 3.5) == ()
    fired = m.step(ctx, t0 + 15.0, 3.5)
    assert [(f.source, f.target) for f in fired] == [("A2", "B")] and m.path == "B"


def test_moving_traffic_excuses_standing() -> None:
    ctx = Ctx(traffic=True)
    m = started(ctx)
    for k in range(1, 60):
        assert m.step(ctx, float(k), 0.0) == ()
    ctx.traffic = False
    assert m.step(ctx, 68.0, 0.0) == ()
    assert m.idle_s("A", 68.0) == pytest.approx(9.0)
    assert m.step(ctx, 69.0, 0.0)[0].target == "A2"


def test_force_lands_even_when_exit_actions_fail() -> None:
    def boom(_: Ctx) -> None:
        raise RuntimeError("exit failed")

    root = State("R", initial="X", children=(State("X", exit=boom), State("Y")))
    m = Machine(root)
    ctx = Ctx()
    m.start(ctx, 0.0)
    fired, errors = m.force("Y", ctx, 1.0, 0.0, "fault")
    assert m.path == "Y" and fired.target == "Y" and [str(e) for e in errors] == ["exit failed"]
    with pytest.raises(KeyError):
        m.force("Nope", ctx, 1.0, 0.0, "x")


@pytest.mark.parametrize(
    ("root", "message"),
    [
        (State("R", initial="X", children=(State("X"), State("X"))), "used twice"),
        (State("R", initial="Z", children=(State("X"),)), "initial 'Z'"),
        (State("R", initial="X", children=(State("X", initial="Q"),)), "no children"),
        (
            State("R", initial="X", children=(State("X", transitions=(Transition("Q", bool, "q"),)),)),
            "unknown state",
        ),
        (State("R", initial="X", children=(State("X", transitions=(Transition("R", bool, "r"),)),)), "root"),
        (State("R", initial="X", children=(State("X", no_progress=NoProgress(1.0, "Q")),)), "not a state"),
        (State("R", initial="X", children=(State("X", no_progress=NoProgress(0.0, "X")),)), "must be > 0"),
    ],
)
def test_definition_errors_name_the_state(root: State[object], message: str) -> None:
    with pytest.raises(HsmDefinitionError, match=message):
        Machine(root)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(st.sampled_from(["a->b", "a1a->a1b", "b->a1b", "reenter", ""]), st.booleans()), max_size=30
    )
)
def test_same_inputs_same_states(script: list[tuple[str, bool]]) -> None:
    """Determinism: two machines fed the same flags, times and odometer take the same transitions."""
    runs = []
    for _ in range(2):
        ctx = Ctx()
        m = started(ctx)
        trace = []
        for k, (flag, traffic) in enumerate(script):
            ctx.flags = {flag}
            ctx.traffic = traffic
            trace.append((m.step(ctx, 3.0 * k, 0.0), m.path))
        runs.append((trace, ctx.log))
    assert runs[0] == runs[1]
