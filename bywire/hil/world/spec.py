"""The scenario's `world:` section: road, ego placement, traffic, sensors, V2V and road side (seed 003).

Parsed as strictly as the rest of a scenario (`hil.scenario`): an unknown key, a wrong type or an
impossible value is refused with the file and the path of the field
(`gcdc_heat.yaml: world.vehicles[3].driver.headway_s: expected a number >= 0.1, got 0.0`). Schema and
examples: docs/scenarios.md. Every quantity in SI units; times in seconds of scenario time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from bywire.schema import Reader, SchemaError

DRIVER_KINDS = ("scripted", "acc", "cacc", "idm")
OUTAGE_KINDS = ("rtk_loss", "no_fix", "frozen")
ROADSIDE_KINDS = ("traffic_light", "speed_limit")
LIGHT_PHASES = ("red", "redAmber", "green", "amber")
KMH = 1.0 / 3.6


class WorldSpecError(SchemaError):
    """A `world:` section that cannot be simulated, with the file and the path of the field."""


@dataclass(frozen=True)
class Interval:
    at_s: float
    duration_s: float

    def active(self, t_s: float) -> bool:
        return self.at_s <= t_s < self.at_s + self.duration_s


@dataclass(frozen=True)
class RoadSpec:
    origin_lat_deg: float = 51.4708  # GCDC 2011: the A270 near Helmond (seed 003 Sec. I)
    origin_lon_deg: float = 5.6230
    heading_deg: float = 0.0  # direction of travel, CCW from east on the local plane
    length_m: float = 8000.0
    lanes: int = 2  # lane 0 is the right lane; lane k is k lane widths to the left
    lane_width_m: float = 3.5  # seed 003 IV-A, Dutch highway lane
    radius_m: float | None = None  # None: straight; else a constant-curvature arc (positive: left)


@dataclass(frozen=True)
class SinusoidSpec:
    """Plexe's sinusoidal leader: mean + amplitude * sin(2 pi f (t - start)) from start_s."""

    mean_mps: float
    amplitude_mps: float
    freq_hz: float
    start_s: float = 0.0


@dataclass(frozen=True)
class BrakeSpec:
    """Plexe's emergency braking: from at_s, decelerate at decel_mps2 (> 0) down to to_mps."""

    at_s: float
    decel_mps2: float
    to_mps: float = 0.0


@dataclass(frozen=True)
class DriverSpec:
    kind: str
    # scripted (kinematic: the speed is the profile exactly; see drivers.ScriptedSpeed)
    speed_profile: tuple[tuple[float, float], ...] = ()
    sinusoid: SinusoidSpec | None = None
    brake: BrakeSpec | None = None
    replay: bool = False  # the leader profile of `--leader-profile CSV` replaces this vehicle's speed
    # acc / cacc / idm
    v_set_mps: float = 100.0 * KMH
    headway_s: float = 1.2
    standstill_m: float = 5.0
    lag_s: float = 0.3
    kp: float = 0.2
    kd: float = 0.7
    # idm
    accel_mps2: float = 1.5
    comfort_decel_mps2: float = 2.0
    reaction_s: float = 0.8
    noise_mps2: float = 0.1
    # limits of the simulated car (emergency braking capability, not GCDC comfort limits)
    max_decel_mps2: float = 9.0
    max_accel_mps2: float = 2.5


@dataclass(frozen=True)
class V2vSenderSpec:
    """How a simulated vehicle broadcasts its state (None on the vehicle: it does not communicate)."""

    station_id: int
    rate_hz: float = 10.0
    latency_s: float = 0.03
    position_noise_m: float = 0.3
    speed_noise_mps: float = 0.05
    frozen: tuple[Interval, ...] = ()  # GPS frozen (a bridge): position and speed repeat, time advances
    silent: tuple[Interval, ...] = ()  # sends nothing
    late_s: tuple[tuple[Interval, float], ...] = ()  # (interval, extra latency)


@dataclass(frozen=True)
class VehicleSpec:
    name: str
    lane: int
    s_m: float
    v0_mps: float
    driver: DriverSpec
    length_m: float = 4.5
    width_m: float = 1.8
    v2v: V2vSenderSpec | None = None
    leaves_at_s: float | None = None  # turns off the road: removed from the world
    lateral_noise_m: float = 0.0  # lane keeping: slow lateral wander (a car near the line)


@dataclass(frozen=True)
class EgoSpec:
    lane: int = 0
    s_m: float = 0.0
    length_m: float = 4.77  # VW Passat B6
    width_m: float = 1.82
    station_id: int = 1


@dataclass(frozen=True)
class RadarSpec:
    range_m: float = 50.0  # seed 003 IV-B: the ACC radar's 50 m
    fov_deg: float = 16.0  # full opening angle of a long-range ACC radar
    range_rate_noise_mps: float = 0.05
    dropout: float = 0.0  # probability that a cycle reports no target
    min_range_m: float = 0.3


@dataclass(frozen=True)
class GpsSpec:
    enabled: bool = True
    rate_hz: float = 10.0
    latency_s: float = 0.02
    outages: tuple[tuple[str, Interval], ...] = ()
    byte_error_rate: float = 0.0


@dataclass(frozen=True)
class V2vSpec:
    host_rate_hz: float = 10.0  # our own CAM (seed 003: 10-25 Hz)
    epoch_unix_s: float = 1305374400.0  # SIL's wall time at t = 0: 2011-05-14 12:00 UTC (GCDC final)
    loss: float = 0.0  # share of the other cars' datagrams lost on the channel, each on its own draw


@dataclass(frozen=True)
class RoadsideSpec:
    kind: str
    s_m: float
    station_id: int
    lane: int | None = None
    limit_mps: float = 0.0
    phases: tuple[tuple[float, str], ...] = ()  # traffic light: (from t_s, phase)
    intersection_id: int = 1
    signal_group: int = 1


@dataclass(frozen=True)
class FuzzSpec:
    at_s: float
    duration_s: float
    rate_hz: float = 500.0
    seed: int = 7


@dataclass(frozen=True)
class WorldSpec:
    road: RoadSpec
    ego: EgoSpec
    radar: RadarSpec
    gps: GpsSpec
    v2v: V2vSpec
    vehicles: tuple[VehicleSpec, ...]
    roadside: tuple[RoadsideSpec, ...] = ()
    fuzz: FuzzSpec | None = None
    trace_hz: float = 10.0
    host_length_m: float = 4.77
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def station_ids(self) -> tuple[int, ...]:
        return tuple(v.v2v.station_id for v in self.vehicles if v.v2v is not None)


def _intervals(r: Reader, key: str) -> tuple[Interval, ...]:
    raw = r.raw(key, []) or []
    if not isinstance(raw, list):
        raise r.error(key, f"expected a list of {{at_s, duration_s}}, got {raw!r}")
    out = []
    for i, item in enumerate(raw):
        ir = type(r)(item, r.source, r._p(f"{key}[{i}]"))
        out.append(Interval(ir.number("at_s", lo=0.0), ir.number("duration_s", lo=0.0)))
        ir.finish()
    return tuple(out)


def _driver(r: Reader) -> DriverSpec:
    kind = r.string("kind", choices=DRIVER_KINDS)
    kw: dict[str, Any] = {"kind": kind}
    if kind == "scripted":
        kw["speed_profile"] = r.profile("speed_profile")
        for i, (_, v) in enumerate(kw["speed_profile"]):
            if not 0.0 <= v <= 70.0:
                raise r.error(f"speed_profile[{i}]", f"speed {v} m/s is not within 0..70")
        if r.has("sinusoid"):
            s = r.sub("sinusoid")
            kw["sinusoid"] = SinusoidSpec(
                mean_mps=s.number("mean_mps", lo=0.0, hi=70.0),
                amplitude_mps=s.number("amplitude_mps", lo=0.0, hi=30.0),
                freq_hz=s.number("freq_hz", lo=0.001, hi=5.0),
                start_s=s.number("start_s", default=0.0, lo=0.0),
            )
            s.finish()
            if kw["sinusoid"].amplitude_mps > kw["sinusoid"].mean_mps:
                raise r.error("sinusoid.amplitude_mps", "larger than the mean: the car would reverse")
        if r.has("brake"):
            b = r.sub("brake")
            kw["brake"] = BrakeSpec(
                at_s=b.number("at_s", lo=0.0),
                decel_mps2=b.number("decel_mps2", lo=0.1, hi=12.0),
                to_mps=b.number("to_mps", default=0.0, lo=0.0, hi=70.0),
            )
            b.finish()
        kw["replay"] = r.boolean("replay", False)
        if not (kw["speed_profile"] or kw.get("sinusoid") or kw["replay"]):
            raise r.error("speed_profile", "a scripted driver needs speed_profile, sinusoid or replay")
    else:
        kw["v_set_mps"] = r.number("v_set_mps", default=100.0 * KMH, lo=0.0, hi=70.0)
        kw["headway_s"] = r.number("headway_s", default=1.2 if kind != "cacc" else 0.6, lo=0.1, hi=5.0)
        kw["standstill_m"] = r.number("standstill_m", default=5.0, lo=0.5, hi=100.0)
        kw["lag_s"] = r.number("lag_s", default=0.3, lo=0.01, hi=2.0)
        if kind in ("acc", "cacc"):
            kw["kp"] = r.number("kp", default=0.2, lo=0.0, hi=5.0)
            kw["kd"] = r.number("kd", default=0.7, lo=0.0, hi=5.0)
        if kind == "idm":
            kw["accel_mps2"] = r.number("accel_mps2", default=1.5, lo=0.1, hi=5.0)
            kw["comfort_decel_mps2"] = r.number("comfort_decel_mps2", default=2.0, lo=0.1, hi=9.0)
            kw["reaction_s"] = r.number("reaction_s", default=0.8, lo=0.0, hi=3.0)
            kw["noise_mps2"] = r.number("noise_mps2", default=0.1, lo=0.0, hi=2.0)
    kw["max_decel_mps2"] = r.number("max_decel_mps2", default=9.0, lo=0.5, hi=12.0)
    kw["max_accel_mps2"] = r.number("max_accel_mps2", default=2.5, lo=0.1, hi=6.0)
    r.finish()
    return DriverSpec(**kw)


def _sender(r: Reader) -> V2vSenderSpec:
    late_raw = r.raw("late", []) or []
    if not isinstance(late_raw, list):
        raise r.error("late", f"expected a list of {{at_s, duration_s, extra_s}}, got {late_raw!r}")
    late = []
    for i, item in enumerate(late_raw):
        lr = type(r)(item, r.source, r._p(f"late[{i}]"))
        iv = Interval(lr.number("at_s", lo=0.0), lr.number("duration_s", lo=0.0))
        late.append((iv, lr.number("extra_s", lo=0.0, hi=10.0)))
        lr.finish()
    spec = V2vSenderSpec(
        station_id=int(r.number("station_id", lo=1.0, hi=4294967295.0)),
        rate_hz=r.number("rate_hz", default=10.0, lo=1.0, hi=50.0),
        latency_s=r.number("latency_ms", default=30.0, lo=0.0, hi=2000.0) / 1e3,
        position_noise_m=r.number("position_noise_m", default=0.3, lo=0.0, hi=20.0),
        speed_noise_mps=r.number("speed_noise_mps", default=0.05, lo=0.0, hi=5.0),
        frozen=_intervals(r, "frozen"),
        silent=_intervals(r, "silent"),
        late_s=tuple(late),
    )
    r.finish()
    return spec


def _vehicle(r: Reader, lanes: int) -> VehicleSpec:
    name = r.string("name")
    lane = int(r.number("lane", default=0.0, lo=0.0, hi=float(lanes - 1)))
    driver = _driver(r.sub("driver"))
    v2v = None
    if r.has("v2v") and r.raw("v2v") is not None:
        v2v = _sender(r.sub("v2v"))
    else:
        r.raw("v2v")
    spec = VehicleSpec(
        name=name,
        lane=lane,
        s_m=r.number("s_m", lo=0.0),
        v0_mps=r.number("v0_mps", default=0.0, lo=0.0, hi=70.0),
        driver=driver,
        length_m=r.number("length_m", default=4.5, lo=1.0, hi=25.0),
        width_m=r.number("width_m", default=1.8, lo=0.5, hi=3.0),
        v2v=v2v,
        leaves_at_s=r.opt_number("leaves_at_s", lo=0.0),
        lateral_noise_m=r.number("lateral_noise_m", default=0.0, lo=0.0, hi=1.5),
    )
    r.finish()
    return spec


def _roadside(r: Reader) -> RoadsideSpec:
    kind = r.string("kind", choices=ROADSIDE_KINDS)
    lane = r.opt_number("lane", lo=0.0, hi=15.0)
    kw: dict[str, Any] = {
        "kind": kind,
        "s_m": r.number("s_m", lo=0.0),
        "station_id": int(r.number("station_id", lo=1.0, hi=4294967295.0)),
        "lane": None if lane is None else int(lane),
    }
    if kind == "speed_limit":
        kw["limit_mps"] = r.number("limit_mps", lo=5.0 * KMH, hi=160.0 * KMH)
    else:
        raw = r.raw("phases")
        if not isinstance(raw, list) or not raw:
            raise r.error("phases", "expected a list of [t_s, phase] with phase red|redAmber|green|amber")
        phases: list[tuple[float, str]] = []
        for i, item in enumerate(raw):
            ok = (
                isinstance(item, list)
                and len(item) == 2
                and isinstance(item[0], int | float)
                and not isinstance(item[0], bool)
                and item[1] in LIGHT_PHASES
            )
            if not ok:
                raise r.error(f"phases[{i}]", f"expected [t_s, red|redAmber|green|amber], got {item!r}")
            if phases and item[0] <= phases[-1][0]:
                raise r.error(f"phases[{i}]", f"times must increase, {item[0]} after {phases[-1][0]}")
            phases.append((float(item[0]), str(item[1])))
        kw["phases"] = tuple(phases)
        kw["intersection_id"] = int(r.number("intersection_id", default=1.0, lo=0.0, hi=65535.0))
        kw["signal_group"] = int(r.number("signal_group", default=1.0, lo=0.0, hi=255.0))
    r.finish()
    return RoadsideSpec(**kw)


def parse_world(
    data: Any, source: str, path: str = "world", error_type: type[SchemaError] = WorldSpecError
) -> WorldSpec:
    """The `world:` mapping of a scenario -> `WorldSpec`; `error_type` (a `SchemaError`) names the bad
    field (the scenario parser passes its own `ScenarioError`)."""
    reader: type[Reader] = type("_WorldReader", (Reader,), {"error_type": error_type})
    r = reader(data, source, path)
    rr = r.sub("road")
    radius = rr.opt_number("radius_m", lo=-1e7, hi=1e7)
    if radius is not None and abs(radius) < 200.0:
        raise rr.error("radius_m", f"|radius| must be >= 200 m (a gently curved road), got {radius}")
    road = RoadSpec(
        origin_lat_deg=rr.number("origin_lat_deg", default=51.4708, lo=-85.0, hi=85.0),
        origin_lon_deg=rr.number("origin_lon_deg", default=5.6230, lo=-180.0, hi=180.0),
        heading_deg=rr.number("heading_deg", default=0.0, lo=-360.0, hi=360.0),
        length_m=rr.number("length_m", default=8000.0, lo=100.0, hi=50_000.0),
        lanes=int(rr.number("lanes", default=2.0, lo=1.0, hi=6.0)),
        lane_width_m=rr.number("lane_width_m", default=3.5, lo=2.5, hi=5.0),
        radius_m=radius,
    )
    rr.finish()
    if road.radius_m is not None and road.length_m > math.pi * abs(road.radius_m):
        raise rr.error("length_m", "a curved road may turn at most 180 degrees (length <= pi * radius)")
    er = r.sub("ego")
    ego = EgoSpec(
        lane=int(er.number("lane", default=0.0, lo=0.0, hi=float(road.lanes - 1))),
        s_m=er.number("s_m", default=100.0, lo=0.0, hi=road.length_m),
        length_m=er.number("length_m", default=4.77, lo=1.0, hi=25.0),
        width_m=er.number("width_m", default=1.82, lo=0.5, hi=3.0),
        station_id=int(er.number("station_id", default=1.0, lo=1.0, hi=4294967295.0)),
    )
    er.finish()
    ra = r.sub("radar")
    radar = RadarSpec(
        range_m=ra.number("range_m", default=50.0, lo=1.0, hi=250.0),
        fov_deg=ra.number("fov_deg", default=16.0, lo=1.0, hi=180.0),
        range_rate_noise_mps=ra.number("range_rate_noise_mps", default=0.05, lo=0.0, hi=5.0),
        dropout=ra.number("dropout", default=0.0, lo=0.0, hi=1.0),
    )
    ra.finish()
    gr = r.sub("gps")
    outages_raw = gr.raw("outages", []) or []
    if not isinstance(outages_raw, list):
        raise gr.error("outages", f"expected a list of {{kind, at_s, duration_s}}, got {outages_raw!r}")
    outages = []
    for i, item in enumerate(outages_raw):
        orr = type(r)(item, source, gr._p(f"outages[{i}]"))
        kind = orr.string("kind", choices=OUTAGE_KINDS)
        outages.append((kind, Interval(orr.number("at_s", lo=0.0), orr.number("duration_s", lo=0.01))))
        orr.finish()
    gps = GpsSpec(
        enabled=gr.boolean("enabled", True),
        rate_hz=gr.number("rate_hz", default=10.0, lo=1.0, hi=20.0),
        latency_s=gr.number("latency_ms", default=20.0, lo=0.0, hi=500.0) / 1e3,
        outages=tuple(outages),
        byte_error_rate=gr.number("byte_error_rate", default=0.0, lo=0.0, hi=0.01),
    )
    gr.finish()
    vr = r.sub("v2v")
    v2v = V2vSpec(
        host_rate_hz=vr.number("host_rate_hz", default=10.0, lo=10.0, hi=25.0),
        loss=vr.number("loss", default=0.0, lo=0.0, hi=0.99),
    )
    vr.finish()
    raw_vehicles = r.raw("vehicles", []) or []
    if not isinstance(raw_vehicles, list):
        raise r.error("vehicles", "expected a list of vehicles")
    vehicles = tuple(
        _vehicle(type(r)(item, source, r._p(f"vehicles[{i}]")), road.lanes)
        for i, item in enumerate(raw_vehicles)
    )
    names = [v.name for v in vehicles]
    for i, n in enumerate(names):
        if n in names[:i] or n == "ego":
            raise error_type(source, r._p(f"vehicles[{i}].name"), f"name {n!r} is taken")
    ids = [ego.station_id] + [v.v2v.station_id for v in vehicles if v.v2v is not None]
    if len(set(ids)) != len(ids):
        raise r.error("vehicles", f"station ids must be unique (the ego's is {ego.station_id}): {ids}")
    for i, v in enumerate(vehicles):
        if v.s_m > road.length_m:
            raise error_type(source, r._p(f"vehicles[{i}].s_m"), f"beyond the road's {road.length_m} m")
    raw_rs = r.raw("roadside", []) or []
    if not isinstance(raw_rs, list):
        raise r.error("roadside", "expected a list of traffic_light / speed_limit")
    roadside = tuple(
        _roadside(type(r)(item, source, r._p(f"roadside[{i}]"))) for i, item in enumerate(raw_rs)
    )
    fuzz = None
    if r.has("fuzz") and r.raw("fuzz") is not None:
        fr = r.sub("fuzz")
        fuzz = FuzzSpec(
            at_s=fr.number("at_s", lo=0.0),
            duration_s=fr.number("duration_s", lo=0.1),
            rate_hz=fr.number("rate_hz", default=500.0, lo=1.0, hi=20_000.0),
            seed=int(fr.number("seed", default=7.0, lo=0.0, hi=2.0**32)),
        )
        fr.finish()
    trace_hz = r.number("trace_hz", default=10.0, lo=1.0, hi=100.0)
    r.finish()
    return WorldSpec(
        road=road,
        ego=ego,
        radar=radar,
        gps=gps,
        v2v=v2v,
        vehicles=vehicles,
        roadside=roadside,
        fuzz=fuzz,
        trace_hz=trace_hz,
        host_length_m=ego.length_m,
    )


__all__ = [
    "BrakeSpec",
    "DriverSpec",
    "EgoSpec",
    "FuzzSpec",
    "GpsSpec",
    "Interval",
    "RadarSpec",
    "RoadSpec",
    "RoadsideSpec",
    "SinusoidSpec",
    "V2vSenderSpec",
    "V2vSpec",
    "VehicleSpec",
    "WorldSpec",
    "WorldSpecError",
    "parse_world",
]
