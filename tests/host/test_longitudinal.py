"""Longitudinal override controller (seed 000 Sec. 11.2) in closed loop on a lagged double integrator."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.host.longitudinal import (
    MPH10_MPS,
    LeadObservation,
    LongitudinalInputs,
    LongitudinalParams,
    LongitudinalState,
    following_accel,
    longitudinal_step,
    position_accel,
    stopping_accel,
    stopping_required_decel,
)

PARAMS = LongitudinalParams()
CONTROL_DT_S = 0.02  # the host agent's 50 Hz
PLANT_SUBSTEPS = 10
ACTUATOR_LAG_S = 0.3


@dataclass
class Trace:
    t_s: list[float] = field(default_factory=list)
    x_m: list[float] = field(default_factory=list)
    v_mps: list[float] = field(default_factory=list)
    accel_cmd_mps2: list[float] = field(default_factory=list)
    active: list[str] = field(default_factory=list)
    stopping_active: list[bool] = field(default_factory=list)
    gap_m: list[float] = field(default_factory=list)

    def switches(self, series: list) -> int:
        return sum(1 for a, b in itertools.pairwise(series) if a != b)

    def sequence(self) -> list[str]:
        seq: list[str] = []
        for a in self.active:
            if not seq or seq[-1] != a:
                seq.append(a)
        return seq


def simulate(
    duration_s: float,
    v0_mps: float,
    v_des_mps: float,
    params: LongitudinalParams = PARAMS,
    lead: tuple[float, float] | None = None,
    lead_accel: Callable[[float], float] = lambda _t: 0.0,
    stop_line_m: float | None = None,
    speed_noise_mps: float = 0.0,
    seed: int = 0,
) -> Trace:
    """Ego: x' = v, v' = a_act (brakes stop at v = 0), a_act' = (a_cmd - a_act) / 0.3 s.

    `lead` = (initial bumper-to-bumper gap, initial speed); the lead accelerates with lead_accel(t)
    and cannot reverse either. The controller runs every 20 ms with a zero-order hold.
    """
    rng = np.random.default_rng(seed)
    x, v, a_act, t = 0.0, v0_mps, 0.0, 0.0
    x_lead, v_lead = (lead[0], lead[1]) if lead is not None else (math.inf, 0.0)
    state = LongitudinalState()
    trace = Trace()
    h = CONTROL_DT_S / PLANT_SUBSTEPS
    for _ in range(round(duration_s / CONTROL_DT_S)):
        v_meas = v + (rng.normal(0.0, speed_noise_mps) if speed_noise_mps else 0.0)
        obs = LeadObservation(gap_m=x_lead - x, v_lead_mps=v_lead) if lead is not None else None
        stop = stop_line_m - x if stop_line_m is not None else None
        state, a_cmd, active = longitudinal_step(
            state, LongitudinalInputs(v_meas, v_des_mps, obs, stop), params
        )
        trace.t_s.append(t)
        trace.x_m.append(x)
        trace.v_mps.append(v)
        trace.accel_cmd_mps2.append(a_cmd)
        trace.active.append(active)
        trace.stopping_active.append(state.stopping_active)
        trace.gap_m.append(x_lead - x)
        for _ in range(PLANT_SUBSTEPS):
            a_act += (a_cmd - a_act) * h / ACTUATOR_LAG_S
            v = max(v + a_act * h, 0.0)
            x += v * h
            if lead is not None:
                v_lead = max(v_lead + lead_accel(t) * h, 0.0)
                x_lead += v_lead * h
            t += h
    return trace


def assert_saturated(trace: Trace, params: LongitudinalParams = PARAMS) -> None:
    assert all(params.accel_min_mps2 <= a <= params.accel_max_mps2 for a in trace.accel_cmd_mps2)


# --- gains and parameters ---------------------------------------------------------------------


def test_following_gains_give_a_double_eigenvalue_at_minus_one() -> None:
    c0, c1, tau = PARAMS.follow_c0_per_s2, PARAMS.follow_c1_per_s, PARAMS.follow_tau_s
    assert c0 == pytest.approx(1.0)
    assert c1 == pytest.approx(2.0 - tau)
    # Eq 28: lambda² + (c0 tau + c1) lambda + c0.
    roots = np.roots([1.0, c0 * tau + c1, c0])
    assert roots == pytest.approx([-1.0, -1.0], abs=1e-6)


def test_following_gains_for_another_eigenvalue() -> None:
    params = LongitudinalParams(follow_eigenvalue_per_s=1.5, follow_tau_s=0.8)
    c0, c1 = params.follow_c0_per_s2, params.follow_c1_per_s
    assert np.roots([1.0, c0 * 0.8 + c1, c0]) == pytest.approx([-1.5, -1.5], abs=1e-6)


def test_darpa_separation_one_length_plus_one_per_10_mph() -> None:
    length_m = PARAMS.follow_d0_m
    assert length_m == pytest.approx(4.77)
    # At 10 mph the desired gap is two vehicle lengths, at 20 mph three.
    for n in (1, 2):
        desired = PARAMS.follow_d0_m + PARAMS.follow_tau_s * n * MPH10_MPS
        assert desired == pytest.approx((n + 1) * length_m)
    other = LongitudinalParams.for_vehicle_length(5.5)
    assert other.follow_d0_m == 5.5 and other.follow_tau_s == pytest.approx(5.5 / MPH10_MPS)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"follow_tau_s": 2.5}, "c1 = 2 omega"),
        ({"stop_decel_off_mps2": 3.0}, "hysteresis would be inverted"),
        ({"velocity_gain_per_s": 0.0}, "velocity_gain_per_s"),
        ({"accel_min_mps2": 0.5}, "accel_min_mps2"),
        ({"stop_aim_beyond_m": math.nan}, "stop_aim_beyond_m"),
    ],
)
def test_params_reject_inconsistent_values(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        LongitudinalParams(**kwargs)


@pytest.mark.parametrize(
    ("inputs", "field_name"),
    [
        (LongitudinalInputs(math.nan, 10.0), "v_mps"),
        (LongitudinalInputs(5.0, math.inf), "v_des_mps"),
        (LongitudinalInputs(5.0, -1.0), "v_des_mps"),
        (LongitudinalInputs(5.0, 10.0, LeadObservation(math.nan, 3.0)), "lead.gap_m"),
        (LongitudinalInputs(5.0, 10.0, LeadObservation(20.0, -math.inf)), "lead.v_lead_mps"),
        (LongitudinalInputs(5.0, 10.0, None, math.nan), "stop_distance_m"),
    ],
)
def test_bad_inputs_are_named(inputs: LongitudinalInputs, field_name: str) -> None:
    with pytest.raises(ValueError, match=f"LongitudinalInputs.{field_name}"):
        longitudinal_step(LongitudinalState(), inputs, PARAMS)


# --- the individual laws -------------------------------------------------------------------------


def test_following_law_is_zero_at_the_desired_gap_and_speed() -> None:
    v = 12.0
    gap = PARAMS.follow_d0_m + PARAMS.follow_tau_s * v
    assert following_accel(v, LeadObservation(gap, v), PARAMS) == pytest.approx(0.0)
    assert following_accel(v, LeadObservation(gap - 2.0, v), PARAMS) == pytest.approx(-2.0)
    assert following_accel(v, LeadObservation(gap, v - 1.0), PARAMS) == pytest.approx(-PARAMS.follow_c1_per_s)


def test_stopping_law_is_constant_deceleration_to_its_aim_point() -> None:
    m = PARAMS.stop_aim_beyond_m
    # v² / (2 (d + m)) is invariant along a constant-deceleration path ending at -m.
    b = 2.0
    for d in (50.0, 20.0, 5.0, 0.1):
        v = math.sqrt(2 * b * (d + m))
        assert stopping_required_decel(v, d, PARAMS) == pytest.approx(b)
        assert stopping_accel(v, d, PARAMS) == pytest.approx(-b)
    # At and past the singularity (m beyond the line): full braking, never inf or NaN.
    assert stopping_accel(1.0, -m, PARAMS) == PARAMS.accel_min_mps2
    assert stopping_accel(0.0, -m - 3.0, PARAMS) == PARAMS.accel_min_mps2


def test_position_law_never_creeps_inside_the_hold_zone() -> None:
    assert position_accel(0.0, 10.0, PARAMS) > 0.0
    assert position_accel(0.0, PARAMS.stop_hold_zone_m, PARAMS) == 0.0
    # A noisy, slightly negative speed reading at the line must not push the car over it.
    assert position_accel(-0.1, 0.05, PARAMS) == 0.0
    assert position_accel(0.5, 0.1, PARAMS) < 0.0


def test_override_selects_the_most_cautious_controller() -> None:
    state = LongitudinalState()
    free = LongitudinalInputs(10.0, 15.0)
    _, a, active = longitudinal_step(state, free, PARAMS)
    assert active == "velocity" and a == pytest.approx(2.0)  # 0.5 * 5 m/s, inside a_max

    close_lead = LongitudinalInputs(10.0, 15.0, LeadObservation(8.0, 8.0))
    _, a, active = longitudinal_step(state, close_lead, PARAMS)
    assert active == "following" and a < 0.0

    far_lead_near_line = LongitudinalInputs(10.0, 15.0, LeadObservation(200.0, 10.0), 30.0)
    new_state, a, active = longitudinal_step(state, far_lead_near_line, PARAMS)
    assert new_state.stopping_active and active == "stopping"
    assert a == pytest.approx(-(10.0**2) / (2 * (30.0 + PARAMS.stop_aim_beyond_m)))


def test_step_is_pure() -> None:
    state = LongitudinalState(stopping_active=True)
    inputs = LongitudinalInputs(8.0, 10.0, LeadObservation(30.0, 7.0), 25.0)
    first = longitudinal_step(state, inputs, PARAMS)
    assert longitudinal_step(state, inputs, PARAMS) == first
    assert state == LongitudinalState(stopping_active=True)


def test_saturation_at_both_ends() -> None:
    _, a, _ = longitudinal_step(LongitudinalState(), LongitudinalInputs(0.0, 40.0), PARAMS)
    assert a == PARAMS.accel_max_mps2
    crash = LongitudinalInputs(20.0, 20.0, LeadObservation(-3.0, 0.0))
    _, a, active = longitudinal_step(LongitudinalState(), crash, PARAMS)
    assert a == PARAMS.accel_min_mps2 and active == "following"


# --- closed loop ----------------------------------------------------------------------------------


@pytest.mark.parametrize(("v0", "v_des"), [(0.0, 15.0), (5.0, 25.0), (20.0, 10.0)])
def test_cruise_converges_without_overshoot(v0: float, v_des: float) -> None:
    trace = simulate(40.0, v0, v_des)
    step = abs(v_des - v0)
    if v_des > v0:
        assert max(trace.v_mps) <= v_des + 0.05 * step
    else:
        assert min(trace.v_mps) >= v_des - 0.05 * step
    assert trace.v_mps[-1] == pytest.approx(v_des, abs=0.05)
    assert set(trace.active) == {"velocity"}
    assert_saturated(trace)


@pytest.mark.parametrize(("v_lead", "gap0"), [(10.0, 40.0), (5.0, 8.0), (20.0, 60.0)])
def test_following_converges_to_the_desired_gap(v_lead: float, gap0: float) -> None:
    trace = simulate(60.0, v0_mps=v_lead, v_des_mps=25.0, lead=(gap0, v_lead))
    desired = PARAMS.follow_d0_m + PARAMS.follow_tau_s * v_lead
    assert trace.gap_m[-1] == pytest.approx(desired, abs=0.1)
    assert trace.v_mps[-1] == pytest.approx(v_lead, abs=0.05)
    assert trace.active[-1] == "following"
    assert min(trace.gap_m) > PARAMS.follow_d0_m - 0.5
    assert_saturated(trace)


def test_velocity_to_following_transfer_is_bumpless() -> None:
    # Cruise at 20 m/s onto a lead at 12 m/s, 120 m ahead: the command must not jump at hand-over.
    trace = simulate(40.0, v0_mps=20.0, v_des_mps=20.0, lead=(120.0, 12.0))
    hand_overs = [
        i
        for i in range(1, len(trace.active))
        if {trace.active[i - 1], trace.active[i]} == {"velocity", "following"}
    ]
    assert hand_overs, "the scenario must hand over from velocity to following control"
    a = trace.accel_cmd_mps2
    for i in hand_overs:
        # A min of continuous laws: the step at the hand-over is no larger than the laws' own change
        # per 20 ms sample just after it (a bump would show as an outlier here).
        slope = max(abs(a[j] - a[j - 1]) for j in range(i + 1, i + 6))
        assert abs(a[i] - a[i - 1]) <= slope + 0.02


@pytest.mark.parametrize("v0", [5.0, 10.0, 15.0, 25.0])
def test_lead_braking_to_a_stop_never_collides(v0: float) -> None:
    gap0 = PARAMS.follow_d0_m + PARAMS.follow_tau_s * v0  # settled following
    trace = simulate(
        40.0, v0_mps=v0, v_des_mps=v0 + 5.0, lead=(gap0, v0), lead_accel=lambda t: -3.0 if t >= 2.0 else 0.0
    )
    assert min(trace.gap_m) > 0.0
    assert min(trace.gap_m) >= PARAMS.follow_d0_m - 0.5
    assert trace.gap_m[-1] >= PARAMS.follow_d0_m - 0.5
    assert trace.v_mps[-1] == pytest.approx(0.0, abs=0.01)
    assert_saturated(trace)


@pytest.mark.parametrize("v0", [15.0, 8.0, 25.0, 2.0])
def test_stopping_at_a_line_ends_just_before_it(v0: float) -> None:
    line_m = 40.0 + v0 * v0 / (2 * PARAMS.stop_decel_on_mps2)  # starts at cruise speed
    trace = simulate(60.0, v0_mps=v0, v_des_mps=v0, stop_line_m=line_m)
    assert max(trace.x_m) <= line_m  # never crosses
    assert line_m - 0.3 <= trace.x_m[-1] <= line_m
    assert trace.v_mps[-1] == pytest.approx(0.0, abs=0.01)
    assert trace.sequence()[0] == "velocity" and trace.sequence()[-1] == "position"
    if v0 >= 8.0:
        # From speed, the constant-deceleration law brakes at a_s,max before the PD takes over.
        assert trace.sequence() == ["velocity", "stopping", "position"]
        braking = [a for a, act in zip(trace.accel_cmd_mps2, trace.active, strict=True) if act == "stopping"]
        assert max(braking) == pytest.approx(-PARAMS.stop_decel_on_mps2, abs=0.35)
    assert_saturated(trace)


def test_stopping_from_15_mps_does_not_brake_early() -> None:
    line_m = 200.0
    trace = simulate(40.0, v0_mps=15.0, v_des_mps=15.0, stop_line_m=line_m)
    first_brake = next(i for i, a in enumerate(trace.accel_cmd_mps2) if a < -0.1)
    distance_left = line_m - trace.x_m[first_brake]
    # Braking starts where a constant a_s,max stops the car (plus the aim margin), not earlier.
    expected = 15.0**2 / (2 * PARAMS.stop_decel_on_mps2) - PARAMS.stop_aim_beyond_m
    assert distance_left == pytest.approx(expected, abs=15.0 * CONTROL_DT_S + 0.1)


def test_hysteresis_prevents_chattering_under_speed_noise() -> None:
    line_m = 120.0
    kwargs = {"duration_s": 40.0, "v0_mps": 15.0, "v_des_mps": 15.0, "stop_line_m": line_m}
    with_hysteresis = simulate(**kwargs, speed_noise_mps=0.2, seed=1)
    assert with_hysteresis.switches(with_hysteresis.stopping_active) == 2  # on once, off once at the end
    assert max(with_hysteresis.x_m) <= line_m
    assert with_hysteresis.x_m[-1] >= line_m - 0.3

    # The same run with one threshold (no hysteresis) chatters: this is what the test guards.
    one_threshold = LongitudinalParams(stop_decel_on_mps2=1.5, stop_decel_off_mps2=1.5)
    without = simulate(**kwargs, params=one_threshold, speed_noise_mps=0.2, seed=1)
    assert without.switches(without.stopping_active) > 6


def test_stop_line_removed_releases_the_stopping_law() -> None:
    state, _, _ = longitudinal_step(LongitudinalState(), LongitudinalInputs(15.0, 15.0, None, 60.0), PARAMS)
    assert state.stopping_active
    state, a, active = longitudinal_step(state, LongitudinalInputs(15.0, 15.0), PARAMS)
    assert not state.stopping_active and active == "velocity" and a == pytest.approx(0.0)


# --- properties ---------------------------------------------------------------------------------

finite_speed = st.floats(-2.0, 60.0, allow_nan=False)
maybe_lead = st.none() | st.builds(LeadObservation, st.floats(-20.0, 500.0), st.floats(-5.0, 60.0))
maybe_stop = st.none() | st.floats(-50.0, 1000.0)


@settings(max_examples=400, deadline=None)
@given(
    stopping_active=st.booleans(),
    v=finite_speed,
    v_des=st.floats(0.0, 60.0),
    lead=maybe_lead,
    stop=maybe_stop,
)
def test_one_step_is_finite_and_saturated(stopping_active, v, v_des, lead, stop) -> None:
    state, a, active = longitudinal_step(
        LongitudinalState(stopping_active), LongitudinalInputs(v, v_des, lead, stop), PARAMS
    )
    assert math.isfinite(a)
    assert PARAMS.accel_min_mps2 <= a <= PARAMS.accel_max_mps2
    assert active in ("velocity", "following", "stopping", "position")
    if stop is None:
        assert not state.stopping_active and active != "position" and active != "stopping"
    if lead is None:
        assert active != "following"


@settings(max_examples=25, deadline=None)
@given(
    v0=st.floats(0.0, 30.0),
    v_des=st.floats(0.0, 30.0),
    lead=st.none() | st.tuples(st.floats(5.0, 150.0), st.floats(0.0, 30.0)),
    lead_brake=st.floats(-4.0, 0.5),
    stop=st.none() | st.floats(5.0, 300.0),
)
def test_closed_loop_from_random_initial_conditions_stays_bounded(v0, v_des, lead, lead_brake, stop) -> None:
    trace = simulate(
        20.0,
        v0_mps=v0,
        v_des_mps=v_des,
        lead=lead,
        lead_accel=lambda t: lead_brake if t > 1.0 else 0.0,
        stop_line_m=stop,
    )
    assert all(math.isfinite(a) for a in trace.accel_cmd_mps2)
    assert all(math.isfinite(v) and 0.0 <= v <= max(v0, v_des) + 1.0 for v in trace.v_mps)
    assert_saturated(trace)
