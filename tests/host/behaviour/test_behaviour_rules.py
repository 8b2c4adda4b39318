"""Traffic-rule constants and MTC parameter sets: values, sources (read from the rules draft), use."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest
from shared_data import shared_data_dir

from bywire.host.behaviour import rules
from bywire.host.behaviour.mtc import ConflictVehicle, DriveOff, moving_traffic_check
from bywire.host.behaviour.rules import (
    MTC_SITUATIONS,
    MtcParams,
    MtcSituation,
    forward_following_distance_m,
    mtc_params,
)
from bywire.host.longitudinal import (
    LongitudinalInputs,
    LongitudinalParams,
    LongitudinalState,
    longitudinal_step,
)

RULES_DRAFT = shared_data_dir() / "rndf" / "spec" / "Urban_Challenge_Rules_Draft.txt"


def test_forward_following_distance_one_length_per_10_mph() -> None:
    length = rules.PASSAT_VARIANT_LENGTH_M
    assert forward_following_distance_m(0.0) == pytest.approx(length)
    assert forward_following_distance_m(10.0 * rules.MPH_MPS) == pytest.approx(2.0 * length)
    assert forward_following_distance_m(30.0 * rules.MPH_MPS, 5.0) == pytest.approx(20.0)
    # Eq. 25's d_f0 + tau v of the longitudinal controller is the same rule.
    lon = LongitudinalParams()
    for v in (0.0, 3.0, 8.9, 13.4):
        assert forward_following_distance_m(v) == pytest.approx(lon.follow_d0_m + lon.follow_tau_s * v)


def test_forward_following_distance_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="speed_mps"):
        forward_following_distance_m(-1.0)
    with pytest.raises(ValueError, match="vehicle_length_m"):
        forward_following_distance_m(5.0, 0.0)


def test_units() -> None:
    assert pytest.approx(1609.344 / 3600.0) == rules.MPH_MPS
    assert pytest.approx(13.4112) == rules.SPEED_LIMIT_MAX_MPS
    assert rules.PRECEDENCE_STUCK_S == rules.MAX_EXCESS_DELAY_S == 10.0


def _rules_text() -> str:
    if not RULES_DRAFT.exists():
        pytest.skip(f"DARPA rules draft not found at {RULES_DRAFT}")
    return re.sub(r"\s+", " ", RULES_DRAFT.read_text(encoding="utf-8", errors="replace"))


@pytest.mark.parametrize(
    ("phrase", "value", "constant"),
    [
        (r"within (\d+) meter of the stop line", 1.0, "STOP_LINE_TOLERANCE_M"),
        (r"less than (\d+)-second delay before proceeding at clear intersection", 10.0, "MAX_EXCESS_DELAY_S"),
        (
            r"minimum safety separation of (\d+) meters fore and aft when executing a passing",
            8.0,
            "PASSING_SEPARATION_M",
        ),
        (r"maintaining minimum (\d+) meters fore and aft", 8.0, "MERGE_SPACING_M"),
        (r"gap of at least (\d+) seconds between vehicles", 10.0, "MERGE_GAP_ACCEPT_S"),
        (r"Complete maneuver takes place within (\d+) meters", 40.0, "PASSING_MANEUVER_MAX_LENGTH_M"),
        (r"never comes closer than (\d+) meters when following", 15.0, "FOLLOW_GAP_AT_15MPH_MIN_M"),
        (r"stays within (\d+) meters when following", 40.0, "FOLLOW_GAP_AT_15MPH_MAX_M"),
        (r"stops between (\d+) and \d+ meters behind a stopped", 5.0, "STOPPED_LEAD_GAP_MIN_M"),
        (r"stops between \d+ and (\d+) meters behind a stopped", 10.0, "STOPPED_LEAD_GAP_MAX_M"),
    ],
)
def test_constants_match_the_rules_draft(phrase: str, value: float, constant: str) -> None:
    """Every constant sourced from the DARPA draft is read back from the document itself."""
    match = re.search(phrase, _rules_text())
    assert match is not None, f"phrase {phrase!r} not in {RULES_DRAFT}"
    assert float(match.group(1)) == value == getattr(rules, constant)


def test_speed_limit_matches_the_rules_draft() -> None:
    match = re.search(r"Speed limits for the Urban Challenge will be (\d+) mph or less", _rules_text())
    assert match is not None
    assert float(match.group(1)) * rules.MPH_MPS == pytest.approx(rules.SPEED_LIMIT_MAX_MPS)


# --------------------------------------------------------------------------------------- MTC parameter sets


def test_standard_situations_are_all_there_and_read_only() -> None:
    names = {
        MtcSituation.INTERSECTION_CROSSING,
        MtcSituation.INTERSECTION_LEFT_TURN,
        MtcSituation.MERGE,
        MtcSituation.LANE_CHANGE,
        MtcSituation.PASSING,
    }
    assert set(MTC_SITUATIONS) == names
    with pytest.raises(TypeError):
        MTC_SITUATIONS["mine"] = MTC_SITUATIONS["merge"]  # type: ignore[index]
    assert mtc_params("merge") is MTC_SITUATIONS["merge"]
    with pytest.raises(ValueError, match=r"unknown MTC situation 'roundabout'.*merge"):
        mtc_params("roundabout")


def test_rule_distances_are_in_the_windows() -> None:
    """8 m fore and aft (rules 5.2) in every window on the other vehicle's side."""
    for name, p in MTC_SITUATIONS.items():
        assert p.d_b1_m >= rules.MERGE_SPACING_M, name
        assert p.d_b2_m >= rules.MERGE_SPACING_M, name
        assert p.d_a2_m >= rules.PASSAT_VARIANT_LENGTH_M, name  # our rear bumper must clear too
        assert p.hysteresis_factor == 0.8


def test_params_validation_names_the_field() -> None:
    good = MTC_SITUATIONS["merge"]
    for field, value in [
        ("d_a1_m", -1.0),
        ("gap_ab_s", math.nan),
        ("accel_sat_mps2", 0.0),
        ("v_desired_mps", math.inf),
        ("hysteresis_factor", 1.2),
        ("hysteresis_factor", 0.0),
    ]:
        with pytest.raises(ValueError, match=f"MtcParams.{field}"):
            dataclasses.replace(good, **{field: value})


def test_in_motion_and_desired_speed() -> None:
    p = MtcParams(2.0, 4.0, 6.0, 8.0, 5.0, 1.0, 1.0, 5.0, hysteresis_factor=0.5)
    m = p.in_motion()
    assert (m.d_a1_m, m.d_a2_m, m.d_b1_m, m.d_b2_m, m.gap_ab_s, m.gap_ba_s) == (1.0, 2.0, 3.0, 4.0, 2.5, 0.5)
    assert (m.accel_sat_mps2, m.v_desired_mps) == (1.0, 5.0)
    assert p.with_desired_speed(9.0).v_desired_mps == 9.0


def _accepts_gap(situation: str, gap_s: float, speed_mps: float, own_dist_to_mp_m: float = 3.0) -> bool:
    """Standing at the line (front bumper 3 m before MP), a stream of vehicles `gap_s` apart at
    `speed_mps` passes; is there an instant within 2 gaps at which the MTC lets us go?"""
    params = mtc_params(situation)
    spacing_m = gap_s * speed_mps
    for t in np.arange(0.0, 2.0 * gap_s, 0.02):
        stream = [
            ConflictVehicle(k * spacing_m - speed_mps * t, speed_mps, own_dist_to_mp_m) for k in range(-3, 8)
        ]
        if moving_traffic_check(0.0, stream, params).free:
            return True
    return False


@pytest.mark.parametrize("situation", ["intersection_crossing", "intersection_left_turn", "merge"])
@pytest.mark.parametrize("mph", [10.0, 20.0, 30.0])
def test_a_10_s_gap_is_accepted(situation: str, mph: float) -> None:
    """Rules 5.2: "Vehicle should pull into the traffic lane when oncoming vehicles leave a gap of at
    least 10 seconds between vehicles" -- the standard sets may not be too cautious for that."""
    assert _accepts_gap(situation, rules.MERGE_GAP_ACCEPT_S, mph * rules.MPH_MPS)


@pytest.mark.parametrize("situation", ["intersection_crossing", "intersection_left_turn", "merge"])
def test_a_5_s_gap_at_30_mph_is_refused(situation: str) -> None:
    """... and not reckless: at 30 mph a 5 s gap (67 m) is too short to pull out from standstill."""
    assert not _accepts_gap(situation, 5.0, 30.0 * rules.MPH_MPS)


@pytest.mark.parametrize("situation", ["intersection_crossing", "intersection_left_turn", "merge", "passing"])
def test_drive_off_model_never_ahead_of_our_longitudinal_controller(situation: str) -> None:
    """The A-first clause is safe only if the real car is at least as far along as the model (Fig. 12's
    approximation): drive off from standstill with host/longitudinal.py's velocity loop (50 Hz, ideal
    actuator) and compare distances over 20 s."""
    params = mtc_params(situation)
    model = DriveOff(0.0, params.v_desired_mps, params.accel_sat_mps2)
    lon = LongitudinalParams()
    state, v, x, dt = LongitudinalState(), 0.0, 0.0, 0.02
    for k in range(1, 1001):
        state, accel, _ = longitudinal_step(state, LongitudinalInputs(v, params.v_desired_mps), lon)
        x += v * dt + 0.5 * accel * dt * dt
        v += accel * dt
        assert x >= model.distance_m(k * dt) - 1e-9, k * dt
