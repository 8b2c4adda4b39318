"""Lane map: record lanes from a GPS track, match positions to lanes, geodesic distances (seed 003 Sec. IV-A).

Seed 003 IV-A: the map is recorded a priori by driving the right lane; "a local Mercator coordinate system
with its origin anchored at the first point of the GPS track" (`geo.LocalFrame`); the track is subdivided
"into piecewise linear segments of length 0.5 m"; "further lanes can be added at a given offset" (3.5 m,
the Dutch highway lane); the vertices are stored in a 2-D kd-tree (here scipy's cKDTree, exact l2 nearest
neighbours, the paper used ANN); an object is assigned to the lane of its nearest vertex and "projected
onto the two connected line segments to obtain its foot point"; the geodesic distance between two objects
is the difference of their foot points' arc lengths, precomputed per vertex from the lane's start.

Recording (`record_lane`): local coordinates (from lat/lon or already x/y), stationary samples (< 1 cm
apart) dropped, resampled by chord length to 0.5 m, smoothed lightly (Gaussian, sigma `smooth_m`, 1 m by
default; the ends are padded by point reflection so that a straight end is not pulled in), resampled again
to exactly 0.5 m. `LaneMap.with_offset_lane` adds a lane at a lateral offset (positive: left of the
driving direction) along the smoothed normals, refusing offsets larger than 0.9 times the tightest radius
of the reference lane (the offset curve would fold).

Matching (`LaneMap.match`). Deviation, for the pitfall of seed 003 IV-B ("vehicles physically driving on a
neighbouring lane ... projected onto our lane — in the worst case directly in front of us"), which the
paper handled with a hand-kept blacklist: the nearest vertex of *each* lane near the position is
projected onto that lane's two segments, and the lane with the smallest perpendicular distance wins, if
that distance is within `max_lateral_m` (half a lane plus a margin; farther is off the map: None) and,
when a heading is given, the lane's direction agrees within `heading_tolerance_rad`. The match reports
`margin_m`, how much closer the chosen lane is than the next one: a car near the line between two lanes
has a small margin, and the radar fusion treats it with suspicion. The blacklist stays available there.
Foot points before the start or beyond the end of a lane extrapolate the end segment (``beyond_end``),
so gaps stay defined near the ends.

File format (`save` / `load`): JSON ``{"format": "bywire.lanemap", "version": 1, "origin_lat_deg",
"origin_lon_deg", "spacing_m", "lanes": [{"id": int, "name": str, "points": [[x, y], ...]}]}``, x/y in
metres on the local plane, millimetre resolution. Loading checks every field and raises `LaneMapError`
naming the file and the field (``lanes[1].points[37][0]``) or the line and column of a JSON syntax error.

Geometry: every lane is a `bywire.host.roadnet.path.Path` through its 0.5 m vertices (arc length, point_at,
the parallel curve for offset lanes, vectorised projection for predicted trajectories). On top of it the
map keeps what seed 003 describes and Path has not: one kd-tree over the vertices of all lanes with each
vertex's lane, and a scalar foot-point projection for the per-cycle `match` (a few microseconds instead of
Path.project's numpy path) that, like `project`, extrapolates past a lane's ends.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.ndimage import gaussian_filter1d
from scipy.spatial import cKDTree

from bywire.host.geo import LocalFrame, wrap_angle
from bywire.host.roadnet.path import Path as LanePath

FloatArray = npt.NDArray[np.float64]

SEGMENT_M = 0.5  # seed 003 IV-A
LANE_WIDTH_M = 3.5  # seed 003 IV-A, Dutch highway lane
MIN_STEP_M = 0.01  # closer samples are a standing car
HEADING_SMOOTH_M = 2.5  # lanes turn over tens of metres; see _path_through
# A local transverse Mercator plane is metric for tens of km; 1000 km from the origin is a wrong file (and
# at 1e15 m the 0.5 m segments vanish in floating point: found by the long fuzz campaign).
MAX_COORD_M = 1e6
FORMAT = "bywire.lanemap"
VERSION = 1
# Objects at the roadside: a traffic light or a sign stands up to a few metres beside the lane it governs.
ROADSIDE_MAX_LATERAL_M = 10.0


class LaneMapError(ValueError):
    """A lane map file or track that cannot be used; the message says which file and field."""


def _resample(points: FloatArray, spacing_m: float) -> FloatArray:
    d = np.hypot(*np.diff(points, axis=0).T)
    s = np.concatenate(([0.0], np.cumsum(d)))
    n = max(math.floor(s[-1] / spacing_m + 1e-9), 1)
    s_new = np.arange(n + 1) * spacing_m
    if s[-1] - s_new[-1] > 0.25 * spacing_m:
        s_new = np.append(s_new, s[-1])  # keep the true end; the last segment is shorter
    return np.column_stack((np.interp(s_new, s, points[:, 0]), np.interp(s_new, s, points[:, 1])))


def _drop_stationary(points: FloatArray) -> FloatArray:
    keep = [0]
    for i in range(1, len(points)):
        if math.hypot(*(points[i] - points[keep[-1]])) >= MIN_STEP_M:
            keep.append(i)
    return points[keep]


def _smooth(points: FloatArray, sigma_samples: float) -> FloatArray:
    if sigma_samples <= 0.0 or len(points) < 3:
        return points
    pad = min(math.ceil(4.0 * sigma_samples), len(points) - 1)
    # Point reflection keeps a straight (linear) end exactly where it is.
    head = 2.0 * points[0] - points[pad:0:-1]
    tail = 2.0 * points[-1] - points[-2 : -pad - 2 : -1]
    padded = np.vstack((head, points, tail))
    out = gaussian_filter1d(padded, sigma_samples, axis=0, mode="nearest")
    return np.asarray(out[pad : pad + len(points)], dtype=np.float64)


def _path_through(points: FloatArray) -> LanePath:
    """A roadnet `Path` whose samples are exactly `points`.

    Heading by central differences, smoothed over `HEADING_SMOOTH_M`: what noise the light position
    smoothing leaves (~1-2 cm) is a few centidegrees of heading over one 0.5 m segment, which an offset
    lane 3.5 m away would turn into ~10 cm of wiggle. Curvature is the derivative of that heading."""
    x, y = points[:, 0], points[:, 1]
    s = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))))
    heading = np.unwrap(np.arctan2(np.gradient(y), np.gradient(x)))
    if len(s) > 2:
        sigma = HEADING_SMOOTH_M / max(float(np.median(np.diff(s))), 1e-6)
        heading = gaussian_filter1d(heading, sigma, mode="nearest")
    curvature = np.gradient(heading, s) if len(s) > 2 else np.zeros_like(s)
    return LanePath(x, y, heading, curvature, s)


@dataclass(frozen=True)
class Lane:
    """One lane: a `roadnet.path.Path` sampled every 0.5 m, with its id and name."""

    lane_id: int
    name: str
    points_m: FloatArray  # (N, 2) vertices, 0.5 m apart
    path: LanePath = field(init=False, repr=False, compare=False)
    xy_list: list[tuple[float, float]] = field(init=False, repr=False, compare=False)
    # ("start" | "end", unit direction of the end segment, its anchor point): what `_project_on`
    # extrapolates along past the lane's ends, worked out once.
    ends: tuple[tuple[str, FloatArray, FloatArray], ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        pts = np.ascontiguousarray(self.points_m, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
            raise LaneMapError(f"lane {self.lane_id}: needs an (N >= 2, 2) array of points, got {pts.shape}")
        seg = np.hypot(*np.diff(pts, axis=0).T)
        if not np.all(np.isfinite(pts)) or np.any(seg <= 0.0):
            raise LaneMapError(f"lane {self.lane_id}: points must be finite and distinct in sequence")
        if float(np.max(np.abs(pts))) > MAX_COORD_M:
            raise LaneMapError(
                f"lane {self.lane_id}: points beyond {MAX_COORD_M:.0f} m from the map's origin"
            )
        object.__setattr__(self, "points_m", pts)
        try:
            path = _path_through(pts)
        except ValueError as e:  # roadnet's Path checks its samples too; say which lane
            raise LaneMapError(f"lane {self.lane_id}: {e}") from e
        object.__setattr__(self, "path", path)
        # Python floats for the scalar projection: indexing a numpy array per element costs ~10x more.
        object.__setattr__(self, "xy_list", [(float(a), float(b)) for a, b in pts])
        ends = []
        for end, (a, b) in (("start", (pts[0], pts[1])), ("end", (pts[-2], pts[-1]))):
            ends.append((end, (b - a) / np.hypot(*(b - a)), a if end == "start" else b))
        object.__setattr__(self, "ends", tuple(ends))

    @property
    def s_m(self) -> FloatArray:
        """Arc length of each vertex from the lane's start."""
        return self.path.s_m

    @property
    def length_m(self) -> float:
        return self.path.length_m

    def point_at(self, s_m: float) -> tuple[float, float, float]:
        """(x, y, heading) at arc length s (clamped to the lane)."""
        p = self.path.point_at(s_m)
        return p.x_m, p.y_m, p.heading_rad


@dataclass(frozen=True)
class Projection:
    """A point's foot point on one lane (arrays when several points were projected)."""

    s_m: FloatArray
    lateral_m: FloatArray  # signed, + left of the lane's direction
    foot_x_m: FloatArray
    foot_y_m: FloatArray
    heading_rad: FloatArray  # the lane's direction at the foot point
    beyond_end: npt.NDArray[np.bool_]


def _extrapolate_ends(
    lane: Lane, xy: FloatArray, s: FloatArray
) -> list[tuple[FloatArray, FloatArray, npt.NDArray[np.bool_]]]:
    """Set the arc lengths `s` of the points xy (M, 2) past the lane's ends (the path clamps them there)
    along the end segments' extensions; per end with such points: its direction, anchor and the points."""
    past = []
    for end, u, anchor in lane.ends:
        along = (xy - anchor) @ u
        hit = along < 0.0 if end == "start" else along > 0.0
        hit &= (s <= 0.0) if end == "start" else (s >= lane.path.length_m)
        if np.any(hit):
            s[hit] = along[hit] + (0.0 if end == "start" else lane.path.length_m)
            past.append((u, anchor, hit))
    return past


def _project_on(lane: Lane, xy: FloatArray) -> Projection:
    """Foot points of xy (M, 2) on a lane: `Path.project_points`, and beyond the lane's ends the foot point
    on the end segment's extension (the path clamps there; a gap must keep growing past the map's end)."""
    path = lane.path
    s, lateral, heading = path.project_points(xy[:, 0], xy[:, 1])
    s = np.asarray(s, dtype=np.float64)
    lateral = np.asarray(lateral, dtype=np.float64)
    heading = np.asarray(heading, dtype=np.float64)
    beyond = np.zeros(len(xy), dtype=bool)
    for u, anchor, hit in _extrapolate_ends(lane, xy, s):
        r = xy[hit] - anchor
        lateral[hit] = u[0] * r[:, 1] - u[1] * r[:, 0]
        heading[hit] = math.atan2(u[1], u[0])
        beyond |= hit
    foot_heading = heading
    fx = xy[:, 0] + lateral * np.sin(foot_heading)
    fy = xy[:, 1] - lateral * np.cos(foot_heading)
    return Projection(s, lateral, fx, fy, heading, beyond)


def _project_point(lane: Lane, x: float, y: float, i: int) -> tuple[float, float, float, float, float, bool]:
    """Scalar `_project_on` for one point (the per-cycle path).

    Returns (s, lateral, foot x, foot y, heading, beyond_end)."""
    pts = lane.xy_list
    last = len(pts) - 1
    best: tuple[float, float, float, float, float, float, bool] | None = None
    for i0 in (max(i - 1, 0), min(i, last - 1)):
        ax, ay = pts[i0]
        bx, by = pts[i0 + 1]
        dx, dy = bx - ax, by - ay
        seg_len = math.hypot(dx, dy)
        ux, uy = dx / seg_len, dy / seg_len
        t = (x - ax) * ux + (y - ay) * uy
        tc = t
        if i0 > 0 and tc < 0.0:
            tc = 0.0
        if i0 < last - 1 and tc > seg_len:
            tc = seg_len
        fx, fy = ax + ux * tc, ay + uy * tc
        rx, ry = x - fx, y - fy
        dist = math.hypot(rx, ry)
        if best is None or dist < best[0]:
            s = float(lane.s_m[i0]) + tc
            best = (dist, s, ux * ry - uy * rx, fx, fy, math.atan2(uy, ux), tc < 0.0 or tc > seg_len)
        if i0 == min(i, last - 1):
            break
    assert best is not None
    return best[1:]


@dataclass(frozen=True)
class LaneMatch:
    lane_id: int
    s_m: float
    lateral_m: float
    foot_x_m: float
    foot_y_m: float
    lane_heading_rad: float
    margin_m: float  # next-closest lane's |lateral| minus ours (inf: no other lane near)
    beyond_end: bool


@dataclass(frozen=True)
class MapObject:
    """A vehicle, traffic light or speed-limit sign to place on the map."""

    kind: str  # "vehicle", "traffic_light", "speed_limit", ...
    object_id: str | int
    x_m: float
    y_m: float
    heading_rad: float | None = None


@dataclass(frozen=True)
class AssignedObject:
    obj: MapObject
    match: LaneMatch | None  # None: no lane near enough


class LaneMap:
    """Lanes on one local plane, all their vertices in one kd-tree."""

    def __init__(
        self,
        frame: LocalFrame,
        lanes: Sequence[Lane],
        spacing_m: float = SEGMENT_M,
        max_lateral_m: float = 0.5 * LANE_WIDTH_M + 0.5,
        heading_tolerance_rad: float = math.radians(60.0),
    ) -> None:
        if not lanes:
            raise LaneMapError("a lane map needs at least one lane")
        ids = [ln.lane_id for ln in lanes]
        if len(set(ids)) != len(ids):
            raise LaneMapError(f"lane ids must be unique, got {ids}")
        self.frame = frame
        self.lanes = tuple(lanes)
        self.spacing_m = spacing_m
        self.max_lateral_m = max_lateral_m
        self.heading_tolerance_rad = heading_tolerance_rad
        self._by_id = {ln.lane_id: ln for ln in self.lanes}
        self._points = np.vstack([ln.points_m for ln in self.lanes])
        self._lane_index = np.concatenate([np.full(len(ln.points_m), k) for k, ln in enumerate(self.lanes)])
        self._vertex = np.concatenate([np.arange(len(ln.points_m)) for ln in self.lanes])
        self._tree = cKDTree(self._points)
        # Python-level copies for the scalar per-cycle path (numpy per-element access is ~10x slower).
        self._xy = [(float(a), float(b)) for a, b in self._points]
        self._lane_of = [int(k) for k in self._lane_index]
        self._vertex_of = [int(k) for k in self._vertex]

    def lane(self, lane_id: int) -> Lane:
        try:
            return self._by_id[lane_id]
        except KeyError:
            raise KeyError(f"no lane {lane_id} in the map (lanes {sorted(self._by_id)})") from None

    @property
    def n_vertices(self) -> int:
        return len(self._points)

    # ----------------------------------------------------------------------------------- building

    def with_offset_lane(self, from_lane_id: int, offset_m: float, lane_id: int, name: str = "") -> LaneMap:
        """A new map with a lane `offset_m` to the left (+) or right (-) of lane `from_lane_id`."""
        ref = self.lane(from_lane_id)
        try:
            shifted = ref.path.offset(offset_m)
        except ValueError as e:  # the parallel curve folds where the offset reaches a centre of curvature
            raise LaneMapError(f"lane {lane_id} at {offset_m} m from lane {from_lane_id}: {e}") from e
        pts = _resample(_drop_stationary(shifted.xy), self.spacing_m)
        lane = Lane(lane_id, name or f"offset {offset_m:+.2f} m from {from_lane_id}", pts)
        return LaneMap(
            self.frame, (*self.lanes, lane), self.spacing_m, self.max_lateral_m, self.heading_tolerance_rad
        )

    # ----------------------------------------------------------------------------------- matching

    def project(self, lane_id: int, xy: FloatArray) -> Projection:
        """Foot points of points xy (M, 2) on one given lane (e.g. a predicted trajectory)."""
        return _project_on(self.lane(lane_id), np.atleast_2d(np.asarray(xy, dtype=np.float64)))

    def project_s_many(self, lane_id: int, xy: FloatArray) -> FloatArray:
        """`project(lane_id, xy).s_m`, bit for bit, without the lateral offsets, headings and foot
        points (the fusion's predicted trajectories, every cycle, need the arc lengths alone)."""
        lane = self.lane(lane_id)
        pts = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        path = lane.path
        s = np.asarray(path.project_points_s(pts[:, 0], pts[:, 1]), dtype=np.float64)
        _extrapolate_ends(lane, pts, s)
        return s

    def project_s(self, lane_id: int, x_m: float, y_m: float) -> float:
        """`project(lane_id, [[x_m, y_m]]).s_m[0]`, bit for bit, without numpy for one point between the
        lane's ends (the fusion's per-cycle question for every car on our lane)."""
        lane = self.lane(lane_id)
        x, y = float(x_m), float(y_m)
        if math.isfinite(x) and math.isfinite(y):
            s = lane.path.project_point_s(x, y)
            if 0.0 < s < lane.path.length_m:  # `_project_on` extrapolates only a foot point on an end
                return s
        return float(self.project(lane_id, np.array([[x, y]])).s_m[0])

    def match(
        self, x_m: float, y_m: float, heading_rad: float | None = None, max_lateral_m: float | None = None
    ) -> LaneMatch | None:
        """The lane a position (and heading) is on; None when no lane is within max_lateral_m."""
        limit = self.max_lateral_m if max_lateral_m is None else max_lateral_m
        # Every vertex within reach, then each lane's nearest: the lanes near a point are all examined,
        # not only the one that happens to own the nearest vertex.
        x_m, y_m = float(x_m), float(y_m)
        nearest: dict[int, tuple[float, int]] = {}  # lane index -> (squared distance, vertex)
        for i in self._tree.query_ball_point(np.array((x_m, y_m)), limit + self.spacing_m):
            px, py = self._xy[i]
            d2 = (px - x_m) ** 2 + (py - y_m) ** 2
            li = self._lane_of[i]
            if li not in nearest or d2 < nearest[li][0]:
                nearest[li] = (d2, self._vertex_of[i])
        found: list[tuple[float, int, tuple[float, float, float, float, float, bool]]] = []
        for li, (_, vertex) in nearest.items():
            proj = _project_point(self.lanes[li], x_m, y_m, vertex)
            if (
                heading_rad is not None
                and abs(wrap_angle(heading_rad - proj[4])) > self.heading_tolerance_rad
            ):
                continue
            found.append((abs(proj[1]), li, proj))
        if not found:
            return None
        found.sort(key=lambda e: e[0])
        best_abs, li, (s, lat, fx, fy, hdg, beyond) = found[0]
        if best_abs > limit:
            return None
        margin = found[1][0] - best_abs if len(found) > 1 else math.inf
        return LaneMatch(self.lanes[li].lane_id, s, lat, fx, fy, hdg, margin, beyond)

    def match_brute_force(self, x_m: float, y_m: float) -> LaneMatch | None:
        """Nearest vertex by an O(n) numpy scan, then the same projection (benchmark baseline, no heading)."""
        x_m, y_m = float(x_m), float(y_m)
        d2 = (self._points[:, 0] - x_m) ** 2 + (self._points[:, 1] - y_m) ** 2
        i = int(np.argmin(d2))
        lane = self.lanes[int(self._lane_index[i])]
        s, lat, fx, fy, hdg, beyond = _project_point(lane, x_m, y_m, int(self._vertex[i]))
        if abs(lat) > self.max_lateral_m:
            return None
        return LaneMatch(lane.lane_id, s, lat, fx, fy, hdg, math.inf, beyond)

    @staticmethod
    def along_lane_distance(a: LaneMatch, b: LaneMatch) -> float | None:
        """Geodesic distance from a's foot point to b's (positive: b ahead); None on different lanes."""
        return b.s_m - a.s_m if a.lane_id == b.lane_id else None

    def assign(
        self, objects: Sequence[MapObject], max_lateral_by_kind: dict[str, float] | None = None
    ) -> list[AssignedObject]:
        """Each object to its lane with its s (vehicles with their heading; roadside objects farther out)."""
        limits = {"traffic_light": ROADSIDE_MAX_LATERAL_M, "speed_limit": ROADSIDE_MAX_LATERAL_M}
        limits.update(max_lateral_by_kind or {})
        return [
            AssignedObject(o, self.match(o.x_m, o.y_m, o.heading_rad, limits.get(o.kind))) for o in objects
        ]

    # -------------------------------------------------------------------------------------- files

    def to_json(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "version": VERSION,
            "origin_lat_deg": self.frame.origin_lat_deg,
            "origin_lon_deg": self.frame.origin_lon_deg,
            "spacing_m": self.spacing_m,
            "lanes": [
                {"id": ln.lane_id, "name": ln.name, "points": np.round(ln.points_m, 3).tolist()}
                for ln in self.lanes
            ],
        }

    def save(self, path: Path) -> None:
        path.write_text(json.dumps(self.to_json(), separators=(",", ":")) + "\n", encoding="utf-8")

    @staticmethod
    def load(path: Path) -> LaneMap:
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as e:
            raise LaneMapError(f"{path}: cannot read: {e}") from e
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as e:
            raise LaneMapError(f"{path}:{e.lineno}:{e.colno}: not JSON: {e.msg}") from e
        except RecursionError as e:
            raise LaneMapError(f"{path}: JSON nested too deeply") from e
        return LaneMap.from_json(doc, str(path))

    @staticmethod
    def from_json(doc: Any, source: str = "<lane map>") -> LaneMap:
        def err(where: str, why: str) -> LaneMapError:
            return LaneMapError(f"{source}: {where}: {why}")

        def number(v: Any, where: str) -> float:
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise err(where, f"must be a finite number, got {v!r:.40}")
            return float(v)

        if not isinstance(doc, dict):
            raise err("top level", f"must be an object, got {type(doc).__name__}")
        if doc.get("format") != FORMAT:
            raise err("format", f"must be {FORMAT!r}, got {doc.get('format')!r:.40}")
        if doc.get("version") != VERSION:
            raise err("version", f"unsupported {doc.get('version')!r:.20} (this reader knows {VERSION})")
        for key in ("origin_lat_deg", "origin_lon_deg", "spacing_m", "lanes"):
            if key not in doc:
                raise err(key, "missing")
        lat = number(doc["origin_lat_deg"], "origin_lat_deg")
        lon = number(doc["origin_lon_deg"], "origin_lon_deg")
        if not (-85.0 <= lat <= 85.0 and -180.0 <= lon <= 180.0):
            raise err("origin_lat_deg/origin_lon_deg", f"({lat}, {lon}) out of range")
        spacing = number(doc["spacing_m"], "spacing_m")
        if not 0.01 <= spacing <= 100.0:
            raise err("spacing_m", f"{spacing} outside 0.01..100")
        lanes_doc = doc["lanes"]
        if not isinstance(lanes_doc, list) or not lanes_doc:
            raise err("lanes", "must be a non-empty list")
        lanes: list[Lane] = []
        seen: set[int] = set()
        for k, ld in enumerate(lanes_doc):
            where = f"lanes[{k}]"
            if not isinstance(ld, dict):
                raise err(where, "must be an object")
            lid = ld.get("id")
            if isinstance(lid, bool) or not isinstance(lid, int):
                raise err(f"{where}.id", f"must be an integer, got {lid!r:.40}")
            if lid in seen:
                raise err(f"{where}.id", f"duplicate lane id {lid}")
            seen.add(lid)
            name = ld.get("name", "")
            if not isinstance(name, str):
                raise err(f"{where}.name", "must be a string")
            pts_doc = ld.get("points")
            if not isinstance(pts_doc, list) or len(pts_doc) < 2:
                raise err(f"{where}.points", "must be a list of at least 2 [x, y] pairs")
            pts = np.empty((len(pts_doc), 2))
            for j, p in enumerate(pts_doc):
                if not isinstance(p, list) or len(p) != 2:
                    raise err(f"{where}.points[{j}]", f"must be [x, y], got {p!r:.40}")
                for axis in (0, 1):
                    v = number(p[axis], f"{where}.points[{j}][{axis}]")
                    if abs(v) > MAX_COORD_M:
                        raise err(
                            f"{where}.points[{j}][{axis}]",
                            f"{v} m is beyond {MAX_COORD_M:.0f} m of the origin",
                        )
                    pts[j, axis] = v
            seg = np.hypot(*np.diff(pts, axis=0).T)
            bad = np.flatnonzero(seg <= 0.0)
            if bad.size:
                raise err(f"{where}.points[{int(bad[0]) + 1}]", "repeats the point before it")
            lanes.append(Lane(lid, name, pts))
        return LaneMap(LocalFrame(lat, lon), lanes, spacing)


def record_lane(
    track: FloatArray,
    frame: LocalFrame | None = None,
    geodetic: bool = False,
    spacing_m: float = SEGMENT_M,
    smooth_m: float = 1.0,
    lane_id: int = 0,
    name: str = "right",
) -> LaneMap:
    """A one-lane map from a driven track: (N, 2) local x/y [m], or lat/lon [deg] with ``geodetic=True``
    (the frame's origin is then the first sample unless a frame is given, as in seed 003 IV-A)."""
    pts = np.asarray(track, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
        raise LaneMapError(f"track must be an (N >= 2, 2) array, got shape {pts.shape}")
    bad = np.flatnonzero(~np.all(np.isfinite(pts), axis=1))
    if bad.size:
        raise LaneMapError(f"track sample {int(bad[0])} is not finite: {pts[bad[0]].tolist()}")
    if geodetic:
        if frame is None:
            frame = LocalFrame(float(pts[0, 0]), float(pts[0, 1]))
        x, y = frame.to_local_many(pts[:, 0], pts[:, 1])
        pts = np.column_stack((x, y))
    elif frame is None:
        raise LaneMapError("a track in local x/y needs the frame it is expressed in")
    pts = _drop_stationary(pts)
    if len(pts) < 2 or float(np.sum(np.hypot(*np.diff(pts, axis=0).T))) < spacing_m:
        raise LaneMapError(f"track is shorter than one {spacing_m} m segment")
    pts = _resample(pts, spacing_m)
    pts = _resample(_drop_stationary(_smooth(pts, smooth_m / spacing_m)), spacing_m)
    return LaneMap(frame, [Lane(lane_id, name, pts)], spacing_m)
