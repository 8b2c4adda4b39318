"""The world as the plant drives it: traffic, radar, GPS receiver, V2V and the per-vehicle trace, stepped
at the plant's events.

`WorldSim.step(t_s, outputs)` (scenario time, the FMU's outputs at t_s) places our car, advances the
traffic, hands the datagrams due by t_s to the V2X link (`send`), the receiver emulator's bytes to the
GPS line (`gps_write`), and appends `traffic.csv` rows at `trace_hz`. `radar(...)` answers the plant's
RADAR_Target cycle. A scenario with the spine's `host.lead` and no `world:` gets `lead_world(lead)`: a
one-lane straight road with the lead as a scripted car on it and the spine's radar (120 m range, no beam
limit, no dropouts), so those scenarios keep their metrics.
"""

from __future__ import annotations

import datetime
from collections.abc import Callable, Sequence
from typing import Any

from bywire.hil.world.spec import (
    DriverSpec,
    EgoSpec,
    GpsSpec,
    RadarSpec,
    RoadSpec,
    V2vSpec,
    VehicleSpec,
    WorldSpec,
)
from bywire.hil.world.traffic import TRAFFIC_COLUMNS, World
from bywire.hil.world.v2v import V2vBroadcaster
from bywire.host.trace import TraceWriter
from bywire.host.world.nmea_emulator import EmulatorConfig, Outage, ReceiverEmulator, TruthState

LEGACY_RADAR_RANGE_M = 120.0  # the spine's radar (hil.plant before it had a world)
EGO_LENGTH_M = 4.77


def lead_world(
    gap0_m: float, profile: Sequence[tuple[float, float]], length_m: float, leaves_at_s: float | None
) -> WorldSpec:
    """The spine's 1-D lead car as a world: one straight lane, the lead `gap0_m` ahead of our front bumper."""
    lead = VehicleSpec(
        name="lead",
        lane=0,
        s_m=0.5 * EGO_LENGTH_M + gap0_m + 0.5 * length_m,
        v0_mps=0.0,
        driver=DriverSpec(kind="scripted", speed_profile=tuple(profile)),
        length_m=length_m,
        leaves_at_s=leaves_at_s,
    )
    return WorldSpec(
        road=RoadSpec(lanes=1, length_m=100_000.0),
        ego=EgoSpec(lane=0, s_m=0.0, length_m=EGO_LENGTH_M),
        radar=RadarSpec(
            range_m=LEGACY_RADAR_RANGE_M, fov_deg=180.0, range_rate_noise_mps=0.05, min_range_m=0.0
        ),
        gps=GpsSpec(enabled=False),
        v2v=V2vSpec(),
        vehicles=(lead,),
        trace_hz=10.0,
    )


def emulator_config(spec: WorldSpec, epoch_unix_s: float) -> EmulatorConfig:
    g = spec.gps
    date = datetime.datetime.fromtimestamp(epoch_unix_s, tz=datetime.UTC)
    return EmulatorConfig(
        origin_lat_deg=spec.road.origin_lat_deg,
        origin_lon_deg=spec.road.origin_lon_deg,
        gga_hz=g.rate_hz,
        rmc_hz=g.rate_hz,
        hdt_hz=g.rate_hz,
        gst_hz=1.0,
        latency_s=g.latency_s,
        outages=tuple(Outage(iv.at_s, iv.at_s + iv.duration_s, kind) for kind, iv in g.outages),  # type: ignore[arg-type]
        byte_error_rate=g.byte_error_rate,
        utc_start_s=epoch_unix_s % 86400.0,
        date=(date.year, date.month, date.day),
    )


class WorldSim:
    def __init__(
        self,
        spec: WorldSpec,
        seed: int,
        unix_time: Callable[[float], float],
        send: Callable[[bytes], Any] | None = None,
        gps_write: Callable[[bytes], Any] | None = None,
        trace: TraceWriter | None = None,
        replay_profile: Sequence[tuple[float, float]] = (),
    ) -> None:
        self.spec = spec
        self.world = World(spec, seed, replay_profile)
        self.unix_time = unix_time
        self.send = send
        self.gps_write = gps_write
        self.trace = trace or TraceWriter(None, TRAFFIC_COLUMNS)
        self.broadcaster = V2vBroadcaster(self.world, unix_time, seed) if send is not None else None
        self.gps: ReceiverEmulator | None = None
        if spec.gps.enabled and gps_write is not None:
            self.gps = ReceiverEmulator(emulator_config(spec, unix_time(0.0)), seed)
        self._next_trace_s = 0.0
        self.datagrams = 0
        self.gps_bytes = 0

    def step(self, t_s: float, x_m: float, y_m: float, heading_rad: float, speed_mps: float,
             accel_mps2: float, yaw_rate_radps: float) -> None:  # fmt: skip
        w = self.world
        w.place_ego(t_s, x_m, y_m, heading_rad, speed_mps, accel_mps2, yaw_rate_radps)
        w.step(t_s)
        if self.broadcaster is not None and self.send is not None:
            for payload in self.broadcaster.due(t_s):
                self.send(payload)
                self.datagrams += 1
        if self.gps is not None and self.gps_write is not None:
            e = w.ego
            data = self.gps.update(t_s, TruthState(t_s, e.x_m, e.y_m, e.heading_rad, e.speed_mps))
            if data:
                self.gps_write(data)
                self.gps_bytes += len(data)
        if t_s >= self._next_trace_s - 1e-9:
            self._next_trace_s += 1.0 / self.spec.trace_hz
            if self._next_trace_s < t_s:
                self._next_trace_s = t_s + 1.0 / self.spec.trace_hz
            for row in w.trace_rows():
                self.trace.append(row)

    def lead(self) -> tuple[float, float] | None:
        return self.world.lead_of_ego()

    def summary(self) -> dict[str, Any]:
        stats = self.world.summary()
        out: dict[str, Any] = {
            "vehicles": stats,
            "collisions": sum(int(v["collisions"]) for v in stats.values()),
            "names": self.world.names,
            "v2v_datagrams": self.datagrams,
            "gps_bytes": self.gps_bytes,
        }
        if self.broadcaster is not None and self.broadcaster.fuzzer is not None:
            out["fuzz_sent"] = self.broadcaster.fuzz_sent
        if self.broadcaster is not None and self.broadcaster.lost:
            out["v2v_lost"] = self.broadcaster.lost
        gaps = [float(v["min_gap_m"]) for v in stats.values() if v["min_gap_m"] is not None]
        out["min_gap_all_m"] = min(gaps) if gaps else None
        ttcs = [float(v["min_ttc_s"]) for v in stats.values() if v["min_ttc_s"] is not None]
        out["min_ttc_all_s"] = min(ttcs) if ttcs else None
        return out


__all__ = ["WorldSim", "emulator_config", "lead_world"]
