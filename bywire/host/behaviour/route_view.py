"""The route as the behaviour layer reads it: one sampled path with edges, events, speeds (seed 000 Sec. 8).

A `RouteView` wraps a mission `Route` (host/roadnet/route.py), optionally preceded by a *lead-in* edge:
after a replan from the current pose the route starts at the waypoint ahead, and the edge we are on
comes first so that our position lies on the path. It precomputes, once per route:

- the path (x, y, heading, curvature, s) of all edges joined, and each edge's [start, end) arc length;
- per sample, the speed cap: the edge's MDF maximum (30 mph where the MDF has none, rules 1.7), in
  curves v = sqrt(a_lat / |kappa|) with `rules.CURVE_LATERAL_ACCEL_MPS2`, and in turns near full lock
  (|kappa| >= `rules.TIGHT_TURN_CURVATURE_1PM`) at most `rules.TIGHT_TURN_SPEED_MPS`;
- the events ahead: intersections (an EXIT edge of an intersection that `is_real`, or a stop line:
  the waypoint where we enter it, whether we stop there, where the crossing ends), lane changes,
  manoeuvre pieces (zone, parking, K-turn edges: `Route.drive_pieces`), checkpoints and the end.

Tracking (`locate`): the rear axle is projected onto the path inside a window around the last known
arc length, never onto a far part of the path that passes close by (a loop, the other half of a
K-turn). Objects are projected the same way (`project_objects`), vectorised, inside a window ahead.

Desired speed (`speed_profile`): the lowest of sqrt(v_cap(s)² + 2 b (s - s_ego)) over the samples
ahead, i.e. the speed from which a cap ahead is reached by braking at b =
`rules.SPEED_ANTICIPATION_DECEL_MPS2`. The velocity controller (seed 000 eq. 31, a_v = -c_v (v - v_d))
follows a ramp of slope -b only with a lag of b / c_v; while the profile is falling, the command is
lowered by that lag (never below the cap it brakes for), so the car, not the command, meets the cap.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from bywire.host.roadnet.graph import Edge, EdgeKind, RoadGraph
from bywire.host.roadnet.ids import WaypointId
from bywire.host.roadnet.path import Path, concat
from bywire.host.roadnet.route import MANOEUVRES, Route

from . import rules
from .intersection_map import IntersectionInfo, IntersectionMap
from .situation import PathStub, TrackedObject, stub_from_arrays

__all__ = [
    "CheckpointMark",
    "IntersectionEvent",
    "PathObject",
    "PieceEvent",
    "RouteView",
    "locate_on",
    "objects_on_path",
]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class IntersectionEvent:
    """Where our route crosses an intersection."""

    info: IntersectionInfo
    approach: WaypointId  # the waypoint where we enter: the stop line if `stop`
    s_m: float  # arc length of `approach` along the route path
    stop: bool
    crossing: int  # index of the route edge that crosses (starts at `approach`)
    exit_end_s_m: float  # where the crossing ends (its edge's end, at most INTERSECTION_MAX_CROSSING_M on)


@dataclass(frozen=True)
class PieceEvent:
    """A run of route edges of one kind (lane change, zone, parking, K-turn) and where it lies."""

    kind: EdgeKind
    first: int  # index of its first edge
    last: int  # index of its last edge
    start_s_m: float
    end_s_m: float


@dataclass(frozen=True)
class CheckpointMark:
    mission_index: int  # position in the MDF's checkpoint list
    number: int  # checkpoint number
    s_m: float  # arc length of its waypoint along the route path
    final: bool  # the mission's last: we stop there
    spot: bool  # the end of a PARK edge (the checkpoint of a parking spot)


@dataclass(frozen=True)
class PathObject:
    """An object seen along a path: arc length of its centre, offset (left > 0), heading error."""

    obj: TrackedObject
    s_m: float
    lateral_m: float
    heading_error_rad: float  # object heading minus the path's travel heading, wrapped
    in_corridor: bool  # its body overlaps ours (plus clearance) if we drove past it on the path

    @property
    def rear_s_m(self) -> float:
        return self.s_m - 0.5 * self.obj.length_m * abs(math.cos(self.heading_error_rad))

    @property
    def front_s_m(self) -> float:
        return self.s_m + 0.5 * self.obj.length_m * abs(math.cos(self.heading_error_rad))

    @property
    def speed_along_mps(self) -> float:
        """Its speed along our path, >= 0 (an oncoming or crossing object counts as standing)."""
        return max(self.obj.speed_mps * math.cos(self.heading_error_rad), 0.0)


def _wrap(a: FloatArray) -> FloatArray:
    return np.asarray((a + np.pi) % (2.0 * np.pi) - np.pi, dtype=np.float64)


def objects_on_path(
    x: FloatArray,
    y: FloatArray,
    travel_heading: FloatArray,
    s: FloatArray,
    objects: Sequence[TrackedObject],
    half_width_m: float,
    clearance_m: float = rules.LATERAL_CLEARANCE_M,
) -> list[PathObject]:
    """Project objects onto a sampled path (nearest sample, then along its tangent), vectorised.

    `in_corridor`: the object's body (its half extent across our path, from length, width and heading)
    comes within `half_width_m + clearance_m` of the path's centre line, and it is within the path's
    extent. Objects farther than 20 m from every sample are left out.
    """
    if not objects or x.size == 0:
        return []
    if x.size > 8:  # every 4th sample (1 m) finds the nearest; the tangent then places it exactly enough
        x, y, travel_heading, s = x[::4], y[::4], travel_heading[::4], s[::4]
    ox = np.array([o.x_m for o in objects])
    oy = np.array([o.y_m for o in objects])
    dx = ox[:, None] - x[None, :]
    dy = oy[:, None] - y[None, :]
    with np.errstate(over="ignore", invalid="ignore"):  # absurd (finite) positions are simply far
        d2 = dx * dx + dy * dy
    j = np.argmin(d2, axis=1)
    rows = np.arange(len(objects))
    near = d2[rows, j] <= 400.0
    h = travel_heading[j]
    c, sn = np.cos(h), np.sin(h)
    along = dx[rows, j] * c + dy[rows, j] * sn
    lateral = -dx[rows, j] * sn + dy[rows, j] * c
    s_obj = s[j] + along
    out: list[PathObject] = []
    for k, obj in enumerate(objects):
        if not near[k]:
            continue
        err = math.atan2(math.sin(obj.heading_rad - h[k]), math.cos(obj.heading_rad - h[k]))
        across = 0.5 * (obj.width_m * abs(math.cos(err)) + obj.length_m * abs(math.sin(err)))
        inside = s[0] - 1.0 <= s_obj[k] <= s[-1] + 1.0
        corridor = inside and abs(float(lateral[k])) - across < half_width_m + clearance_m
        out.append(PathObject(obj, float(s_obj[k]), float(lateral[k]), err, bool(corridor)))
    return out


def curve_speed_cap_mps(kappa_1pm: npt.ArrayLike) -> FloatArray:
    """The speed a curve allows: 2 m/s^2 lateral, and at most `rules.TIGHT_TURN_SPEED_MPS` near full
    lock (see rules.TIGHT_TURN_CURVATURE_1PM)."""
    k = np.abs(np.asarray(kappa_1pm, dtype=np.float64))
    cap = np.sqrt(rules.CURVE_LATERAL_ACCEL_MPS2 / np.maximum(k, 1e-9))
    return np.where(k >= rules.TIGHT_TURN_CURVATURE_1PM, np.minimum(cap, rules.TIGHT_TURN_SPEED_MPS), cap)


class RouteView:
    """A route with its precomputed path, speeds and events (see the module docstring)."""

    def __init__(
        self,
        graph: RoadGraph,
        route: Route,
        imap: IntersectionMap,
        lead_in: Edge | None = None,
    ) -> None:
        self.graph = graph
        self.route = route
        self.lead_in = lead_in
        edges: list[Edge] = ([lead_in] if lead_in is not None else []) + list(route.edges)
        self.edges: tuple[Edge, ...] = tuple(edges)
        lengths = np.array([e.length_m for e in edges], dtype=np.float64)
        self.edge_start = np.concatenate(([0.0], np.cumsum(lengths)[:-1])) if edges else np.zeros(0)
        self.edge_end = self.edge_start + lengths
        self.edge_positions: dict[tuple[WaypointId, WaypointId], list[int]] = {}
        for i, e in enumerate(edges):
            self.edge_positions.setdefault(e.key, []).append(i)
        if not edges or lead_in is None:
            path = route.path
        else:
            path = concat([lead_in.path, route.path]) if route.edges else lead_in.path
        if len(path) < 2:  # a route of no length: a 1 cm path keeps everything defined
            p = path.start
            path = Path(
                [p.x_m, p.x_m + 0.01 * math.cos(p.heading_rad)],
                [p.y_m, p.y_m + 0.01 * math.sin(p.heading_rad)],
                [p.heading_rad, p.heading_rad],
                [0.0, 0.0],
            )
        self.path = path
        self.x = np.asarray(path.x_m)
        self.y = np.asarray(path.y_m)
        self.heading = np.asarray(path.heading_unwrapped_rad)
        self.heading_wrapped = _wrap(self.heading)
        self.kappa = np.asarray(path.curvature_1pm)
        self.s = np.asarray(path.s_m)
        self.length_m = float(self.s[-1])
        self.v_cap = self._speed_caps()
        self.intersections = self._intersections(imap)
        self.pieces = self._pieces()
        self.checkpoints, self.unreachable = self._checkpoints()
        finals = [m for m in self.checkpoints if m.final]
        # where the mission ends on this route (the last reachable checkpoint), None in a parking spot
        self.finish_s_m: float | None = finals[0].s_m if finals and not finals[0].spot else None

    # ------------------------------------------------------------------------------- construction

    def _speed_caps(self) -> FloatArray:
        limit = np.full(self.s.size, rules.SPEED_LIMIT_MAX_MPS)
        if self.edges:
            idx = np.clip(np.searchsorted(self.edge_start, self.s, side="right") - 1, 0, len(self.edges) - 1)
            top = rules.SPEED_LIMIT_MAX_MPS
            per_edge = np.array([min(e.speed_max_mps or top, top) for e in self.edges])
            limit = per_edge[idx]
        return np.asarray(np.minimum(limit, curve_speed_cap_mps(self.kappa)), dtype=np.float64)

    def _intersections(self, imap: IntersectionMap) -> list[IntersectionEvent]:
        events: list[IntersectionEvent] = []
        for i, e in enumerate(self.edges):
            if e.kind in MANOEUVRES or e.start.is_perimeter or e.end.is_perimeter:
                continue
            if i == 0 and self.lead_in is not None:
                continue  # we are already on it
            stop = self.graph.is_stop(e.start)
            info = imap.at(e.start)
            if info is None or not (stop or (e.kind == EdgeKind.EXIT and info.is_real)):
                continue
            s0 = float(self.edge_start[i])
            end = min(float(self.edge_end[i]), s0 + rules.INTERSECTION_MAX_CROSSING_M)
            events.append(IntersectionEvent(info, e.start, s0, stop, i, end))
        return events

    def _pieces(self) -> list[PieceEvent]:
        out: list[PieceEvent] = []
        kinds = MANOEUVRES | {EdgeKind.LANE_CHANGE}
        i = 0
        while i < len(self.edges):
            kind = self.edges[i].kind
            if kind not in kinds:
                i += 1
                continue
            zone_like = {EdgeKind.ZONE, EdgeKind.PARK, EdgeKind.UNPARK}
            j = i
            if kind in zone_like:
                while j + 1 < len(self.edges) and self.edges[j + 1].kind in zone_like:
                    j += 1
                kind = EdgeKind.ZONE
            out.append(PieceEvent(kind, i, j, float(self.edge_start[i]), float(self.edge_end[j])))
            i = j + 1
        return out

    def _checkpoints(self) -> tuple[list[CheckpointMark], list[int]]:
        marks: list[CheckpointMark] = []
        unreachable: list[int] = []
        k = 1 if self.lead_in is not None else 0
        s_here = float(self.edge_start[k]) if k < len(self.edges) else self.length_m
        legs = self.route.legs
        last_reachable = max((i for i, leg in enumerate(legs) if leg.reached), default=-1)
        for i, leg in enumerate(legs):
            if not leg.reached:
                unreachable.append(leg.index)
                continue
            spot = False
            if leg.edges:
                k += len(leg.edges)
                s_here = float(self.edge_end[k - 1])
                spot = leg.edges[-1].kind == EdgeKind.PARK
            marks.append(CheckpointMark(leg.index, leg.checkpoint, s_here, i == last_reachable, spot))
        return marks, unreachable

    # ------------------------------------------------------------------------------- lookups

    def edge_index_at(self, s_m: float) -> int:
        """Index of the edge at arc length `s_m` (clamped to the route)."""
        if not self.edges:
            return 0
        i = int(np.searchsorted(self.edge_start, s_m, side="right")) - 1
        return min(max(i, 0), len(self.edges) - 1)

    def next_intersection(self, s_m: float) -> IntersectionEvent | None:
        """The first intersection whose crossing ends beyond `s_m`."""
        for ev in self.intersections:
            if ev.exit_end_s_m > s_m:
                return ev
        return None

    def next_piece(self, s_m: float, kinds: frozenset[EdgeKind] | None = None) -> PieceEvent | None:
        """The first manoeuvre or lane-change piece that ends beyond `s_m` (of `kinds` if given)."""
        for p in self.pieces:
            if p.end_s_m > s_m and (kinds is None or p.kind in kinds):
                return p
        return None

    def locate(
        self, x_m: float, y_m: float, s_hint_m: float, back_m: float = 5.0, ahead_m: float = 30.0
    ) -> tuple[float, float, float]:
        """(s, lateral offset left > 0, path heading) of the point's foot in [hint - back, hint + ahead]."""
        return locate_on(self.x, self.y, self.s, self.heading, x_m, y_m, s_hint_m, back_m, ahead_m)

    def window(self, s_from_m: float, s_to_m: float) -> slice:
        i0 = max(int(np.searchsorted(self.s, s_from_m, side="left")) - 1, 0)
        i1 = min(int(np.searchsorted(self.s, s_to_m, side="right")) + 1, self.s.size)
        return slice(i0, i1)

    def project_objects(
        self, objects: Sequence[TrackedObject], s_from_m: float, s_to_m: float, half_width_m: float
    ) -> list[PathObject]:
        w = self.window(s_from_m, s_to_m)
        return objects_on_path(
            self.x[w], self.y[w], self.heading_wrapped[w], self.s[w], objects, half_width_m
        )

    def stub(self, s0_m: float, length_m: float, back_m: float) -> tuple[PathStub, float]:
        """The stub from `s0 - back` to `s0 + length` and the arc length of `s0` on it."""
        w = self.window(s0_m - back_m, s0_m + length_m)
        s = self.s[w]
        lo, hi = max(s0_m - back_m, 0.0), min(s0_m + length_m, self.length_m)
        keep = (s > lo) & (s < hi)
        ss = np.concatenate(([lo], s[keep], [hi])) if hi > lo else np.array([lo])
        if ss.size < 2:
            stub = stub_from_arrays([self.x[-1]], [self.y[-1]], [self.heading[-1]], [0.0], 1)
            return stub, 0.0
        xs = np.interp(ss, s, self.x[w])  # on the window only: np.interp is linear in its table
        ys = np.interp(ss, s, self.y[w])
        hs = np.interp(ss, s, self.heading[w])
        ks = np.interp(ss, s, self.kappa[w])
        # the route's samples are distinct and its s is their chord length: no need to recompute them
        stub = PathStub(xs, ys, _wrap(hs), ks, ss - lo, 1)
        return stub, min(max(s0_m - lo, 0.0), stub.length_m)

    def speed_profile(
        self, s_from_m: float, decel_mps2: float, horizon_m: float, lag_s: float
    ) -> tuple[float, float]:
        """(speed command, the cap it brakes for) over [s_from, s_from + horizon]; see the docstring."""
        w = self.window(s_from_m, s_from_m + horizon_m)
        s = self.s[w]
        cap = self.v_cap[w]
        ahead = np.maximum(s - s_from_m, 0.0)
        env = np.sqrt(cap * cap + 2.0 * decel_mps2 * ahead)
        k = int(np.argmin(env))
        v_env, v_cap = float(env[k]), float(cap[k])
        if ahead[k] > 0.0 and v_env > v_cap:
            return max(v_env - decel_mps2 * lag_s, v_cap), v_cap
        return v_env, v_cap

    def point_at(self, s_m: float) -> tuple[float, float, float]:
        """(x, y, heading) at arc length `s_m` (clamped)."""
        s = min(max(s_m, 0.0), self.length_m)
        w = self.window(s, s)
        return (
            float(np.interp(s, self.s[w], self.x[w])),
            float(np.interp(s, self.s[w], self.y[w])),
            float(np.interp(s, self.s[w], self.heading[w])),
        )

    def lane_width_at(self, s_m: float) -> float:
        """Width of the lane at `s_m` (12 ft where the RNDF gives none)."""
        if not self.edges:
            return 12 * 0.3048
        width = self.edges[self.edge_index_at(s_m)].lane_width_m
        return width if width else 12 * 0.3048


def locate_on(
    x: FloatArray,
    y: FloatArray,
    s: FloatArray,
    heading: FloatArray,
    x_m: float,
    y_m: float,
    s_hint_m: float,
    back_m: float,
    ahead_m: float,
) -> tuple[float, float, float]:
    """Foot of (x_m, y_m) on the polyline, searched among the segments overlapping [hint - back, hint +
    ahead]: (arc length, lateral offset left of the heading > 0, heading there). Past either end of the
    polyline the end segment is extended."""
    n = s.size
    i0 = max(int(np.searchsorted(s, s_hint_m - back_m, side="left")) - 1, 0)
    i1 = min(int(np.searchsorted(s, s_hint_m + ahead_m, side="right")) + 1, n)
    if i1 - i0 < 2:
        i0, i1 = (max(n - 2, 0), n) if s_hint_m > s[-1] else (0, min(2, n))
    xs, ys = x[i0:i1], y[i0:i1]
    dx, dy = np.diff(xs), np.diff(ys)
    len2 = np.maximum(dx * dx + dy * dy, 1e-12)
    t_raw = ((x_m - xs[:-1]) * dx + (y_m - ys[:-1]) * dy) / len2
    t = np.clip(t_raw, 0.0, 1.0)
    if i1 == n and t_raw[-1] > 1.0:
        t[-1] = t_raw[-1]
    if i0 == 0 and t_raw[0] < 0.0:
        t[0] = t_raw[0]
    fx, fy = xs[:-1] + t * dx, ys[:-1] + t * dy
    with np.errstate(over="ignore", invalid="ignore"):  # absurd (finite) positions: no foot, no warning
        j = int(np.argmin((x_m - fx) ** 2 + (y_m - fy) ** 2))
    i = i0 + j
    tj = float(t[j])
    arc = float(s[i] + tj * (s[i + 1] - s[i]))
    h = float(heading[i] + min(max(tj, 0.0), 1.0) * (heading[i + 1] - heading[i]))
    lateral = -math.sin(h) * (x_m - float(fx[j])) + math.cos(h) * (y_m - float(fy[j]))
    return arc, lateral, h
