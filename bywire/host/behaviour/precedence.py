"""Four-way-stop precedence done right (seed 000 Secs. 9.3 case a and 12) and priority-road right of way.

`IntersectionPrecedence` answers, at a stop-sign intersection, "may we go?" and "whom are we waiting
for?". Seed 000 Sec. 12 reports the bug it replaces: AnnieWAY's state machine "omitted consideration
of other four-way-stop vehicles after 10 s", so with n vehicles already waiting it stopped 10 s instead
of n x 10 s. Here nothing is timed globally: every vehicle that has precedence over us is waited for
until it has gone, in its order, however many there are; a timer only ever runs for *one* vehicle,
the one whose turn it is, and only while the intersection box is clear.

Rules (California vehicle code as the Urban Challenge applies it; rules 5.2 "proper precedence order
at every intersection"; Sec. 9.3 case a: "all vehicles are registered that are already waiting on
another stop line that have the right-of-way"):

1. Precedence is by the time each vehicle came to a stop at its stop line (`arrived_s`, from the
   tracker), not by when we first saw it: a vehicle reported late, but stopped before us, still goes
   first. Vehicles that stopped before us (by more than `tie_s`) go before us, in arrival order.
2. Arrivals within `tie_s` of ours are simultaneous: the vehicle on our right goes first (yield to
   the right). One on our left yields to us; one opposite or on our own approach does not conflict by
   precedence (whether paths cross is the MTC's job, Sec. 9.3).
3. A vehicle that stops after us waits for us: it never delays our decision, unless it goes out of
   turn and is inside the box, where we wait until it has left.
4. A vehicle leaves the queue by entering the box (it took its turn; we then wait until it has left
   the box) or by disappearing from every stop line without entering the box (it turned away,
   reversed, or was a false track): either way we no longer wait for it.
5. Bounded waiting (ours): the vehicle whose turn it is (the first still waiting) gets `stuck_s`
   (rules.PRECEDENCE_STUCK_S) of uninterrupted clear box to start (its clock restarts after anyone
   else has crossed); if it has not moved by then it is declared stuck,
   we stop waiting for it, and the next one's turn begins at that instant. So n vehicles that never
   move cost at most n x stuck_s (each gets its full turn: this is the n x 10 s the paper asks for),
   after which we go *with caution* and the decision says so and lists them. A vehicle stalled in the
   box for `box_stuck_s` is treated the same way.

Observations arrive as snapshots (`update`): the vehicles seen stopped at stop lines with their
arrival times, and the vehicles inside the intersection box. The tracker's first arrival time of a
vehicle is kept while it stays at its line (later refinements would reorder a queue that is already
being served). A vehicle reported both at a stop line and in the box counts as in the box (it has
started). Vehicles at our own stop line (behind us) are ignored.

`right_of_way` covers priority roads (Sec. 9.3 cases b and c): which observed vehicles have the right
of way over our turn, and which MTC parameter set to check each of them with.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Literal

from .rules import INTERSECTION_BOX_STUCK_S, PRECEDENCE_STUCK_S, PRECEDENCE_TIE_S, MtcSituation

__all__ = [
    "Approach",
    "ApproachingVehicle",
    "IntersectionPrecedence",
    "PrecedenceDecision",
    "RightOfWay",
    "Side",
    "StopLine",
    "Turn",
    "WaitingVehicle",
    "YieldTo",
    "relative_side",
    "right_of_way",
]

Side = Literal["right", "left", "opposite", "same"]

# Timer comparisons forgive float rounding of sums of clock ticks (10 x 0.1 s is not exactly 1.0 s).
_TIME_EPS_S = 1e-9


def _wrap(angle_rad: float) -> float:
    return math.atan2(math.sin(angle_rad), math.cos(angle_rad))


def relative_side(own_heading_rad: float, other_heading_rad: float) -> Side:
    """Where another approach lies as seen from ours, from the two directions of travel at the lines.

    Driving north, the vehicle on our right comes from the east and drives west: its heading is ours
    turned +90 deg (counter-clockwise). Sectors of 90 deg around +90 (right), -90 (left), 180
    (opposite) and 0 (same approach).
    """
    diff = _wrap(other_heading_rad - own_heading_rad)
    quarter = math.pi / 4.0
    if abs(diff) <= quarter:
        return "same"
    if abs(diff) >= 3.0 * quarter:
        return "opposite"
    return "right" if diff > 0.0 else "left"


@dataclass(frozen=True)
class StopLine:
    """A stop line of the intersection and the direction of travel of a vehicle waiting at it."""

    line_id: str
    approach_heading_rad: float  # ENU, counter-clockwise from east, towards the intersection


@dataclass(frozen=True)
class WaitingVehicle:
    """A vehicle seen stopped at one of the intersection's stop lines."""

    vehicle_id: str
    stop_line_id: str
    arrived_s: float  # when it came to a stop at the line (tracker's estimate)


@dataclass(frozen=True)
class PrecedenceDecision:
    """The answer at one instant."""

    may_go: bool
    with_caution: bool  # we go only because vehicles were declared stuck (see `stuck`)
    ahead: tuple[str, ...]  # still waiting at their lines with precedence over us, in their order
    crossing: tuple[str, ...]  # inside the box (not stalled): we wait until they have left
    stuck: tuple[str, ...]  # declared stuck (never took their turn, or stalled in the box): skipped
    reason: str

    @property
    def waiting_for(self) -> tuple[str, ...]:
        """Everyone we are waiting for: first those with precedence, then those in the box."""
        return self.ahead + self.crossing


@dataclass
class _Waiter:
    stop_line_id: str
    arrived_s: float
    side: Side


class IntersectionPrecedence:
    """Precedence at one stop-sign intersection, for one crossing of ours (make a new one per crossing).

    Feed it snapshots with `update(t_s, waiting, in_box)` and call `arrive(t_s)` when we have stopped
    at our own line; each `update` returns the `PrecedenceDecision`. Times are seconds on one monotonic
    clock; they may not go backwards.
    """

    def __init__(
        self,
        stop_lines: Iterable[StopLine],
        own_stop_line_id: str,
        *,
        tie_s: float = PRECEDENCE_TIE_S,
        stuck_s: float = PRECEDENCE_STUCK_S,
        box_stuck_s: float = INTERSECTION_BOX_STUCK_S,
    ) -> None:
        self._lines = {line.line_id: line for line in stop_lines}
        if own_stop_line_id not in self._lines:
            raise ValueError(
                f"IntersectionPrecedence: own_stop_line_id {own_stop_line_id!r} is not one of the "
                f"stop lines {sorted(self._lines)}"
            )
        for line in self._lines.values():
            if not math.isfinite(line.approach_heading_rad):
                raise ValueError(f"StopLine {line.line_id!r}: approach_heading_rad must be finite")
        for name, value in (("tie_s", tie_s), ("stuck_s", stuck_s), ("box_stuck_s", box_stuck_s)):
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"IntersectionPrecedence: {name} = {value} must be finite and >= 0")
        self._own_line = own_stop_line_id
        self._own_heading = self._lines[own_stop_line_id].approach_heading_rad
        self._tie_s = tie_s
        self._stuck_s = stuck_s
        self._box_stuck_s = box_stuck_s
        self._own_arrived_s: float | None = None
        self._t_last_s = -math.inf
        self._waiting: dict[str, _Waiter] = {}
        self._box: dict[str, float] = {}  # vehicle id -> when first seen in the box
        self._stuck: dict[str, float] = {}  # vehicle id -> when declared stuck
        self._clock: tuple[str, float] | None = None  # (vehicle whose turn it is, when its turn began)

    # ------------------------------------------------------------------------------------ inputs

    @property
    def own_arrived_s(self) -> float | None:
        return self._own_arrived_s

    def arrive(self, t_s: float) -> None:
        """We have come to a stop at our own stop line at `t_s` (once per crossing)."""
        self._check_time("arrive", t_s)
        if self._own_arrived_s is not None:
            raise ValueError(
                f"IntersectionPrecedence.arrive({t_s}): we already arrived at {self._own_arrived_s}; "
                "make a new IntersectionPrecedence per crossing"
            )
        self._own_arrived_s = t_s
        self._t_last_s = t_s

    def update(
        self, t_s: float, waiting: Iterable[WaitingVehicle], in_box: Iterable[str] = ()
    ) -> PrecedenceDecision:
        """Take one snapshot of the intersection at `t_s` and decide."""
        self._check_time("update", t_s)
        box_now = set(in_box)
        seen: dict[str, WaitingVehicle] = {}
        for i, obs in enumerate(waiting):
            where = f"IntersectionPrecedence.update(t_s={t_s}): waiting[{i}] ({obs.vehicle_id!r})"
            if obs.stop_line_id not in self._lines:
                raise ValueError(
                    f"{where}: unknown stop_line_id {obs.stop_line_id!r}; known {sorted(self._lines)}"
                )
            if not math.isfinite(obs.arrived_s) or obs.arrived_s > t_s:
                raise ValueError(f"{where}: arrived_s = {obs.arrived_s} must be finite and <= t_s")
            if obs.vehicle_id in seen:
                raise ValueError(f"{where}: vehicle listed twice in one snapshot")
            if obs.stop_line_id == self._own_line or obs.vehicle_id in box_now:
                continue
            seen[obs.vehicle_id] = obs

        waiting_next: dict[str, _Waiter] = {}
        for vid, obs in seen.items():
            known = self._waiting.get(vid)
            if known is not None and known.stop_line_id == obs.stop_line_id:
                waiting_next[vid] = known  # keep the first arrival time (see module docstring)
            else:
                side = relative_side(self._own_heading, self._lines[obs.stop_line_id].approach_heading_rad)
                waiting_next[vid] = _Waiter(obs.stop_line_id, obs.arrived_s, side)
        self._waiting = waiting_next
        self._box = {vid: self._box.get(vid, t_s) for vid in box_now}
        self._t_last_s = t_s
        return self._decide(t_s)

    # ------------------------------------------------------------------------------------ logic

    def _check_time(self, what: str, t_s: float) -> None:
        if not math.isfinite(t_s):
            raise ValueError(f"IntersectionPrecedence.{what}: t_s = {t_s} must be finite")
        if t_s < self._t_last_s:
            raise ValueError(
                f"IntersectionPrecedence.{what}: t_s = {t_s} is before the last update at {self._t_last_s}"
            )

    def _has_precedence(self, w: _Waiter, own_arrived_s: float) -> bool:
        if w.arrived_s < own_arrived_s - self._tie_s:
            return True
        return abs(w.arrived_s - own_arrived_s) <= self._tie_s and w.side == "right"

    def _queue(self, own_arrived_s: float) -> list[str]:
        ahead = [vid for vid, w in self._waiting.items() if self._has_precedence(w, own_arrived_s)]
        # Earlier arrival first; within a tie the vehicle on our right is the only one ahead anyway.
        return sorted(ahead, key=lambda vid: (self._waiting[vid].arrived_s, vid))

    def _decide(self, t_s: float) -> PrecedenceDecision:
        own = self._own_arrived_s
        stalled = [vid for vid, since in self._box.items() if t_s - since >= self._box_stuck_s - _TIME_EPS_S]
        for vid in stalled:
            self._stuck.setdefault(vid, self._box[vid] + self._box_stuck_s)
        crossing = tuple(sorted(vid for vid in self._box if vid not in stalled))
        if own is None:
            self._clock = None
            return PrecedenceDecision(
                may_go=False,
                with_caution=False,
                ahead=(),
                crossing=crossing,
                stuck=(),
                reason="not stopped at our stop line yet",
            )

        queue = [vid for vid in self._queue(own) if vid not in self._stuck]
        if crossing or not queue:
            self._clock = None  # nobody's turn is being wasted while the box is busy
        else:
            if self._clock is None or self._clock[0] != queue[0]:
                self._clock = (queue[0], t_s)
            while self._clock is not None and t_s - self._clock[1] >= self._stuck_s - _TIME_EPS_S:
                vid, began_s = self._clock
                declared_s = began_s + self._stuck_s
                self._stuck[vid] = declared_s
                queue.pop(0)
                self._clock = (queue[0], declared_s) if queue else None

        # Stuck vehicles still present (at a line, or stalled in the box) are why we go with caution.
        stuck_present = tuple(
            vid
            for vid in sorted(self._stuck, key=lambda v: (self._stuck[v], v))
            if vid in self._waiting or vid in self._box
        )
        ahead = tuple(queue)
        may_go = not ahead and not crossing
        with_caution = may_go and bool(stuck_present)
        if may_go:
            reason = (
                f"our turn; going with caution past stuck vehicle(s) {', '.join(stuck_present)}"
                if with_caution
                else "our turn: nobody with precedence is waiting and the box is clear"
            )
        else:
            parts = []
            if ahead:
                turn = ""
                if self._clock is not None:
                    waited_s = t_s - self._clock[1]
                    turn = f" ({self._clock[0]}'s turn for {waited_s:.1f} s of {self._stuck_s:.0f} s)"
                parts.append(f"waiting for {', '.join(ahead)} with precedence{turn}")
            if crossing:
                parts.append(f"box occupied by {', '.join(crossing)}")
            reason = "; ".join(parts)
        return PrecedenceDecision(
            may_go=may_go,
            with_caution=with_caution,
            ahead=ahead,
            crossing=crossing,
            stuck=stuck_present,
            reason=reason,
        )


# ------------------------------------------------------------------------------------ priority roads


class Turn(StrEnum):
    """Our manoeuvre through the intersection."""

    LEFT = "left"
    STRAIGHT = "straight"
    RIGHT = "right"


class Approach(StrEnum):
    """Where an observed vehicle comes from, as seen from our approach."""

    ONCOMING = "oncoming"
    FROM_LEFT = "from_left"
    FROM_RIGHT = "from_right"
    SAME_DIRECTION = "same_direction"


@dataclass(frozen=True)
class ApproachingVehicle:
    """An observed vehicle approaching or inside the intersection."""

    vehicle_id: str
    approach: Approach
    on_priority_road: bool


@dataclass(frozen=True)
class YieldTo:
    """A vehicle with the right of way over our manoeuvre and the MTC parameter set to check it with."""

    vehicle: ApproachingVehicle
    situation: str  # a key of rules.MTC_SITUATIONS


@dataclass(frozen=True)
class RightOfWay:
    """Sec. 9.3 cases a-c: whom we must yield to (each must pass the MTC before we go)."""

    yield_to: tuple[YieldTo, ...]
    case: Literal[
        "a", "b", "c"
    ]  # a: we are on a stop road; b: priority road, nobody to yield to; c: we yield

    @property
    def must_stop(self) -> bool:
        """Case a stops at the stop line; case c stops before crossing the opposing lane; b drives on."""
        return self.case != "b"


# What we cross or merge into, per turn, for traffic on the priority road (right-hand traffic): the
# near lane carries traffic from our left, the far lane traffic from our right; an oncoming vehicle
# may go straight across a left turn of ours or turn left into the lane we turn right into.
_FROM_STOP_ROAD: dict[Turn, dict[Approach, str]] = {
    Turn.RIGHT: {Approach.FROM_LEFT: MtcSituation.MERGE, Approach.ONCOMING: MtcSituation.MERGE},
    Turn.STRAIGHT: {
        Approach.FROM_LEFT: MtcSituation.INTERSECTION_CROSSING,
        Approach.FROM_RIGHT: MtcSituation.INTERSECTION_CROSSING,
        Approach.ONCOMING: MtcSituation.INTERSECTION_CROSSING,
    },
    Turn.LEFT: {
        Approach.FROM_LEFT: MtcSituation.INTERSECTION_CROSSING,
        Approach.FROM_RIGHT: MtcSituation.MERGE,
        Approach.ONCOMING: MtcSituation.INTERSECTION_CROSSING,
    },
}


def right_of_way(
    own_turn: Turn, own_on_priority_road: bool, vehicles: Sequence[ApproachingVehicle]
) -> RightOfWay:
    """Which observed vehicles have the right of way over our turn (Sec. 9.3 cases a-c).

    On the priority road (cases b/c) only a left turn yields, to oncoming priority traffic
    (`intersection_left_turn`). From a stop road (case a; precedence among the stop roads is
    `IntersectionPrecedence`'s) every priority vehicle whose lane we cross or merge into has the right
    of way. Vehicles in our own direction are the following controller's business and never listed;
    stop-road vehicles never have the right of way over a priority-road vehicle.
    """
    if own_on_priority_road:
        if own_turn != Turn.LEFT:
            return RightOfWay(yield_to=(), case="b")
        listed = tuple(
            YieldTo(v, MtcSituation.INTERSECTION_LEFT_TURN)
            for v in vehicles
            if v.on_priority_road and v.approach == Approach.ONCOMING
        )
        return RightOfWay(yield_to=listed, case="c" if listed else "b")
    conflicts = _FROM_STOP_ROAD[own_turn]
    listed = tuple(
        YieldTo(v, conflicts[v.approach]) for v in vehicles if v.on_priority_road and v.approach in conflicts
    )
    return RightOfWay(yield_to=listed, case="a")
