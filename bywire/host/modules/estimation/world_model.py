"""The world model of seed 003 section IV as a module: the vehicle manager with CYRA prediction, the lane map
and radar fusion turn V2V, the pose and the radar into `/world/leads`, the vehicles ahead in our lane and
the road side (traffic lights, speed limits). Pure: it replays exactly.
"""

from __future__ import annotations

import math

from bywire.host.geo import LocalFrame
from bywire.host.modules.gcdc_messages import (
    POSE,
    V2V_RECEIVED,
    WORLD_LEADS,
    Lead,
    LeadSet,
    PoseReport,
    RoadsideItem,
    V2vBatch,
    V2vLight,
    V2vLimit,
)
from bywire.host.modules.messages import (
    RADAR,
    RadarReport,
)
from bywire.host.runtime.module import Module, ModuleContext
from bywire.host.world.lanemap import LaneMap
from bywire.host.world.pose import Pose
from bywire.host.world.radar_fusion import FusionConfig, RadarFusion, RadarMeasurement
from bywire.host.world.vehicles import VehicleManager, VehicleMessage


def _pose_of(r: PoseReport) -> Pose:
    return Pose(
        r.t_s, r.x_m, r.y_m, r.heading_rad, r.speed_mps, r.accel_mps2, r.yaw_rate_radps, r.lat_deg, r.lon_deg,
        r.position_std_m, math.radians(0.1), r.rtk, r.gnss, r.dead_reckoning, r.stale, r.fix_quality,
    )  # fmt: skip


class WorldModel(Module):
    """Vehicle manager + lane map + radar fusion (seed 003 II-f, IV): the vehicles ahead in our lane."""

    def __init__(
        self,
        frame: LocalFrame,
        lanemap: LaneMap,
        fusion: FusionConfig | None = None,
        max_leads: int = 10,
    ) -> None:
        self.frame = frame
        self.map = lanemap
        self.vm = VehicleManager()
        self.fusion = RadarFusion(lanemap, fusion)
        self.max_leads = max_leads
        self._lights: dict[tuple[int, int, int], V2vLight] = {}
        self._limits: dict[tuple[int, int], V2vLimit] = {}
        self._last_radar_s = -math.inf
        self.off_map = 0

    def _receive(self, batch: V2vBatch) -> None:
        for v in batch.vehicles:
            x, y = self.frame.to_local(v.lat_deg, v.lon_deg)
            if self.map.match(x, y) is None:
                # Off every lane of the map (a car on a side road, a sender hundreds of metres away, a
                # forged fleet): nothing the platoon can follow or hit; keeps the manager and fusion small.
                self.off_map += 1
                continue
            msg = VehicleMessage.from_geodetic(
                self.frame, v.station_id, v.t_gen_s, v.lat_deg, v.lon_deg, v.heading_true_deg, v.speed_mps,
                None if math.isnan(v.yaw_rate_radps) else v.yaw_rate_radps,
                None if math.isnan(v.accel_mps2) else v.accel_mps2,
                v.length_m, v.width_m,
            )  # fmt: skip
            self.vm.receive(msg, v.t_rx_s)
        for light in batch.lights:
            self._lights[(light.station_id, light.intersection_id, light.signal_group)] = light
        for lim in batch.limits:
            self._limits[(lim.station_id, lim.zone_id)] = lim

    def _roadside(self, now: float, host_lane: int, front_s: float) -> tuple[RoadsideItem, ...]:
        items: list[RoadsideItem] = []
        for key, light in list(self._lights.items()):
            if now - light.t_gen_s > 1.0:  # a light not heard for a second says nothing
                del self._lights[key]
                continue
            x, y = self.frame.to_local(light.lat_deg, light.lon_deg)
            m = self.map.match(x, y)
            if m is None or m.lane_id != host_lane:
                continue
            ttc = (
                light.time_to_change_s - (now - light.t_gen_s)
                if math.isfinite(light.time_to_change_s)
                else math.nan
            )
            items.append(
                RoadsideItem("traffic_light", light.station_id, m.s_m - front_s, light.phase, ttc, math.nan)
            )
        for lim in self._limits.values():
            x, y = self.frame.to_local(lim.lat_deg, lim.lon_deg)
            m = self.map.match(x, y)
            if m is None or m.lane_id != host_lane:
                continue
            items.append(
                RoadsideItem("speed_limit", lim.station_id, m.s_m - front_s, "", math.nan, lim.limit_mps)
            )
        return tuple(sorted(items, key=lambda i: i.distance_m))

    def step(self, ctx: ModuleContext) -> None:
        now = ctx.now_s
        for batch in ctx.new(V2V_RECEIVED):
            self._receive(batch)
        self.vm.prune(now)
        pose: PoseReport | None = ctx.latest(POSE)
        radar: RadarReport | None = ctx.latest(RADAR)
        frozen = sum(1 for tr in self.vm.tracks.values() if tr.frozen)
        silent = sum(1 for tr in self.vm.tracks.values() if tr.silent(now))
        if pose is None or not pose.valid or pose.stale:
            ctx.publish(
                WORLD_LEADS,
                LeadSet(
                    now, False, -1, math.nan, (), (), math.nan, -1, False, len(self.vm.tracks), frozen, silent
                ),
            )
            return
        meas: RadarMeasurement | None = None
        if radar is not None and radar.valid and radar.rx_s > self._last_radar_s:
            meas = RadarMeasurement(radar.rx_s, True, radar.range_m, radar.range_rate_mps, 0.0)
            self._last_radar_s = radar.rx_s
        elif radar is not None and not radar.valid:
            meas = RadarMeasurement(now, False)
        res = self.fusion.update(now, _pose_of(pose), meas, self.vm)
        leads = tuple(
            Lead(
                -1 if e.station_id is None else e.station_id, str(e.source), str(e.confidence), e.gap_m,
                e.speed_mps, e.accel_mps2, e.length_m, tuple(e.grid_s.tolist()),
                tuple(e.positions_m.tolist()),
                tuple(e.speeds_mps.tolist()),
            )
            for e in res.leads[: self.max_leads]
        )  # fmt: skip
        lane = -1 if res.host_lane_id is None else res.host_lane_id
        front_s = res.host_s_m + 0.5 * self.fusion.cfg.host_length_m
        roadside = self._roadside(now, lane, front_s) if lane >= 0 else ()
        ctx.publish(
            WORLD_LEADS,
            LeadSet(
                now, True, lane, res.host_s_m, leads, roadside,
                math.nan if res.radar_gap_m is None else res.radar_gap_m,
                -1 if res.associated_station is None else res.associated_station,
                res.association_confident, len(self.vm.tracks), frozen, silent,
            ),
        )  # fmt: skip
