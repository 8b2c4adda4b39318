"""Radar fusion: the vehicles ahead in our lane, V2V states merged with the radar (seed 003 Sec. IV-B, VI).

Seed 003 IV-B: vehicles on the neighbouring lane broadcast positions that noise projected onto ours, and
"GPS outage under bridges froze the position of some vehicles, causing our vehicle to stop"; the remedy
was the ACC radar: "once the vehicle ahead was within the 50-m range and tracked with high confidence by
radar, we put full trust into the radar measurements and ignored any broadcasted position in between our
car and the radar's detection". Sec. VI: "put more trust in the onboard sensors than in communicated
positions".

Per cycle (`RadarFusion.update(t_s, pose, radar, vehicles)`):

1. Our lane and arc length from the pose (`LaneMap.match` with our heading).
2. Communicating vehicles: each station's state predicted to t_s by the vehicle manager (latency removed),
   matched to a lane with its heading, blacklisted stations skipped (the paper's manual blacklist is kept
   as configuration). Lane hysteresis: a station's lane changes only after `lane_confirm_cycles`
   consecutive matches to the new lane with a margin of at least `min_lane_margin_m` (a position near the
   line between two lanes changes nothing), so a noisy next-lane car does not flicker into ours.
   Those on our lane and ahead: gap = along-lane distance from our front bumper to their rear bumper.
3. Radar: the target (range r, range rate, azimuth az, measured from our front bumper) is placed on the map
   (``front + r (cos(psi + az), sin(psi + az))``); a target on another lane is ignored (counted); its gap is
   the arc length from our front bumper to it, its speed ``v_own + range_rate / cos(az)``. A small
   alpha-beta tracker gives it continuity: a measurement within `radar_continuity_gate_m` of the
   prediction continues the track, one outside starts a new track (a cut-in or a different car); invalid
   cycles coast the track until `radar_lost_cycles` in a row lose it. A jump replaces the track only when
   the new target is seen again where it should be on the next hit (one clutter echo does not break an
   association; a cut-in costs one radar cycle).
4. Association: the communicating vehicle on our lane ahead whose gap and speed agree with the radar
   track (within `gap_gate_m` + 2 sigma of its position and `speed_gate_mps`), nearest first. N =
   `confirm_cycles` consecutive consistent cycles with the same station and radar track make it confident.
   Once confident it holds while the radar track continues: inconsistency of a healthy station is
   tolerated for `lose_inconsistent_cycles`, and of a frozen or silent one indefinitely (the radar keeps
   the gap: the bridge). It is lost when the radar track ends (`radar_lost_cycles` misses or a new
   track), when the station is inconsistent for too long, or leaves our lane.
5. Output, sorted by gap (index k = vehicle k + 1 ahead, as `PlatoonStrategy` takes them):
   - confident: the station as ``fused``: gap and speed from the radar, acceleration from V2V (intent);
     V2V vehicles between us and the radar's detection are ignored (paper); those beyond stay ``v2v``.
   - a confirmed radar track that no communicating vehicle explains, and nearer than every one of them:
     a ``radar`` leader (a non-communicating car, or one whose broadcast is wrong), then the V2V ones.
   - otherwise the V2V vehicles. A radar track farther than a V2V vehicle it does not match is reported
     (`FusionResult.radar_gap_m`) but not listed: the nearer V2V vehicle binds anyway.

Confidence: ``high`` fused (radar tracking) or a long radar-only track; ``medium`` a healthy V2V
vehicle, a young radar track, or a fused one whose radar is coasting; ``low`` a frozen or silent sender.

Predictions for the platoon MPC on `grid_s` (relative to t_s), positions relative to our front bumper at
t_s: V2V vehicles from the manager's CYRA trajectory projected onto our lane (``s(t) - L/2 - s_front``);
fused and radar-only ones with constant acceleration on the lane from the radar's gap and speed and the
V2V (fused) or tracked (radar) acceleration, speed kept in [0, v_max] (`LeaderPrediction.constant_accel`'s
form). `FusionResult.leader_predictions(params)` hands them to `PlatoonStrategy.step`.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from .lanemap import LaneMap
from .pose import Pose
from .vehicles import KMH_TO_MPS, VehicleManager, VehicleState

if TYPE_CHECKING:  # only the hand-over needs the QP's types
    from bywire.host.platoon.follow_qp import FollowParams, LeaderPrediction

FloatArray = npt.NDArray[np.float64]


class Source(StrEnum):
    RADAR = "radar"
    V2V = "v2v"
    FUSED = "fused"


class Confidence(StrEnum):
    HIGH = "high"
    MEDIUM = "medium"
    LOW = "low"


@dataclass(frozen=True)
class RadarMeasurement:
    """One radar cycle (vehicle CAN RADAR_Target): range from our front bumper, range rate, azimuth
    (positive to the left)."""

    t_s: float
    valid: bool
    range_m: float = math.nan
    range_rate_mps: float = math.nan
    azimuth_rad: float = 0.0

    @staticmethod
    def from_target(t_s: float, target: Any) -> RadarMeasurement:
        """From `bywire.protocol.vehicle_can.RadarTarget` (or anything with its fields)."""
        return RadarMeasurement(
            t_s,
            bool(target.valid),
            float(target.range_m),
            float(target.range_rate_mps),
            float(target.azimuth_rad),
        )


@dataclass(frozen=True)
class FusionConfig:
    host_length_m: float = 4.77  # VW Passat B6; the pose is the geometric centre, the radar at the front
    radar_range_m: float = 50.0  # seed 003 IV-B
    blacklist: frozenset[int] = frozenset()
    lane_confirm_cycles: int = 3
    min_lane_margin_m: float = 0.5
    radar_continuity_gate_m: float = 2.5
    radar_alpha: float = 0.5
    radar_beta: float = 0.3
    radar_confirm_cycles: int = 3  # a radar-only track is listed after this many hits
    radar_lost_cycles: int = 5  # missing/off-lane cycles in a row before the radar track is dropped
    gap_gate_m: float = 3.0
    speed_gate_mps: float = 1.5
    confirm_cycles: int = 5  # N: consistent cycles to a confident association
    lose_inconsistent_cycles: int = 10  # M for a healthy V2V sender that disagrees with the radar
    speed_max_mps: float = 130.0 * KMH_TO_MPS
    horizon_s: float = 10.0
    dt_s: float = 0.2  # prediction grid; FollowParams' default
    radar_accel_tau_s: float = 0.5

    @property
    def grid_s(self) -> FloatArray:
        return np.arange(round(self.horizon_s / self.dt_s) + 1, dtype=np.float64) * self.dt_s


@dataclass(frozen=True)
class LeadEstimate:
    """One vehicle ahead in our lane."""

    station_id: int | None  # None: radar only
    source: Source
    confidence: Confidence
    gap_m: float  # our front bumper to its rear bumper, along the lane
    speed_mps: float
    accel_mps2: float
    length_m: float
    grid_s: FloatArray  # prediction times relative to the fusion's t_s
    positions_m: FloatArray  # its rear bumper relative to our front bumper at t_s, on grid_s
    speeds_mps: FloatArray

    def leader_prediction(self, params: FollowParams) -> LeaderPrediction:
        """On the follow QP's grid (linear interpolation of ours; params' horizon must not exceed it)."""
        from bywire.host.platoon.follow_qp import LeaderPrediction

        t = params.time_grid_s()
        if t[-1] > self.grid_s[-1] + 1e-9:
            raise ValueError(
                f"QP horizon {t[-1]} s exceeds the fusion's prediction horizon {self.grid_s[-1]} s"
            )
        return LeaderPrediction(
            positions_m=np.interp(t, self.grid_s, self.positions_m),
            speeds_mps=np.interp(t, self.grid_s, self.speeds_mps),
        )


@dataclass(frozen=True)
class FusionResult:
    t_s: float
    host_lane_id: int | None
    host_s_m: float
    leads: tuple[LeadEstimate, ...]
    radar_gap_m: float | None  # the radar track's gap (None: no track)
    associated_station: int | None
    association_confident: bool

    @property
    def leader(self) -> LeadEstimate | None:
        return self.leads[0] if self.leads else None

    def leader_predictions(self, params: FollowParams) -> list[LeaderPrediction]:
        return [lead.leader_prediction(params) for lead in self.leads]


def constant_accel_profile(
    gap_m: float, speed_mps: float, accel_mps2: float, t_s: FloatArray, speed_max_mps: float
) -> tuple[FloatArray, FloatArray]:
    """Along-lane positions and speeds with constant acceleration until 0 or v_max, then constant speed."""
    v0 = min(max(speed_mps, 0.0), speed_max_mps)
    if accel_mps2 > 0.0:
        t_sat = (speed_max_mps - v0) / accel_mps2
    elif accel_mps2 < 0.0:
        t_sat = -v0 / accel_mps2
    else:
        t_sat = math.inf
    te = np.minimum(t_s, t_sat)
    v_end = v0 + accel_mps2 * te
    positions = gap_m + v0 * te + 0.5 * accel_mps2 * te**2 + v_end * (t_s - te)
    return np.asarray(positions, dtype=np.float64), np.asarray(v_end, dtype=np.float64)


@dataclass
class _RadarTrack:
    track_id: int
    t_s: float
    gap_m: float
    rel_speed_mps: float
    speed_mps: float
    t_hit_s: float
    speed_at_hit_mps: float
    accel_mps2: float = 0.0
    hits: int = 1
    misses: int = 0


@dataclass
class _Candidate:
    state: VehicleState
    s_m: float
    gap_m: float


@dataclass
class _LaneMemory:
    lane_id: int | None
    pending: int | None = None
    count: int = 0


class RadarFusion:
    """See the module docstring. Holds the radar track, the association and the lanes' hysteresis."""

    def __init__(self, lanemap: LaneMap, config: FusionConfig | None = None) -> None:
        self.map = lanemap
        self.cfg = config or FusionConfig()
        self.counts: Counter[str] = Counter()
        self._track: _RadarTrack | None = None
        self._pending: tuple[float, float, float, float] | None = None  # t, gap, rel, speed of a jump
        self._next_track_id = 1
        self._lanes: dict[int, _LaneMemory] = {}
        self._assoc_station: int | None = None
        self._assoc_track: int | None = None
        self._assoc_hits = 0
        self._assoc_bad = 0
        self.confident = False
        self._states: dict[int, VehicleState] = {}

    # ------------------------------------------------------------------------------------- lanes

    def _station_lane(self, st: VehicleState) -> int | None:
        m = self.map.match(st.x_m, st.y_m, st.heading_rad)
        lane = None if m is None else m.lane_id
        mem = self._lanes.get(st.station_id)
        if mem is None:
            self._lanes[st.station_id] = _LaneMemory(lane)
            return lane
        if lane == mem.lane_id or (m is not None and m.margin_m < self.cfg.min_lane_margin_m):
            mem.pending, mem.count = None, 0
            return mem.lane_id
        if lane == mem.pending:
            mem.count += 1
        else:
            mem.pending, mem.count = lane, 1
        if mem.count >= self.cfg.lane_confirm_cycles:
            mem.lane_id, mem.pending, mem.count = lane, None, 0
            self.counts["lane_change"] += 1
        return mem.lane_id

    # ------------------------------------------------------------------------------------- radar

    def _radar_step(
        self, t_s: float, pose: Pose, radar: RadarMeasurement | None, host_lane: int | None, front_s: float
    ) -> None:
        c = self.cfg
        tr = self._track
        meas: tuple[float, float, float] | None = None  # gap, relative speed, target speed
        if (
            radar is not None
            and radar.valid
            and all(math.isfinite(v) for v in (radar.range_m, radar.range_rate_mps, radar.azimuth_rad))
        ):
            if 0.0 <= radar.range_m <= c.radar_range_m and abs(radar.azimuth_rad) < 0.5 * math.pi:
                meas = self._radar_gap(pose, radar, host_lane, front_s)
            else:
                self.counts["radar_out_of_range"] += 1
        if tr is not None:
            # Coast to now: the gap closes at the relative speed; the target's speed follows ours plus it.
            tr.gap_m += tr.rel_speed_mps * max(t_s - tr.t_s, 0.0)
            tr.t_s = t_s
            tr.speed_mps = max(pose.speed_mps + tr.rel_speed_mps, 0.0)
        if meas is None:
            if tr is not None:
                tr.misses += 1
                if tr.misses >= c.radar_lost_cycles:
                    self.counts["radar_track_lost"] += 1
                    self._track = None
            return
        gap, rel, speed = meas
        if tr is not None and abs(gap - tr.gap_m) <= c.radar_continuity_gate_m:
            self._pending = None
            tr.gap_m += c.radar_alpha * (gap - tr.gap_m)
            # Range rate is measured directly (Doppler): blend it rather than differentiate the range.
            tr.rel_speed_mps += c.radar_beta * (rel - tr.rel_speed_mps)
            new_speed = max(pose.speed_mps + tr.rel_speed_mps, 0.0)
            dt_hit = t_s - tr.t_hit_s
            if dt_hit > 1e-6:
                alpha = dt_hit / (c.radar_accel_tau_s + dt_hit)
                tr.accel_mps2 += alpha * ((new_speed - tr.speed_at_hit_mps) / dt_hit - tr.accel_mps2)
            tr.speed_mps = tr.speed_at_hit_mps = new_speed
            tr.t_hit_s = t_s
            tr.hits += 1
            tr.misses = 0
            return
        if tr is not None:
            # A jump: a cut-in, the leader leaving, or one clutter echo. The old track coasts (a miss) until
            # the new target is seen again where it should be; only then is the track replaced.
            pend = self._pending
            self._pending = (t_s, gap, rel, speed)
            again = (
                pend is not None
                and abs(gap - (pend[1] + pend[2] * (t_s - pend[0]))) <= c.radar_continuity_gate_m
            )
            if not again:
                tr.misses += 1
                if tr.misses >= c.radar_lost_cycles:
                    self.counts["radar_track_lost"] += 1
                    self._track = None
                return
            self.counts["radar_track_replaced"] += 1
        self._pending = None
        self._track = _RadarTrack(
            self._next_track_id, t_s, gap, rel, speed, t_hit_s=t_s, speed_at_hit_mps=speed
        )
        self._next_track_id += 1

    def _radar_gap(
        self, pose: Pose, radar: RadarMeasurement, host_lane: int | None, front_s: float
    ) -> tuple[float, float, float] | None:
        c = self.cfg
        half = 0.5 * c.host_length_m
        fx = pose.x_m + half * math.cos(pose.heading_rad)
        fy = pose.y_m + half * math.sin(pose.heading_rad)
        ang = pose.heading_rad + radar.azimuth_rad
        tx, ty = fx + radar.range_m * math.cos(ang), fy + radar.range_m * math.sin(ang)
        cos_az = max(math.cos(radar.azimuth_rad), 0.5)
        rel = radar.range_rate_mps / cos_az
        if host_lane is None:
            gap = radar.range_m * math.cos(radar.azimuth_rad)
        else:
            m = self.map.match(tx, ty)
            if m is None or m.lane_id != host_lane:
                # A car on the next lane (or off the road) seen by the radar is not our leader.
                self.counts["radar_off_lane"] += 1
                return None
            gap = m.s_m - front_s
        return gap, rel, pose.speed_mps + rel

    # -------------------------------------------------------------------------------- the cycle

    def update(
        self, t_s: float, pose: Pose, radar: RadarMeasurement | None, vehicles: VehicleManager
    ) -> FusionResult:
        c = self.cfg
        host = self.map.match(pose.x_m, pose.y_m, pose.heading_rad)
        host_lane = None if host is None else host.lane_id
        host_s = math.nan if host is None else host.s_m
        front_s = host_s + 0.5 * c.host_length_m
        if host is None:
            self.counts["host_off_map"] += 1
        self._radar_step(t_s, pose, radar, host_lane, front_s)

        cands: list[_Candidate] = []
        states = vehicles.states(t_s)
        self._states = {st.station_id: st for st in states}
        for st in states:
            if st.station_id in c.blacklist:
                self.counts["blacklisted"] += 1
                continue
            lane = self._station_lane(st)
            if host_lane is None or lane != host_lane:
                continue
            s = self.map.project_s(host_lane, st.x_m, st.y_m)
            if s <= host_s:
                continue
            cands.append(_Candidate(st, s, s - 0.5 * st.length_m - front_s))
        cands.sort(key=lambda cd: cd.gap_m)
        for sid in [k for k in self._lanes if k not in vehicles.tracks]:
            del self._lanes[sid]

        self._associate(cands)
        leads = self._assemble(t_s, cands, vehicles, host_lane, front_s)
        tr = self._track
        return FusionResult(
            t_s=t_s,
            host_lane_id=host_lane,
            host_s_m=host_s,
            leads=tuple(leads),
            radar_gap_m=None if tr is None else tr.gap_m,
            associated_station=self._assoc_station,
            association_confident=self.confident,
        )

    def _consistent(self, cd: _Candidate, tr: _RadarTrack) -> bool:
        c = self.cfg
        gate = c.gap_gate_m + 2.0 * cd.state.position_std_m
        return abs(cd.gap_m - tr.gap_m) <= gate and abs(cd.state.speed_mps - tr.speed_mps) <= c.speed_gate_mps

    def _drop_association(self, why: str) -> None:
        if self.confident:
            self.counts[f"association_lost_{why}"] += 1
        self._assoc_station = self._assoc_track = None
        self._assoc_hits = self._assoc_bad = 0
        self.confident = False

    def _associate(self, cands: list[_Candidate]) -> None:
        c = self.cfg
        tr = self._track
        if tr is None:
            self._drop_association("radar")
            return
        if self.confident:
            if tr.track_id != self._assoc_track:
                self._drop_association("radar")
                return
            cd = next((x for x in cands if x.state.station_id == self._assoc_station), None)
            if cd is None:
                st = self._states.get(self._assoc_station) if self._assoc_station is not None else None
                if st is not None and st.low_confidence:
                    # A frozen or silent sender's broadcast may put it anywhere, even behind us: the radar
                    # keeps the gap (seed 003 IV-B), the association stays.
                    self.counts["radar_holds_low_confidence_sender"] += 1
                    return
                # A healthy station that left our lane is no longer our leader; a vanished one leaves the
                # radar track as a radar-only leader.
                self._drop_association("lane")
                return
            if self._consistent(cd, tr):
                self._assoc_bad = 0
            elif not cd.state.low_confidence:
                self._assoc_bad += 1
                if self._assoc_bad >= c.lose_inconsistent_cycles:
                    self._drop_association("inconsistent")
            else:
                self.counts["radar_holds_low_confidence_sender"] += 1
            return
        match = next((x for x in cands if self._consistent(x, tr)), None)
        if match is None:
            self._assoc_station = self._assoc_track = None
            self._assoc_hits = 0
            return
        sid = match.state.station_id
        if sid == self._assoc_station and tr.track_id == self._assoc_track:
            self._assoc_hits += 1
        else:
            self._assoc_station, self._assoc_track, self._assoc_hits = sid, tr.track_id, 1
        if self._assoc_hits >= c.confirm_cycles:
            self.confident = True
            self._assoc_bad = 0
            self.counts["association_confident"] += 1

    def _v2v_estimate(
        self, cd: _Candidate, t_s: float, vehicles: VehicleManager, host_lane: int | None, front_s: float
    ) -> LeadEstimate:
        c = self.cfg
        grid = c.grid_s
        traj = vehicles.predict_trajectory(cd.state.station_id, t_s + grid, t_now_s=t_s)
        assert traj is not None and host_lane is not None  # candidates exist only on our known lane
        s_m = self.map.project_s_many(host_lane, np.column_stack((traj.x_m, traj.y_m)))
        positions = s_m - 0.5 * cd.state.length_m - front_s
        conf = Confidence.LOW if cd.state.low_confidence else Confidence.MEDIUM
        return LeadEstimate(
            station_id=cd.state.station_id,
            source=Source.V2V,
            confidence=conf,
            gap_m=cd.gap_m,
            speed_mps=cd.state.speed_mps,
            accel_mps2=cd.state.accel_mps2,
            length_m=cd.state.length_m,
            grid_s=grid,
            positions_m=positions,
            speeds_mps=traj.speed_mps,
        )

    def _radar_estimate(self, tr: _RadarTrack, cd: _Candidate | None) -> LeadEstimate:
        c = self.cfg
        grid = c.grid_s
        if cd is not None:
            # V2V acceleration is the sender's intent, unless its broadcast is frozen or stale: then the
            # radar's own estimate (a frozen sender's filter sees speed jumps that are not braking).
            accel = (
                cd.state.accel_mps2
                if not cd.state.low_confidence
                else float(np.clip(tr.accel_mps2, -8.0, 3.0))
            )
            source = Source.FUSED
            conf = Confidence.HIGH if tr.misses == 0 else Confidence.MEDIUM
            length = cd.state.length_m
        else:
            accel = float(np.clip(tr.accel_mps2, -8.0, 3.0))
            source = Source.RADAR
            conf = Confidence.HIGH if tr.hits >= c.confirm_cycles and tr.misses == 0 else Confidence.MEDIUM
            length = 4.5
        positions, speeds = constant_accel_profile(tr.gap_m, tr.speed_mps, accel, grid, c.speed_max_mps)
        return LeadEstimate(
            station_id=None if cd is None else cd.state.station_id,
            source=source,
            confidence=conf,
            gap_m=tr.gap_m,
            speed_mps=tr.speed_mps,
            accel_mps2=accel,
            length_m=length,
            grid_s=grid,
            positions_m=positions,
            speeds_mps=speeds,
        )

    def _assemble(
        self,
        t_s: float,
        cands: list[_Candidate],
        vehicles: VehicleManager,
        host_lane: int | None,
        front_s: float,
    ) -> list[LeadEstimate]:
        c = self.cfg
        tr = self._track
        leads: list[LeadEstimate] = []
        if tr is not None and self.confident:
            cd = next((x for x in cands if x.state.station_id == self._assoc_station), None)
            if cd is None:  # a low-confidence sender whose broadcast is off our lane (see _associate)
                assert self._assoc_station is not None
                cd = _Candidate(self._states[self._assoc_station], math.nan, math.nan)
            fused = self._radar_estimate(tr, cd)
            leads.append(fused)
            for other in cands:
                if other is cd:
                    continue
                if other.gap_m < tr.gap_m:
                    # Seed 003 IV-B: broadcast positions between us and the radar's detection are ignored.
                    self.counts["v2v_ignored_between"] += 1
                    continue
                leads.append(self._v2v_estimate(other, t_s, vehicles, host_lane, front_s))
            return sorted(leads, key=lambda e: e.gap_m)
        if host_lane is not None:
            leads = [self._v2v_estimate(cd, t_s, vehicles, host_lane, front_s) for cd in cands]
        confirmed = tr is not None and tr.hits >= c.radar_confirm_cycles
        explained = tr is not None and any(self._consistent(cd, tr) for cd in cands)
        nearest_v2v = cands[0].gap_m if cands else math.inf
        if tr is not None and confirmed and not explained and tr.gap_m < nearest_v2v:
            # Something the radar sees nearer than every communicating car: a non-communicating vehicle.
            leads.insert(0, self._radar_estimate(tr, None))
        return leads
