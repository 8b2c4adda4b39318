"""Moving-traffic check (seed 000 Sec. 9, eqs. 8-17): drive-off model, conditions, combination, properties."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from bywire.host.behaviour.mtc import (
    ConflictVehicle,
    DriveOff,
    check_vehicle,
    leave_time_s,
    moving_traffic_check,
    reach_time_s,
)
from bywire.host.behaviour.rules import MTC_SITUATIONS, MtcParams

CROSSING = MTC_SITUATIONS["intersection_crossing"]

# ----------------------------------------------------------------------------------------- drive-off


def test_drive_off_known_values() -> None:
    # From standstill to 5 m/s at 1 m/s²: t_sw = 5 s (eq. 9), 12.5 m in the ramp, then 5 m/s.
    a = DriveOff(0.0, 5.0, 1.0)
    assert a.switch_time_s == pytest.approx(5.0)
    assert a.switch_distance_m == pytest.approx(12.5)
    assert a.distance_m(2.0) == pytest.approx(2.0)  # a t² / 2
    assert a.distance_m(5.0) == pytest.approx(12.5)
    assert a.distance_m(7.0) == pytest.approx(22.5)  # 12.5 + 5 * 2
    assert a.time_to_travel_s(2.0) == pytest.approx(2.0)
    assert a.time_to_travel_s(22.5) == pytest.approx(7.0)
    assert a.distance_m(-1.0) == 0.0 and a.time_to_travel_s(-3.0) == 0.0
    assert a.distance_m(math.inf) == math.inf and a.time_to_travel_s(math.inf) == math.inf


def test_eq11_is_the_inverse_of_eq10s_second_branch() -> None:
    """The garbled "t^2 sw" of eq. 11 is t_sw²; eq. 11 as printed (with that reading) agrees with ours."""
    v0, vd, a_sat = 2.0, 8.0, 1.5
    model = DriveOff(v0, vd, a_sat)
    t_sw = (vd - v0) / a_sat
    for d in (30.0, 50.0, 100.0):
        t_a = (d - v0 * t_sw - (a_sat / 2.0) * t_sw**2) / (v0 + a_sat * t_sw) + t_sw  # eq. 11
        assert t_a > t_sw
        assert model.time_to_travel_s(d) == pytest.approx(t_a, rel=1e-12)
    # Eq. 12's first branch: (-v0 + sqrt(v0² + 2 a d)) / a for d inside the ramp.
    for d in (0.5, 5.0, 19.9):
        paper = (-v0 + math.sqrt(v0 * v0 + 2.0 * a_sat * d)) / a_sat
        assert model.time_to_travel_s(d) == pytest.approx(paper, rel=1e-12)


def test_drive_off_ramps_down_when_faster_than_desired() -> None:
    a = DriveOff(10.0, 4.0, 2.0)
    assert a.switch_time_s == pytest.approx(3.0)
    assert a.distance_m(3.0) == pytest.approx(10.0 * 3.0 - 0.5 * 2.0 * 9.0)
    assert a.distance_m(5.0) == pytest.approx(21.0 + 4.0 * 2.0)


@given(
    v0=st.floats(0.0, 20.0),
    vd=st.floats(0.1, 20.0),
    a_sat=st.floats(0.1, 5.0),
    t=st.floats(0.0, 60.0),
)
def test_drive_off_inverse_roundtrip_and_monotone(v0: float, vd: float, a_sat: float, t: float) -> None:
    a = DriveOff(v0, vd, a_sat)
    d = a.distance_m(t)
    assert d >= 0.0
    assert a.distance_m(t + 0.1) > d or t + 0.1 <= 0.0
    if d > 1e-9:
        assert a.time_to_travel_s(d) == pytest.approx(t, rel=1e-6, abs=1e-6)


def test_drive_off_rejects_bad_parameters() -> None:
    with pytest.raises(ValueError, match="v0_mps"):
        DriveOff(-1.0, 5.0, 1.0)
    with pytest.raises(ValueError, match="v_desired_mps"):
        DriveOff(0.0, 0.0, 1.0)
    with pytest.raises(ValueError, match="accel_sat_mps2"):
        DriveOff(0.0, 5.0, math.nan)


# ----------------------------------------------------------------------------------------- eq. 8


def test_eq8_reach_time() -> None:
    assert reach_time_s(30.0, 10.0) == pytest.approx(3.0)
    assert reach_time_s(30.0, 0.0) == math.inf  # v_B = 0: never arrives
    assert reach_time_s(-20.0, 10.0) == pytest.approx(-2.0)  # passed 2 s ago
    assert reach_time_s(-20.0, 0.0) == -math.inf
    assert reach_time_s(0.0, 0.0) == 0.0  # standing on it: there now
    assert leave_time_s(0.0, 0.0) == math.inf  # ... and never leaves
    assert leave_time_s(5.0, 5.0) == pytest.approx(1.0)


# ----------------------------------------------------------------------------------------- the conditions


def test_a_first_decided_by_eqs_13_and_14() -> None:
    # Standing 3 m before MP, B 100 m away at 10 m/s: B reaches MP in 10 s, we in sqrt(6) = 2.45 s.
    r = check_vehicle(0.0, ConflictVehicle(100.0, 10.0, 3.0, "B"), CROSSING)
    assert r.free and r.decided_by == "we_first"
    assert r.spatial_ab and r.temporal_ab
    assert r.t_a_mp_s == pytest.approx(math.sqrt(6.0))
    assert r.t_b_mp_s == pytest.approx(10.0)
    assert "free" in r.describe() and "we go first" in r.describe()


def test_b_first_decided_by_eqs_15_and_16() -> None:
    # B just past MP and leaving fast; we are 40 m away at 4.47 m/s.
    r = check_vehicle(4.47, ConflictVehicle(-2.0, 10.0, 40.0, "B"), CROSSING)
    assert r.free and r.decided_by == "they_first"
    assert r.spatial_ba and r.temporal_ba and not r.temporal_ab


def test_refusal_names_the_failed_conditions() -> None:
    r = check_vehicle(0.0, ConflictVehicle(40.0, 10.0, 3.0, "car7"), CROSSING)
    assert not r.free and r.decided_by == "refused"
    assert "temporal_ab (eq. 14)" in r.failed
    assert "car7: refused" in r.describe()


def test_stationary_b_never_arrives_before_its_window() -> None:
    # v_B = 0 before P_B1: it never enters the zone, we may go (eq. 8 gives t = inf).
    r = check_vehicle(0.0, ConflictVehicle(30.0, 0.0, 3.0), CROSSING)
    assert r.free and r.decided_by == "we_first"
    assert r.t_b_mp_s == math.inf


def test_stationary_b_inside_its_window_blocks_forever() -> None:
    for d_b in (CROSSING.d_b1_m, 0.0, -CROSSING.d_b2_m):  # at P_B1, on MP, exactly on P_B2
        r = check_vehicle(0.0, ConflictVehicle(d_b, 0.0, 3.0), CROSSING)
        assert not r.free, d_b
    # ... but once it stands beyond P_B2 it no longer matters.
    assert check_vehicle(0.0, ConflictVehicle(-CROSSING.d_b2_m - 0.1, 0.0, 3.0), CROSSING).free


def test_combination_needs_both_conditions_of_one_order() -> None:
    """The extracted `(spat_AB and temp_AB) or (spat_BA or temp_BA)` would approve this, into a collision.

    A slow B (1 m/s) 5 m before MP reaches MP in 5 s, we (50 m away at 5 m/s) in 10 s: the time gap
    at MP is fine (eq. 16), but B is inside its window [P_B1, P_B2] until t = 13 s while we pass
    through ours from 9.4 s to 11.6 s (eq. 15 fails).
    """
    params = CROSSING.with_desired_speed(5.0)
    vehicle = ConflictVehicle(5.0, 1.0, 50.0)
    r = check_vehicle(5.0, vehicle, params)
    garbled = (r.spatial_ab and r.temporal_ab) or (r.spatial_ba or r.temporal_ba)
    assert garbled
    assert r.temporal_ba and not r.spatial_ba
    assert not r.free
    overlap = _zone_overlap(5.0, vehicle, params, in_motion=False)
    assert overlap is not None and 9.3 < overlap < 11.6


# ----------------------------------------------------------------------------------------- simulation

SIM_DT_S = 1e-3


def _simulate(
    own_speed_mps: float, vehicle: ConflictVehicle, params: MtcParams, in_motion: bool, horizon_s: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Point masses on a fine time grid: A by integrating the drive-off speed profile (trapezoids, not
    the closed form under test), B at constant speed. Returns (t, A's position rel. MP, B's rel. MP)."""
    p = params.in_motion() if in_motion else params
    t = np.arange(0.0, horizon_s, SIM_DT_S)
    step = np.where(p.v_desired_mps >= own_speed_mps, 1.0, -1.0) * p.accel_sat_mps2 * t
    v_a = own_speed_mps + step
    v_a = (
        np.minimum(v_a, p.v_desired_mps)
        if p.v_desired_mps >= own_speed_mps
        else np.maximum(v_a, p.v_desired_mps)
    )
    x_a = np.concatenate(([0.0], np.cumsum(0.5 * (v_a[1:] + v_a[:-1]) * SIM_DT_S)))
    a_rel = x_a - vehicle.own_dist_to_mp_m
    b_rel = vehicle.speed_mps * t - vehicle.dist_to_mp_m
    return t, a_rel, b_rel


def _zone_overlap(
    own_speed_mps: float, vehicle: ConflictVehicle, params: MtcParams, in_motion: bool, tol_m: float = 1e-6
) -> float | None:
    """First time at which A is inside [P_A1, P_A2] while B is inside [P_B1, P_B2], or None."""
    p = params.in_motion() if in_motion else params
    horizon = _horizon_s(own_speed_mps, vehicle, p)
    t, a_rel, b_rel = _simulate(own_speed_mps, vehicle, params, in_motion, horizon)
    a_in = (a_rel >= -p.d_a1_m + tol_m) & (a_rel <= p.d_a2_m - tol_m)
    b_in = (b_rel >= -p.d_b1_m + tol_m) & (b_rel <= p.d_b2_m - tol_m)
    both = np.flatnonzero(a_in & b_in)
    return float(t[both[0]]) if both.size else None


def _horizon_s(own_speed_mps: float, vehicle: ConflictVehicle, p: MtcParams) -> float:
    """Until A is past P_A2: after that A is never inside its window again (it only moves forward)."""
    a = DriveOff(own_speed_mps, p.v_desired_mps, p.accel_sat_mps2)
    return a.time_to_travel_s(vehicle.own_dist_to_mp_m + p.d_a2_m) + 1.0


param_sets = st.one_of(
    st.sampled_from(list(MTC_SITUATIONS.values())),
    st.builds(
        MtcParams,
        d_a1_m=st.floats(0.0, 30.0),
        d_a2_m=st.floats(0.0, 30.0),
        d_b1_m=st.floats(0.0, 30.0),
        d_b2_m=st.floats(0.0, 30.0),
        gap_ab_s=st.floats(0.0, 8.0),
        gap_ba_s=st.floats(0.0, 8.0),
        accel_sat_mps2=st.floats(0.3, 3.0),
        v_desired_mps=st.floats(1.0, 15.0),
        hysteresis_factor=st.floats(0.5, 1.0),
    ),
)
vehicles = st.builds(
    ConflictVehicle,
    dist_to_mp_m=st.floats(-40.0, 150.0),
    speed_mps=st.one_of(st.just(0.0), st.floats(0.0, 20.0)),
    own_dist_to_mp_m=st.floats(-20.0, 80.0),
)


@settings(max_examples=300, deadline=None)
@given(own_speed=st.floats(0.0, 15.0), vehicle=vehicles, params=param_sets, in_motion=st.booleans())
def test_approval_is_conflict_free_in_simulation(
    own_speed: float, vehicle: ConflictVehicle, params: MtcParams, in_motion: bool
) -> None:
    """Sec. 9.2's promise: when the check approves, A is never inside [P_A1, P_A2] while B is inside
    [P_B1, P_B2], and the time gap at MP is at least the required one for the approved order."""
    r = check_vehicle(own_speed, vehicle, params, in_motion)
    if not r.free:
        return
    assert _zone_overlap(own_speed, vehicle, params, in_motion) is None
    p = params.in_motion() if in_motion else params
    # Time at MP: A's from the simulation (0 when already past), B's by constant-speed extrapolation.
    horizon = _horizon_s(own_speed, vehicle, p)
    t, a_rel, _ = _simulate(own_speed, vehicle, params, in_motion, horizon)
    reached = np.flatnonzero(a_rel >= 0.0)
    t_a = float(t[reached[0]]) if reached.size else math.inf
    d_b, v_b = vehicle.dist_to_mp_m, vehicle.speed_mps
    t_b = d_b / v_b if v_b > 0.0 else (math.inf if d_b > 0.0 else -math.inf)
    tol = 2.0 * SIM_DT_S
    if r.decided_by == "we_first":
        assert t_b - t_a >= p.gap_ab_s - tol
    else:
        assert t_a - t_b >= p.gap_ba_s - tol


def _moved(vehicle: ConflictVehicle, d_b: float, v_b: float) -> ConflictVehicle:
    return dataclasses.replace(vehicle, dist_to_mp_m=d_b, speed_mps=v_b)


@settings(max_examples=300, deadline=None)
@given(
    own_speed=st.floats(0.0, 15.0),
    vehicle=vehicles,
    params=param_sets,
    closer=st.floats(0.0, 50.0),
    faster=st.floats(0.0, 10.0),
)
def test_we_first_clause_is_monotone_in_the_threat(
    own_speed: float, vehicle: ConflictVehicle, params: MtcParams, closer: float, faster: float
) -> None:
    """A closer or faster B never turns a refusal of "we first" (eqs. 13 and 14) into an approval."""
    base = check_vehicle(own_speed, vehicle, params)
    threat = check_vehicle(
        own_speed, _moved(vehicle, vehicle.dist_to_mp_m - closer, vehicle.speed_mps + faster), params
    )
    if threat.spatial_ab and threat.temporal_ab:
        assert base.spatial_ab and base.temporal_ab


@settings(max_examples=300, deadline=None)
@given(
    own_speed=st.floats(0.0, 15.0),
    vehicle=vehicles,
    params=param_sets,
    farther=st.floats(0.0, 50.0),
    slower=st.floats(0.0, 1.0),
)
def test_they_first_clause_is_monotone_in_the_delay(
    own_speed: float, vehicle: ConflictVehicle, params: MtcParams, farther: float, slower: float
) -> None:
    """A B farther away, or (still before MP) slower, never turns a refusal of "B first" (eqs. 15 and
    16) into an approval. (Past MP a slower B passed MP longer ago, which rightly helps eq. 16.)"""
    assume(vehicle.dist_to_mp_m > 0.0)
    base = check_vehicle(own_speed, vehicle, params)
    later = check_vehicle(
        own_speed,
        _moved(vehicle, vehicle.dist_to_mp_m + farther, vehicle.speed_mps * (1.0 - slower)),
        params,
    )
    if later.spatial_ba and later.temporal_ba:
        assert base.spatial_ba and base.temporal_ba


def test_the_combined_check_is_not_monotone_in_bs_speed() -> None:
    """A fast B that clears the zone before we get there is fine; a slower one is not (documented)."""
    slow = check_vehicle(4.47, ConflictVehicle(20.0, 2.0, 40.0), CROSSING)
    fast = check_vehicle(4.47, ConflictVehicle(20.0, 10.0, 40.0), CROSSING)
    assert not slow.free
    assert fast.free and fast.decided_by == "they_first"


@settings(max_examples=200, deadline=None)
@given(
    own_speed=st.floats(0.0, 15.0),
    vehicle=vehicles,
    params=param_sets,
    grow=st.tuples(*[st.floats(0.0, 10.0)] * 6),
)
def test_stricter_parameters_never_approve_more(
    own_speed: float, vehicle: ConflictVehicle, params: MtcParams, grow: tuple[float, ...]
) -> None:
    stricter = dataclasses.replace(
        params,
        d_a1_m=params.d_a1_m + grow[0],
        d_a2_m=params.d_a2_m + grow[1],
        d_b1_m=params.d_b1_m + grow[2],
        d_b2_m=params.d_b2_m + grow[3],
        gap_ab_s=params.gap_ab_s + grow[4],
        gap_ba_s=params.gap_ba_s + grow[5],
    )
    if check_vehicle(own_speed, vehicle, stricter).free:
        assert check_vehicle(own_speed, vehicle, params).free


@settings(max_examples=200, deadline=None)
@given(own_speed=st.floats(0.0, 15.0), vehicle=vehicles, params=param_sets)
def test_hysteresis_never_refuses_what_standstill_approves(
    own_speed: float, vehicle: ConflictVehicle, params: MtcParams
) -> None:
    if check_vehicle(own_speed, vehicle, params, in_motion=False).free:
        assert check_vehicle(own_speed, vehicle, params, in_motion=True).free


def test_hysteresis_band() -> None:
    """Sec. 9.3: a go once moving is not withdrawn by a small change. B reaches MP 4.5 s after us:
    under Delta T_AB = 5 s at standstill, above 0.8 * 5 s = 4 s once in motion."""
    vehicle = ConflictVehicle(
        dist_to_mp_m=10.0 * (math.sqrt(6.0) + 4.5), speed_mps=10.0, own_dist_to_mp_m=3.0
    )
    assert not check_vehicle(0.0, vehicle, CROSSING, in_motion=False).free
    moving = check_vehicle(0.0, vehicle, CROSSING, in_motion=True)
    assert moving.free and moving.in_motion
    scaled = CROSSING.in_motion()
    assert scaled.gap_ab_s == pytest.approx(0.8 * CROSSING.gap_ab_s)
    assert scaled.d_b1_m == pytest.approx(0.8 * CROSSING.d_b1_m)
    assert scaled.accel_sat_mps2 == CROSSING.accel_sat_mps2


# ----------------------------------------------------------------------------------------- eq. 17


@settings(max_examples=200, deadline=None)
@given(
    own_speed=st.floats(0.0, 15.0),
    others=st.lists(vehicles, min_size=0, max_size=6),
    params=param_sets,
    in_motion=st.booleans(),
    seed=st.randoms(),
)
def test_n_vehicles_approve_only_if_each_does(
    own_speed: float, others: list[ConflictVehicle], params: MtcParams, in_motion: bool, seed
) -> None:
    total = moving_traffic_check(own_speed, others, params, in_motion)
    singles = [check_vehicle(own_speed, v, params, in_motion) for v in others]
    assert total.free == all(r.free for r in singles)
    assert [r.free for r in total.vehicles] == [r.free for r in singles]
    assert len(total.blocking) == sum(not r.free for r in singles)
    shuffled = list(others)
    seed.shuffle(shuffled)
    assert moving_traffic_check(own_speed, shuffled, params, in_motion).free == total.free
    # Adding a vehicle never turns a refusal into an approval.
    if others and not moving_traffic_check(own_speed, others[:-1], params, in_motion).free:
        assert not total.free


def test_we_may_go_between_two_vehicles() -> None:
    """Eq. 17 with one vehicle passing first and another arriving late: both pairwise checks hold
    along the one drive-off, so the gap between them is used."""
    before = ConflictVehicle(-9.0, 13.4, 3.0, "gone")  # just cleared P_B2
    after = ConflictVehicle(120.0, 13.4, 3.0, "coming")
    r = moving_traffic_check(0.0, [before, after], CROSSING)
    assert r.free
    assert [v.decided_by for v in r.vehicles] == ["they_first", "we_first"]
    assert moving_traffic_check(0.0, [], CROSSING).free


def test_per_vehicle_parameter_override() -> None:
    lane_change = MTC_SITUATIONS["lane_change"]
    v = ConflictVehicle(40.0, 10.0, 3.0, params=lane_change)
    assert check_vehicle(0.0, v, CROSSING) == check_vehicle(
        0.0, dataclasses.replace(v, params=None), lane_change
    )


# ----------------------------------------------------------------------------------------- errors


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("dist_to_mp_m", math.nan),
        ("own_dist_to_mp_m", math.inf),
        ("speed_mps", -0.5),
        ("speed_mps", math.nan),
    ],
)
def test_bad_inputs_name_the_field(field: str, value: float) -> None:
    v = dataclasses.replace(ConflictVehicle(10.0, 5.0, 3.0, "car3"), **{field: value})
    with pytest.raises(ValueError, match=field) as err:
        moving_traffic_check(0.0, [ConflictVehicle(50.0, 5.0, 3.0), v], CROSSING)
    assert "vehicles[1]" in str(err.value) and "car3" in str(err.value)
    with pytest.raises(ValueError, match="own_speed_mps"):
        check_vehicle(-1.0, ConflictVehicle(10.0, 5.0, 3.0), CROSSING)


@settings(max_examples=300, deadline=None)
@given(
    own_speed=st.floats(allow_nan=True, allow_infinity=True),
    d_b=st.floats(allow_nan=True, allow_infinity=True),
    v_b=st.floats(allow_nan=True, allow_infinity=True),
    d_a=st.floats(allow_nan=True, allow_infinity=True),
)
def test_any_float_input_gives_a_result_or_a_value_error(
    own_speed: float, d_b: float, v_b: float, d_a: float
) -> None:
    try:
        r = moving_traffic_check(own_speed, [ConflictVehicle(d_b, v_b, d_a)], CROSSING)
    except ValueError:
        return
    assert isinstance(r.free, bool)
