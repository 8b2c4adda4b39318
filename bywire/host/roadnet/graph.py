"""The geometric graph of a road network (seed 000 sec. 8, Fig. 10a/b).

"All elements of the RNDF (lanes, checkpoints, exits, etc.) are converted to a graph-based, geometrical
representation. RNDF way points form the vertices of the graph; lanes and exits are represented by graph
edges. Edges yield a geometric representation by smoothing them by spline interpolation. Information such
as distances, lane boundaries, and speed limits annotates the graph edges. These annotations can be
updated dynamically [...] (e.g., road blockages)."

Vertices: every lane waypoint, zone perimeter point and spot waypoint (`WaypointId`).  Edges
(`EdgeKind`), each an `Edge` with its own `Path`:

- LANE: consecutive waypoints of a lane, a piece of the lane's one smooth curve (`path.smooth_curve`
  through all its waypoints), so that consecutive lane edges join with continuous curvature.
- EXIT: an RNDF ``exit`` (lane -> lane, lane -> zone perimeter, perimeter -> lane), a `path.connector`
  tangent to both lanes and matching their curvature, widened by `path.drivable_connector` where it
  would turn tighter than the car's full lock (`GraphParams.exit_max_curvature_1pm`; deviation: the
  paper's smoothing is geometric only, and tight RNDF exits then ask for radii no car steers); into
  or out of a zone, the perimeter side takes the chord's direction and zero curvature.
- LANE_CHANGE (derived): from a waypoint to the first waypoint of an adjacent lane (lane number +-1) in the
  same direction that lies at least `GraphParams.lane_change_min_length_m` ahead; a connector.  Only where
  the lanes really run side by side: the foot point on the other lane lies square across, 1 m to 2.2 lane
  widths away, and the headings differ by less than 30 deg.
- UTURN: an RNDF exit that turns back into the opposite lane of its own segment (the format's dead-end
  U-turn), and (derived, `from_rndf=False`) from each waypoint to the first waypoint of an adjacent
  opposite-direction lane at or beyond the point alongside - the K-turn that replanning around a blocked
  road needs.  (Deviation: the task names two-lane segments; any pair of adjacent opposite lanes gets
  them, i.e. also the inner lanes of a four-lane road.)  The geometry of a U-turn is a placeholder (a
  connector loop); the K-turn itself is manoeuvre planning's.
- ZONE (derived): inside a zone, from every entry (perimeter point some lane exits to) to every exit
  perimeter point and every spot's first waypoint, and from every spot's first waypoint to the exits and
  to the other spots.  Straight lines: a lower bound for the route search; zone navigation (sec. 10)
  plans the real path.
- PARK: spot waypoint 1 -> 2 (the checkpoint); UNPARK: 2 -> 1, driven in reverse (the car's heading is the
  path's + pi).

Annotations: length, speed limits (MDF, per segment/zone, `apply_speed_limits`), lane width (an exit's
"implied lane" is the narrower of its two lanes, format sec. 2.1), boundaries, stop sign and checkpoint at
the end vertex, the RNDF line of an exit, and `blocked`, which `block_edge` / `unblock_all` change at run
time.  Exits whose connector is tighter than `GraphParams.warn_radius_m` land in `RoadGraph.warnings`.

An RNDF exit and a derived edge between the same two vertices: the RNDF exit wins.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from enum import StrEnum

import networkx as nx
import numpy as np

from .curves import connector, drivable_connector, smooth_curve
from .errors import ParseWarning
from .geo import CoordinateFrame, frame_for
from .ids import LaneId, WaypointId
from .mdf import Mission, ResolvedMission
from .path import DEFAULT_STEP_M, Path, PathPoint, concat, wrap_angle
from .rndf import Boundary, Lane, RoadNetwork

# 12 ft, the common lane width of the DARPA files, where a lane gives none.
DEFAULT_LANE_WIDTH_M = 12 * 0.3048


class EdgeKind(StrEnum):
    LANE = "lane"
    EXIT = "exit"
    LANE_CHANGE = "lane_change"
    UTURN = "uturn"
    ZONE = "zone"
    PARK = "park"
    UNPARK = "unpark"


@dataclass(frozen=True)
class GraphParams:
    step_m: float = DEFAULT_STEP_M
    # A lane change shorter than this is no manoeuvre a car makes at road speed: a 3.7 m shift over 25 m
    # (quintic profile) at 8 m/s peaks at 5.77 * 3.7 * 8^2 / 25^2 = 2.2 m/s^2 lateral.
    lane_change_min_length_m: float = 25.0
    # Lanes "run side by side" where their headings differ by less than this ...
    parallel_max_rad: float = math.radians(30.0)
    # ... and "run opposite" where they differ by more than this (an RNDF exit of this turn is a U-turn).
    opposite_min_rad: float = math.radians(150.0)
    # Adjacent lane centres lie between these (the upper one in lane widths).
    adjacent_min_m: float = 1.0
    adjacent_max_widths: float = 2.2
    lane_changes: bool = True
    uturns: bool = True
    # Waypoints of a lane closer than this are one point of its curve (see path.smooth_curve): RNDF
    # points are good to about a metre, and a 0.1 m chord between 10 m ones makes the spline hook.
    merge_waypoints_m: float = 0.5
    # An RNDF exit whose connector needs a tighter radius than this is reported in `RoadGraph.warnings`.
    # Real intersections give 2-3 m radii between stop line and entry (the car cuts the corner wider);
    # below 1 m the file's geometry is off (VAIL's 12.2.3 -> 5.1.1 turns 90 deg within 4.5 m along its
    # heading; Cornell's Sample1 has exits that point backwards, i.e. cusps).
    warn_radius_m: float = 1.0
    # The tightest curvature an RNDF exit's path may ask of the car where the waypoints leave room
    # (path.drivable_connector); None keeps the least-energy connector everywhere. Default: the Passat
    # at full lock (seed 000 Sec. 11.1: l = 2.72 m, delta_max = 30 deg), tan(30 deg) / 2.72 m. The
    # least-energy curve of the sample mission's exit 11.1.4 -> 7.1.11 turns on 2.9 m; the car, on
    # 4.7 m at most, ran 0.87 m wide of it.
    exit_max_curvature_1pm: float | None = math.tan(math.radians(30.0)) / 2.72


@dataclass(eq=False)
class Edge:
    """A directed edge and its annotations; `blocked` and the speed limits change at run time.

    `geometry` is the edge's `Path`, or a function that makes it: derived edges (lane changes, K-turns,
    zone edges) are many and seldom driven, so their connectors are computed on first use of `path`.
    """

    start: WaypointId
    end: WaypointId
    kind: EdgeKind
    geometry: Path | Callable[[], Path] = field(repr=False)
    areas: tuple[int, ...] = ()  # segments / zones whose speed limits apply (both ends of an exit)
    lane: LaneId | None = None  # the lane the edge ends in (LANE: its own lane)
    lane_width_m: float | None = None
    # LANE: the lane's lines; LANE_CHANGE / derived UTURN: the one line crossed, on its side
    left_boundary: Boundary | None = None
    right_boundary: Boundary | None = None
    stop_at_end: bool = False
    checkpoint_at_end: int | None = None
    from_rndf: bool = True
    rndf_line: int | None = None
    speed_min_mps: float | None = None
    speed_max_mps: float | None = None
    blocked: bool = False

    @property
    def path(self) -> Path:
        if not isinstance(self.geometry, Path):
            self.geometry = self.geometry()
        return self.geometry

    @property
    def key(self) -> tuple[WaypointId, WaypointId]:
        return (self.start, self.end)

    @property
    def length_m(self) -> float:
        return self.path.length_m

    def __repr__(self) -> str:
        flags = " blocked" if self.blocked else ""
        return f"Edge({self.start} -> {self.end}, {self.kind.value}, {self.length_m:.1f} m{flags})"


@dataclass
class _LaneGeometry:
    lane: Lane
    path: Path | None  # None: a lane of one (distinct) point
    knots: np.ndarray  # sample index of each waypoint
    s_m: np.ndarray  # arc length of each waypoint


class RoadGraph:
    """Vertices, edges with geometry and annotations, and the lookups the planners need."""

    def __init__(self, network: RoadNetwork, frame: CoordinateFrame, params: GraphParams) -> None:
        self.network = network
        self.frame = frame
        self.params = params
        self.digraph: nx.DiGraph = nx.DiGraph()
        self._xy: dict[WaypointId, tuple[float, float]] = {}
        self._pose: dict[WaypointId, PathPoint] = {}
        self._lane_s: dict[WaypointId, float] = {}
        self._lanes: dict[LaneId, _LaneGeometry] = {}
        self._stops: set[WaypointId] = set()
        self._checkpoint_at: dict[WaypointId, int] = {}
        self.max_speed_mps = 0.0
        self.warnings: list[ParseWarning] = []

    # -- lookups

    def vertices(self) -> Iterator[WaypointId]:
        return iter(self.digraph.nodes)

    def vertex_xy(self, v: WaypointId) -> tuple[float, float]:
        return self._xy[v]

    def vertex_pose(self, v: WaypointId) -> PathPoint | None:
        """Pose of a lane waypoint on its lane curve (None for perimeter and spot points)."""
        return self._pose.get(v)

    def edge(self, u: WaypointId, v: WaypointId) -> Edge:
        edge: Edge = self.digraph.edges[u, v]["edge"]
        return edge

    def has_edge(self, u: WaypointId, v: WaypointId) -> bool:
        return bool(self.digraph.has_edge(u, v))

    def edges(self, kind: EdgeKind | Iterable[EdgeKind] | None = None) -> Iterator[Edge]:
        kinds = None if kind is None else {kind} if isinstance(kind, EdgeKind) else set(kind)
        for _, _, e in self.digraph.edges(data="edge"):
            if kinds is None or e.kind in kinds:
                yield e

    def out_edges(self, v: WaypointId) -> list[Edge]:
        return [e for _, _, e in self.digraph.out_edges(v, data="edge")]

    def in_edges(self, v: WaypointId) -> list[Edge]:
        return [e for _, _, e in self.digraph.in_edges(v, data="edge")]

    def lane_path(self, lane: LaneId) -> Path | None:
        """The whole smooth curve of a lane (None for a lane of a single point)."""
        return self._lanes[lane].path

    def lane_s(self, v: WaypointId) -> float:
        """Arc length of lane waypoint `v` along its lane's curve (KeyError for other vertices)."""
        return self._lane_s[v]

    def is_stop(self, v: WaypointId) -> bool:
        return v in self._stops

    def checkpoint_at(self, v: WaypointId) -> int | None:
        return self._checkpoint_at.get(v)

    def checkpoint_vertex(self, number: int) -> WaypointId:
        return self.network.checkpoint_waypoint(number)

    def path_of(self, edges: Iterable[Edge]) -> Path:
        """The edges' paths joined into one (they must be consecutive)."""
        return concat(e.path for e in edges)

    # -- run-time annotations

    def block_edge(self, u: WaypointId, v: WaypointId) -> None:
        """Mark an edge impassable (a blocked road reported by perception)."""
        self.edge(u, v).blocked = True

    def unblock_all(self) -> int:
        """Forget every blockade; returns how many there were."""
        n = 0
        for e in self.edges():
            n += e.blocked
            e.blocked = False
        return n

    def blocked_edges(self) -> list[Edge]:
        return [e for e in self.edges() if e.blocked]

    def apply_speed_limits(self, mission: Mission | ResolvedMission | None) -> None:
        """Speed limits of the MDF on every edge: the lowest defined maximum and the highest defined
        minimum of the edge's areas; None where the MDF has none (or the segment's RNDF 1.1 limit)."""
        if isinstance(mission, ResolvedMission):
            mission = mission.mission
        limits = {} if mission is None else mission.speed_limits
        rndf_limits = {s.id: s.speed_limit_mps for s in self.network.segments}
        top = 0.0
        for e in self.edges():
            maxima = []
            minima = []
            for area in e.areas:
                lim = limits.get(area)
                if lim is not None and lim.max_mps is not None:
                    maxima.append(lim.max_mps)
                elif rndf_limits.get(area) is not None:
                    maxima.append(rndf_limits[area])  # type: ignore[arg-type]
                if lim is not None and lim.min_mps is not None:
                    minima.append(lim.min_mps)
            e.speed_max_mps = min(maxima) if maxima else None
            e.speed_min_mps = max(minima) if minima else None
            top = max(top, e.speed_max_mps or 0.0)
        self.max_speed_mps = top

    # -- construction

    def _add(self, edge: Edge) -> None:
        if self.digraph.has_edge(edge.start, edge.end):
            old = self.edge(edge.start, edge.end)
            if old.from_rndf or not edge.from_rndf:
                return
        edge.stop_at_end = edge.end in self._stops
        edge.checkpoint_at_end = self._checkpoint_at.get(edge.end)
        self.digraph.add_edge(edge.start, edge.end, edge=edge)


def build_graph(
    network: RoadNetwork,
    mission: Mission | ResolvedMission | None = None,
    params: GraphParams | None = None,
    frame: CoordinateFrame | None = None,
) -> RoadGraph:
    """The geometric graph of `network`, speed limits from `mission` (if given)."""
    params = params or GraphParams()
    g = RoadGraph(network, frame or frame_for(network), params)
    _vertices(g)
    for seg in network.segments:
        for lane in seg.lanes:
            _lane_edges(g, seg.id, lane)
    for seg in network.segments:
        for lane in seg.lanes:
            for ex in lane.exits:
                _exit_edge(g, ex.exit, ex.entry, ex.line)
    for zone in network.zones:
        for ex in zone.perimeter.exits:
            _exit_edge(g, ex.exit, ex.entry, ex.line)
    if params.lane_changes or params.uturns:
        for seg in network.segments:
            _adjacent_lane_edges(g, seg.id, seg.lanes)
    for zone in network.zones:
        _zone_edges(g, zone.id)
    g.apply_speed_limits(mission)
    return g


def _vertices(g: RoadGraph) -> None:
    net = g.network
    points = list(net.waypoints())
    x, y = g.frame.to_xy([p.lat for p in points], [p.lon for p in points])
    for p, px, py in zip(points, x, y, strict=True):
        g._xy[p.id] = (float(px), float(py))
        g.digraph.add_node(p.id)
    for seg in net.segments:
        for lane in seg.lanes:
            g._stops.update(s.waypoint for s in lane.stops)
    g._checkpoint_at = {c.waypoint: n for n, c in net.checkpoints.items()}


def _lane_edges(g: RoadGraph, sid: int, lane: Lane) -> None:
    ids = [w.id for w in lane.waypoints]
    xy = np.array([g._xy[i] for i in ids])
    try:
        path, knots = smooth_curve(xy[:, 0], xy[:, 1], g.params.step_m, merge_m=g.params.merge_waypoints_m)
    except ValueError:  # a single (distinct) point: a vertex without lane edges
        g._lanes[lane.id] = _LaneGeometry(lane, None, np.zeros(len(ids), dtype=np.intp), np.zeros(len(ids)))
        return
    s = path.s_m[knots]
    g._lanes[lane.id] = _LaneGeometry(lane, path, knots, s)
    for wid, k in zip(ids, knots, strict=True):
        g._pose[wid] = path.at_index(int(k))
        g._lane_s[wid] = float(path.s_m[k])
    for i in range(len(ids) - 1):
        g._add(
            Edge(
                start=ids[i],
                end=ids[i + 1],
                kind=EdgeKind.LANE,
                geometry=path.slice_samples(int(knots[i]), int(knots[i + 1])),
                areas=(sid,),
                lane=lane.id,
                lane_width_m=lane.width_m,
                left_boundary=lane.left_boundary,
                right_boundary=lane.right_boundary,
            )
        )


def _free_pose(g: RoadGraph, v: WaypointId, toward: WaypointId, outgoing: bool) -> PathPoint:
    """Pose of `v` on its lane, or (perimeter/spot point) one heading along the chord to/from `toward`."""
    pose = g._pose.get(v)
    if pose is not None:
        return pose
    (x0, y0), (x1, y1) = g._xy[v], g._xy[toward]
    h = math.atan2(y1 - y0, x1 - x0) if outgoing else math.atan2(y0 - y1, x0 - x1)
    return PathPoint(x0, y0, h, 0.0, 0.0)


def _area(v: WaypointId) -> int:
    return v.segment


def _lane_width(g: RoadGraph, v: WaypointId) -> float | None:
    geo = g._lanes.get(v.lane_id)
    return None if geo is None else geo.lane.width_m


def _exit_edge(g: RoadGraph, a: WaypointId, b: WaypointId, line: int) -> None:
    start = _free_pose(g, a, b, outgoing=True)
    end = _free_pose(g, b, a, outgoing=False)
    turn = abs(wrap_angle(end.heading_rad - start.heading_rad))
    lane_to_lane = a.lane_id in g._lanes and b.lane_id in g._lanes
    uturn = lane_to_lane and a.segment == b.segment and a.lane != b.lane and turn > g.params.opposite_min_rad
    limit = g.params.exit_max_curvature_1pm
    if uturn or limit is None:  # a U-turn is a K-turn's business, not a curve's
        path = connector(start, end, g.params.step_m)
    else:
        path = drivable_connector(start, end, limit, g.params.step_m)
    kmax = float(np.max(np.abs(path.curvature_1pm)))
    widths = [w for w in (_lane_width(g, a), _lane_width(g, b)) if w is not None]
    if not uturn and kmax * g.params.warn_radius_m > 1.0:
        g.warnings.append(
            ParseWarning(
                g.network.path,
                line,
                f"exit {a} -> {b}: its smooth connector needs a radius of {1.0 / kmax:.2f} m; the waypoints "
                "leave no room for a drivable turn",
            )
        )
    g._add(
        Edge(
            start=a,
            end=b,
            kind=EdgeKind.UTURN if uturn else EdgeKind.EXIT,
            geometry=path,
            areas=tuple(dict.fromkeys((_area(a), _area(b)))),
            lane=b.lane_id if b.lane_id in g._lanes else None,
            lane_width_m=min(widths) if widths else None,
            rndf_line=line,
        )
    )


def _adjacent_lane_edges(g: RoadGraph, sid: int, lanes: tuple[Lane, ...]) -> None:
    by_number = {lane.id.lane: lane for lane in lanes}
    p = g.params
    for lane in lanes:
        geo_a = g._lanes[lane.id]
        if geo_a.path is None:
            continue
        for other_n in (lane.id.lane - 1, lane.id.lane + 1):
            other = by_number.get(other_n)
            if other is None:
                continue
            geo_b = g._lanes[other.id]
            if geo_b.path is None:
                continue
            width = max(lane.width_m or DEFAULT_LANE_WIDTH_M, other.width_m or DEFAULT_LANE_WIDTH_M)
            max_gap = p.adjacent_max_widths * width
            ids_b = [w.id for w in other.waypoints]
            poses = [g._pose.get(w.id) for w in lane.waypoints]
            located = [(i, q) for i, q in enumerate(poses) if q is not None]
            s_b, lateral, heading_b = geo_b.path.project_points(
                [q.x_m for _, q in located], [q.y_m for _, q in located]
            )
            foot_x, foot_y, _, _ = geo_b.path.sample(s_b)
            for (i, pose), sb, off, hb, fx, fy in zip(
                located, s_b, lateral, heading_b, foot_x, foot_y, strict=True
            ):
                # beside the other lane: its foot point lies square across (past the lane's ends the
                # distance to the foot grows beyond the lateral offset)
                gap = math.hypot(pose.x_m - fx, pose.y_m - fy)
                if not p.adjacent_min_m <= gap <= max_gap or gap > abs(off) + 0.5:
                    continue
                err = abs(wrap_angle(pose.heading_rad - float(hb)))
                wid = lane.waypoints[i].id
                if err < p.parallel_max_rad and p.lane_changes and i < len(lane.waypoints) - 1:
                    j = int(np.searchsorted(geo_b.s_m, sb + p.lane_change_min_length_m, side="left"))
                    if j < len(ids_b):
                        _derived_edge(g, sid, wid, ids_b[j], EdgeKind.LANE_CHANGE, other, lane)
                elif err > p.opposite_min_rad and p.uturns:
                    # the other lane runs the other way: the first of its waypoints at or past the point
                    # alongside is where the K-turn ends
                    j = int(np.searchsorted(geo_b.s_m, sb - 1e-6, side="left"))
                    if j < len(ids_b):
                        _derived_edge(g, sid, wid, ids_b[j], EdgeKind.UTURN, other, lane)


def _derived_edge(
    g: RoadGraph,
    sid: int,
    a: WaypointId,
    b: WaypointId,
    kind: EdgeKind,
    target: Lane,
    source: Lane,
) -> None:
    start, end, step = g._pose[a], g._pose[b], g.params.step_m
    # which of our lane's lines the manoeuvre crosses: the target lies left or right of our heading
    left = -math.sin(start.heading_rad) * (end.x_m - start.x_m) + math.cos(start.heading_rad) * (
        end.y_m - start.y_m
    )
    crossed = source.left_boundary if left > 0 else source.right_boundary
    g._add(
        Edge(
            start=a,
            end=b,
            kind=kind,
            # tangent length = chord: right for a lane change's gentle S; a K-turn's shape is a placeholder
            geometry=lambda: connector(start, end, step, scale_factors=(1.0,)),
            areas=(sid,),
            lane=target.id,
            lane_width_m=target.width_m,
            left_boundary=crossed if left > 0 else None,
            right_boundary=None if left > 0 else crossed,
            from_rndf=False,
        )
    )


def _straight(g: RoadGraph, a: WaypointId, b: WaypointId) -> Path:
    (x0, y0), (x1, y1) = g._xy[a], g._xy[b]
    h = math.atan2(y1 - y0, x1 - x0)
    if math.hypot(x1 - x0, y1 - y0) <= 1e-3:
        return Path.point(x0, y0, h)
    n = max(2, math.ceil(math.hypot(x1 - x0, y1 - y0) / g.params.step_m) + 1)
    return Path(np.linspace(x0, x1, n), np.linspace(y0, y1, n), np.full(n, h), np.zeros(n))


def _zone_edges(g: RoadGraph, zid: int) -> None:
    zone = g.network.zone(zid)
    perimeter = {p.id for p in zone.perimeter.points}
    entries = sorted({ex.entry for ex in g.network.exits() if ex.entry in perimeter})
    exits = sorted({ex.exit for ex in zone.perimeter.exits})
    spots = [(s.waypoints[0].id, s.waypoints[1].id, s.width_m) for s in zone.spots]
    firsts = [a for a, _, _ in spots]

    def add(a: WaypointId, b: WaypointId, kind: EdgeKind, width: float | None = None) -> None:
        if a != b:
            g._add(Edge(a, b, kind, lambda: _straight(g, a, b), (zid,), lane_width_m=width, from_rndf=False))

    for e in entries:
        for x in exits:
            add(e, x, EdgeKind.ZONE)
        for s1 in firsts:
            add(e, s1, EdgeKind.ZONE)
    for s1 in firsts:
        for x in exits:
            add(s1, x, EdgeKind.ZONE)
        for t1 in firsts:
            add(s1, t1, EdgeKind.ZONE)
    for s1, s2, width in spots:
        add(s1, s2, EdgeKind.PARK, width)
        add(s2, s1, EdgeKind.UNPARK, width)


@dataclass(frozen=True)
class JoinCheck:
    """Heading and curvature jumps where one edge's path meets the next's."""

    heading_jump_rad: float
    curvature_jump_1pm: float


def join_jump(a: Edge, b: Edge) -> JoinCheck:
    """How much heading and curvature jump from the end of `a` to the start of `b`."""
    pa, pb = a.path.end, b.path.start
    return JoinCheck(
        abs(wrap_angle(pb.heading_rad - pa.heading_rad)), abs(pb.curvature_1pm - pa.curvature_1pm)
    )
