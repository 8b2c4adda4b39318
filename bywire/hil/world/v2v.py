"""What the simulated vehicles and the road side broadcast (seed 003 Sec. III, IV-B, IV-C, VI).

`V2vBroadcaster.due(t_s)` returns the datagrams (ETSI CAMs, SPATEMs and MAPEMs, `protocol.v2x.wire`) whose
delivery time has come by scenario time t_s; the plant hands them to the V2X link (UDP broadcast on
loopback in HIL, the in-process `mem://` domain in SIL). Deterministic for a seed.

Per communicating vehicle (`V2vSenderSpec`), at `rate_hz` on epochs ``k / rate + phase`` (the phase spread
by station id, as real senders are not synchronised): its state at the epoch, stamped with the epoch's
wall time (`unix_time`, GNSS time in the GCDC), position with white noise per axis (`position_noise_m`),
speed with `speed_noise_mps`, delivered `latency_s` later; its CAM carries the low-frequency container
at the ETSI rate (`etsi_cam.LowFrequencyClock`). The simulated cars are GCDC participants: at the GCDC
profile's fixed rate, not the ETSI generation rules (host/modules/io/v2v.py), and each sends beside its
CAM the GCDC 2016 iCLCM (`protocol.v2x.iclcm`), same stamp and latency, from its driver model:

- controllerType: cacc / acc for those drivers, cc for a scripted speed, manual for a human (IDM);
- targetLongitudinalAcceleration: the driver's command u (unavailable for a human, whose command is no
  controller's request); timeHeadway and cruiseSpeed: the driver's time gap and set speed (acc, cacc);
- the most important object: the car ahead on its lane (its station id, 0 if it does not communicate),
  gap and gap rate; bearing and lane unavailable;
- platoonID: 1 (A) on our car's starting lane, 2 (B) on another; the rear axle at REAR_AXLE_SHARE of the
  length behind the front bumper (the Passat's 3.67 m of 4.77 m; no car spec has one).

No random draw is spent on an iCLCM: the CAMs' noise is the same with or without them.

Channel loss (`world.v2v.loss`, a campaign's axis): each of the other cars' datagrams, CAM and iCLCM
alike, is lost with that probability on its own draw, from a generator of its own, so that the states
sent (and their noise) are the same at every loss rate, and a run without loss draws nothing.

The bad data of seed 003 (Sec. IV-B, VI):

- frozen (a GPS outage under a bridge, seed 003 Fig. 6, Sec. VI): the broadcast position stays where it
  was when the interval began; speed, heading and acceleration go on (they come from the car's odometry
  and gyro), and the generation time advances; the iCLCM goes on unchanged;
- silent: nothing is sent, neither CAM nor iCLCM (seed 003 VI: "did not send anything at all");
- late: `extra_s` more latency (outdated data), the generation time still the epoch's.

Road side: a traffic light's RSU sends its signal group's phase and time to change in a SPATEM at 10 Hz and
its stop line in a MAPEM at 1 Hz (the first at once), a speed-limit sign its zone in a MAPEM road segment
at 1 Hz, each from the stop line's / zone start's position on the road, facing the road's direction.

A hostile sender (`FuzzSpec`): `protocol.v2x.fuzz.V2xFuzzer` floods the link with random and mutated
datagrams at `rate_hz` during its interval, its fleet of fake vehicles placed 700 m beside the road (inside
the receiver's 2 km vicinity, so their clean frames are accepted and reach the vehicle manager, but never
on our lane) and never using a real station id (so the platoon's own senders keep their histories).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable

import numpy as np

from bywire.hil.world.spec import FuzzSpec, RoadsideSpec, WorldSpec
from bywire.hil.world.traffic import EGO, TrafficVehicle, World
from bywire.protocol.v2x.codec import SpeedLimit, TrafficLightPhase, VehicleState
from bywire.protocol.v2x.dsrc import IntersectionMap, RoadMap, SignalGroupState, SignalPhases, StopLine
from bywire.protocol.v2x.etsi_cam import LowFrequencyClock
from bywire.protocol.v2x.fuzz import V2xFuzzer
from bywire.protocol.v2x.iclcm import ControllerType, CooperativeState
from bywire.protocol.v2x.receiver import GeoPoint
from bywire.protocol.v2x.wire import encode

LIGHT_RATE_HZ = 10.0
MAP_RATE_HZ = 1.0
FUZZ_OFFSET_M = 700.0
REAR_AXLE_SHARE = 3.67 / 4.77  # front bumper to rear axle over the length: the Passat B6's
CONTROLLER_OF_DRIVER = {
    "cacc": ControllerType.CACC,
    "acc": ControllerType.ACC,
    "scripted": ControllerType.CC,
    "idm": ControllerType.MANUAL,
}


def _phase_at(rs: RoadsideSpec, t_s: float) -> tuple[str, float | None]:
    """The light's phase at t_s and the time until its next change (None: no change scripted)."""
    phase = rs.phases[0][1]
    nxt: float | None = None
    for t_p, p in rs.phases:
        if t_p <= t_s:
            phase = p
        else:
            nxt = t_p - t_s
            break
    return phase, nxt


class V2vBroadcaster:
    def __init__(self, world: World, unix_time: Callable[[float], float], seed: int = 1) -> None:
        self.world = world
        self.spec: WorldSpec = world.spec
        self.unix_time = unix_time
        self.rng = np.random.default_rng(seed + 7919)
        self._loss = self.spec.v2v.loss
        self._loss_rng = np.random.default_rng(seed + 104729)
        self.lost = 0
        self._queue: list[tuple[float, int, bytes]] = []
        self._seq = 0
        self._next: dict[int, float] = {}
        self._frozen_at: dict[int, tuple[float, float]] = {}
        self._last_fix: dict[int, tuple[float, float]] = {}
        for v in world.vehicles:
            if v.spec.v2v is not None:
                period = 1.0 / v.spec.v2v.rate_hz
                self._next[v.index] = (v.spec.v2v.station_id * 0.6180339887 % 1.0) * period
        self._low_frequency: dict[int, LowFrequencyClock] = {}
        self._next_light = 0.0
        self._next_map = 0.0
        self.sent = 0
        self.fuzzer: V2xFuzzer | None = None
        self._fuzz_next = math.inf
        fz = self.spec.fuzz
        if fz is not None:
            self.fuzzer = self._make_fuzzer(fz)
            self._fuzz_next = fz.at_s
        self.fuzz_sent = 0

    def _make_fuzzer(self, fz: FuzzSpec) -> V2xFuzzer:
        road = self.world.road
        h = math.radians(self.spec.road.heading_deg)
        # Beside the road, to the left of its start: inside the vicinity gate, never on a lane.
        lat, lon = road.frame.to_geodetic(-FUZZ_OFFSET_M * math.sin(h), FUZZ_OFFSET_M * math.cos(h))
        return V2xFuzzer(
            fz.seed,
            center=GeoPoint(lat, lon),
            own_station_id=self.spec.ego.station_id,
            avoid_station_ids=frozenset(self.spec.station_ids)
            | frozenset(rs.station_id for rs in self.spec.roadside),
        )

    def _push(self, deliver_s: float, payload: bytes) -> None:
        heapq.heappush(self._queue, (deliver_s, self._seq, payload))
        self._seq += 1

    def _vehicle_state(self, v: TrafficVehicle, epoch: float) -> VehicleState:
        assert v.spec.v2v is not None
        sd = v.spec.v2v
        w = self.world
        pose = w.pose_of(v)
        x, y = pose.x_m, pose.y_m
        if sd.position_noise_m > 0.0:
            nx, ny = self.rng.normal(0.0, sd.position_noise_m, 2)
            x, y = x + float(nx), y + float(ny)
        if any(iv.active(epoch) for iv in sd.frozen):
            # The receiver repeats its last fix exactly (noise included): that is what makes it frozen.
            x, y = self._frozen_at.setdefault(v.index, self._last_fix.get(v.index, (x, y)))
        else:
            self._frozen_at.pop(v.index, None)
            self._last_fix[v.index] = (x, y)
        lat, lon = w.road.frame.to_geodetic(x, y)
        azimuth = w.road.frame.true_azimuth_from_heading(pose.heading_rad, lat, lon)
        speed = max(
            0.0, v.v_mps + float(self.rng.normal(0.0, sd.speed_noise_mps)) if sd.speed_noise_mps else v.v_mps
        )
        return VehicleState(
            station_id=sd.station_id,
            generation_time_s=self.unix_time(epoch),
            lat_deg=lat,
            lon_deg=lon,
            heading_rad=math.atan2(
                math.sin(math.radians(90.0 - azimuth)), math.cos(math.radians(90.0 - azimuth))
            ),
            speed_mps=speed,
            yaw_rate_radps=0.0,
            accel_mps2=min(max(v.a_mps2, -16.0), 16.0),
            length_m=v.spec.length_m,
            width_m=v.spec.width_m,
        )

    def _cooperative_state(self, v: TrafficVehicle, generation_time_s: float) -> CooperativeState:
        """The iCLCM a simulated car sends beside its CAM (module docstring)."""
        assert v.spec.v2v is not None
        w = self.world
        d = v.spec.driver
        controller = CONTROLLER_OF_DRIVER[d.kind]
        follows = controller in (ControllerType.ACC, ControllerType.CACC)
        manual = controller is ControllerType.MANUAL
        mio_id, mio_range, mio_rate = 0, None, None
        pred = w.pred.get(v.index)
        if pred is not None:
            if pred == EGO:
                mio_id, mio_speed = self.spec.ego.station_id, w.ego.speed_mps
            else:
                lead = w.vehicles[pred - 1]
                mio_id = lead.spec.v2v.station_id if lead.spec.v2v is not None else 0
                mio_speed = lead.v_mps
            gap = w.gap[v.index]
            mio_range = gap if 0.0 <= gap <= 655.34 else None
            mio_rate = mio_speed - v.v_mps
        return CooperativeState(
            station_id=v.spec.v2v.station_id,
            generation_time_s=generation_time_s,
            controller_type=controller,
            target_accel_mps2=None if manual else min(max(v.u_mps2, -10.0), 10.0),
            time_headway_s=d.headway_s if follows and d.headway_s <= 36.0 else None,
            cruise_speed_mps=d.v_set_mps if follows and d.v_set_mps <= 50.0 else None,
            rear_axle_m=min(REAR_AXLE_SHARE * v.spec.length_m, 40.95),
            mio_station_id=mio_id,
            mio_range_m=mio_range,
            mio_range_rate_mps=mio_rate,
            platoon_id=1 if v.lane == self.spec.ego.lane else 2,
        )

    def _place(self, rs: RoadsideSpec) -> tuple[float, float, float]:
        """(lat, lon, true heading counter-clockwise from east) of a road-side object's place on the road."""
        road = self.world.road
        p = road.pose_at(0 if rs.lane is None else rs.lane, rs.s_m)
        lat, lon = road.frame.to_geodetic(p.x_m, p.y_m)
        azimuth = road.frame.true_azimuth_from_heading(p.heading_rad, lat, lon)
        return lat, lon, math.remainder(math.radians(90.0 - azimuth), 2.0 * math.pi)

    def _spatem(self, rs: RoadsideSpec, t_s: float) -> bytes:
        phase, ttc = _phase_at(rs, t_s)
        group = SignalGroupState(
            rs.intersection_id,
            rs.signal_group,
            TrafficLightPhase(phase),
            None if ttc is None else min(ttc, 300.0),
        )
        return encode(SignalPhases(rs.station_id, self.unix_time(t_s), (group,)))

    def _mapem(self, rs: RoadsideSpec, t_s: float) -> bytes:
        lat, lon, heading = self._place(rs)
        gen = self.unix_time(t_s)
        if rs.kind == "speed_limit":
            zone = SpeedLimit(rs.station_id, gen, rs.station_id & 0xFFFF, lat, lon, rs.limit_mps, heading)
            return encode(RoadMap(rs.station_id, gen, speed_limits=(zone,)))
        line = StopLine(rs.signal_group, lat, lon, heading)
        return encode(
            RoadMap(rs.station_id, gen, intersections=(IntersectionMap(rs.intersection_id, (line,)),))
        )

    def due(self, t_s: float) -> list[bytes]:
        """Datagrams delivered by t_s, in delivery order (call at the plant's events)."""
        for v in self.world.vehicles:
            nxt = self._next.get(v.index)
            if nxt is None or not v.present:
                continue
            sd = v.spec.v2v
            assert sd is not None
            period = 1.0 / sd.rate_hz
            while nxt <= t_s:
                if not any(iv.active(nxt) for iv in sd.silent):
                    latency = sd.latency_s + sum(extra for iv, extra in sd.late_s if iv.active(nxt))
                    state = self._vehicle_state(v, nxt)
                    lf = self._low_frequency.setdefault(v.index, LowFrequencyClock()).due(
                        state.generation_time_s
                    )
                    for payload in (
                        encode(state, low_frequency=lf),
                        encode(self._cooperative_state(v, state.generation_time_s)),
                    ):
                        if self._loss and self._loss_rng.random() < self._loss:
                            self.lost += 1
                        else:
                            self._push(nxt + latency, payload)
                nxt += period
            self._next[v.index] = nxt
        while self.spec.roadside and self._next_map <= t_s:
            for rs in self.spec.roadside:
                self._push(self._next_map + 0.01, self._mapem(rs, self._next_map))
            self._next_map += 1.0 / MAP_RATE_HZ
        while self.spec.roadside and self._next_light <= t_s:
            for rs in self.spec.roadside:
                if rs.kind == "traffic_light":
                    self._push(self._next_light + 0.01, self._spatem(rs, self._next_light))
            self._next_light += 1.0 / LIGHT_RATE_HZ
        fz = self.spec.fuzz
        if self.fuzzer is not None and fz is not None:
            end = fz.at_s + fz.duration_s
            while self._fuzz_next <= min(t_s, end):
                _, frame = self.fuzzer.next(self.unix_time(self._fuzz_next))
                self._push(self._fuzz_next, frame)
                self.fuzz_sent += 1
                self._fuzz_next += 1.0 / fz.rate_hz
        out = []
        while self._queue and self._queue[0][0] <= t_s:
            out.append(heapq.heappop(self._queue)[2])
        self.sent += len(out)
        return out


__all__ = ["V2vBroadcaster"]
