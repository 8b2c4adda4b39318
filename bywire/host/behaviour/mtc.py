"""The moving-traffic check (MTC) of seed 000 Sec. 9 (eqs. 8-17): may we enter a conflict zone now?

Sec. 9.1 reduces a dynamic manoeuvre (merging, crossing, turning left across traffic, lane change,
passing) to a static one: every other vehicle B keeps its speed (assumption 1) along the centre of
its lane (2); we, A, drive off with a known constant acceleration up to the manoeuvre speed (3);
positions and speeds are known (4). Everything is one-dimensional: d_A and d_B are the distances to
the merge point MP along each vehicle's own path (negative once past it), v_A and v_B the speeds
along it (Fig. 14). The zone we may not share with B is the pair of windows [P_A1, P_A2] on our path
and [P_B1, P_B2] on B's: P_X1 lies D_X1 before MP, P_X2 lies D_X2 after it.

B, eq. 8: the time to reach a point d ahead is t = d / v_B. v_B = 0 means "never" (t = +inf) for a
point ahead; a point B has already reached (d <= 0) was reached at t = d / v_B <= 0 (constant-speed
extrapolation backwards; -inf for a B standing past it). *Leaving* the closed window at P_B2 needs
B to pass P_B2: a B standing exactly on P_B2 never leaves (inf), one past it has left.

A, eqs. 9-12 (`DriveOff`): the speed ramps linearly from v_0 to v_d at a_sat, then stays (Fig. 12):
t_sw = (v_d - v_0) / a_sat (eq. 9) and

    d_AP(t) = v_0 t + a_sat t² / 2                                         t <= t_sw
            = v_0 t_sw + a_sat t_sw² / 2 + v_d (t - t_sw)                   t >  t_sw     (eq. 10)

The extracted eq. 11 reads "t_a = (d - v_0 t_sw - (a_sat/2) t^2 sw) / (v_0 + a_sat t_sw) + t_sw":
the stray "t^2 sw" is t_sw², and v_0 + a_sat t_sw = v_d, so eq. 11 is the inverse of the second
branch of eq. 10, t_a = t_sw + (d - d_sw) / v_d with d_sw = d_AP(t_sw) = (v_0 + v_d) t_sw / 2. Eq.
12 takes t_a when t_a > t_sw (equivalently d > d_sw) and otherwise the positive root of the first
branch, (-v_0 + sqrt(v_0² + 2 a_sat d)) / a_sat ("the ambiguity of the solution was resolved": the
other root is negative). We evaluate that root as 2 d / (v_0 + sqrt(v_0² + 2 a d)), the same number
without the cancellation at small a d / v_0², and defined for a < 0. Deviation (as in AnnieWAY's
published code): when v_0 > v_d the ramp goes *down* to v_d at the same |a_sat| (t_sw = |v_d - v_0|
/ a_sat); the paper only drives off. Times and distances are clamped at 0: where we were before now
does not matter (d_AP(t < 0) = 0; a point we already passed is reached at t = 0).

Conditions (eqs. 13-16), with t_B1 the time B enters its window (reaches P_B1), t_B2 the time it
leaves it (passes P_B2), t_AMP / t_BMP the times at MP:

    we first,  spatial  (13): d_AP(max(t_B1, 0)) > d_A + D_A2     (beyond P_A2 when B enters; d_AP(inf) = inf)
    we first,  temporal (14): t_BMP > t_AMP + Delta T_AB
    they first, spatial (15): t_B2 < 0  or  d_AP(t_B2) < d_A - D_A1   (not yet at P_A1 when B leaves)
    they first, temporal(16): t_AMP > t_BMP + Delta T_BA

Eq. 15's "t_B2 < 0" case is ours (the paper's text only has the second part): once B has left its
window it no longer matters where we are, e.g. when we already stand inside our own window at a stop
line that is closer to MP than D_A1 (AnnieWAY's code has the same special case).

Combination: the extracted text reads free = (spat_AB and temp_AB) or (spat_BA **or** temp_BA).
That cannot be right: it would let the temporal condition (16) alone approve, i.e. a slow B that
reached MP early enough but is still inside its window [P_B1, P_B2] while we drive through ours,
and the paper's own sentence after the formula ("it is ensured that neither is A between P_A1 and
P_A2 as long as B is between P_B1 and P_B2 nor are the time gaps in MP shorter than permitted")
needs both conditions of the chosen order. Sec. 9.2 says the same: "both spatial and temporal
conditions have to be fulfilled at the same time". So

    free = (spat_AB and temp_AB) or (spat_BA and temp_BA)

(tests/host/behaviour/test_behaviour_mtc.py shows a case the garbled form approves into a collision). Why
it holds: d_AP is non-decreasing in t, B's position increasing (or constant), so (13) puts us beyond P_A2
for every t >= t_B1, i.e. whenever B is inside its window, and (15) keeps us before P_A1 for every t <=
t_B2; (14) and (16) are the time gaps at MP themselves. Both orders cannot hold at once (Delta T >= 0).

n vehicles (eq. 17): free_tot = free_1 and ... and free_n. Every pairwise check uses the same drive-off
of ours, so each approved pair is conflict-free along that one trajectory, whatever order it approves
(we may go between two vehicles: after B_1, before B_2).

Hysteresis (Sec. 9.3): once we have set ourselves in motion the requirements are "slightly reduced":
every D and Delta T is multiplied by h (`MtcParams.hysteresis_factor`, 0.8 in AnnieWAY's code), so a
go decision does not flicker back to stop on measurement noise. The caller says `in_motion=True` once
it has started the manoeuvre on a go of this check.

Monotonicity, stated exactly (tests check it): the we-first clause never turns from refused to free
when a B comes closer or faster; the they-first clause never does when B comes farther, or, while B
is still before MP, slower (past MP a slower B passed MP longer ago, which rightly helps eq. 16); the
whole check never does when any D or Delta T grows or a vehicle is added. The combined check is
*not* monotone in B's speed or distance: a B fast enough to clear the zone before we reach it is
approved (they first) where a slower one is refused; that is the model, not a defect.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Literal

from .rules import MtcParams

__all__ = [
    "ConflictVehicle",
    "DriveOff",
    "MtcDecision",
    "MtcResult",
    "MtcVehicleResult",
    "check_vehicle",
    "leave_time_s",
    "moving_traffic_check",
    "reach_time_s",
]

MtcDecision = Literal["we_first", "they_first", "refused"]


@dataclass(frozen=True)
class DriveOff:
    """Our (A's) drive-off model, eqs. 9-12: speed ramps from v_0 to v_d at |a_sat|, then holds v_d."""

    v0_mps: float
    v_desired_mps: float
    accel_sat_mps2: float
    _accel: float = field(init=False, repr=False, compare=False)
    _t_sw: float = field(init=False, repr=False, compare=False)
    _d_sw: float = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.v0_mps) and self.v0_mps >= 0.0):
            raise ValueError(f"DriveOff.v0_mps = {self.v0_mps}: must be finite and >= 0 (forward only)")
        if not (math.isfinite(self.v_desired_mps) and self.v_desired_mps > 0.0):
            raise ValueError(f"DriveOff.v_desired_mps = {self.v_desired_mps}: must be finite and > 0")
        if not (math.isfinite(self.accel_sat_mps2) and self.accel_sat_mps2 > 0.0):
            raise ValueError(f"DriveOff.accel_sat_mps2 = {self.accel_sat_mps2}: must be finite and > 0")
        # Derived once: the check evaluates the model several times per vehicle.
        accel = self.accel_sat_mps2 if self.v_desired_mps >= self.v0_mps else -self.accel_sat_mps2
        t_sw = abs(self.v_desired_mps - self.v0_mps) / self.accel_sat_mps2
        object.__setattr__(self, "_accel", accel)
        object.__setattr__(self, "_t_sw", t_sw)
        object.__setattr__(self, "_d_sw", 0.5 * (self.v0_mps + self.v_desired_mps) * t_sw)

    @property
    def switch_time_s(self) -> float:
        """t_sw of eq. 9 (|v_d - v_0| / a_sat: also a ramp down when v_0 > v_d)."""
        return self._t_sw

    @property
    def switch_distance_m(self) -> float:
        """d_sw = d_AP(t_sw) = (v_0 + v_d) t_sw / 2."""
        return self._d_sw

    def distance_m(self, t_s: float) -> float:
        """d_AP(t), eq. 10: distance travelled t seconds from now (0 for t <= 0, inf for t = inf)."""
        if t_s <= 0.0:
            return 0.0
        if math.isinf(t_s):
            return math.inf
        t_sw = self._t_sw
        if t_s <= t_sw:
            return self.v0_mps * t_s + 0.5 * self._accel * t_s * t_s
        return self._d_sw + self.v_desired_mps * (t_s - t_sw)

    def time_to_travel_s(self, distance_m: float) -> float:
        """t_AP(d), eqs. 11-12: time to travel `distance_m` (0 for d <= 0, inf for d = inf)."""
        if distance_m <= 0.0:
            return 0.0
        if math.isinf(distance_m):
            return math.inf
        d_sw = self._d_sw
        if distance_m > d_sw:  # eq. 11: t_a > t_sw
            return self._t_sw + (distance_m - d_sw) / self.v_desired_mps
        # Eq. 12's root, written as 2d / (v_0 + sqrt(v_0² + 2 a d)); the radicand is >= v_d² > 0 here.
        v0 = self.v0_mps
        root = math.sqrt(max(v0 * v0 + 2.0 * self._accel * distance_m, 0.0))
        return 2.0 * distance_m / (v0 + root)


def reach_time_s(distance_m: float, speed_mps: float) -> float:
    """Eq. 8, t = d / v_B: when a constant-speed vehicle reaches a point `distance_m` ahead.

    +inf when it stands before the point; a point already reached gives t <= 0 (d / v_B, extrapolated
    backwards; -inf for a vehicle standing past it, 0 for one standing on it).
    """
    if distance_m > 0.0:
        return distance_m / speed_mps if speed_mps > 0.0 else math.inf
    if speed_mps > 0.0:
        return distance_m / speed_mps
    return -math.inf if distance_m < 0.0 else 0.0


def leave_time_s(distance_m: float, speed_mps: float) -> float:
    """When a constant-speed vehicle passes *beyond* a point `distance_m` ahead (leaves a closed window).

    Like `reach_time_s`, except that a vehicle standing on the point never leaves it (+inf).
    """
    if speed_mps <= 0.0 and distance_m == 0.0:
        return math.inf
    return reach_time_s(distance_m, speed_mps)


@dataclass(frozen=True)
class ConflictVehicle:
    """One other vehicle B_i as the MTC sees it, with the conflict's merge point MP (Fig. 14).

    `params` overrides the check's parameter set for this vehicle (e.g. the oncoming lane of a left
    turn and the lane we merge into are two conflicts of one manoeuvre).
    """

    dist_to_mp_m: float  # d_B: B's front bumper to MP along B's path; negative once past MP
    speed_mps: float  # v_B >= 0 along B's path (assumption 1: constant)
    own_dist_to_mp_m: float  # d_A: our front bumper to this MP along our path; negative once past
    vehicle_id: str = ""
    params: MtcParams | None = None


@dataclass(frozen=True)
class MtcVehicleResult:
    """The verdict for one B, with every condition and time that went into it (for logs and tests)."""

    vehicle_id: str
    free: bool
    decided_by: MtcDecision  # the clause that approved, or "refused"
    spatial_ab: bool  # eq. 13
    temporal_ab: bool  # eq. 14
    spatial_ba: bool  # eq. 15
    temporal_ba: bool  # eq. 16
    t_a_mp_s: float  # t_AMP: we reach MP
    t_b_mp_s: float  # t_BMP: B reaches MP (eq. 8)
    t_b_enter_s: float  # t_B1: B reaches P_B1
    t_b_leave_s: float  # t_B2: B passes P_B2
    in_motion: bool  # the reduced (hysteresis) requirements were used

    @property
    def failed(self) -> tuple[str, ...]:
        """Names of the conditions that failed, e.g. ("spatial_ab (eq. 13)", "temporal_ba (eq. 16)")."""
        names = (
            ("spatial_ab (eq. 13)", self.spatial_ab),
            ("temporal_ab (eq. 14)", self.temporal_ab),
            ("spatial_ba (eq. 15)", self.spatial_ba),
            ("temporal_ba (eq. 16)", self.temporal_ba),
        )
        return tuple(name for name, ok in names if not ok)

    def describe(self) -> str:
        """One line for a log."""
        who = self.vehicle_id or "B"
        times = f"t_AMP {self.t_a_mp_s:.2f} s, t_BMP {self.t_b_mp_s:.2f} s"
        if self.free:
            order = "we go first" if self.decided_by == "we_first" else f"{who} goes first"
            return f"{who}: free ({order}; {times})"
        return f"{who}: refused ({', '.join(self.failed)} failed; {times})"


@dataclass(frozen=True)
class MtcResult:
    """Eq. 17: free only if every vehicle's check is free (vacuously free without vehicles)."""

    free: bool
    vehicles: tuple[MtcVehicleResult, ...]

    @property
    def blocking(self) -> tuple[MtcVehicleResult, ...]:
        return tuple(r for r in self.vehicles if not r.free)


def _validate(vehicle: ConflictVehicle, index: int | None) -> None:
    d_b, d_a, v_b = vehicle.dist_to_mp_m, vehicle.own_dist_to_mp_m, vehicle.speed_mps
    if math.isfinite(d_b) and math.isfinite(d_a) and math.isfinite(v_b) and v_b >= 0.0:
        return  # the hot path: no message built
    where = f"ConflictVehicle({vehicle.vehicle_id!r})"
    if index is not None:
        where = f"vehicles[{index}] ({vehicle.vehicle_id!r})"
    for name, value in (("dist_to_mp_m", d_b), ("own_dist_to_mp_m", d_a), ("speed_mps", v_b)):
        if not math.isfinite(value):
            raise ValueError(f"{where}.{name} = {value}: must be finite")
    raise ValueError(
        f"{where}.speed_mps = {v_b}: must be >= 0 along B's path "
        "(assumption 1; clamp tracker noise before the check)"
    )


def _check_own_speed(own_speed_mps: float) -> None:
    if not (math.isfinite(own_speed_mps) and own_speed_mps >= 0.0):
        raise ValueError(f"MTC own_speed_mps = {own_speed_mps}: must be finite and >= 0 (forward only)")


class _Prepared:
    """The effective parameter set and our drive-off model per distinct MtcParams of one call (the
    hysteresis scaling and the model are built once, not per vehicle)."""

    def __init__(self, own_speed_mps: float, in_motion: bool) -> None:
        self._own_speed_mps = own_speed_mps
        self._in_motion = in_motion
        self._cache: dict[int, tuple[MtcParams, MtcParams, DriveOff]] = {}

    def get(self, params: MtcParams) -> tuple[MtcParams, DriveOff]:
        hit = self._cache.get(id(params))
        if hit is None or hit[0] is not params:
            p = params.in_motion() if self._in_motion else params
            hit = (params, p, DriveOff(self._own_speed_mps, p.v_desired_mps, p.accel_sat_mps2))
            self._cache[id(params)] = hit
        return hit[1], hit[2]


def _check(vehicle: ConflictVehicle, p: MtcParams, a: DriveOff, in_motion: bool) -> MtcVehicleResult:
    d_a, d_b, v_b = vehicle.own_dist_to_mp_m, vehicle.dist_to_mp_m, vehicle.speed_mps

    t_b_enter = reach_time_s(d_b - p.d_b1_m, v_b)
    t_b_leave = leave_time_s(d_b + p.d_b2_m, v_b)
    t_b_mp = reach_time_s(d_b, v_b)
    t_a_mp = a.time_to_travel_s(d_a)

    spatial_ab = a.distance_m(max(t_b_enter, 0.0)) > d_a + p.d_a2_m
    temporal_ab = t_b_mp > t_a_mp + p.gap_ab_s
    spatial_ba = t_b_leave < 0.0 or a.distance_m(t_b_leave) < d_a - p.d_a1_m
    temporal_ba = t_a_mp > t_b_mp + p.gap_ba_s

    decided_by: MtcDecision = "refused"
    if spatial_ab and temporal_ab:
        decided_by = "we_first"
    elif spatial_ba and temporal_ba:
        decided_by = "they_first"
    return MtcVehicleResult(
        vehicle_id=vehicle.vehicle_id,
        free=decided_by != "refused",
        decided_by=decided_by,
        spatial_ab=spatial_ab,
        temporal_ab=temporal_ab,
        spatial_ba=spatial_ba,
        temporal_ba=temporal_ba,
        t_a_mp_s=t_a_mp,
        t_b_mp_s=t_b_mp,
        t_b_enter_s=t_b_enter,
        t_b_leave_s=t_b_leave,
        in_motion=in_motion,
    )


def check_vehicle(
    own_speed_mps: float, vehicle: ConflictVehicle, params: MtcParams, in_motion: bool = False
) -> MtcVehicleResult:
    """Eqs. 8-16 for one other vehicle: may we (speed v_A, driving off per `params`) enter now?

    `vehicle.params`, when set, replaces `params`. `in_motion`: we have already set ourselves in motion
    on an earlier go, so the reduced requirements apply (Sec. 9.3 hysteresis). Pure; raises ValueError
    naming the field for non-finite inputs or negative speeds.
    """
    _check_own_speed(own_speed_mps)
    _validate(vehicle, None)
    p, a = _Prepared(own_speed_mps, in_motion).get(vehicle.params or params)
    return _check(vehicle, p, a, in_motion)


def moving_traffic_check(
    own_speed_mps: float,
    vehicles: Iterable[ConflictVehicle],
    params: MtcParams,
    in_motion: bool = False,
) -> MtcResult:
    """Eq. 17: the check for every vehicle B_i; free only if each is free. Every vehicle is evaluated
    (no short cut) so that the log shows all of them. Validates all inputs before checking any."""
    _check_own_speed(own_speed_mps)
    listed = tuple(vehicles)
    for i, vehicle in enumerate(listed):
        _validate(vehicle, i)
    prepared = _Prepared(own_speed_mps, in_motion)
    results = tuple(_check(v, *prepared.get(v.params or params), in_motion) for v in listed)
    return MtcResult(free=all(r.free for r in results), vehicles=results)
