"""Route Network Definition File reader (DARPA, "RNDF and MDF Formats", May 12 2006, sec. 2; seed 000 sec. 8).

`load_rndf(path)` / `parse_rndf(text, path)` return a `RoadNetwork`: segments -> lanes -> waypoints (lat/lon
as written), lane width (feet in the file, metres here), left/right boundaries, checkpoints, stop signs and
exits; zones with their perimeter points, perimeter exits and parking spots; and the items of the later
Stanford/AnnieWAY "RNDF 1.1" extension (crosswalks, traffic lights in intersections, lane types, segment
speed limits).  Anything the reader cannot make sense of raises `RndfError` ``file:line: what was expected``.

What the reader guarantees (so that a damaged file does not pass as a smaller valid network):

- Every block is closed by its own end marker and the file by ``end_file``; nothing but comments may follow
  it.  A file cut anywhere before its last ``end_file`` is therefore an error.
- Waypoint lines of a lane (spot, perimeter) must carry that lane's id and strictly increasing numbers: a
  line moved into another lane, or two swapped waypoints, are errors.  Spots have exactly ``Z.N.1`` and
  ``Z.N.2``.
- Ids are unique: segment/zone/intersection numbers (one id space), lanes, spots, waypoints, crosswalks,
  traffic lights, checkpoint numbers.
- Unknown keywords are errors (a misspelt ``stop`` would otherwise silently drop a stop sign).
- The counts of the 2006 format are required (``num_segments``, ``num_zones``, ``num_lanes``,
  ``num_waypoints``, ``num_spots``, ``num_perimeterpoints``; every real file has them); the extension's
  (``num_intersections``, ``num_crosswalks``, ``num_trafficlights``) are optional.

Tolerated, with a `ParseWarning` (real files do all of these), and errors with ``strict=True`` (the
"strict validator" of the format summary): header counts (``num_segments``, ``num_lanes``,
``num_waypoints``, ...) that disagree with the body; waypoint numbers that do not run 1, 2, 3, ... (UT
Austin's ``prc_small`` starts a lane at 14); a duplicated exit or stop; a spot without a checkpoint; a
checkpoint, stop or exit named in the header of a lane it does not belong to; and references (exit and
entry, checkpoint, stop, crosswalk and traffic light use) to something that does not exist.  Exits may
point forward in the file, so references are checked once it is read; a dangling one is **dropped** with a
warning at the line of the reference: Cornell's ``Sample1`` has an exit to ``6.2.10`` of an 8-point lane,
``Sample2`` a checkpoint on ``1.1.18`` of a 2-point lane, and both files are otherwise sound.  (Deviation
from "dangling references are errors": every shared real file must load; strict mode keeps the error.)
Accepted silently: header lines in any order (``checkpoint`` before ``num_waypoints``), lanes listed out of
order, ``num_spots 0``, ``solid_yellow`` (2007 files), tabs and spaces mixed, CRLF, comments anywhere.

Deviation - coordinates: the Cornell sample networks write local metres (x east first, y north second; the
order makes their two-way roads right-hand traffic) where the format has latitude/longitude.  With
``coordinates="auto"`` a file whose median spacing between consecutive points exceeds 0.05 "degrees" is
read as local metres (`RoadNetwork.coordinates == "local_m"`, with a warning): 0.05 deg is 5.5 km, far more
than any waypoint spacing in a DARPA network, while 0.05 m is far less than any waypoint spacing in metres.
Geographic files must have |lat| <= 90 and |lon| <= 180 at every point.
"""

from __future__ import annotations

import itertools
import statistics
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal, TypeVar, get_args

from .errors import ParseWarning, RndfError
from .ids import LaneId, WaypointId
from .tokens import Cursor, Line, decode

_T = TypeVar("_T")

FEET_TO_M = 0.3048
MPH_TO_MPS = 0.44704

Boundary = Literal["double_yellow", "solid_white", "broken_white", "solid_yellow"]
LaneType = Literal["car_lane", "bike_lane"]
CrossingKind = Literal["stop", "incoming"]
Coordinates = Literal["wgs84", "local_m"]

BOUNDARIES: tuple[str, ...] = get_args(Boundary)
LANE_TYPES: tuple[str, ...] = get_args(LaneType)
CROSSING_KINDS: tuple[str, ...] = get_args(CrossingKind)

# See the module docstring: median point spacing above this (in the file's units) means metres.
LOCAL_METRES_SPACING = 0.05


@dataclass(frozen=True)
class Waypoint:
    """A lane, spot or perimeter point: `lat`, `lon` as written (degrees, or metres x/y in a local_m file)."""

    id: WaypointId
    lat: float
    lon: float
    line: int


@dataclass(frozen=True)
class Checkpoint:
    number: int
    waypoint: WaypointId
    line: int


@dataclass(frozen=True)
class Exit:
    """Travel may proceed from `exit` to `entry` (lane waypoint or zone perimeter point)."""

    exit: WaypointId
    entry: WaypointId
    line: int


@dataclass(frozen=True)
class StopSign:
    """A stop line through `waypoint`, perpendicular to the lane."""

    waypoint: WaypointId
    line: int


@dataclass(frozen=True)
class CrosswalkUse:
    """RNDF 1.1 ``cross``: at `waypoint` the lane meets crosswalk `crosswalk`; stop there or just note it."""

    waypoint: WaypointId
    crosswalk: LaneId
    kind: CrossingKind
    line: int


@dataclass(frozen=True)
class TrafficLightUse:
    """RNDF 1.1 ``light``: the lane's traffic light `light` governs the stop at `waypoint`."""

    waypoint: WaypointId
    light: LaneId
    line: int


@dataclass(frozen=True)
class Lane:
    id: LaneId
    waypoints: tuple[Waypoint, ...]
    width_m: float | None  # None: not given, or given as 0
    left_boundary: Boundary | None
    right_boundary: Boundary | None
    checkpoints: tuple[Checkpoint, ...]
    stops: tuple[StopSign, ...]
    exits: tuple[Exit, ...]
    line: int
    declared_waypoints: int | None = None
    lane_type: LaneType | None = None  # RNDF 1.1
    crosswalk_uses: tuple[CrosswalkUse, ...] = ()
    traffic_light_uses: tuple[TrafficLightUse, ...] = ()


@dataclass(frozen=True)
class Crosswalk:
    """RNDF 1.1: a crosswalk M.K of segment M, the line p1-p2 (lat, lon), `width_m` wide."""

    id: LaneId
    width_m: float | None
    p1: tuple[float, float]
    p2: tuple[float, float]
    line: int


@dataclass(frozen=True)
class Segment:
    id: int
    name: str | None
    lanes: tuple[Lane, ...]
    line: int
    declared_lanes: int | None = None
    crosswalks: tuple[Crosswalk, ...] = ()
    speed_limit_mps: float | None = None  # RNDF 1.1 segment header (mph in the file)
    offroad: bool = False


@dataclass(frozen=True)
class Perimeter:
    id: LaneId  # Z.0
    points: tuple[Waypoint, ...]
    exits: tuple[Exit, ...]
    line: int
    declared_points: int | None = None


@dataclass(frozen=True)
class Spot:
    """A parking spot: drive over waypoints[0] to waypoints[1] (checkpoint, spot centre), reverse out."""

    id: LaneId
    width_m: float | None
    checkpoint: Checkpoint | None
    waypoints: tuple[Waypoint, Waypoint]
    line: int


@dataclass(frozen=True)
class Zone:
    id: int
    name: str | None
    perimeter: Perimeter
    spots: tuple[Spot, ...]
    line: int
    declared_spots: int | None = None
    offroad: bool = False


@dataclass(frozen=True)
class TrafficLight:
    """RNDF 1.1: traffic light I.K of intersection I at (lat, lon), height `z_m`; a group switches as one."""

    id: LaneId
    group_id: int | None
    lat: float
    lon: float
    z_m: float | None
    line: int


@dataclass(frozen=True)
class Intersection:
    id: int
    traffic_lights: tuple[TrafficLight, ...]
    line: int
    declared_traffic_lights: int | None = None


@dataclass(frozen=True)
class RoadNetwork:
    """A parsed RNDF. Lookups (`waypoint`, `lane`, `checkpoint_waypoint`, ...) are dictionaries built once."""

    path: str
    name: str
    format_version: str | None
    creation_date: str | None
    segments: tuple[Segment, ...]
    zones: tuple[Zone, ...]
    coordinates: Coordinates
    intersections: tuple[Intersection, ...] = ()
    declared_segments: int | None = None
    declared_zones: int | None = None
    declared_intersections: int | None = None
    warnings: tuple[ParseWarning, ...] = field(default=(), compare=False)
    _waypoints: dict[WaypointId, Waypoint] = field(init=False, repr=False, compare=False)
    _lanes: dict[LaneId, Lane] = field(init=False, repr=False, compare=False)
    _checkpoints: dict[int, Checkpoint] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        waypoints: dict[WaypointId, Waypoint] = {}
        lanes: dict[LaneId, Lane] = {}
        checkpoints: dict[int, Checkpoint] = {}
        for seg in self.segments:
            for lane in seg.lanes:
                lanes[lane.id] = lane
                waypoints.update((w.id, w) for w in lane.waypoints)
                checkpoints.update((c.number, c) for c in lane.checkpoints)
        for zone in self.zones:
            waypoints.update((w.id, w) for w in zone.perimeter.points)
            for spot in zone.spots:
                waypoints.update((w.id, w) for w in spot.waypoints)
                if spot.checkpoint is not None:
                    checkpoints[spot.checkpoint.number] = spot.checkpoint
        object.__setattr__(self, "_waypoints", waypoints)
        object.__setattr__(self, "_lanes", lanes)
        object.__setattr__(self, "_checkpoints", checkpoints)

    def waypoint(self, wid: WaypointId) -> Waypoint:
        """Lane, spot or perimeter point by id (KeyError if absent)."""
        return self._waypoints[wid]

    def has_waypoint(self, wid: WaypointId) -> bool:
        return wid in self._waypoints

    def waypoints(self) -> Iterator[Waypoint]:
        """Every point of the network: lane waypoints, perimeter points, spot waypoints."""
        return iter(self._waypoints.values())

    def lane(self, lid: LaneId) -> Lane:
        return self._lanes[lid]

    def lanes(self) -> Iterator[Lane]:
        return iter(self._lanes.values())

    @property
    def checkpoints(self) -> dict[int, Checkpoint]:
        """Checkpoint number -> checkpoint (lanes and spots)."""
        return dict(self._checkpoints)

    def checkpoint_waypoint(self, number: int) -> WaypointId:
        """Waypoint of checkpoint `number` (KeyError if the network has no such checkpoint)."""
        return self._checkpoints[number].waypoint

    def exits(self) -> Iterator[Exit]:
        """Lane exits and perimeter exits."""
        for seg in self.segments:
            for lane in seg.lanes:
                yield from lane.exits
        for zone in self.zones:
            yield from zone.perimeter.exits

    def segment(self, sid: int) -> Segment:
        for seg in self.segments:
            if seg.id == sid:
                return seg
        raise KeyError(sid)

    def zone(self, zid: int) -> Zone:
        for zone in self.zones:
            if zone.id == zid:
                return zone
        raise KeyError(zid)

    @property
    def area_ids(self) -> tuple[int, ...]:
        """Segment and zone ids (the ids an MDF gives speed limits for)."""
        return tuple(s.id for s in self.segments) + tuple(z.id for z in self.zones)


# ---------------------------------------------------------------------------------------------- parser

_FILE_HEADER = ("num_segments", "num_zones", "num_intersections", "format_version", "creation_date")
_STRUCTURE = frozenset(
    {
        "segment",
        "end_segment",
        "lane",
        "end_lane",
        "zone",
        "end_zone",
        "perimeter",
        "end_perimeter",
        "spot",
        "end_spot",
        "crosswalk",
        "end_crosswalk",
        "intersection",
        "end_intersection",
        "trafficlight",
        "end_trafficlight",
        "end_file",
    }
)


@dataclass
class _Pending:
    """A reference checked once the whole file is read (exits may point forward)."""

    what: str  # "entry", "waypoint", "crosswalk", "traffic light"
    target: WaypointId | LaneId
    line: int


class _RndfParser:
    def __init__(
        self, text: str, path: str, coordinates: Literal["auto", "wgs84", "local_m"], strict: bool
    ) -> None:
        self.c = Cursor(text, path, RndfError)
        self.path = path
        self.strict = strict
        self.coordinates_mode = coordinates
        self.warnings: list[ParseWarning] = []
        self.pending: list[_Pending] = []
        self.checkpoint_lines: dict[int, int] = {}
        self.area_lines: dict[int, int] = {}
        self.point_lines: list[tuple[WaypointId, float, float, int]] = []  # for the coordinate check

    def warn(self, line: int, message: str) -> None:
        self.warnings.append(ParseWarning(self.path, line, message))

    # -- small helpers

    def _wid(self, line: Line, token: str, what: str) -> WaypointId:
        try:
            return WaypointId.parse(token)
        except ValueError:
            raise self.c.fail(line, f"expected a waypoint id M.N.P as {what}, found {token!r}") from None

    def _lid(self, line: Line, token: str, what: str) -> LaneId:
        try:
            return LaneId.parse(token)
        except ValueError:
            raise self.c.fail(line, f"expected an id M.N as {what}, found {token!r}") from None

    def _own_wid(self, line: Line, token: str, owner: LaneId, what: str) -> WaypointId:
        """A waypoint id in `owner`'s header; another lane's is a quirk (Cornell's Sample2), not an error."""
        wid = self._wid(line, token, what)
        if wid.lane_id != owner:
            self.warn(line.number, f"{what} {wid} named in the header of {owner}, not its own lane")
        return wid

    def _once(self, seen: set[str], line: Line) -> None:
        if line.keyword in seen:
            raise self.c.fail(line, f"expected one '{line.keyword}' in this block, found a second")
        seen.add(line.keyword)

    def _area_id(self, line: Line, what: str) -> int:
        (tok,) = self.c.args(line, 1, f"{what} <id>")
        num = self.c.integer(line, tok, f"{what} id", minimum=1)
        if num in self.area_lines:
            raise self.c.fail(
                line,
                f"expected a new segment/zone/intersection id, {num} is already used on line "
                f"{self.area_lines[num]}",
            )
        self.area_lines[num] = line.number
        return num

    def _width_m(self, line: Line, what: str) -> float | None:
        (tok,) = self.c.args(line, 1, f"{line.keyword} <{what} in feet>")
        feet = self.c.integer(line, tok, what)
        return feet * FEET_TO_M if feet > 0 else None

    def _point(self, line: Line, wid: WaypointId) -> Waypoint:
        if len(line.tokens) != 3:
            raise self.c.fail(line, f"expected '{wid} <latitude> <longitude>'")
        lat = self.c.number(line, line.tokens[1], "as latitude")
        lon = self.c.number(line, line.tokens[2], "as longitude")
        self.point_lines.append((wid, lat, lon, line.number))
        return Waypoint(wid, lat, lon, line.number)

    def _checkpoint(self, line: Line, owner: LaneId) -> Checkpoint:
        wtok, ntok = self.c.args(line, 2, "checkpoint <waypoint id> <checkpoint number>")
        wid = self._own_wid(line, wtok, owner, "checkpoint waypoint")
        number = self.c.integer(line, ntok, "checkpoint number", minimum=1)
        if number in self.checkpoint_lines:
            raise self.c.fail(
                line,
                f"expected a new checkpoint number, {number} is already used on line "
                f"{self.checkpoint_lines[number]}",
            )
        self.checkpoint_lines[number] = line.number
        self.pending.append(_Pending("waypoint", wid, line.number))
        return Checkpoint(number, wid, line.number)

    def _points_in_order(self, points: list[Waypoint], line: Line, wid: WaypointId, owner: LaneId) -> None:
        if wid.lane_id != owner or wid.number < 1:
            raise self.c.fail(
                line, f"expected a point of {owner} ({owner}.P, P >= 1) or an end marker, found {wid}"
            )
        if points and wid.number <= points[-1].id.number:
            prev = points[-1]
            raise self.c.fail(
                line, f"expected a point of {owner} numbered after {prev.id} (line {prev.line}), found {wid}"
            )
        if wid.number != (points[-1].id.number + 1 if points else 1):
            self.warn(line.number, f"{wid} does not continue the numbering of {owner} (1, 2, 3, ...)")

    def _count(self, declared: int | None, found: int, what: str, line: int) -> None:
        if declared is not None and declared != found:
            self.warn(line, f"header declares {declared} {what}, the body has {found}")

    # -- grammar

    def parse(self) -> RoadNetwork:
        c = self.c
        first = c.take("RNDF_name")
        if first.keyword != "RNDF_name":
            raise c.unexpected(first, "RNDF_name at the start of an RNDF")
        name = c.text(first)
        header: dict[str, Line] = {}
        while (line := c.peek()) is not None and line.keyword in _FILE_HEADER:
            c.take("")
            if line.keyword in header:
                raise c.fail(line, f"expected one '{line.keyword}' in the file header, found a second")
            header[line.keyword] = line
        counts: dict[str, int | None] = {}
        for key in ("num_segments", "num_zones", "num_intersections"):
            hl = header.get(key)
            if hl is None:
                if key != "num_intersections":
                    where = c.peek() or first
                    raise c.fail(where, f"expected {key} in the file header (after RNDF_name)")
                counts[key] = None
                continue
            (tok,) = c.args(hl, 1, f"{key} <count>")
            counts[key] = c.integer(hl, tok, key)
        segments: list[Segment] = []
        zones: list[Zone] = []
        intersections: list[Intersection] = []
        while True:
            line = c.take("segment, zone or end_file")
            if line.keyword == "segment":
                segments.append(self._segment(line))
            elif line.keyword == "zone":
                zones.append(self._zone(line))
            elif line.keyword == "intersection":
                intersections.append(self._intersection(line))
            elif line.keyword == "end_file":
                c.args(line, 0, "end_file")
                end_line = line.number
                break
            else:
                raise c.unexpected(line, "segment, zone, intersection or end_file")
        extra = c.peek()
        if extra is not None:
            raise c.fail(extra, f"expected nothing but comments after end_file (line {end_line})")
        self._count(counts["num_segments"], len(segments), "segments", header["num_segments"].number)
        self._count(counts["num_zones"], len(zones), "zones", header["num_zones"].number)
        if "num_intersections" in header:
            self._count(
                counts["num_intersections"],
                len(intersections),
                "intersections",
                header["num_intersections"].number,
            )
        network = RoadNetwork(
            path=self.path,
            name=name,
            format_version=c.text(header["format_version"]) if "format_version" in header else None,
            creation_date=c.text(header["creation_date"]) if "creation_date" in header else None,
            segments=tuple(segments),
            zones=tuple(zones),
            coordinates=self._coordinates(),
            intersections=tuple(intersections),
            declared_segments=counts["num_segments"],
            declared_zones=counts["num_zones"],
            declared_intersections=counts["num_intersections"],
        )
        network = self._resolve(network)
        if self.strict and self.warnings:
            quirk = min(self.warnings, key=lambda w: w.line)
            raise RndfError(self.path, quirk.line, f"expected no format quirks (strict): {quirk.message}")
        return _with_warnings(network, self.warnings)

    def _segment(self, start: Line) -> Segment:
        c = self.c
        sid = self._area_id(start, "segment")
        seen: set[str] = set()
        name: str | None = None
        num_lanes: int | None = None
        num_crosswalks: int | None = None
        speed_limit: float | None = None
        offroad = False
        lanes: list[Lane] = []
        crosswalks: list[Crosswalk] = []
        lane_ids: dict[LaneId, int] = {}
        while True:
            line = c.take(f"end_segment of segment {sid}")
            kw = line.keyword
            if kw in ("num_lanes", "segment_name", "num_crosswalks", "speed_limit", "offroad") and not lanes:
                self._once(seen, line)
                if kw == "num_lanes":
                    (tok,) = c.args(line, 1, "num_lanes <count>")
                    num_lanes = c.integer(line, tok, "num_lanes")
                elif kw == "segment_name":
                    name = c.text(line)
                elif kw == "num_crosswalks":
                    (tok,) = c.args(line, 1, "num_crosswalks <count>")
                    num_crosswalks = c.integer(line, tok, "num_crosswalks")
                elif kw == "speed_limit":
                    (tok,) = c.args(line, 1, "speed_limit <mph>")
                    mph = c.number(line, tok, "as speed_limit (mph)")
                    if mph < 0:
                        raise c.fail(line, f"expected a speed limit >= 0 mph, found {tok!r}")
                    speed_limit = mph * MPH_TO_MPS if mph > 0 else None
                else:
                    offroad = self._flag(line)
            elif kw == "lane":
                lane = self._lane(line, sid)
                if lane.id in lane_ids:
                    raise c.fail(
                        line, f"expected a new lane id, {lane.id} is already used on line {lane_ids[lane.id]}"
                    )
                lane_ids[lane.id] = line.number
                lanes.append(lane)
            elif kw == "crosswalk":
                cw = self._crosswalk(line, sid)
                if any(x.id == cw.id for x in crosswalks):
                    raise c.fail(
                        line, f"expected a new crosswalk id, {cw.id} is already used in this segment"
                    )
                crosswalks.append(cw)
            elif kw == "end_segment":
                c.args(line, 0, "end_segment")
                break
            else:
                raise c.unexpected(line, f"lane, crosswalk or end_segment in segment {sid}")
        if num_lanes is None:
            raise c.fail(start, f"expected num_lanes in the header of segment {sid}")
        if not lanes:
            raise c.fail(start, f"expected at least one lane in segment {sid}")
        self._count(num_lanes, len(lanes), f"lanes in segment {sid}", start.number)
        if num_crosswalks is not None:
            self._count(num_crosswalks, len(crosswalks), f"crosswalks in segment {sid}", start.number)
        return Segment(
            id=sid,
            name=name,
            lanes=tuple(lanes),
            line=start.number,
            declared_lanes=num_lanes,
            crosswalks=tuple(crosswalks),
            speed_limit_mps=speed_limit,
            offroad=offroad,
        )

    def _flag(self, line: Line) -> bool:
        (tok,) = self.c.args(line, 0, f"{line.keyword} [0|1]", optional=1) or ("1",)
        if tok not in ("0", "1"):
            raise self.c.fail(line, f"expected '{line.keyword}' optionally followed by 0 or 1, found {tok!r}")
        return tok == "1"

    def _lane(self, start: Line, sid: int) -> Lane:
        c = self.c
        (tok,) = c.args(start, 1, "lane <M.N>")
        lid = self._lid(start, tok, "lane id")
        if lid.segment != sid or lid.lane < 1:
            raise c.fail(start, f"expected a lane {sid}.N (N >= 1) of segment {sid}, found {tok!r}")
        seen: set[str] = set()
        num_waypoints: int | None = None
        width: float | None = None
        left: Boundary | None = None
        right: Boundary | None = None
        lane_type: LaneType | None = None
        checkpoints: list[Checkpoint] = []
        stops: list[StopSign] = []
        exits: list[Exit] = []
        crossings: list[CrosswalkUse] = []
        lights: list[TrafficLightUse] = []
        points: list[Waypoint] = []
        while True:
            line = c.take(f"end_lane of lane {lid}")
            kw = line.keyword
            if kw[0].isdigit():
                wid = self._wid(line, kw, "waypoint")
                self._points_in_order(points, line, wid, lid)
                points.append(self._point(line, wid))
            elif kw == "num_waypoints":
                self._once(seen, line)
                (tok,) = c.args(line, 1, "num_waypoints <count>")
                num_waypoints = c.integer(line, tok, "num_waypoints")
            elif kw == "lane_width":
                self._once(seen, line)
                width = self._width_m(line, "lane_width")
            elif kw in ("left_boundary", "right_boundary"):
                self._once(seen, line)
                (tok,) = c.args(line, 1, f"{kw} <{'|'.join(BOUNDARIES)}>")
                if tok not in BOUNDARIES:
                    raise c.fail(line, f"expected a boundary ({', '.join(BOUNDARIES)}), found {tok!r}")
                if kw == "left_boundary":
                    left = tok  # type: ignore[assignment]
                else:
                    right = tok  # type: ignore[assignment]
            elif kw == "lane_type":
                self._once(seen, line)
                (tok,) = c.args(line, 1, f"lane_type <{'|'.join(LANE_TYPES)}>")
                if tok not in LANE_TYPES:
                    raise c.fail(line, f"expected a lane type ({', '.join(LANE_TYPES)}), found {tok!r}")
                lane_type = tok  # type: ignore[assignment]
            elif kw == "checkpoint":
                checkpoints.append(self._checkpoint(line, lid))
            elif kw == "stop":
                (tok,) = c.args(line, 1, "stop <waypoint id>")
                wid = self._own_wid(line, tok, lid, "stop waypoint")
                if any(s.waypoint == wid for s in stops):
                    self.warn(line.number, f"stop at {wid} given twice; kept once")
                    continue
                self.pending.append(_Pending("waypoint", wid, line.number))
                stops.append(StopSign(wid, line.number))
            elif kw == "exit":
                etok, ntok = c.args(line, 2, "exit <exit waypoint> <entry waypoint>")
                ex = self._exit(line, self._own_wid(line, etok, lid, "exit waypoint"), ntok)
                if any((e.exit, e.entry) == (ex.exit, ex.entry) for e in exits):
                    self.warn(line.number, f"exit {ex.exit} -> {ex.entry} given twice; kept once")
                else:
                    exits.append(ex)
            elif kw == "cross":
                wtok, ctok, ktok = c.args(line, 3, "cross <waypoint id> <crosswalk id> <stop|incoming>")
                wid = self._own_wid(line, wtok, lid, "crossing waypoint")
                cw = self._lid(line, ctok, "crosswalk id")
                if ktok not in CROSSING_KINDS:
                    raise c.fail(
                        line, f"expected 'stop' or 'incoming' after the crosswalk id, found {ktok!r}"
                    )
                self.pending.append(_Pending("waypoint", wid, line.number))
                self.pending.append(_Pending("crosswalk", cw, line.number))
                crossings.append(CrosswalkUse(wid, cw, ktok, line.number))  # type: ignore[arg-type]
            elif kw == "light":
                wtok, ltok = c.args(line, 2, "light <waypoint id> <traffic light id>")
                wid = self._own_wid(line, wtok, lid, "traffic light waypoint")
                tl = self._lid(line, ltok, "traffic light id")
                self.pending.append(_Pending("waypoint", wid, line.number))
                self.pending.append(_Pending("traffic light", tl, line.number))
                lights.append(TrafficLightUse(wid, tl, line.number))
            elif kw == "end_lane":
                c.args(line, 0, "end_lane")
                break
            elif kw in _STRUCTURE:
                raise c.fail(line, f"expected end_lane of lane {lid} before {kw!r}")
            else:
                raise c.unexpected(
                    line, f"a lane header keyword, a waypoint {lid}.P or end_lane in lane {lid}"
                )
        if num_waypoints is None:
            raise c.fail(start, f"expected num_waypoints in the header of lane {lid}")
        if not points:
            raise c.fail(start, f"expected at least one waypoint in lane {lid}")
        self._count(num_waypoints, len(points), f"waypoints in lane {lid}", start.number)
        return Lane(
            id=lid,
            waypoints=tuple(points),
            width_m=width,
            left_boundary=left,
            right_boundary=right,
            checkpoints=tuple(checkpoints),
            stops=tuple(stops),
            exits=tuple(exits),
            line=start.number,
            declared_waypoints=num_waypoints,
            lane_type=lane_type,
            crosswalk_uses=tuple(crossings),
            traffic_light_uses=tuple(lights),
        )

    def _exit(self, line: Line, exit_wid: WaypointId, entry_token: str) -> Exit:
        entry = self._wid(line, entry_token, "entry waypoint")
        if entry == exit_wid:
            raise self.c.fail(line, f"expected an entry other than the exit waypoint {exit_wid} itself")
        self.pending.append(_Pending("waypoint", exit_wid, line.number))
        self.pending.append(_Pending("entry", entry, line.number))
        return Exit(exit_wid, entry, line.number)

    def _crosswalk(self, start: Line, sid: int) -> Crosswalk:
        c = self.c
        (tok,) = c.args(start, 1, "crosswalk <M.K>")
        cid = self._lid(start, tok, "crosswalk id")
        if cid.segment != sid or cid.lane < 1:
            raise c.fail(start, f"expected a crosswalk {sid}.K of segment {sid}, found {tok!r}")
        seen: set[str] = set()
        width: float | None = None
        ends: dict[str, tuple[float, float]] = {}
        while True:
            line = c.take(f"end_crosswalk of crosswalk {cid}")
            kw = line.keyword
            if kw == "crosswalk_width":
                self._once(seen, line)
                width = self._width_m(line, "crosswalk_width")
            elif kw in ("crosswalk_p1", "crosswalk_p2"):
                self._once(seen, line)
                lat_t, lon_t = c.args(line, 2, f"{kw} <latitude> <longitude>")
                ends[kw] = (c.number(line, lat_t, "as latitude"), c.number(line, lon_t, "as longitude"))
                self.point_lines.append((WaypointId(cid.segment, cid.lane, 0), *ends[kw], line.number))
            elif kw == "end_crosswalk":
                c.args(line, 0, "end_crosswalk")
                break
            else:
                raise c.unexpected(
                    line, f"crosswalk_width, crosswalk_p1, crosswalk_p2 or end_crosswalk in {cid}"
                )
        for key in ("crosswalk_p1", "crosswalk_p2"):
            if key not in ends:
                raise c.fail(start, f"expected {key} in crosswalk {cid}")
        return Crosswalk(cid, width, ends["crosswalk_p1"], ends["crosswalk_p2"], start.number)

    def _zone(self, start: Line) -> Zone:
        c = self.c
        zid = self._area_id(start, "zone")
        seen: set[str] = set()
        name: str | None = None
        num_spots: int | None = None
        offroad = False
        perimeter: Perimeter | None = None
        spots: list[Spot] = []
        while True:
            line = c.take(f"end_zone of zone {zid}")
            kw = line.keyword
            if kw in ("num_spots", "zone_name", "offroad") and perimeter is None:
                self._once(seen, line)
                if kw == "num_spots":
                    (tok,) = c.args(line, 1, "num_spots <count>")
                    num_spots = c.integer(line, tok, "num_spots")
                elif kw == "zone_name":
                    name = c.text(line)
                else:
                    offroad = self._flag(line)
            elif kw == "perimeter":
                if perimeter is not None:
                    raise c.fail(line, f"expected one perimeter in zone {zid}, found a second")
                perimeter = self._perimeter(line, zid)
            elif kw == "spot":
                if perimeter is None:
                    raise c.fail(line, f"expected the perimeter of zone {zid} before its spots")
                spot = self._spot(line, zid)
                if any(s.id == spot.id for s in spots):
                    raise c.fail(line, f"expected a new spot id, {spot.id} is already used in zone {zid}")
                spots.append(spot)
            elif kw == "end_zone":
                c.args(line, 0, "end_zone")
                break
            else:
                raise c.unexpected(line, f"a zone header keyword, perimeter, spot or end_zone in zone {zid}")
        if num_spots is None:
            raise c.fail(start, f"expected num_spots in the header of zone {zid}")
        if perimeter is None:
            raise c.fail(start, f"expected a perimeter in zone {zid}")
        self._count(num_spots, len(spots), f"spots in zone {zid}", start.number)
        return Zone(zid, name, perimeter, tuple(spots), start.number, num_spots, offroad)

    def _perimeter(self, start: Line, zid: int) -> Perimeter:
        c = self.c
        (tok,) = c.args(start, 1, "perimeter <Z.0>")
        pid = self._lid(start, tok, "perimeter id")
        if pid != LaneId(zid, 0):
            raise c.fail(start, f"expected perimeter {zid}.0 of zone {zid}, found {tok!r}")
        seen: set[str] = set()
        declared: int | None = None
        points: list[Waypoint] = []
        exits: list[Exit] = []
        while True:
            line = c.take(f"end_perimeter of zone {zid}")
            kw = line.keyword
            if kw[0].isdigit():
                wid = self._wid(line, kw, "perimeter point")
                self._points_in_order(points, line, wid, pid)
                points.append(self._point(line, wid))
            elif kw == "num_perimeterpoints":
                self._once(seen, line)
                (tok,) = c.args(line, 1, "num_perimeterpoints <count>")
                declared = c.integer(line, tok, "num_perimeterpoints")
            elif kw == "exit":
                etok, ntok = c.args(line, 2, "exit <perimeter point> <entry waypoint>")
                ex = self._exit(line, self._own_wid(line, etok, pid, "exit perimeter point"), ntok)
                if any((e.exit, e.entry) == (ex.exit, ex.entry) for e in exits):
                    self.warn(line.number, f"exit {ex.exit} -> {ex.entry} given twice; kept once")
                else:
                    exits.append(ex)
            elif kw == "end_perimeter":
                c.args(line, 0, "end_perimeter")
                break
            elif kw in _STRUCTURE:
                raise c.fail(line, f"expected end_perimeter of zone {zid} before {kw!r}")
            else:
                raise c.unexpected(line, f"num_perimeterpoints, exit, a point {pid}.P or end_perimeter")
        if declared is None:
            raise c.fail(start, f"expected num_perimeterpoints in perimeter {pid}")
        if not points:
            raise c.fail(start, f"expected perimeter points in perimeter {pid}")
        if len(points) < 3:
            self.warn(start.number, f"perimeter {pid} has {len(points)} points, which enclose no area")
        self._count(declared, len(points), f"perimeter points in {pid}", start.number)
        return Perimeter(pid, tuple(points), tuple(exits), start.number, declared)

    def _spot(self, start: Line, zid: int) -> Spot:
        c = self.c
        (tok,) = c.args(start, 1, "spot <Z.N>")
        sid = self._lid(start, tok, "spot id")
        if sid.segment != zid or sid.lane < 1:
            raise c.fail(start, f"expected a spot {zid}.N (N >= 1) of zone {zid}, found {tok!r}")
        seen: set[str] = set()
        width: float | None = None
        checkpoint: Checkpoint | None = None
        points: list[Waypoint] = []
        while True:
            line = c.take(f"end_spot of spot {sid}")
            kw = line.keyword
            if kw[0].isdigit():
                wid = self._wid(line, kw, "spot waypoint")
                if wid.lane_id != sid or wid.number != len(points) + 1 or len(points) == 2:
                    raise c.fail(
                        line, f"expected the spot's waypoints {sid}.1 then {sid}.2 and no others, found {kw}"
                    )
                points.append(self._point(line, wid))
            elif kw == "spot_width":
                self._once(seen, line)
                width = self._width_m(line, "spot_width")
            elif kw == "checkpoint":
                self._once(seen, line)
                checkpoint = self._checkpoint(line, sid)
            elif kw == "end_spot":
                c.args(line, 0, "end_spot")
                break
            elif kw in _STRUCTURE:
                raise c.fail(line, f"expected end_spot of spot {sid} before {kw!r}")
            else:
                raise c.unexpected(line, f"spot_width, checkpoint, a waypoint {sid}.P or end_spot")
        if len(points) != 2:
            raise c.fail(
                start, f"expected two waypoints {sid}.1 and {sid}.2 in spot {sid}, found {len(points)}"
            )
        if checkpoint is None:
            self.warn(start.number, f"spot {sid} has no checkpoint (the format puts one on {sid}.2)")
        return Spot(sid, width, checkpoint, (points[0], points[1]), start.number)

    def _intersection(self, start: Line) -> Intersection:
        c = self.c
        iid = self._area_id(start, "intersection")
        declared: int | None = None
        seen: set[str] = set()
        lights: list[TrafficLight] = []
        while True:
            line = c.take(f"end_intersection of intersection {iid}")
            kw = line.keyword
            if kw == "num_trafficlights" and not lights:
                self._once(seen, line)
                (tok,) = c.args(line, 1, "num_trafficlights <count>")
                declared = c.integer(line, tok, "num_trafficlights")
            elif kw == "trafficlight":
                light = self._traffic_light(line, iid)
                if any(x.id == light.id for x in lights):
                    raise c.fail(line, f"expected a new traffic light id, {light.id} is already used")
                lights.append(light)
            elif kw == "end_intersection":
                c.args(line, 0, "end_intersection")
                break
            else:
                raise c.unexpected(line, f"num_trafficlights, trafficlight or end_intersection in {iid}")
        self._count(declared, len(lights), f"traffic lights in intersection {iid}", start.number)
        return Intersection(iid, tuple(lights), start.number, declared)

    def _traffic_light(self, start: Line, iid: int) -> TrafficLight:
        c = self.c
        (tok,) = c.args(start, 1, "trafficlight <I.K>")
        lid = self._lid(start, tok, "traffic light id")
        if lid.segment != iid or lid.lane < 1:
            raise c.fail(start, f"expected a traffic light {iid}.K of intersection {iid}, found {tok!r}")
        seen: set[str] = set()
        group: int | None = None
        position: tuple[float, float, float | None] | None = None
        while True:
            line = c.take(f"end_trafficlight of traffic light {lid}")
            kw = line.keyword
            if kw == "group_id":
                self._once(seen, line)
                (gtok,) = c.args(line, 1, "group_id <number>")
                group = c.integer(line, gtok, "group_id")
            elif kw == "position":
                self._once(seen, line)
                vals = c.args(line, 2, "position <latitude> <longitude> [height m]", optional=1)
                lat = c.number(line, vals[0], "as latitude")
                lon = c.number(line, vals[1], "as longitude")
                z = c.number(line, vals[2], "as height") if len(vals) == 3 else None
                position = (lat, lon, z)
                self.point_lines.append((WaypointId(lid.segment, lid.lane, 0), lat, lon, line.number))
            elif kw == "end_trafficlight":
                c.args(line, 0, "end_trafficlight")
                break
            else:
                raise c.unexpected(line, f"group_id, position or end_trafficlight in traffic light {lid}")
        if position is None:
            raise c.fail(start, f"expected a position in traffic light {lid}")
        return TrafficLight(lid, group, position[0], position[1], position[2], start.number)

    # -- after the whole file

    def _resolve(self, net: RoadNetwork) -> RoadNetwork:
        """Check every reference; a dangling one is an error in strict mode, else dropped with a warning."""
        crosswalks = {cw.id for seg in net.segments for cw in seg.crosswalks}
        lights = {tl.id for i in net.intersections for tl in i.traffic_lights}
        spot_points = {w.id for z in net.zones for s in z.spots for w in s.waypoints}
        dropped: set[int] = set()
        for ref in self.pending:
            problem = None
            if ref.what in ("waypoint", "entry"):
                assert isinstance(ref.target, WaypointId)
                if not net.has_waypoint(ref.target):
                    problem = f"an existing waypoint, {ref.target} is not defined"
                elif ref.what == "entry" and ref.target in spot_points:
                    problem = f"a lane waypoint or perimeter point as entry, {ref.target} is a spot waypoint"
            elif ref.what == "crosswalk" and ref.target not in crosswalks:
                problem = f"an existing crosswalk, {ref.target} is not defined"
            elif ref.what == "traffic light" and ref.target not in lights:
                problem = f"an existing traffic light, {ref.target} is not defined"
            if problem is None:
                continue
            if self.strict:
                raise RndfError(self.path, ref.line, f"expected {problem}")
            if ref.line not in dropped:
                dropped.add(ref.line)
                self.warn(ref.line, f"dangling reference dropped: expected {problem}")
        return _drop_lines(net, dropped) if dropped else net

    def _coordinates(self) -> Coordinates:
        mode = self.coordinates_mode
        if mode == "auto":
            mode = "local_m" if _looks_metric(self.point_lines) else "wgs84"
            if mode == "local_m" and self.point_lines:
                self.warn(
                    self.point_lines[0][3],
                    "coordinates are not latitude/longitude (median point spacing "
                    f"> {LOCAL_METRES_SPACING}); read as local metres, x east first, y north second",
                )
        if mode == "wgs84":
            for _, lat, lon, number in self.point_lines:
                if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
                    raise RndfError(
                        self.path,
                        number,
                        f"expected latitude in [-90, 90] and longitude in [-180, 180], found {lat} {lon}",
                    )
        return mode


def _looks_metric(points: list[tuple[WaypointId, float, float, int]]) -> bool:
    gaps = [
        max(abs(a[1] - b[1]), abs(a[2] - b[2]))
        for a, b in itertools.pairwise(points)
        if a[0].lane_id == b[0].lane_id and a[0].number and b[0].number  # number 0: crosswalk / light
    ]
    return bool(gaps) and statistics.median(gaps) > LOCAL_METRES_SPACING


def _drop_lines(net: RoadNetwork, lines: set[int]) -> RoadNetwork:
    """`net` without the exits, checkpoints, stops and crosswalk/light uses stated on `lines`."""

    def keep(items: tuple[_T, ...]) -> tuple[_T, ...]:
        return tuple(x for x in items if x.line not in lines)  # type: ignore[attr-defined]

    segments = tuple(
        replace(
            seg,
            lanes=tuple(
                replace(
                    lane,
                    checkpoints=keep(lane.checkpoints),
                    stops=keep(lane.stops),
                    exits=keep(lane.exits),
                    crosswalk_uses=keep(lane.crosswalk_uses),
                    traffic_light_uses=keep(lane.traffic_light_uses),
                )
                for lane in seg.lanes
            ),
        )
        for seg in net.segments
    )
    zones = tuple(
        replace(
            zone,
            perimeter=replace(zone.perimeter, exits=keep(zone.perimeter.exits)),
            spots=tuple(
                replace(spot, checkpoint=None)
                if spot.checkpoint is not None and spot.checkpoint.line in lines
                else spot
                for spot in zone.spots
            ),
        )
        for zone in net.zones
    )
    return replace(net, segments=segments, zones=zones)


def _with_warnings(net: RoadNetwork, warnings: list[ParseWarning]) -> RoadNetwork:
    object.__setattr__(net, "warnings", tuple(sorted(warnings, key=lambda w: w.line)))
    return net


def parse_rndf(
    text: str,
    path: str = "<rndf>",
    coordinates: Literal["auto", "wgs84", "local_m"] = "auto",
    strict: bool = False,
) -> RoadNetwork:
    """Parse RNDF text; `path` is only used in messages. Raises `RndfError`.

    ``strict=True`` turns every tolerated quirk (the `ParseWarning`s) into an `RndfError` at its line.
    """
    return _RndfParser(text, path, coordinates, strict).parse()


def load_rndf(
    path: str | Path, coordinates: Literal["auto", "wgs84", "local_m"] = "auto", strict: bool = False
) -> RoadNetwork:
    """Read and parse an RNDF file (bytes decoded as Latin-1; non-ASCII outside comments is an error)."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise RndfError(str(p), 0, f"expected a readable file ({exc.strerror or exc})") from None
    return parse_rndf(decode(data), str(p), coordinates, strict)
