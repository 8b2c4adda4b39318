"""The V2X link as two modules (seed 003 sections II and IV-B): `V2vRxIo` hands every datagram to the
hardened `protocol.v2x.receiver.V2vReceiver` and publishes what it accepted with the rejection counts
(CAMs as vehicles, SPATEM phases placed at their MAPEM stop lines as lights, MAPEM zones as limits);
`V2vTxIo` broadcasts our own ETSI CAM at 10-25 Hz from the pose, its low-frequency container every 500 ms.

Time: V2V generation times are UNIX seconds on the wire; `V2vRxIo` maps them onto the runtime clock with
the host's `unix_time(now)` (SIL: the scenario's epoch + simulated time; HIL: the wall clock's offset to
CLOCK_MONOTONIC), so everything downstream runs on one clock.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from bywire.host.geo import LocalFrame, wrap_angle
from bywire.host.modules.gcdc_messages import (
    POSE,
    V2V_RECEIVED,
    V2V_SENT,
    CamSent,
    PoseReport,
    ReasonCount,
    V2vBatch,
    V2vLight,
    V2vLimit,
    V2vVehicle,
)
from bywire.host.runtime.module import Module, ModuleContext
from bywire.protocol.v2x.codec import GEN_TIME_RESOLUTION_S, SpeedLimit, TrafficLightState, VehicleState
from bywire.protocol.v2x.dsrc import RoadMap, SignalPhases
from bywire.protocol.v2x.etsi_cam import LowFrequencyClock
from bywire.protocol.v2x.receiver import GeoPoint, ReceiverParams, V2vReceiver
from bywire.protocol.v2x.roadside import RoadsideView
from bywire.protocol.v2x.wire import encode

MAX_DATAGRAMS_PER_RELEASE = 200  # bounds a release under a flood; the rest waits in the socket buffer


def _nan(value: float | None) -> float:
    return math.nan if value is None else float(value)


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
            if isinstance(msg, VehicleState):
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
            ),
        )


class V2vTxIo(Module):
    """Our own ETSI CAM from the pose (seed 003 IV-B's vector), at the module's rate (10-25 Hz)."""

    def __init__(
        self,
        transport: Any,
        unix_time: Callable[[float], float],
        frame: LocalFrame,
        station_id: int,
        length_m: float = 4.77,
        width_m: float = 1.82,
    ) -> None:
        self.transport = transport
        self.unix_time = unix_time
        self.frame = frame
        self.station_id = station_id
        self.length_m = length_m
        self.width_m = width_m
        self.count = 0
        self._last_gen = -math.inf
        self._low_frequency = LowFrequencyClock()

    def step(self, ctx: ModuleContext) -> None:
        now = ctx.now_s
        pose: PoseReport | None = ctx.latest(POSE)
        sent = False
        gen = self.unix_time(now)
        if (
            pose is not None
            and pose.valid
            and not pose.stale
            and self.transport is not None
            and gen >= self._last_gen + GEN_TIME_RESOLUTION_S  # an equal stamp on the wire is a replay
        ):
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
        ctx.publish(V2V_SENT, CamSent(now, sent, self.station_id, gen, self.count))
