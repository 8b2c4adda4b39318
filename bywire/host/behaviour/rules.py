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

The hierarchical state machine's constants (trigger distances, speeds, stillness, no-progress times,
the K-turn and passing geometry) follow the parameter sets; each names its source and unit, and the
ones of AnnieWAY's published planner (`aw_ChsmPlanner.hpp`) are marked "AnnieWAY code".

Every standard set is checked against rules 5.2 ("Vehicle should pull into the traffic lane when
oncoming vehicles leave a gap of at least 10 seconds") in tests/host/behaviour/test_behaviour_rules.py:
standing at the stop line, the MTC must find a moment to go inside a 10 s gap of a 30 mph stream.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Final

__all__ = [
    "BLOCKADE_RANGE_M",
    "BLOCKADE_STILL_S",
    "CHECKPOINT_TOLERANCE_M",
    "CONFLICT_DISTANCE_M",
    "CURVE_LATERAL_ACCEL_MPS2",
    "DRIVE_NO_PROGRESS_S",
    "FOLLOW_GAP_AT_15MPH_MAX_M",
    "FOLLOW_GAP_AT_15MPH_MIN_M",
    "GLOBAL_REPLAN_INTERVAL_S",
    "INTERSECTION_APPROACH_TRIGGER_M",
    "INTERSECTION_BOX_STUCK_S",
    "INTERSECTION_DECISION_M",
    "INTERSECTION_MAX_CROSSING_M",
    "INTERSECTION_MIN_WAIT_S",
    "INTERSECTION_NO_PROGRESS_S",
    "INTERSECTION_SPEED_MPS",
    "KTURN_RADIUS_M",
    "KTURN_SPEED_MPS",
    "KTURN_SWITCH_DISTANCE_M",
    "KTURN_TRIGGER_M",
    "LANE_CHANGE_TRIGGER_M",
    "LATERAL_CLEARANCE_M",
    "LEAD_HORIZON_M",
    "MAX_EXCESS_DELAY_S",
    "MAX_MICROSTEPS",
    "MERGE_GAP_ACCEPT_S",
    "MERGE_SPACING_M",
    "MPH10_MPS",
    "MPH_MPS",
    "MTC_APPROACH_HORIZON_M",
    "MTC_SITUATIONS",
    "OFF_TRACK_M",
    "PASSAT_REAR_AXLE_TO_FRONT_M",
    "PASSAT_VARIANT_LENGTH_M",
    "PASSAT_WHEELBASE_M",
    "PASSAT_WIDTH_M",
    "PASSING_MANEUVER_MAX_LENGTH_M",
    "PASSING_SEPARATION_M",
    "PASS_NO_INTERSECTION_M",
    "PASS_SHIFT_LENGTH_M",
    "PASS_SPEED_MPS",
    "PASS_STILL_S",
    "PAUSE_MOVED_RESET_M",
    "PRECEDENCE_STUCK_S",
    "PRECEDENCE_TIE_S",
    "PRIO_STOP_DECEL_MPS2",
    "PROGRESS_DISTANCE_M",
    "QUEUE_GAP_M",
    "RECOVERY_CREEP_SPEED_MPS",
    "RECOVERY_LEAP_M",
    "RECOVERY_NO_PROGRESS_S",
    "RECOVERY_SETTLE_S",
    "RECOVERY_SUCCESS_M",
    "SPEED_ANTICIPATION_DECEL_MPS2",
    "SPEED_LIMIT_MAX_MPS",
    "SPOT_SPEED_MPS",
    "STEER_ALLOW_M",
    "STEER_CRAWL_MPS",
    "STEER_PLAN_RATE_RADPS",
    "STILL_DISPLACEMENT_M",
    "STILL_SPEED_MPS",
    "STOOD_BEHIND_MAX_GAP_M",
    "STOPPED_LEAD_GAP_MAX_M",
    "STOPPED_LEAD_GAP_MIN_M",
    "STOPPED_LEAD_STANDOFF_M",
    "STOPPED_SPEED_MPS",
    "STOP_LINE_HEADING_RAD",
    "STOP_LINE_LATERAL_M",
    "STOP_LINE_PAST_M",
    "STOP_LINE_TOLERANCE_M",
    "STOP_LINE_ZONE_M",
    "STUB_BACK_M",
    "STUB_LENGTH_M",
    "TIGHT_TURN_CURVATURE_1PM",
    "TIGHT_TURN_SPEED_MPS",
    "TRAFFIC_NEAR_M",
    "TURNAROUND_SEARCH_M",
    "ZONE_APPROACH_TRIGGER_M",
    "ZONE_BACK_OUT_MARGIN_M",
    "ZONE_HANDOVER_M",
    "ZONE_NO_PROGRESS_S",
    "ZONE_PARK_DWELL_S",
    "ZONE_REPLAN_STALL_S",
    "ZONE_SPEED_MAX_MPS",
    "ZONE_SPOT_ALIGN_M",
    "ZONE_SPOT_STRAIGHT_M",
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


# --- the vehicle as behaviour sees it (ours, from the B6 Variant's data sheet) -----------------------------
# The pose of a `Situation` is the rear axle (the lateral controller's reference point, Sec. 11.1); the
# rules judge the front bumper. 4.77 m = 0.95 m front overhang + 2.72 m wheelbase + 1.10 m rear overhang.
PASSAT_REAR_AXLE_TO_FRONT_M: Final = 2.72 + 0.95
PASSAT_WIDTH_M: Final = 1.82  # body without mirrors

# --- the hierarchical state machine (behaviour.py and its state families) ---------------------------------
# "AnnieWAY code" below: the constants of `aw_ChsmPlanner.hpp` (the published planner); we took values.

# Path stub handed to the controllers: "reaches approximately 30 m ahead" (seed 000 Sec. 8). It starts a
# little behind the rear axle so that the controller's projection always falls inside it (AnnieWAY code:
# `center_line_back_sample_length`).
STUB_LENGTH_M: Final = 30.0
STUB_BACK_M: Final = 2.0
MAX_MICROSTEPS: Final = 16  # AnnieWAY code: > 16 transitions in one cycle = "errornous transitions"

# Speeds. Curves: 2 m/s² lateral, what a passenger accepts (the route planner's `RouteCosts` uses the
# same); a lower speed ahead (curve, limit, stop) is anticipated with 1 m/s² (ours: comfortable).
CURVE_LATERAL_ACCEL_MPS2: Final = 2.0
# Turns near full lock (ours): 2 m/s² lateral would allow 3.2 m/s on a 5 m radius, but the steering
# (0.7 rad/s, 0.1 s lag: vehicle_models/passat) then turns in late, and the car saturates and runs wide
# of a stop-line exit by up to 0.5 m; at 2 m/s it stays within ~0.2 m. Curvatures from
# 0.2 1/m (a 5 m radius, 94 % of the Passat's full lock) are driven at this speed at most; below it the
# car tracks at the lateral-acceleration speed (NQE area A: 0.17 m at most); 0.15 1/m made NQE area
# A's laps 10-15 % slower for 0.12 m.
TIGHT_TURN_CURVATURE_1PM: Final = 0.2
TIGHT_TURN_SPEED_MPS: Final = 2.0
SPEED_ANTICIPATION_DECEL_MPS2: Final = 1.0
INTERSECTION_SPEED_MPS: Final = MPH10_MPS  # ours: the MTC's manoeuvre speed v_d (rules.MTC_SITUATIONS)
ZONE_SPEED_MAX_MPS: Final = 5.0 * MPH_MPS  # ours: below the MDF zone limit of the sample (5-10 mph)
SPOT_SPEED_MPS: Final = 0.5 * ZONE_SPEED_MAX_MPS  # ours: into and out of a parking spot
KTURN_SPEED_MPS: Final = 1.5  # ours (AnnieWAY code: 2 m/s); each leg ends in a stop
PASS_SPEED_MPS: Final = 3.0  # ours: the 12 m shift below peaks at 1.3 m/s² lateral at this speed
RECOVERY_CREEP_SPEED_MPS: Final = 1.0  # ours: a recovery moves at walking pace
# Time to steer (ours): a planned path's curvature may jump (a Reeds-Shepp shot from full left to full
# right lock); the car slows so that its wheels, turning at STEER_PLAN_RATE_RADPS (half the Passat's
# 0.7 rad/s road-wheel limit: the rest is the controller's), reach each angle ahead within
# STEER_ALLOW_M past where the path asks for it, down to STEER_CRAWL_MPS. At the zone speed the jump
# of the parking lot's exit left the car 1.3 m off its path and 0.7 m over the lane's edge.
STEER_PLAN_RATE_RADPS: Final = 0.35
STEER_ALLOW_M: Final = 0.5
STEER_CRAWL_MPS: Final = 0.4

# Standstill and stillness. A vehicle "has stopped" below 0.2 m/s (AnnieWAY code: 0.1 m/s; ours doubles
# it for the speed noise of a tracker); an object is "still" while slower than 0.3 m/s and within 1 m
# of where it came to rest (a parked car's track jitters by decimetres).
STOPPED_SPEED_MPS: Final = 0.2
STILL_SPEED_MPS: Final = 0.3
STILL_DISPLACEMENT_M: Final = 1.0

# Objects on our path. Lead vehicles are looked for this far ahead (ours: at 30 mph DARPA's following
# distance is 19 m, the stopping distance at 1 m/s² 90 m); an object is in our way when its body comes
# within this clearance of ours, laterally (ours: 0.3 m, a tracker's width error).
LEAD_HORIZON_M: Final = 100.0
LATERAL_CLEARANCE_M: Final = 0.3
# Behind a stopped lead we stop in the middle of the rules' 5-10 m band (rules 5.2); we "stand behind"
# it (the passing and blockade timers run) while its rear is at most 10 m + 3 m (ours: the stopping
# controller's reach) ahead of our front bumper.
STOPPED_LEAD_STANDOFF_M: Final = 0.5 * (STOPPED_LEAD_GAP_MIN_M + STOPPED_LEAD_GAP_MAX_M)
STOOD_BEHIND_MAX_GAP_M: Final = STOPPED_LEAD_GAP_MAX_M + 3.0
TRAFFIC_NEAR_M: Final = 60.0  # ours: moving vehicles this close mean we wait on traffic, not stuck

# Intersections (seed 000 Sec. 9.3; AnnieWAY code TRIGGER_DIST_APPROACH_INTERSECTION 55 m,
# TRIGGER_DIST_BLINK 30 m where the turn is decided and signalled, MIN_WAIT_STOPLINE 0.5 s).
INTERSECTION_APPROACH_TRIGGER_M: Final = 55.0
INTERSECTION_DECISION_M: Final = 30.0
INTERSECTION_MIN_WAIT_S: Final = 1.0  # ours: a full stop a human sees as one, well inside rules' 10 s
INTERSECTION_MAX_CROSSING_M: Final = 40.0  # ours: a crossing edge longer than this ends the box here
# A vehicle is "at" a stop line when it has stopped with its front bumper at most 3 m before it (a car
# stops 0-1 m short); pulling away it stays there until its front is 3 m past the line, where its
# centre is inside the box (the hull of the intersection's waypoints, through the stop lines). Ours.
STOP_LINE_ZONE_M: Final = 3.0
STOP_LINE_PAST_M: Final = 3.0
STOP_LINE_LATERAL_M: Final = 2.0  # ... within half a lane of its lane's centre line
STOP_LINE_HEADING_RAD: Final = math.radians(45.0)  # ... and facing along it
# Paths of two lanes come into conflict where their centre lines come closer than this (ours: two 1.8 m
# wide cars on centre lines 2.5 m apart leave 0.7 m; parallel lanes are 3.7 m apart and never conflict).
CONFLICT_DISTANCE_M: Final = 2.5
# Priority vehicles farther than this from the merge point are not checked (ours: the 10 s gap of rules
# 5.2 at 30 mph is 134 m).
MTC_APPROACH_HORIZON_M: Final = 150.0
# Case b turns into case c (IntersectionPrioDriveInside -> IntersectionPrioStop) only while we can still
# stop before the oncoming lane with this deceleration ("point of no return", ours: firm, not hard).
PRIO_STOP_DECEL_MPS2: Final = 2.0

# Lane changes, passing, blockades (rules 5.2; AnnieWAY code MIN_WAIT_OBSTACLE / MIN_WAIT_PARKED 5 s,
# VEHICLE_STAND_TILL_BLOCKADE_TIME 10 s, TRIGGER_DIST_KTURN 20 m).
# ours (AnnieWAY code: 15 m): a change the MTC refuses stops at its start, from 10 m/s at 1.25 m/s².
LANE_CHANGE_TRIGGER_M: Final = 40.0
PASS_STILL_S: Final = 5.0  # a vehicle still this long is parked or stalled: we may pass it
BLOCKADE_STILL_S: Final = MAX_EXCESS_DELAY_S  # still this long and not passable: the road is blocked
BLOCKADE_RANGE_M: Final = 30.0  # ours: only an obstacle this close ahead can be judged a blockade
# Passing: leave the lane over 12 m (a quintic shift of one lane, 3.7 m: its second derivative peaks
# at 5.77 * 3.7 / 12² = 0.15 1/m, the path's curvature a little below), stay out until our rear axle
# is PASSING_SEPARATION_M past the obstacle's front, come back over 12 m: from a stop 7.5 m behind a
# 4.8 m car that is 35 m, inside the 40 m of rules 5.2.
PASS_SHIFT_LENGTH_M: Final = 12.0
# rules 1.7: "Vehicles must not pass other vehicles queued at an intersection": a still vehicle whose
# front is this close to the next stop line or intersection on our route (or to a still vehicle that
# is itself queued) is queued (ours: 15 m, three car lengths of gap).
QUEUE_GAP_M: Final = 15.0
PASS_NO_INTERSECTION_M: Final = 40.0  # ours: no passing manoeuvre ends closer than this to an intersection
KTURN_TRIGGER_M: Final = 20.0  # AnnieWAY code TRIGGER_DIST_KTURN
KTURN_RADIUS_M: Final = 5.5  # ours: atan(2.72 / 5.5) = 26 deg of steer, 4 deg below the lock for control
# ours: without an opposite lane in our segment, a K-turn turns onto the nearest lane of any segment running
# back alongside within this (a street drawn as two one-way segments: no U-turn edge between them)
TURNAROUND_SEARCH_M: Final = 20.0
KTURN_SWITCH_DISTANCE_M: Final = 0.5  # ours: a leg of the K-turn ends within this of its end point

# Zones: the stand-in path (zone/navigator.py) lines up with a spot this far before its first waypoint
# (ours: the orbital controller halves an error every 3 m, so 8 m takes out 85 % of a misalignment).
ZONE_APPROACH_TRIGGER_M: Final = 30.0  # ours (AnnieWAY code: 10 m): time to slow down to zone speed
ZONE_SPOT_ALIGN_M: Final = 8.0
# ours: the zone planner takes over this far before the perimeter entry (an obstacle in the lot may stop
# the car short of the perimeter on the route's straight zone edge, which the planner drives around)
ZONE_HANDOVER_M: Final = 5.0
# ours: out of a spot straight back until the front bumper is this far out of it (DARPA rules 5.2),
# then the planner's path
ZONE_BACK_OUT_MARGIN_M: Final = 1.0
ZONE_SPOT_STRAIGHT_M: Final = 1.0  # ours: a planned entry runs straight from this far before the spot
ZONE_REPLAN_STALL_S: Final = 3.0  # ours: stopped this long short of a planned leg's end: plan again
ZONE_PARK_DWELL_S: Final = 1.0  # ours: stand at the checkpoint in the spot, then back out
CHECKPOINT_TOLERANCE_M: Final = 0.5  # ours: the front bumper "passes over" a checkpoint within this

# No progress and recovery (seed 000 Sec. 8: "Most states implement a recovery state that is activated
# whenever the car makes no progress at all for a certain amount of time"). Progress is 0.5 m of travel
# (AnnieWAY code RECOVERY_PROGRESS_INDICATOR) or waiting on moving traffic. The times are ours, in
# multiples of the rules' 10 s of excess delay (rules 5.2): Drive 3 x (its own obstacle logic decides
# within BLOCKADE_STILL_S); Intersection 6 x (three other approaches each get their full
# PRECEDENCE_STUCK_S turn, a vehicle may stall in the box INTERSECTION_BOX_STUCK_S, plus 10 s);
# a recovery gets 2 x before the global recovery takes over. (AnnieWAY's code had these disabled:
# RECOVERY_TIMEOUT 100000 s.)
PROGRESS_DISTANCE_M: Final = 0.5
DRIVE_NO_PROGRESS_S: Final = 3.0 * MAX_EXCESS_DELAY_S
INTERSECTION_NO_PROGRESS_S: Final = 3.0 * PRECEDENCE_STUCK_S + INTERSECTION_BOX_STUCK_S + MAX_EXCESS_DELAY_S
ZONE_NO_PROGRESS_S: Final = 3.0 * MAX_EXCESS_DELAY_S
RECOVERY_NO_PROGRESS_S: Final = 2.0 * MAX_EXCESS_DELAY_S
RECOVERY_SETTLE_S: Final = 0.5  # AnnieWAY code MIN_WAIT_FOR_OBSTACLEMAP: stand still, look, then act
RECOVERY_SUCCESS_M: Final = 5.0  # ours: a recovery has worked once we made this much headway
RECOVERY_LEAP_M: Final = 15.0  # AnnieWAY code FROG_MODE_LEAP_DIST: an obstacle this close blocks the road
GLOBAL_REPLAN_INTERVAL_S: Final = 5.0  # AnnieWAY code GETBACKONTRACK_REPLAN_INTERVAL
OFF_TRACK_M: Final = 5.0  # ours: farther than this from the route, we are not on it any more
PAUSE_MOVED_RESET_M: Final = 10.0  # AnnieWAY code TRIGGER_DIST_CLEAR_HISTORY: moved in PAUSE -> re-localise


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
