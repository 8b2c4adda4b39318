"""Traffic-rule constants for the behaviour layer, each with its source and unit (seed 000 Secs. 9, 11.2.1).

Sources, cited by section below:

- "rules 1.7" / "rules 5.2" / "rules App." : DARPA Urban Challenge Rules, draft of May 17 2006
  (`shared/data/rndf/spec/Urban_Challenge_Rules_Draft.txt`): 1.7 Objectives, 5.2 Evaluation Criteria,
  Appendix: Definitions.
- "seed 000 Sec. x": Kammel et al. 2008 (AnnieWAY). The forward following distance ("one vehicle
  length minimum and one length for every additional 10 mph") is DARPA's, quoted in seed 000 Sec.
  11.2.1; the May 2006 draft we hold does not contain it yet (it came with DARPA's later evaluation
  criteria), so we cite the paper.
- "AnnieWAY code": the team's merge-feasibility check as published inside the Stanford Driving
  Software (`aw_MergeFeasabilityCheck.cpp`): hysteresis factor 0.8, nominal drive-off acceleration
  1 m/s², intersection time gaps 6 s / 1 s, passing 4 s / 2 s. We took values, not code.
- "ours": our choice, with the reason next to it.

The moving-traffic check (MTC, seed 000 Sec. 9, `mtc.py`) takes one `MtcParams` per conflict
situation (Sec. 9.3: "the different traffic situations can be accounted for with a corresponding
parameter set"); `MTC_SITUATIONS` holds the standard ones. Geometry convention of every set (Fig. 14):
distances are measured from a vehicle's *front bumper* to the merge point MP along its own path;
P_A1 lies D_A1 before MP on our path, P_A2 lies D_A2 after it, and likewise P_B1 / P_B2 on the other
vehicle's path. We may not be inside [P_A1, P_A2] while another vehicle is inside [P_B1, P_B2]. So
D_X1 is the reach of the other path's lane (half a lane, 2 m, the front bumper entering it) plus a
margin, and D_X2 is that plus the vehicle's own length (the rear bumper leaving it) plus a margin.
Where the rules ask for 8 m fore and aft (rules 5.2, passing and pulling into traffic) the other
vehicle's window is at least 8 m on each side of MP.

Every standard set is checked against rules 5.2 ("Vehicle should pull into the traffic lane when
oncoming vehicles leave a gap of at least 10 seconds") in tests/test_behaviour_rules.py: standing
at the stop line, the MTC must find a moment to go inside a 10 s gap of a 30 mph stream.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Final

__all__ = [
    "FOLLOW_GAP_AT_15MPH_MAX_M",
    "FOLLOW_GAP_AT_15MPH_MIN_M",
    "INTERSECTION_BOX_STUCK_S",
    "MAX_EXCESS_DELAY_S",
    "MERGE_GAP_ACCEPT_S",
    "MERGE_SPACING_M",
    "MPH10_MPS",
    "MPH_MPS",
    "MTC_SITUATIONS",
    "PASSAT_VARIANT_LENGTH_M",
    "PASSAT_WHEELBASE_M",
    "PASSING_MANEUVER_MAX_LENGTH_M",
    "PASSING_SEPARATION_M",
    "PRECEDENCE_STUCK_S",
    "PRECEDENCE_TIE_S",
    "SPEED_LIMIT_MAX_MPS",
    "STOPPED_LEAD_GAP_MAX_M",
    "STOPPED_LEAD_GAP_MIN_M",
    "STOP_LINE_TOLERANCE_M",
    "MtcParams",
    "MtcSituation",
    "forward_following_distance_m",
    "mtc_params",
]

MPH_MPS: Final = 0.44704  # 1 mph in m/s (exact: 1609.344 m / 3600 s)
MPH10_MPS: Final = 10.0 * MPH_MPS  # DARPA's unit of "one more vehicle length" of separation

PASSAT_VARIANT_LENGTH_M: Final = 4.77  # VW Passat B6 Variant (AnnieWAY), bumper to bumper
PASSAT_WHEELBASE_M: Final = 2.72  # l of seed 000 Sec. 11.1

# --- speeds ------------------------------------------------------------------------------------------
SPEED_LIMIT_MAX_MPS: Final = 30.0 * MPH_MPS  # rules 1.7: "Speed limits ... will be 30 mph or less"

# --- following (rules 5.2 Basic traffic; seed 000 Sec. 11.2.1) -----------------------------------------
FOLLOW_GAP_AT_15MPH_MIN_M: Final = 15.0  # rules 5.2: never closer than 15 m behind a lead at 15 mph
FOLLOW_GAP_AT_15MPH_MAX_M: Final = 40.0  # rules 5.2: stays within 40 m of a lead at 15 mph
STOPPED_LEAD_GAP_MIN_M: Final = 5.0  # rules 5.2: stops between 5 and 10 m behind a stopped lead
STOPPED_LEAD_GAP_MAX_M: Final = 10.0

# --- intersections (rules 1.7, 5.2; seed 000 Sec. 12) ---------------------------------------------------
STOP_LINE_TOLERANCE_M: Final = 1.0  # rules 1.7 / 5.2: front bumper within 1 m of the stop line
MAX_EXCESS_DELAY_S: Final = 10.0  # rules 1.7 / 5.2: proceed with less than 10 s delay when clear
# Precedence: a vehicle whose turn it is and which does not move within this time is taken as stuck,
# and we stop waiting for it (then drive on with caution). Ours: the rules give a robot 10 s to get
# going at a clear intersection (rules 5.2), so we grant every other driver the same, *per vehicle*:
# AnnieWAY's timer of 10 s for all vehicles together was the four-way-stop bug of seed 000 Sec. 12.
PRECEDENCE_STUCK_S: Final = MAX_EXCESS_DELAY_S
# Two arrivals at stop lines closer than this count as simultaneous and yield to the right (ours:
# a 10 Hz tracker dates a stop to +-0.1 s; humans see arrivals within half a second as "together").
PRECEDENCE_TIE_S: Final = 0.5
# A vehicle inside the intersection box for longer than this is taken as stalled there; we stop
# waiting for it and drive on with caution (the path's collision check avoids it). Ours: crossing a
# 25 m box at a walking-pace 2 m/s takes ~12 s, so 20 s is well beyond a slow but moving vehicle.
INTERSECTION_BOX_STUCK_S: Final = 20.0

# --- merging and passing (rules 5.2) --------------------------------------------------------------------
MERGE_SPACING_M: Final = 8.0  # rules 5.2 Advanced traffic: 8 m fore and aft while pulling into traffic
MERGE_GAP_ACCEPT_S: Final = 10.0  # rules 5.2: must pull in when oncoming traffic leaves a 10 s gap
PASSING_SEPARATION_M: Final = 8.0  # rules 5.2 Basic navigation: 8 m fore and aft when passing
PASSING_MANEUVER_MAX_LENGTH_M: Final = 40.0  # rules 5.2: leave lane, pass and return within 40 m


def forward_following_distance_m(
    speed_mps: float, vehicle_length_m: float = PASSAT_VARIANT_LENGTH_M
) -> float:
    """Minimum forward separation: one vehicle length plus one per additional 10 mph (m).

    DARPA's rule as quoted in seed 000 Sec. 11.2.1: L (1 + v / 10 mph), continuous in v (a stepped
    reading, one more length per *full* 10 mph, is never larger, so this one is the safe side). It is
    d_f0 + tau v of eq. 25 with d_f0 = L, tau = L / 4.4704 m/s (the longitudinal controller's
    default). Note that rules 5.2 asks for 15 m at 15 mph, more than this gives for L < 6 m
    (11.9 m for the Passat); `FOLLOW_GAP_AT_15MPH_MIN_M` keeps that evaluation figure.
    """
    if not (math.isfinite(speed_mps) and speed_mps >= 0.0):
        raise ValueError(f"forward_following_distance_m: speed_mps = {speed_mps} must be finite and >= 0")
    if not (math.isfinite(vehicle_length_m) and vehicle_length_m > 0.0):
        raise ValueError(
            f"forward_following_distance_m: vehicle_length_m = {vehicle_length_m} must be finite and > 0"
        )
    return vehicle_length_m * (1.0 + speed_mps / MPH10_MPS)


@dataclass(frozen=True)
class MtcParams:
    """One parameter set of the moving-traffic check (seed 000 Sec. 9, Fig. 14 and Sec. 9.3).

    Distances front bumper to MP along each vehicle's own path (see the module docstring), times in
    seconds. `hysteresis_factor` h (Sec. 9.3: "slightly reducing the requirements once the autonomous
    vehicle has set itself in motion"): once we move, every D and Delta T is multiplied by h.
    """

    d_a1_m: float  # D_A1: P_A1 lies this far before MP on our path
    d_a2_m: float  # D_A2: P_A2 lies this far after MP on our path
    d_b1_m: float  # D_B1: P_B1 lies this far before MP on the other vehicle's path
    d_b2_m: float  # D_B2: P_B2 lies this far after MP on the other vehicle's path
    gap_ab_s: float  # Delta T_AB: we at MP first, then at least this long before B reaches MP (eq. 14)
    gap_ba_s: float  # Delta T_BA: B at MP first, then at least this long before we reach MP (eq. 16)
    accel_sat_mps2: float  # a_sat of the drive-off model (eqs. 9-12)
    v_desired_mps: float  # v_d: the speed of the manoeuvre (eqs. 9-12)
    hysteresis_factor: float = 0.8  # h, AnnieWAY code

    def __post_init__(self) -> None:
        for name in ("d_a1_m", "d_a2_m", "d_b1_m", "d_b2_m", "gap_ab_s", "gap_ba_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"MtcParams.{name} = {value}: must be finite and >= 0")
        for name in ("accel_sat_mps2", "v_desired_mps"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"MtcParams.{name} = {value}: must be finite and > 0")
        h = self.hysteresis_factor
        if not (math.isfinite(h) and 0.0 < h <= 1.0):
            raise ValueError(
                f"MtcParams.hysteresis_factor = {h}: must be in (0, 1] (it reduces requirements)"
            )

    def in_motion(self) -> MtcParams:
        """The reduced set used once we have set ourselves in motion: every D and Delta T times h."""
        h = self.hysteresis_factor
        return dataclasses.replace(
            self,
            d_a1_m=h * self.d_a1_m,
            d_a2_m=h * self.d_a2_m,
            d_b1_m=h * self.d_b1_m,
            d_b2_m=h * self.d_b2_m,
            gap_ab_s=h * self.gap_ab_s,
            gap_ba_s=h * self.gap_ba_s,
            hysteresis_factor=1.0,
        )

    def with_desired_speed(self, v_desired_mps: float) -> MtcParams:
        """The same situation driven at another manoeuvre speed v_d (e.g. the lane's speed limit)."""
        return dataclasses.replace(self, v_desired_mps=v_desired_mps)


class MtcSituation:
    """Names of the standard conflict situations (keys of `MTC_SITUATIONS`)."""

    INTERSECTION_CROSSING: Final = "intersection_crossing"
    INTERSECTION_LEFT_TURN: Final = "intersection_left_turn"
    MERGE: Final = "merge"
    LANE_CHANGE: Final = "lane_change"
    PASSING: Final = "passing"


_HALF_LANE_M = 2.0  # half of a 4 m lane: the front bumper enters the other path's lane 2 m before MP
_MARGIN_M = 1.0  # ours: covers the tracker's position error and the point-mass abstraction (Sec. 9.1)
_L = PASSAT_VARIANT_LENGTH_M
_TURN_SPEED_MPS = MPH10_MPS  # ours: 10 mph through an intersection (turn radii of 10-15 m, ~1.5 m/s² lateral)

_SITUATIONS: dict[str, MtcParams] = {
    # Crossing (or turning into) a priority road after stopping at its stop line: Fig. 13 (a). B's
    # window is 8 m either side of MP (rules 5.2), ours the lane reach and our length. Delta T_AB 5 s:
    # B arrives at least 5 s after us, which at 30 mph is 67 m, enough for B to brake comfortably
    # (2 m/s²: 45 m) should we stall in its lane. (AnnieWAY code: 6 s; with these windows that never
    # accepts a 10 s gap in a 10 mph stream, against rules 5.2.) Delta T_BA 1.5 s: we reach MP 1.5 s after
    # B left it (AnnieWAY code: 1 s; ours +0.5 s for the tracker's speed error). a_sat 1 m/s²: the
    # AnnieWAY code's nominal acceleration. From standstill the velocity loop of host/longitudinal.py
    # (eq. 31, c_v = 0.5 1/s) is never behind this ramp while v_d >= 2 a_sat / c_v = 4 m/s (its
    # distance lag v_d / c_v against the ramp's v_d² / (2 a_sat)), so at 10 mph the A-first clause
    # errs on the safe side.
    MtcSituation.INTERSECTION_CROSSING: MtcParams(
        d_a1_m=_HALF_LANE_M + _MARGIN_M,
        d_a2_m=_HALF_LANE_M + _L + _MARGIN_M,
        d_b1_m=MERGE_SPACING_M,
        d_b2_m=MERGE_SPACING_M,
        gap_ab_s=5.0,
        gap_ba_s=1.5,
        accel_sat_mps2=1.0,
        v_desired_mps=_TURN_SPEED_MPS,
    ),
    # Left turn across oncoming traffic on a priority road, from a stop before the opposing lane:
    # Fig. 13 (b), Sec. 9.3 case (c). The same windows as a crossing; the oncoming driver sees us
    # turning and the rules ask for "safe behavior", so the same 5 s / 1.5 s gaps.
    MtcSituation.INTERSECTION_LEFT_TURN: MtcParams(
        d_a1_m=_HALF_LANE_M + _MARGIN_M,
        d_a2_m=_HALF_LANE_M + _L + _MARGIN_M,
        d_b1_m=MERGE_SPACING_M,
        d_b2_m=MERGE_SPACING_M,
        gap_ab_s=5.0,
        gap_ba_s=1.5,
        accel_sat_mps2=1.0,
        v_desired_mps=_TURN_SPEED_MPS,
    ),
    # Merging into a moving lane (right turn into traffic, traffic circle entry): after MP we share
    # B's lane, so B ends up behind us (A first) or ahead of us (B first). Our window reaches 8 m
    # past MP plus our length (rules 5.2: 8 m fore and aft while pulling in); Delta T_BA 2 s so
    # that we start out behind B at a following distance (30 mph: 4 lengths = 19 m = 1.4 s).
    MtcSituation.MERGE: MtcParams(
        d_a1_m=_HALF_LANE_M + _MARGIN_M,
        d_a2_m=MERGE_SPACING_M + _L,
        d_b1_m=MERGE_SPACING_M,
        d_b2_m=MERGE_SPACING_M,
        gap_ab_s=5.0,
        gap_ba_s=2.0,
        accel_sat_mps2=1.0,
        v_desired_mps=_TURN_SPEED_MPS,
    ),
    # Changing lanes while moving (Fig. 13 c/d): MP is where our path enters the target lane; B
    # drives in the target lane. 8 m fore and aft (rules 5.2), gaps of 3 s / 2 s (ours: we are
    # already at lane speed, so the gaps are pure following headways, above the 1.4 s of DARPA's
    # following distance at 30 mph). a_sat 0.5 m/s²: a gentle speed adaptation during the change.
    MtcSituation.LANE_CHANGE: MtcParams(
        d_a1_m=MERGE_SPACING_M,
        d_a2_m=MERGE_SPACING_M + _L,
        d_b1_m=MERGE_SPACING_M,
        d_b2_m=MERGE_SPACING_M,
        gap_ab_s=3.0,
        gap_ba_s=2.0,
        accel_sat_mps2=0.5,
        v_desired_mps=SPEED_LIMIT_MAX_MPS,
    ),
    # Passing a stopped vehicle through the opposing lane with oncoming traffic (Fig. 13 d): MP is
    # the middle of the stretch of opposing lane we use, at most 40 m long (rules 5.2); both windows
    # cover that stretch plus 8 m (rules 5.2: 8 m fore and aft). Gaps 4 s / 2 s: AnnieWAY code.
    MtcSituation.PASSING: MtcParams(
        d_a1_m=PASSING_MANEUVER_MAX_LENGTH_M / 2.0 + PASSING_SEPARATION_M,
        d_a2_m=PASSING_MANEUVER_MAX_LENGTH_M / 2.0 + PASSING_SEPARATION_M,
        d_b1_m=PASSING_MANEUVER_MAX_LENGTH_M / 2.0 + PASSING_SEPARATION_M,
        d_b2_m=PASSING_MANEUVER_MAX_LENGTH_M / 2.0 + PASSING_SEPARATION_M,
        gap_ab_s=4.0,
        gap_ba_s=2.0,
        accel_sat_mps2=1.0,
        v_desired_mps=_TURN_SPEED_MPS,
    ),
}

MTC_SITUATIONS: Final[Mapping[str, MtcParams]] = MappingProxyType(_SITUATIONS)
"""The standard MTC parameter sets by situation name (read-only; derive variants with
`dataclasses.replace` or `MtcParams.with_desired_speed`)."""


def mtc_params(situation: str) -> MtcParams:
    """The standard parameter set of `situation`; ValueError naming the known ones otherwise."""
    try:
        return MTC_SITUATIONS[situation]
    except KeyError:
        known = ", ".join(sorted(MTC_SITUATIONS))
        raise ValueError(f"unknown MTC situation {situation!r}; known: {known}") from None
