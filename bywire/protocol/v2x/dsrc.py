"""Road-side messages: SPATEM and MAPEM (ETSI TS 103 301 over ISO TS 19091 DSRC) to and from SI dataclasses.

Seed 003 Sec. IV-B: the GCDC road side broadcast traffic-light states and speed limits. The field says so
in two messages: the SPATEM (messageID 4) carries each signal group's phase and when it changes, the MAPEM
(messageID 5) where the signal groups' stop lines are and the road's regulatory speed limits. A receiver
joins the two (`roadside.RoadsideView`): a phase alone says nothing about where to stop.

SPATEM (`SignalPhases`): one IntersectionState per intersection, each with `moy` (minute of the UTC year)
and `timeStamp` (ms in that minute), our generation time to the ms; one MovementState per signal group,
its first MovementEvent the current phase and, when known, `timing.minEndTime` = `likelyTime`, a TimeMark
(0.1 s within the hour) at which the phase ends. Phases (ISO TS 19091 MovementPhaseState):

| ours | sent as | also read as |
|---|---|---|
| red | stop-And-Remain | stop-Then-Proceed |
| redAmber | pre-Movement | |
| green | protected-Movement-Allowed | permissive-Movement-Allowed |
| amber | protected-clearance | permissive-clearance |
| None (unknown) | unavailable | dark, caution-Conflicting-Traffic |

MAPEM (`RoadMap`): `timeStamp` (minute of the year: a map's time is known to the minute only), intersections
and road segments. An intersection (`IntersectionMap`) has its reference point at its first stop line
and per signal group (`StopLine`) an ingress lane whose first node is the stop line and whose second lies
INGRESS_NODE_M upstream, connected under that signal group to an egress lane drawn EGRESS_NODES_M beyond
it; offsets are Node-XY-32b (cm, +-327 m), each node relative to the one before (ISO TS 19091). A speed
limit (`SpeedLimit`) is a road segment whose id is the zone, whose reference point is where the zone
starts, whose `speedLimits` holds one vehicleMaxSpeed (Velocity, 0.02 m/s) and whose one lane is drawn as
an ingress lane ending at the start (its second node INGRESS_NODE_M before it): travel towards the first
node is the way the limit applies. Speed limits are sent this way because the standard
road-side message for signs, the IVIM (ISO TS 19321), is not among the schemas we ship, and the MAPEM's
regulatory speed limit says exactly "this limit from here along this road".

Strict decoding as for CAMs (canonical bytes only); a message with a regional extension fails to decode
(MALFORMED): no regional profile is ours. Generation times: a SPATEM's is resolved to the UTC year nearest
the receive time, a MAPEM's likewise to the start of its minute (or the receive time, when absent).
"""

from __future__ import annotations

import calendar
import math
import time
from dataclasses import dataclass
from typing import Any, Final

from .codec import (
    DSRC_PROTOCOL_VERSION,
    MSG_MAPEM,
    MSG_SPATEM,
    DecodeReason,
    SpeedLimit,
    TrafficLightPhase,
    V2xDecodeError,
    V2xEncodeError,
    asn1_decode,
    asn1_encode,
    check_canonical,
    checked_integer,
    finite,
    header_value,
    lat_from_etsi,
    lon_from_etsi,
    position_to_etsi,
)
from .schemas import SchemaSet, compiled

INGRESS_NODE_M: Final = 10.0  # second node of a lane: enough for a receiver to tell its direction
EGRESS_NODES_M: Final = (15.0, 25.0)  # an egress lane beyond a notional 15 m intersection
VELOCITY_MPS: Final = 0.02  # ISO TS 19091 Velocity unit
VELOCITY_UNAVAILABLE: Final = 8191
TIME_MARK_PER_HOUR: Final = 36_000  # TimeMark: 0.1 s in the hour; 36000 a leap second, 36001 unknown
TIME_MARK_UNKNOWN: Final = 36_001
MINUTES_PER_YEAR_MAX: Final = 527_040  # 366 days; 527040 itself is "invalid"
_M_PER_DEG = 6_371_008.8 * math.pi / 180.0  # mean-sphere metres per degree (offsets of <= 327 m)
_INGRESS: Final = (b"\x80", 2)  # LaneDirection ingressPath(0)
_EGRESS: Final = (b"\x40", 2)  # LaneDirection egressPath(1)
_MOTOR_VEHICLES: Final = (b"\x10\x00", 10)  # LaneSharing individualMotorizedVehicleTraffic(3)
_VEHICLE_LANE: Final = ("vehicle", (b"\x00", 8))
_STATUS_NORMAL: Final = (b"\x00\x00", 16)

_PHASE_TO_WIRE: Final = {
    TrafficLightPhase.RED: "stop-And-Remain",
    TrafficLightPhase.RED_AMBER: "pre-Movement",
    TrafficLightPhase.GREEN: "protected-Movement-Allowed",
    TrafficLightPhase.AMBER: "protected-clearance",
}
_PHASE_FROM_WIRE: Final = {
    "stop-And-Remain": TrafficLightPhase.RED,
    "stop-Then-Proceed": TrafficLightPhase.RED,
    "pre-Movement": TrafficLightPhase.RED_AMBER,
    "protected-Movement-Allowed": TrafficLightPhase.GREEN,
    "permissive-Movement-Allowed": TrafficLightPhase.GREEN,
    "protected-clearance": TrafficLightPhase.AMBER,
    "permissive-clearance": TrafficLightPhase.AMBER,
}


@dataclass(frozen=True, slots=True)
class SignalGroupState:
    """One signal group's phase (None: unknown) and the time from the generation time to its end."""

    intersection_id: int
    signal_group: int
    phase: TrafficLightPhase | None
    time_to_change_s: float | None = None


@dataclass(frozen=True, slots=True)
class SignalPhases:
    """A SPATEM: the phases of an RSU's signal groups at generation_time_s (UNIX s)."""

    station_id: int
    generation_time_s: float
    groups: tuple[SignalGroupState, ...]


@dataclass(frozen=True, slots=True)
class StopLine:
    """Where a signal group's traffic stops (WGS84 degrees); heading_rad: counter-clockwise from east, the
    direction of travel across it (None: the lane is a point)."""

    signal_group: int
    lat_deg: float
    lon_deg: float
    heading_rad: float | None = None


@dataclass(frozen=True, slots=True)
class IntersectionMap:
    intersection_id: int
    stop_lines: tuple[StopLine, ...]
    revision: int = 0


@dataclass(frozen=True, slots=True)
class RoadMap:
    """A MAPEM: intersections (where signal groups stop) and speed-limit zones (road segments)."""

    station_id: int
    generation_time_s: float
    intersections: tuple[IntersectionMap, ...] = ()
    speed_limits: tuple[SpeedLimit, ...] = ()
    revision: int = 0


# ---------------------------------------------------------------------------------------------- time


def _year_start(unix_s: float) -> int:
    return calendar.timegm((time.gmtime(unix_s).tm_year, 1, 1, 0, 0, 0, 0, 0, 0))


def minute_of_the_year(owner: str, unix_s: float) -> tuple[int, int]:
    """UNIX seconds (UTC) -> (MinuteOfTheYear, DSecond ms within that minute)."""
    t = finite(owner, "generation_time_s", unix_s)
    if not 0.0 <= t < 2**37:
        raise V2xEncodeError(f"{owner}.generation_time_s", f"{unix_s!r} s is not a time we can send")
    ms = round((t - _year_start(t)) * 1000.0)
    return ms // 60_000, ms % 60_000


def from_minute_of_the_year(moy: int, ms: int, reference_time_s: float) -> float:
    """(MinuteOfTheYear, ms) -> UNIX seconds in the UTC year (this, last or next) nearest the reference."""
    year = time.gmtime(reference_time_s).tm_year
    best = math.inf
    for y in (year - 1, year, year + 1):
        t = calendar.timegm((y, 1, 1, 0, 0, 0, 0, 0, 0)) + moy * 60 + ms / 1000.0
        if abs(t - reference_time_s) < abs(best - reference_time_s):
            best = t
    return best


def _time_mark(owner: str, generation_time_s: float, time_to_change_s: float) -> int:
    ttc = finite(owner, "time_to_change_s", time_to_change_s)
    if not 0.0 <= ttc <= 3599.9:
        raise V2xEncodeError(f"{owner}.time_to_change_s", f"{time_to_change_s!r} s is outside 0..3599.9 s")
    return round((generation_time_s % 3600.0 + ttc) * 10.0) % TIME_MARK_PER_HOUR


def _time_to_change(mark: int, generation_time_s: float) -> float | None:
    if mark >= TIME_MARK_PER_HOUR:  # a leap second's mark or unknown
        return None
    # The mark counts 0.1 s, the generation time ms: the end is known to 0.05 s.
    return round(((mark - generation_time_s % 3600.0 * 10.0) % TIME_MARK_PER_HOUR) / 10.0, 3)


# ---------------------------------------------------------------------------------------------- geometry


def _offset_cm(lat0: float, lon0: float, lat: float, lon: float) -> tuple[int, int]:
    east = (lon - lon0) * _M_PER_DEG * math.cos(math.radians(lat0))
    north = (lat - lat0) * _M_PER_DEG
    return round(east * 100.0), round(north * 100.0)


def _node(owner: str, dx_m: float, dy_m: float) -> dict[str, Any]:
    x, y = round(dx_m * 100.0), round(dy_m * 100.0)
    if not (-32_768 <= x <= 32_767 and -32_768 <= y <= 32_767):
        raise V2xEncodeError(owner, f"a lane node {dx_m:.1f}, {dy_m:.1f} m from the last is beyond +-327 m")
    return {"delta": ("node-XY6", {"x": x, "y": y})}


def _lane(
    owner: str,
    lane_id: int,
    direction: tuple[bytes, int],
    start_m: tuple[float, float],
    steps_m: list[float],
    heading_rad: float | None,
    connects: list[dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """A vehicle lane whose first node lies start_m (east, north) from the reference point and whose next
    nodes follow at steps_m along heading_rad (all at the first node when the heading is unknown)."""
    h = 0.0 if heading_rad is None else heading_rad
    scale = 0.0 if heading_rad is None else 1.0
    nodes = [_node(owner, *start_m)]
    for step in steps_m:
        nodes.append(_node(owner, scale * step * math.cos(h), scale * step * math.sin(h)))
    lane: dict[str, Any] = {
        "laneID": lane_id,
        "laneAttributes": {
            "directionalUse": direction,
            "sharedWith": _MOTOR_VEHICLES,
            "laneType": _VEHICLE_LANE,
        },
        "nodeList": ("nodes", nodes),
    }
    if connects:
        lane["connectsTo"] = connects
    return lane  # fmt: skip


def _position3d(owner: str, lat: float | None, lon: float | None) -> dict[str, int]:
    lat_n, lon_n = position_to_etsi(owner, lat, lon)
    return {"lat": lat_n, "long": lon_n}


def _node_points(ref_lat: float, ref_lon: float, nodes: list[dict[str, Any]]) -> list[tuple[float, float]]:
    """Absolute (lat, lon) of a node list (each XY node relative to the one before, ISO TS 19091)."""
    out: list[tuple[float, float]] = []
    lat, lon = ref_lat, ref_lon
    for n in nodes:
        kind, d = n["delta"]
        if kind == "node-LatLon":
            lat, lon = d["lat"] / 1e7, d["lon"] / 1e7
        elif kind.startswith("node-XY"):
            lat += d["y"] / 100.0 / _M_PER_DEG
            lon += d["x"] / 100.0 / (_M_PER_DEG * max(math.cos(math.radians(lat)), 1e-6))
        else:
            raise V2xDecodeError(DecodeReason.MALFORMED, f"MAPEM: lane node of kind {kind}")
        out.append((lat, lon))
    return out


def _travel_heading(points: list[tuple[float, float]], *, towards_first: bool) -> float | None:
    """Heading (counter-clockwise from east) along the first two nodes; None for a point."""
    if len(points) < 2:
        return None
    (la0, lo0), (la1, lo1) = points[0], points[1]
    east = (lo1 - lo0) * math.cos(math.radians(la0))
    north = la1 - la0
    if math.hypot(east, north) * _M_PER_DEG < 0.01:
        return None
    h = math.atan2(north, east)
    return math.remainder(h + math.pi, 2.0 * math.pi) if towards_first else h


# ---------------------------------------------------------------------------------------------- SPATEM


def spatem_value(msg: SignalPhases) -> dict[str, Any]:
    o = "SignalPhases"
    moy, ms = minute_of_the_year(o, msg.generation_time_s)
    by_intersection: dict[int, list[SignalGroupState]] = {}
    for g in msg.groups:
        by_intersection.setdefault(
            checked_integer(o, "intersection_id", g.intersection_id, 0, 65_535), []
        ).append(g)
    if not by_intersection:
        raise V2xEncodeError(f"{o}.groups", "a SPATEM needs at least one signal group")
    states = []
    for iid, groups in by_intersection.items():
        movements = []
        for g in groups:
            event: dict[str, Any] = {
                "eventState": "unavailable" if g.phase is None else _PHASE_TO_WIRE[TrafficLightPhase(g.phase)]
            }
            if g.time_to_change_s is not None:
                mark = _time_mark(o, msg.generation_time_s, g.time_to_change_s)
                event["timing"] = {"minEndTime": mark, "likelyTime": mark}
            movements.append(
                {
                    "signalGroup": checked_integer(o, "signal_group", g.signal_group, 0, 255),
                    "state-time-speed": [event],
                }
            )
        states.append(
            {"id": {"id": iid}, "revision": 0, "status": _STATUS_NORMAL, "moy": moy, "timeStamp": ms,
             "states": movements}
        )  # fmt: skip
    return {
        "header": header_value(MSG_SPATEM, DSRC_PROTOCOL_VERSION, o, msg.station_id),
        "spat": {"intersections": states},
    }


def encode_spatem(msg: SignalPhases) -> bytes:
    return asn1_encode(compiled(SchemaSet.ROADSIDE), "SPATEM", spatem_value(msg), "SPATEM")


def decode_spatem(data: bytes, reference_time_s: float | None = None) -> SignalPhases:
    """A SPATEM -> SignalPhases; its time is the latest of its intersections' (moy, timeStamp)."""
    data = bytes(data)
    spec = compiled(SchemaSet.ROADSIDE)
    value = asn1_decode(spec, "SPATEM", data, "SPATEM")
    check_canonical(spec, "SPATEM", value, data, "SPATEM")
    t_ref = time.time() if reference_time_s is None else reference_time_s
    try:
        times = [
            from_minute_of_the_year(s["moy"], s.get("timeStamp", 0), t_ref)
            for s in value["spat"]["intersections"]
            if "moy" in s and s["moy"] < MINUTES_PER_YEAR_MAX and s.get("timeStamp", 0) < 60_000
        ]
        if not times:
            raise V2xDecodeError(DecodeReason.MALFORMED, "SPATEM: no intersection says when (moy, timeStamp)")
        gen = max(times)
        groups = []
        for s in value["spat"]["intersections"]:
            for m in s["states"]:
                event = m["state-time-speed"][0]
                timing = event.get("timing")
                mark = None if timing is None else timing.get("likelyTime", timing["minEndTime"])
                groups.append(
                    SignalGroupState(
                        s["id"]["id"],
                        m["signalGroup"],
                        _PHASE_FROM_WIRE.get(event["eventState"]),
                        None if mark is None else _time_to_change(mark, gen),
                    )
                )
        return SignalPhases(value["header"]["stationID"], gen, tuple(groups))
    except V2xDecodeError:
        raise
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise V2xDecodeError(DecodeReason.DECODER_FAULT, f"SPATEM: {type(e).__name__}: {e}") from None


# ---------------------------------------------------------------------------------------------- MAPEM


def _intersection_value(o: str, m: IntersectionMap) -> dict[str, Any]:
    if not m.stop_lines:
        raise V2xEncodeError(f"{o}.stop_lines", f"intersection {m.intersection_id} has no stop line")
    ref = m.stop_lines[0]
    lanes = []
    for k, s in enumerate(m.stop_lines):
        if not 2 * k + 2 <= 255:
            raise V2xEncodeError(f"{o}.stop_lines", "more than 127 stop lines in one intersection")
        start = _offset_cm(ref.lat_deg, ref.lon_deg, s.lat_deg, s.lon_deg)
        start_m = (start[0] / 100.0, start[1] / 100.0)
        back = None if s.heading_rad is None else s.heading_rad + math.pi
        connect = [
            {"connectingLane": {"lane": 2 * k + 2},
             "signalGroup": checked_integer(o, "signal_group", s.signal_group, 0, 255)}
        ]  # fmt: skip
        lanes.append(_lane(o, 2 * k + 1, _INGRESS, start_m, [INGRESS_NODE_M], back, connect))
        h = 0.0 if s.heading_rad is None else s.heading_rad
        first = EGRESS_NODES_M[0] if s.heading_rad is not None else 0.0
        egress_start = (start_m[0] + first * math.cos(h), start_m[1] + first * math.sin(h))
        lanes.append(
            _lane(o, 2 * k + 2, _EGRESS, egress_start, [EGRESS_NODES_M[1] - EGRESS_NODES_M[0]], s.heading_rad)
        )
    return {
        "id": {"id": checked_integer(o, "intersection_id", m.intersection_id, 0, 65_535)},
        "revision": checked_integer(o, "revision", m.revision, 0, 127),
        "refPoint": _position3d(o, ref.lat_deg, ref.lon_deg),
        "laneSet": lanes,
    }


def _segment_value(o: str, lim: SpeedLimit, revision: int) -> dict[str, Any]:
    v = finite(o, "limit_mps", lim.limit_mps) / VELOCITY_MPS
    if not (0.5 <= v <= VELOCITY_UNAVAILABLE - 1 + 0.5):
        raise V2xEncodeError(f"{o}.limit_mps", f"{lim.limit_mps!r} m/s is outside 0.02..163.8 m/s")
    back = None if lim.heading_rad is None else lim.heading_rad + math.pi
    return {
        "id": {"id": checked_integer(o, "zone_id", lim.zone_id, 0, 65_535)},
        "revision": checked_integer(o, "revision", revision, 0, 127),
        "refPoint": _position3d(o, lim.lat_deg, lim.lon_deg),
        "speedLimits": [{"type": "vehicleMaxSpeed", "speed": round(v)}],
        # as an intersection's ingress lane: travel towards the first node, the zone's start
        "roadLaneSet": [_lane(o, 1, _INGRESS, (0.0, 0.0), [INGRESS_NODE_M], back)],
    }


def mapem_value(msg: RoadMap) -> dict[str, Any]:
    o = "RoadMap"
    moy, _ = minute_of_the_year(o, msg.generation_time_s)
    data: dict[str, Any] = {
        "timeStamp": moy,
        "msgIssueRevision": checked_integer(o, "revision", msg.revision, 0, 127),
    }
    if msg.intersections:
        data["intersections"] = [_intersection_value(o, m) for m in msg.intersections]
    if msg.speed_limits:
        data["roadSegments"] = [_segment_value(o, lim, msg.revision) for lim in msg.speed_limits]
    return {"header": header_value(MSG_MAPEM, DSRC_PROTOCOL_VERSION, o, msg.station_id), "map": data}


def encode_mapem(msg: RoadMap) -> bytes:
    return asn1_encode(compiled(SchemaSet.ROADSIDE), "MAPEM", mapem_value(msg), "MAPEM")


def _stop_lines(g: dict[str, Any]) -> tuple[StopLine, ...]:
    ref_lat, ref_lon = lat_from_etsi(g["refPoint"]["lat"]), lon_from_etsi(g["refPoint"]["long"])
    if ref_lat is None or ref_lon is None:
        return ()  # an intersection whose place is unavailable places nothing
    out = []
    for lane in g["laneSet"]:
        groups = [c["signalGroup"] for c in lane.get("connectsTo", ()) if "signalGroup" in c]
        kind, nodes = lane["nodeList"]
        ingress = lane["laneAttributes"]["directionalUse"][0][0] & 0x80
        if not groups or kind != "nodes" or not ingress:
            continue
        points = _node_points(ref_lat, ref_lon, nodes)
        heading = _travel_heading(points, towards_first=True)
        for sg in dict.fromkeys(groups):
            out.append(StopLine(sg, points[0][0], points[0][1], heading))
    return tuple(out)


def _speed_limit(station_id: int, gen: float, seg: dict[str, Any]) -> SpeedLimit | None:
    speeds = [s["speed"] for s in seg.get("speedLimits", ()) if s["type"] == "vehicleMaxSpeed"]
    if not speeds or speeds[0] == VELOCITY_UNAVAILABLE:
        return None
    lat, lon = lat_from_etsi(seg["refPoint"]["lat"]), lon_from_etsi(seg["refPoint"]["long"])
    heading = None
    if lat is not None and lon is not None and seg["roadLaneSet"]:
        kind, nodes = seg["roadLaneSet"][0]["nodeList"]
        if kind == "nodes":
            heading = _travel_heading(_node_points(lat, lon, nodes), towards_first=True)
    return SpeedLimit(station_id, gen, seg["id"]["id"], lat, lon, speeds[0] * VELOCITY_MPS, heading)


def decode_mapem(data: bytes, reference_time_s: float | None = None) -> RoadMap:
    """A MAPEM -> RoadMap: the ingress lanes' stop lines per signal group, the segments' speed limits."""
    data = bytes(data)
    spec = compiled(SchemaSet.ROADSIDE)
    value = asn1_decode(spec, "MAPEM", data, "MAPEM")
    check_canonical(spec, "MAPEM", value, data, "MAPEM")
    t_ref = time.time() if reference_time_s is None else reference_time_s
    try:
        m = value["map"]
        station = value["header"]["stationID"]
        moy = m.get("timeStamp")
        gen = t_ref if moy is None or moy >= MINUTES_PER_YEAR_MAX else from_minute_of_the_year(moy, 0, t_ref)
        intersections = tuple(
            IntersectionMap(g["id"]["id"], _stop_lines(g), g["revision"]) for g in m.get("intersections", ())
        )
        limits = tuple(
            lim for seg in m.get("roadSegments", ()) if (lim := _speed_limit(station, gen, seg)) is not None
        )
        return RoadMap(station, gen, intersections, limits, m["msgIssueRevision"])
    except V2xDecodeError:
        raise
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise V2xDecodeError(DecodeReason.DECODER_FAULT, f"MAPEM: {type(e).__name__}: {e}") from None
