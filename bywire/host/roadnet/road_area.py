"""Where the road is: the drivable area of a road network, for the planner's obstacle map on a road (seed
000 Sec. 10: K-turns and U-turns are planned "on the obstacle map" like a zone) and for judging whether a
car stayed on it.

The RNDF gives lanes as centre lines with a width, and exits as connectors between them (format sec.
2.1: an exit's implied lane is the narrower of the two). The road is taken to be exactly that: every
LANE and EXIT edge a corridor of its lane width around its path (`DEFAULT_LANE_WIDTH_M` where the file
gives none), the band between adjacent lanes of a segment (their centre lines no more than the graph's
`adjacent_max_widths` lane widths apart: one street, whatever its lanes' painted widths leave between
them), every zone the inside of its perimeter polygon. A point's *excess* is how far it lies
outside all of them (<= 0: on the road): the distance to the nearest path sample minus that sample's half
width, the least over the `NEIGHBOURS` nearest samples (where a narrow exit meets a wide lane, the wide
lane's edge counts). A lane's end is rounded (a half disc of its half width past the last waypoint):
the RNDF says nothing of what lies beyond, and a dead end's last waypoint is where a car stops with
its bumper, not where the asphalt ends.

With a heading, `excess_m` measures against the lanes and exits running that way only: how far a car has
strayed from its own side of the road (into the oncoming lane, where no curb stops it). `of_paths` makes
the area of a few paths alone (a manoeuvre's own lanes).

Derived edges (lane changes, K-turns, zone edges) add nothing: they lie within the lanes and zones they
join or are the placeholder geometry of a manoeuvre planned here.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from .graph import DEFAULT_LANE_WIDTH_M, EdgeKind, RoadGraph
from .ids import LaneId
from .path import Path

__all__ = ["RoadArea", "polygon_contains"]

SAMPLE_M = 0.25
NEIGHBOURS = 8
SECTORS = 16  # a heading picks the sector nearest it: "running our way" is within 90 +- 11 deg

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]


def polygon_contains(poly: FloatArray, x: FloatArray, y: FloatArray) -> BoolArray:
    """Even-odd point-in-polygon test of the points (x, y) against `poly` (n, 2), vectorised."""
    inside = np.zeros(np.shape(x), dtype=bool)
    n = poly.shape[0]
    for i in range(n):
        x0, y0 = poly[i]
        x1, y1 = poly[(i + 1) % n]
        crosses = (y0 > y) != (y1 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_at = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
        inside ^= crosses & (x < x_at)
    return inside


def _corridor(path: Path, width_m: float | None) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Samples (x, y, half width, heading) of a path every `SAMPLE_M`, the lane's width around it."""
    if path.length_m <= 0.0:
        e = np.zeros(0)
        return e, e, e, e
    n = max(2, int(np.ceil(path.length_m / SAMPLE_M)) + 1)
    x, y, h, _ = path.sample(np.linspace(0.0, path.length_m, n))
    half = np.full(n, 0.5 * (width_m or DEFAULT_LANE_WIDTH_M))
    return np.asarray(x, dtype=float), np.asarray(y, dtype=float), half, np.asarray(h, dtype=float)


def _outside_m(poly: FloatArray, x: FloatArray, y: FloatArray) -> FloatArray:
    """How far each point lies outside the polygon (0 inside): its distance to the nearest edge."""
    a = poly
    b = np.roll(poly, -1, axis=0)
    d = b - a
    lengths2 = np.maximum((d**2).sum(axis=1), 1e-12)
    px = x[:, None] - a[None, :, 0]
    py = y[:, None] - a[None, :, 1]
    u = np.clip((px * d[None, :, 0] + py * d[None, :, 1]) / lengths2[None, :], 0.0, 1.0)
    gap = np.hypot(px - u * d[None, :, 0], py - u * d[None, :, 1]).min(axis=1)
    return np.where(polygon_contains(poly, x, y), 0.0, gap)


def _band(graph: RoadGraph, lane: LaneId, other: LaneId) -> tuple[FloatArray, FloatArray, FloatArray] | None:
    """Samples of the midline between `lane` and `other` where they run side by side as one street, each
    a disc reaching both centre lines (None where they never do)."""
    a, b = graph.lane_path(lane), graph.lane_path(other)
    if a is None or b is None:
        return None
    n = max(2, int(np.ceil(a.length_m / SAMPLE_M)) + 1)
    x, y, _, _ = a.sample(np.linspace(0.0, a.length_m, n))
    s_b, lateral, _ = b.project_points(x, y)
    fx, fy, _, _ = b.sample(s_b)
    gap = np.hypot(np.asarray(x) - fx, np.asarray(y) - fy)
    width = max(graph.network.lane(lane).width_m or DEFAULT_LANE_WIDTH_M,
                graph.network.lane(other).width_m or DEFAULT_LANE_WIDTH_M)  # fmt: skip
    p = graph.params
    # square across (past the other lane's ends the foot point is its end, farther than the offset)
    keep = (gap >= p.adjacent_min_m) & (gap <= p.adjacent_max_widths * width) & (gap <= np.abs(lateral) + 0.5)
    if not keep.any():
        return None
    mx = 0.5 * (np.asarray(x) + fx)
    my = 0.5 * (np.asarray(y) + fy)
    return mx[keep], my[keep], 0.5 * gap[keep]


@dataclass(frozen=True)
class RoadArea:
    """The corridors' samples (with their half widths and directions) and the zones' polygons."""

    xy: FloatArray  # (n, 2) path samples of every lane and exit, and of the bands between lanes
    half_width_m: FloatArray  # (n,)
    heading_rad: FloatArray  # (n,) the direction traffic runs at the sample; NaN in a band (both ways)
    zones: tuple[FloatArray, ...]  # perimeter polygons (m, 2)
    tree: cKDTree
    # per heading sector (SECTORS around the circle): the samples running within 90 deg of its centre
    sector_index: tuple[IntArray, ...]
    sector_tree: tuple[cKDTree, ...]

    @classmethod
    def of(cls, graph: RoadGraph) -> RoadArea:
        """Every lane and exit of `graph`, the bands between lanes, the zones (see the module docstring)."""
        parts = [_corridor(e.path, e.lane_width_m) for e in graph.edges((EdgeKind.LANE, EdgeKind.EXIT))]
        if not any(p[0].size for p in parts):
            raise ValueError("road area: the network has no lane with a path")
        for seg in graph.network.segments:
            for lane in seg.lanes:
                for other in seg.lanes:
                    if other.id != lane.id:
                        band = _band(graph, lane.id, other.id)
                        if band is not None:
                            parts.append((*band, np.full(band[0].size, np.nan)))
        zones = tuple(
            np.array([graph.vertex_xy(p.id) for p in zone.perimeter.points], dtype=float)
            for zone in graph.network.zones
            if len(zone.perimeter.points) >= 3
        )
        return cls._of_parts(parts, zones)

    @classmethod
    def of_paths(cls, corridors: Sequence[tuple[Path, float | None]]) -> RoadArea:
        """Only the given paths, each a corridor of its lane width (a manoeuvre's own lanes)."""
        parts = [_corridor(path, width) for path, width in corridors]
        if not any(p[0].size for p in parts):
            raise ValueError("road area: no path with a length")
        return cls._of_parts(parts, ())

    @classmethod
    def _of_parts(
        cls, parts: list[tuple[FloatArray, FloatArray, FloatArray, FloatArray]], zones: tuple[FloatArray, ...]
    ) -> RoadArea:
        x, y, hw, h = (np.concatenate([p[i] for p in parts]) for i in range(4))
        xy = np.column_stack((x, y))
        index: list[IntArray] = []
        for j in range(SECTORS):
            with np.errstate(invalid="ignore"):
                ours = np.cos(h - 2.0 * np.pi * j / SECTORS) > 0.0
            index.append(np.flatnonzero(ours) if ours.any() else np.arange(0))
        trees = tuple(cKDTree(xy[i] if i.size else np.zeros((1, 2))) for i in index)  # empty: never queried
        return cls(xy, hw, h, zones, cKDTree(xy), tuple(index), trees)

    def excess_m(
        self, x_m: npt.ArrayLike, y_m: npt.ArrayLike, heading_rad: float | None = None
    ) -> FloatArray:
        """How far each point lies outside the road (<= 0: on a lane, an exit or in a zone). With
        `heading_rad`, outside the lanes and exits that run that way (within 90 deg; not the bands
        between lanes): how far a car heading so has strayed from its own side of the road."""
        x = np.asarray(x_m, dtype=float)
        y = np.asarray(y_m, dtype=float)
        pts = np.column_stack((x.ravel(), y.ravel()))
        if heading_rad is None:
            tree, of = self.tree, None
        else:
            j = round(heading_rad * SECTORS / (2.0 * np.pi)) % SECTORS
            tree, of = self.sector_tree[j], self.sector_index[j]
            if not of.size:
                return np.full(x.shape, np.inf)
        k = min(NEIGHBOURS, tree.n)
        dist, idx = tree.query(pts, k=k)
        dist = np.asarray(dist).reshape(pts.shape[0], k)
        idx = np.asarray(idx).reshape(pts.shape[0], k)
        if of is not None:
            idx = of[idx]
        excess = np.min(dist - self.half_width_m[idx], axis=1)
        for poly in self.zones:
            excess = np.minimum(excess, _outside_m(poly, pts[:, 0], pts[:, 1]))
        return excess.reshape(x.shape)

    def off_road(self, x_m: FloatArray, y_m: FloatArray) -> BoolArray:
        """True where a point lies outside the road (the obstacle cells of a map on the road)."""
        return self.excess_m(x_m, y_m) > 0.0
