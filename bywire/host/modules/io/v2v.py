"""The V2X link as two modules (seed 003 sections II and IV-B): `V2vRxIo` hands every datagram to the
hardened `protocol.v2x.receiver.V2vReceiver` and publishes what it accepted with the rejection counts
(CAMs as vehicles, iCLCMs as what each station's cooperative controller says, SPATEM phases placed at
their MAPEM stop lines as lights, MAPEM zones as limits); `V2vTxIo` broadcasts our own ETSI CAM from the
pose, its low-frequency container every 500 ms, and in the GCDC profile the GCDC 2016 iCLCM beside it.

When `V2vTxIo` sends (`profile`):

- `etsi` (the default): a CAM when the generation rules of EN 302 637-2 6.1.3 say so
  (`protocol.v2x.cam_generation`: at most 10 Hz, on a 4 deg / 4 m / 0.5 m/s change, at least 1 Hz),
  checked at every release (the module's period must then be 100 ms or less); no iCLCM (the CDD gives
  messageID 10 to SSEM since v1.3.1: an ETSI stack off the GCDC would not read ours as an iCLCM).
- `gcdc` (the platoon profile, host/configs/gcdc.yaml): a CAM and an iCLCM at every release, at the
  module's fixed rate (period 40-100 ms: 10-25 Hz; 100 ms shipped, which is also the ETSI maximum).
  Exempt from the ETSI rules as the closed event's own rule: its followers close their loops over the
  predecessors' messages, and the rules' rhythm is a function of speed (200 ms at 100 km/h, 400 ms at
  36 km/h, 1 s standing) where the platoon's string stability at 0.6 s is shown for information delays
  of 0.05-0.2 s (host/modules/control/platoon.py). Neither the GCDC 2016 iCLCM module nor the CAM
  schemas in the shared data state a rate; ours is the one the platoon is designed and tested at.

The iCLCM (`protocol.v2x.iclcm` maps its fields) is built from the platoon controller's newest status
(requested acceleration, time gap, cruise speed), the world model's nearest lead (the most important
object) and the ECU's state (controllerType cacc while the platoon controller drives the engaged car,
manual otherwise), read as *sampled* topics: `v2v_tx` is never ordered behind, held for or restarted
with their producers (`host.runtime.module`), and the CAM is encoded and sent before any of it, so the
CAM leaves at the instant it did before the iCLCM existed.

Time: V2V generation times are UNIX seconds on the wire; `V2vRxIo` maps them onto the runtime clock with
the host's `unix_time(now)` (SIL: the scenario's epoch + simulated time; HIL: the wall clock's offset to
CLOCK_MONOTONIC), so everything downstream runs on one clock.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Final, Literal

import numpy as np

from bywire.host.geo import LocalFrame, wrap_angle
from bywire.host.modules.gcdc_messages import (
    PLATOON,
    POSE,
    V2V_ICLCM_SENT,
    V2V_RECEIVED,
    V2V_SENT,
    WORLD_LEADS,
    CamSent,
    IclcmSent,
    LeadSet,
    PlatoonStatus,
    PoseReport,
    ReasonCount,
    V2vBatch,
    V2vCooperative,
    V2vLight,
    V2vLimit,
    V2vVehicle,
)
from bywire.host.modules.messages import ECU_STATUS, EcuStatusReport
from bywire.host.runtime.module import Module, ModuleContext
from bywire.protocol.ecu_types import EcuState
from bywire.protocol.v2x.cam_generation import CamGenerationRules
from bywire.protocol.v2x.codec import GEN_TIME_RESOLUTION_S, SpeedLimit, TrafficLightState, VehicleState
from bywire.protocol.v2x.dsrc import RoadMap, SignalPhases
from bywire.protocol.v2x.etsi_cam import LowFrequencyClock
from bywire.protocol.v2x.iclcm import ControllerType, CooperativeState
from bywire.protocol.v2x.receiver import GeoPoint, ReceiverParams, V2vReceiver
from bywire.protocol.v2x.roadside import RoadsideView
from bywire.protocol.v2x.wire import encode

MAX_DATAGRAMS_PER_RELEASE = 200  # bounds a release under a flood; the rest waits in the socket buffer

TxProfile = Literal["etsi", "gcdc"]
TX_PROFILES: Final[tuple[TxProfile, ...]] = ("etsi", "gcdc")
# Front bumper to rear axle of the Passat B6: 0.95 m front overhang + 2.72 m wheelbase
# (host.behaviour.rules.PASSAT_REAR_AXLE_TO_FRONT_M).
PASSAT_REAR_AXLE_M: Final = 0.95 + 2.72
# The platoon's status older than this is not what the car does: the ECU link refuses a request this old
# (gcdc.yaml's request_max_age_ms) and asks for a controlled stop instead.
PLATOON_MAX_AGE_S: Final = 0.25
WORLD_MAX_AGE_S: Final = 0.3  # as the platoon controller's world_stale_s: older, it drives blind
TARGET_ACCEL_MAX_MPS2: Final = 10.0  # the iCLCM's range; an emergency request (-8) fits
# Modes in which the platoon controller closes the loop (not a script's or nobody's requests).
_DRIVING_MODES: Final = frozenset({"cruise", "platoon", "stop_line", "emergency", "hold", "blind"})


def _nan(value: float | None) -> float:
    return math.nan if value is None else float(value)


def _within(value: float, lo: float, hi: float) -> float | None:
    """The value where the wire can carry it; None (unavailable) otherwise, never a clipped lie."""
    return value if lo <= value <= hi else None


def cooperative_topic(msg: CooperativeState, t_gen_s: float, t_rx_s: float = math.nan) -> V2vCooperative:
    """An iCLCM's values as the host topic's object, on the runtime clock (t_gen_s, t_rx_s)."""
    return V2vCooperative(
        station_id=msg.station_id,
        t_gen_s=t_gen_s,
        t_rx_s=t_rx_s,
        controller_type=ControllerType(msg.controller_type).name.lower(),
        target_accel_mps2=_nan(msg.target_accel_mps2),
        time_headway_s=_nan(msg.time_headway_s),
        cruise_speed_mps=_nan(msg.cruise_speed_mps),
        rear_axle_m=msg.rear_axle_m,
        mio_station_id=msg.mio_station_id,
        mio_range_m=_nan(msg.mio_range_m),
        mio_bearing_rad=_nan(msg.mio_bearing_rad),
        mio_range_rate_mps=_nan(msg.mio_range_rate_mps),
        lane=0 if msg.lane is None else msg.lane,
        platoon_id=msg.platoon_id,
    )


class V2vRxIo(Module):
    """The V2X link through the hardened receiver; accepted messages on the runtime clock."""

    def __init__(
        self,
        transport: Any,
        unix_time: Callable[[float], float],
        own_station_id: int,
        params: ReceiverParams | None = None,
    ) -> None:
        self.transport = transport
        self.unix_time = unix_time
        self.receiver = V2vReceiver(params, own_station_id=own_station_id, clock=lambda: math.nan)
        self.roadside = RoadsideView()

    def step(self, ctx: ModuleContext) -> None:
        now = ctx.now_s
        offset = self.unix_time(now) - now
        pose: PoseReport | None = ctx.latest(POSE)
        own = GeoPoint(pose.lat_deg, pose.lon_deg) if pose is not None and pose.valid else None
        vehicles: list[V2vVehicle] = []
        cooperative: list[V2vCooperative] = []
        lights: list[V2vLight] = []
        limits: list[V2vLimit] = []
        datagrams = self.transport.poll(MAX_DATAGRAMS_PER_RELEASE) if self.transport is not None else []
        for d in datagrams:
            msg = self.receiver.check(d.payload, d.rx_time_s, own).message
            t_rx = d.rx_time_s - offset
            placed: list[TrafficLightState | SpeedLimit] = []
            if isinstance(msg, SignalPhases):
                placed.extend(self.roadside.place(msg))
            elif isinstance(msg, RoadMap):
                placed.extend(self.roadside.learn(msg))
            for item in placed:
                if (
                    isinstance(item, TrafficLightState)
                    and item.lat_deg is not None
                    and item.lon_deg is not None
                ):
                    lights.append(
                        V2vLight(
                            item.station_id, item.generation_time_s - offset, item.intersection_id,
                            item.signal_group, item.lat_deg, item.lon_deg,
                            "" if item.phase is None else str(item.phase), _nan(item.time_to_change_s),
                        )
                    )  # fmt: skip
                elif isinstance(item, SpeedLimit) and item.lat_deg is not None and item.lon_deg is not None:
                    limits.append(
                        V2vLimit(
                            item.station_id, item.generation_time_s - offset, item.zone_id, item.lat_deg,
                            item.lon_deg, item.limit_mps,
                        )
                    )  # fmt: skip
            if isinstance(msg, CooperativeState):
                cooperative.append(cooperative_topic(msg, msg.generation_time_s - offset, t_rx))
            elif isinstance(msg, VehicleState):
                if (
                    msg.lat_deg is None
                    or msg.lon_deg is None
                    or msg.heading_rad is None
                    or msg.speed_mps is None
                ):
                    continue  # a state without where and how fast is nothing to drive on
                vehicles.append(
                    V2vVehicle(
                        station_id=msg.station_id,
                        t_gen_s=msg.generation_time_s - offset,
                        t_rx_s=t_rx,
                        lat_deg=msg.lat_deg,
                        lon_deg=msg.lon_deg,
                        heading_true_deg=(90.0 - math.degrees(msg.heading_rad)) % 360.0,
                        speed_mps=msg.speed_mps,
                        yaw_rate_radps=_nan(msg.yaw_rate_radps),
                        accel_mps2=_nan(msg.accel_mps2),
                        length_m=msg.length_m if msg.length_m is not None else 4.5,
                        width_m=msg.width_m if msg.width_m is not None else 1.8,
                    )
                )
        rx = self.receiver
        ctx.publish(
            V2V_RECEIVED,
            V2vBatch(
                now,
                tuple(vehicles),
                tuple(lights),
                tuple(limits),
                rx.received,
                rx.accepted,
                tuple(ReasonCount(k, v) for k, v in rx.v2v_rejected().items()),
                tuple(cooperative),
            ),
        )


class V2vTxIo(Module):
    """Our own ETSI CAM from the pose (seed 003 IV-B's vector) and, in the GCDC profile, the iCLCM from the
    platoon beside it; when, see the module docstring."""

    def __init__(
        self,
        transport: Any,
        unix_time: Callable[[float], float],
        frame: LocalFrame,
        station_id: int,
        length_m: float = 4.77,
        width_m: float = 1.82,
        *,
        profile: TxProfile = "etsi",
        iclcm: bool | None = None,
        platoon_id: int = 0,
        rear_axle_m: float = PASSAT_REAR_AXLE_M,
    ) -> None:
        if profile not in TX_PROFILES:
            raise ValueError(f"v2v_tx: profile must be one of {TX_PROFILES}, got {profile!r}")
        self.transport = transport
        self.unix_time = unix_time
        self.frame = frame
        self.station_id = station_id
        self.length_m = length_m
        self.width_m = width_m
        self.profile = profile
        self.iclcm = profile == "gcdc" if iclcm is None else iclcm
        self.platoon_id = platoon_id
        self.rear_axle_m = rear_axle_m
        self.count = 0
        self.iclcm_count = 0
        self._last_gen = -math.inf
        self._low_frequency = LowFrequencyClock()
        self._rules = CamGenerationRules()

    def _cam_due(self, gen: float, pose: PoseReport) -> bool:
        if gen < self._last_gen + GEN_TIME_RESOLUTION_S:  # an equal stamp on the wire is a replay
            return False
        if self.profile == "gcdc":
            return True
        return self._rules.due(gen, pose.x_m, pose.y_m, pose.heading_rad, pose.speed_mps)

    def step(self, ctx: ModuleContext) -> None:
        now = ctx.now_s
        pose: PoseReport | None = ctx.latest(POSE)
        sent = False
        generated = False
        gen = self.unix_time(now)
        if pose is not None and pose.valid and not pose.stale and self.transport is not None:
            generated = self._cam_due(gen, pose)
        if generated:
            assert pose is not None
            azimuth = self.frame.true_azimuth_from_heading(pose.heading_rad, pose.lat_deg, pose.lon_deg)
            state = VehicleState(
                station_id=self.station_id,
                generation_time_s=gen,
                lat_deg=pose.lat_deg,
                lon_deg=pose.lon_deg,
                heading_rad=wrap_angle(math.radians(90.0 - azimuth)),
                speed_mps=min(max(pose.speed_mps, 0.0), 163.0),
                yaw_rate_radps=min(max(pose.yaw_rate_radps, -5.0), 5.0),
                accel_mps2=min(max(pose.accel_mps2, -16.0), 16.0),
                length_m=self.length_m,
                width_m=self.width_m,
            )
            lf = self._low_frequency.due(gen)
            sent = bool(self.transport.send(encode(state, low_frequency=lf)))
            self._last_gen = gen
            self.count += int(sent)
        # Everything of the iCLCM comes after the CAM is on its way.
        iclcm: V2vCooperative | None = None
        iclcm_sent = False
        if generated and self.iclcm:
            assert pose is not None
            coop = self.cooperative_state(ctx, now, gen, pose)
            iclcm_sent = bool(self.transport.send(encode(coop)))
            self.iclcm_count += int(iclcm_sent)
            iclcm = cooperative_topic(coop, now)
        ctx.publish(V2V_SENT, CamSent(now, sent, self.station_id, gen, self.count))
        ctx.publish(V2V_ICLCM_SENT, IclcmSent(now, iclcm_sent, self.iclcm_count, iclcm))

    def cooperative_state(
        self, ctx: ModuleContext, now: float, gen: float, pose: PoseReport
    ) -> CooperativeState:
        """Our iCLCM at release time `now` (generation time `gen`, UNIX s): see the module docstring."""
        platoon: PlatoonStatus | None = ctx.latest(PLATOON)
        ecu: EcuStatusReport | None = ctx.latest(ECU_STATUS)
        world: LeadSet | None = ctx.latest(WORLD_LEADS)
        if platoon is not None and now - platoon.t_s > PLATOON_MAX_AGE_S:
            platoon = None
        engaged = ecu is not None and ecu.valid and ecu.state == EcuState.ENGAGED
        driving = engaged and platoon is not None and platoon.mode in _DRIVING_MODES
        accel: float | None = None
        if driving:
            assert platoon is not None
            accel = min(max(platoon.accel_cmd_mps2, -TARGET_ACCEL_MAX_MPS2), TARGET_ACCEL_MAX_MPS2)
        mio_id, mio_range, mio_rate = 0, None, None
        if world is not None and world.valid and world.leads and 0.0 <= now - world.t_s <= WORLD_MAX_AGE_S:
            lead = world.leads[0]
            age = now - world.t_s
            v = max(pose.speed_mps, 0.0)
            # as the platoon controller does: the world model's prediction, moved to now
            gap = float(np.interp(age, lead.grid_s, lead.positions_m)) - v * age
            mio_id = max(lead.station_id, 0)  # a radar-only lead has no station id
            mio_range = _within(gap, 0.0, 655.34)
            mio_rate = _within(float(np.interp(age, lead.grid_s, lead.speeds_mps)) - v, -327.67, 327.66)
        return CooperativeState(
            station_id=self.station_id,
            generation_time_s=gen,
            controller_type=ControllerType.CACC if driving else ControllerType.MANUAL,
            target_accel_mps2=accel,
            time_headway_s=None if platoon is None else _within(platoon.time_headway_s, 0.0, 36.0),
            cruise_speed_mps=None if platoon is None else _within(platoon.v_des_mps, 0.0, 50.0),
            rear_axle_m=self.rear_axle_m,
            mio_station_id=mio_id,
            mio_range_m=mio_range,
            mio_range_rate_mps=mio_rate,
            platoon_id=self.platoon_id,
        )
