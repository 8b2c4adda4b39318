"""Four-way-stop precedence (seed 000 Secs. 9.3 a, 12) and priority-road right of way (Sec. 9.3 b, c).

The intersection: four stop lines, named by the side a vehicle waits on; we wait at "S" and drive north.
"E" is on our right (its traffic drives west), "W" on our left, "N" opposite.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.host.behaviour.precedence import (
    Approach,
    ApproachingVehicle,
    IntersectionPrecedence,
    PrecedenceDecision,
    StopLine,
    Turn,
    WaitingVehicle,
    relative_side,
    right_of_way,
)
from bywire.host.behaviour.rules import PRECEDENCE_STUCK_S, PRECEDENCE_TIE_S

LINES = (
    StopLine("S", math.pi / 2.0),
    StopLine("E", math.pi),
    StopLine("N", -math.pi / 2.0),
    StopLine("W", 0.0),
)
DT_S = 0.1


def manager() -> IntersectionPrecedence:
    return IntersectionPrecedence(LINES, "S")


def test_relative_side() -> None:
    assert relative_side(math.pi / 2.0, math.pi) == "right"
    assert relative_side(math.pi / 2.0, 0.0) == "left"
    assert relative_side(math.pi / 2.0, -math.pi / 2.0) == "opposite"
    assert relative_side(math.pi / 2.0, math.pi / 2.0 + 0.1) == "same"
    assert relative_side(0.0, 2.0 * math.pi + math.pi / 2.0) == "right"  # wrapped


# --------------------------------------------------------------------------------------- a small world


@dataclass
class Other:
    """A scripted other vehicle: stops at `line` at `arrive_s`; then, relative to the world clock,
    enters the box at `enter_s` (None: never) for `cross_s`, or vanishes at `vanish_s`."""

    vid: str
    line: str
    arrive_s: float
    enter_s: float | None = None
    cross_s: float = 3.0
    vanish_s: float | None = None

    def waiting(self, t: float) -> bool:
        if t < self.arrive_s:
            return False
        if self.enter_s is not None and t >= self.enter_s:
            return False
        return self.vanish_s is None or t < self.vanish_s

    def in_box(self, t: float) -> bool:
        return self.enter_s is not None and self.enter_s <= t < self.enter_s + self.cross_s


def snapshot(others: list[Other], t: float) -> tuple[list[WaitingVehicle], list[str]]:
    waiting = [WaitingVehicle(o.vid, o.line, o.arrive_s) for o in others if o.waiting(t)]
    return waiting, [o.vid for o in others if o.in_box(t)]


def run(
    others: list[Other], own_arrive_s: float, until_s: float, pm: IntersectionPrecedence | None = None
) -> tuple[float | None, PrecedenceDecision, list[tuple[float, PrecedenceDecision]]]:
    """Step the world at 10 Hz; return (first time we may go, that decision, the whole log)."""
    pm = pm or manager()
    log: list[tuple[float, PrecedenceDecision]] = []
    for k in range(round(until_s / DT_S) + 1):
        t = round(k * DT_S, 9)
        if pm.own_arrived_s is None and t >= own_arrive_s:
            pm.arrive(t)
        decision = pm.update(t, *snapshot(others, t))
        log.append((t, decision))
        if decision.may_go:
            return t, decision, log
    return None, log[-1][1], log


def fifo_world(
    arrivals: list[tuple[str, str, float]], reaction_s: float, cross_s: float, start_s: float = 0.0
) -> list[Other]:
    """Well-behaved drivers all standing at their lines at `start_s` (our arrival: the case AnnieWAY
    never tested): in arrival order, each enters the box `reaction_s` after the box is clear and its
    predecessor has gone, and crosses in `cross_s`."""
    others = []
    box_free_s = start_s
    for vid, line, arrive in sorted(arrivals, key=lambda a: a[2]):
        enter = max(arrive, box_free_s) + reaction_s
        others.append(Other(vid, line, arrive, enter_s=enter, cross_s=cross_s))
        box_free_s = enter + cross_s
    return others


# --------------------------------------------------------------------------------------- 0..3 waiting


def test_nobody_there_we_go_at_once() -> None:
    t, decision, _ = run([], own_arrive_s=0.0, until_s=5.0)
    assert t == 0.0
    assert decision.may_go and not decision.with_caution and decision.waiting_for == ()


def test_not_arrived_yet_never_goes() -> None:
    pm = manager()
    d = pm.update(0.0, [])
    assert not d.may_go and "not stopped" in d.reason


@pytest.mark.parametrize("n", [1, 2, 3])
@pytest.mark.parametrize("reaction_s", [1.0, 9.0])
def test_everyone_already_waiting_goes_first_in_order(n: int, reaction_s: float) -> None:
    """Sec. 12's bug: with n vehicles already standing at the other stop lines when we arrive, we wait
    until all n have crossed, however long that takes (9 s to react + 3 s to cross each: 36 s for
    three, well past any fixed 10 s), and never declare a driver stuck who takes < 10 s to start."""
    arrivals = [("v1", "E", -5.0), ("v2", "N", -4.0), ("v3", "W", -3.0)][:n]
    others = fifo_world(arrivals, reaction_s, cross_s=3.0)
    t_go, decision, log = run(others, own_arrive_s=0.0, until_s=60.0)
    last_cleared = max(o.enter_s + o.cross_s for o in others if o.enter_s is not None)
    assert t_go == pytest.approx(last_cleared, abs=DT_S + 1e-9)
    assert not decision.with_caution and decision.stuck == ()
    # Whom we waited for, in order: the head of `ahead` always the earliest arrival still waiting.
    heads = [d.ahead[0] for _, d in log if d.ahead]
    assert sorted(set(heads), key=heads.index) == [a[0] for a in arrivals]
    if n >= 2 and reaction_s == 9.0:
        assert t_go > n * PRECEDENCE_STUCK_S  # n x 10 s, not 10 s


def test_vehicles_arriving_after_us_wait_for_us() -> None:
    others = [Other("late1", "E", 0.6), Other("late2", "W", 3.0)]
    t_go, decision, _ = run(others, own_arrive_s=0.0, until_s=5.0)
    assert t_go == 0.0
    # ... also when they come while we are still waiting for an earlier one.
    others = [*fifo_world([("early", "N", -2.0)], 2.0, 3.0), Other("late", "E", 1.0)]
    t_go, decision, _ = run(others, own_arrive_s=0.0, until_s=20.0)
    assert t_go == pytest.approx(5.0)
    assert decision.may_go and "late" not in decision.waiting_for


def test_a_late_vehicle_going_out_of_turn_is_waited_for_in_the_box() -> None:
    # "early" has precedence and crosses 5..8 s; "rude" stopped after us but sneaks in at 6 s and is
    # in the box until 12 s: we wait for it too (the box must be clear), then go.
    others = [
        Other("early", "N", -2.0, enter_s=5.0, cross_s=3.0),
        Other("rude", "E", 1.0, enter_s=6.0, cross_s=6.0),
    ]
    t_go, decision, log = run(others, own_arrive_s=0.0, until_s=20.0)
    assert t_go == pytest.approx(12.0)
    assert any(d.crossing == ("rude",) and "box occupied by rude" in d.reason for _, d in log)
    assert not decision.with_caution


def test_a_vehicle_reported_late_but_stopped_before_us_goes_first() -> None:
    pm = manager()
    pm.arrive(0.0)
    assert pm.update(0.0, []).may_go
    # The tracker confirms a vehicle at N that has been standing there since -2 s: it goes first.
    d = pm.update(0.1, [WaitingVehicle("hidden", "N", -2.0)])
    assert not d.may_go and d.ahead == ("hidden",)


# --------------------------------------------------------------------------------------- ties


@pytest.mark.parametrize(("line", "first"), [("E", "them"), ("W", "us"), ("N", "us")])
def test_simultaneous_arrival_yields_to_the_right(line: str, first: str) -> None:
    pm = manager()
    pm.arrive(10.0)
    d = pm.update(10.5, [WaitingVehicle("x", line, 10.0 + PRECEDENCE_TIE_S * 0.8)])
    assert d.may_go == (first == "us")
    if first == "them":
        assert d.ahead == ("x",)


def test_just_outside_the_tie_window_arrival_order_decides() -> None:
    pm = manager()
    pm.arrive(10.0)
    assert pm.update(10.0, [WaitingVehicle("x", "W", 10.0 - PRECEDENCE_TIE_S - 0.01)]).ahead == ("x",)
    pm = manager()
    pm.arrive(10.0)
    assert pm.update(11.0, [WaitingVehicle("x", "E", 10.0 + PRECEDENCE_TIE_S + 0.01)]).may_go


# --------------------------------------------------------------------------------------- stuck and leaving


@pytest.mark.parametrize("n", [1, 2, 3])
def test_vehicles_that_never_move_cost_n_times_the_bound(n: int) -> None:
    others = [Other(f"s{i}", line, -5.0 + i) for i, line in enumerate(["E", "N", "W"][:n])]
    t_go, decision, log = run(others, own_arrive_s=0.0, until_s=60.0)
    assert t_go == pytest.approx(n * PRECEDENCE_STUCK_S, abs=1e-9)
    assert decision.with_caution
    assert decision.stuck == tuple(o.vid for o in others)
    assert "with caution" in decision.reason
    # The log says whose turn it was and for how long.
    assert any("s0's turn for 5.0 s" in d.reason for _, d in log)


def test_stuck_vehicle_then_a_normal_one() -> None:
    others = [Other("stuck", "E", -5.0), Other("normal", "N", -3.0, enter_s=12.0, cross_s=3.0)]
    t_go, decision, _ = run(others, own_arrive_s=0.0, until_s=40.0)
    # stuck declared at 10 s, normal's turn from 10 s, it goes at 12 s and leaves the box at 15 s.
    assert t_go == pytest.approx(15.0)
    assert decision.with_caution and decision.stuck == ("stuck",)


def test_vehicle_that_leaves_without_crossing_is_dropped() -> None:
    others = [Other("turns_away", "N", -3.0, vanish_s=4.0)]
    t_go, decision, _ = run(others, own_arrive_s=0.0, until_s=20.0)
    assert t_go == pytest.approx(4.0)
    assert not decision.with_caution


def test_busy_box_pauses_the_turn_clock() -> None:
    """A head-of-line vehicle is not blamed for waiting while someone else is crossing."""
    others = [Other("head", "E", -5.0), Other("crosser", "W", 5.0, enter_s=5.0, cross_s=8.0)]
    t_go, decision, _ = run(others, own_arrive_s=0.0, until_s=60.0)
    # head's clock: 0..5 s (5 s), paused 5..13 s, restarted at 13 s -> stuck at 23 s.
    assert t_go == pytest.approx(23.0)
    assert decision.stuck == ("head",)


def test_vehicle_stalled_in_the_box_is_bounded_too() -> None:
    pm = IntersectionPrecedence(LINES, "S", box_stuck_s=20.0)
    others = [Other("stalled", "N", -3.0, enter_s=-1.0, cross_s=1e9)]
    t_go, decision, _ = run(others, own_arrive_s=0.0, until_s=40.0, pm=pm)
    assert t_go == pytest.approx(20.0)  # 20 s after it was first seen in the box
    assert decision.with_caution and decision.stuck == ("stalled",)


def test_vehicle_at_our_own_line_is_ignored() -> None:
    pm = manager()
    pm.arrive(0.0)
    assert pm.update(0.1, [WaitingVehicle("behind", "S", -10.0)]).may_go


def test_vehicle_both_waiting_and_in_box_counts_as_in_box() -> None:
    pm = manager()
    pm.arrive(0.0)
    d = pm.update(0.1, [WaitingVehicle("x", "E", -3.0)], ["x"])
    assert d.ahead == () and d.crossing == ("x",)


# --------------------------------------------------------------------------------------- bad input


def test_bad_inputs_say_what_and_where() -> None:
    with pytest.raises(ValueError, match="own_stop_line_id 'Q'"):
        IntersectionPrecedence(LINES, "Q")
    with pytest.raises(ValueError, match="stuck_s"):
        IntersectionPrecedence(LINES, "S", stuck_s=-1.0)
    pm = manager()
    pm.arrive(1.0)
    with pytest.raises(ValueError, match="already arrived"):
        pm.arrive(2.0)
    with pytest.raises(ValueError, match=r"waiting\[1\] \('b'\): unknown stop_line_id 'X'"):
        pm.update(2.0, [WaitingVehicle("a", "E", 0.0), WaitingVehicle("b", "X", 0.0)])
    with pytest.raises(ValueError, match=r"arrived_s = 5\.0 must be finite and <= t_s"):
        pm.update(2.0, [WaitingVehicle("a", "E", 5.0)])
    with pytest.raises(ValueError, match="listed twice"):
        pm.update(2.0, [WaitingVehicle("a", "E", 0.0), WaitingVehicle("a", "E", 0.0)])
    pm.update(3.0, [])
    with pytest.raises(ValueError, match="before the last update"):
        pm.update(2.5, [])
    with pytest.raises(ValueError, match="t_s = nan"):
        pm.update(math.nan, [])


# --------------------------------------------------------------------------------------- properties

lines_other = st.sampled_from(["E", "N", "W"])


@settings(max_examples=60, deadline=None)
@given(
    arrivals=st.lists(
        st.tuples(lines_other, st.integers(-100, 100)), min_size=0, max_size=5, unique_by=lambda a: a[1]
    ),
    reaction_s=st.floats(0.5, 9.5),
    cross_s=st.floats(1.0, 6.0),
)
def test_well_behaved_drivers_all_go_before_us_in_order(
    arrivals: list[tuple[str, int]], reaction_s: float, cross_s: float
) -> None:
    """Random arrival sequences, drivers who take their turns in order and react in < 10 s: we go
    exactly when the last one who stopped before us has crossed, nobody is declared stuck, and
    whoever stopped after us (they wait for us) changes nothing."""
    # Arrival times on a 0.1 s grid, kept out of the tie window around ours (ties: own tests).
    own_arrive = 0.0
    timed = [(f"v{i}", line, k * 0.1) for i, (line, k) in enumerate(arrivals)]
    timed = [a for a in timed if abs(a[2] - own_arrive) > PRECEDENCE_TIE_S]
    before = [a for a in timed if a[2] < own_arrive]
    after = [Other(vid, line, arrive) for vid, line, arrive in timed if arrive > own_arrive]
    others = fifo_world(before, reaction_s, cross_s, own_arrive) + after
    horizon = 10.0 + len(before) * (reaction_s + cross_s + 1.0)
    t_go, decision, log = run(others, own_arrive, until_s=horizon)
    assert t_go is not None
    expected = max((o.enter_s + o.cross_s for o in others if o.enter_s is not None), default=own_arrive)
    assert t_go == pytest.approx(max(expected, own_arrive), abs=DT_S + 1e-9)
    assert decision.stuck == () and not decision.with_caution
    # Never did we go while an earlier vehicle was waiting or crossing.
    for t, d in log:
        blocking = [o.vid for o in others if o.arrive_s < own_arrive and (o.waiting(t) or o.in_box(t))]
        assert d.may_go == (not blocking and t >= own_arrive), (t, blocking, d)
    t_go_without_late, _, _ = run(
        fifo_world(before, reaction_s, cross_s, own_arrive), own_arrive, until_s=horizon
    )
    assert t_go_without_late == t_go


@settings(max_examples=60, deadline=None)
@given(
    script=st.lists(
        st.tuples(
            lines_other,
            st.integers(-150, 150),  # arrival, 0.1 s units
            st.sampled_from(["go", "stuck", "vanish"]),
            st.integers(0, 300),  # delay of the event after arrival, 0.1 s units
            st.integers(5, 80),  # crossing time, 0.1 s units
        ),
        min_size=0,
        max_size=6,
    ),
    own_arrive_k=st.integers(0, 50),
)
def test_invariants_in_any_world(script: list[tuple[str, int, str, int, int]], own_arrive_k: int) -> None:
    """Whatever the others do (out of order, stuck, vanishing, overlapping in the box):
    - we never go while a vehicle is in the box (for less than the stall bound);
    - we never go past an earlier vehicle still waiting unless it was declared stuck (and we say so);
    - no vehicle is declared stuck before it had a full stuck_s turn after our arrival;
    - once the world stops changing, we go within one stuck_s per vehicle still waiting before us."""
    own_arrive = round(own_arrive_k * DT_S, 9)  # on the world's clock grid
    others = []
    for i, (line, arrive_k, kind, delay_k, cross_k) in enumerate(script):
        arrive = arrive_k * DT_S
        event = arrive + delay_k * DT_S
        others.append(
            Other(
                f"v{i}",
                line,
                arrive,
                enter_s=event if kind == "go" else None,
                cross_s=cross_k * DT_S,
                vanish_s=event if kind == "vanish" else None,
            )
        )
    last_change = max(
        [own_arrive]
        + [o.arrive_s for o in others]
        + [o.enter_s + o.cross_s for o in others if o.enter_s is not None]
        + [o.vanish_s for o in others if o.vanish_s is not None]
    )
    earlier = [o for o in others if o.arrive_s < own_arrive - PRECEDENCE_TIE_S]
    horizon = max(last_change, own_arrive) + (len(others) + 1) * PRECEDENCE_STUCK_S + 1.0
    t_go, _, log = run(others, own_arrive, until_s=horizon)
    for t, d in log:
        if not d.may_go:
            continue
        assert not any(o.in_box(t) for o in others), t
        for o in earlier:
            if o.waiting(t):
                assert o.vid in d.stuck and d.with_caution
    first_stuck: dict[str, float] = {}
    for t, d in log:
        for vid in d.stuck:
            first_stuck.setdefault(vid, t)
    for rank, (_vid, t) in enumerate(sorted(first_stuck.items(), key=lambda kv: kv[1])):
        assert t >= own_arrive + (rank + 1) * PRECEDENCE_STUCK_S - 1e-9
    assert t_go is not None
    still_waiting = sum(1 for o in earlier if o.waiting(last_change) or o.arrive_s > last_change)
    tied_right = sum(1 for o in others if abs(o.arrive_s - own_arrive) <= PRECEDENCE_TIE_S and o.line == "E")
    assert (
        t_go <= max(last_change, own_arrive) + (still_waiting + tied_right) * PRECEDENCE_STUCK_S + DT_S + 1e-9
    )


# --------------------------------------------------------------------------------------- priority roads


def _v(vid: str, approach: Approach, prio: bool = True) -> ApproachingVehicle:
    return ApproachingVehicle(vid, approach, prio)


def test_on_the_priority_road_straight_or_right_drives_on() -> None:
    seen = [_v("o", Approach.ONCOMING), _v("l", Approach.FROM_LEFT, False)]
    for turn in (Turn.STRAIGHT, Turn.RIGHT):
        row = right_of_way(turn, True, seen)
        assert row.case == "b" and row.yield_to == () and not row.must_stop


def test_left_turn_from_the_priority_road_yields_to_oncoming_priority_traffic() -> None:
    seen = [
        _v("oncoming", Approach.ONCOMING),
        _v("side", Approach.FROM_RIGHT, False),
        _v("behind", Approach.SAME_DIRECTION),
    ]
    row = right_of_way(Turn.LEFT, True, seen)
    assert row.case == "c" and row.must_stop
    assert [(y.vehicle.vehicle_id, y.situation) for y in row.yield_to] == [
        ("oncoming", "intersection_left_turn")
    ]
    assert right_of_way(Turn.LEFT, True, seen[1:]).case == "b"  # nobody oncoming: drive inside


@pytest.mark.parametrize(
    ("turn", "expected"),
    [
        (Turn.RIGHT, {"left": "merge", "oncoming": "merge"}),
        (
            Turn.STRAIGHT,
            {
                "left": "intersection_crossing",
                "right": "intersection_crossing",
                "oncoming": "intersection_crossing",
            },
        ),
        (Turn.LEFT, {"left": "intersection_crossing", "right": "merge", "oncoming": "intersection_crossing"}),
    ],
)
def test_from_a_stop_road_every_crossed_priority_lane_has_the_right_of_way(
    turn: Turn, expected: dict[str, str]
) -> None:
    seen = [
        _v("left", Approach.FROM_LEFT),
        _v("right", Approach.FROM_RIGHT),
        _v("oncoming", Approach.ONCOMING),
        _v("behind", Approach.SAME_DIRECTION),
        _v("stopper", Approach.FROM_RIGHT, False),  # another stop road: precedence, not right of way
    ]
    row = right_of_way(turn, False, seen)
    assert row.case == "a" and row.must_stop
    assert {y.vehicle.vehicle_id: y.situation for y in row.yield_to} == expected


@settings(max_examples=200, deadline=None)
@given(
    snapshots=st.lists(
        st.tuples(
            st.floats(allow_nan=True, allow_infinity=True),
            st.lists(
                st.tuples(
                    st.sampled_from(["a", "b", "c"]),
                    st.sampled_from(["S", "E", "N", "W", "X"]),
                    st.floats(allow_nan=True, allow_infinity=True),
                ),
                max_size=4,
            ),
            st.lists(st.sampled_from(["a", "b", "c", "d"]), max_size=3),
        ),
        max_size=6,
    ),
    arrive=st.floats(allow_nan=True, allow_infinity=True),
)
def test_garbage_observations_give_a_decision_or_a_value_error(snapshots, arrive: float) -> None:
    pm = manager()
    with contextlib.suppress(ValueError):
        pm.arrive(arrive)
    for t, waiting, box in snapshots:
        try:
            d = pm.update(t, [WaitingVehicle(v, line, a) for v, line, a in waiting], box)
        except ValueError:
            continue
        assert isinstance(d.may_go, bool) and isinstance(d.reason, str)
