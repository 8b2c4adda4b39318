"""Lane paint and curbs of an RNDF road network, as triangles for the simulated LIDAR (seed 000 Sec. 6).

AnnieWAY found painted markings in the reflectivity of its Velodyne and curbs as small height steps in
its range data. This draws both along the lanes of the network's `RoadGraph`:

- every lane's two boundaries, sampled every `SAMPLE_M` along its smooth curve. A boundary the RNDF
  names (`double_yellow`, `solid_white`, `broken_white`, `solid_yellow`) is painted as named; one it
  leaves open is painted by what lies beside it: another lane the same way a broken white line,
  an oncoming lane a double yellow centre line, nothing a solid white edge line. A boundary two lanes
  share is painted once, by the lane listed first. Lines are 12 cm wide (MUTCD 3B: 4-6 in); a
  broken line is 3 m painted in every 12 m (MUTCD: 10 ft segments, 30 ft gaps); a double line is
  two lines 10 cm apart;
- a stop bar 45 cm deep across the lane at every stop waypoint (MUTCD 3B.16: 12-24 in);
- with `curb_height_m` > 0, a curb along every edge without a lane beside it: its face
  `CURB_GUTTER_M` outside the lane, a sidewalk `SIDEWALK_M` wide on top, and a face down again
  behind it (the ground beyond is the road's plane).

Edge lines and curbs stop where an exit (an intersection's connector, a driveway into a zone) passes
within `EXIT_CLEARANCE_M` of them: an intersection has neither. Deviation: crosswalks, arrows and
the lines of zones (parking lots) are not drawn.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from bywire.hil.lidar.mesh import PAINT_THICKNESS_M, Ground, Mesh, Surface, strip_mesh
from bywire.host.roadnet.graph import DEFAULT_LANE_WIDTH_M, EdgeKind, RoadGraph
from bywire.host.roadnet.ids import LaneId

SAMPLE_M = 0.5  # a 12 m radius curve's 0.5 m chords depart from the arc by 2.6 mm
LINE_WIDTH_M = 0.12
DOUBLE_GAP_M = 0.10
DASH_M = 3.0
DASH_PERIOD_M = 12.0
STOP_BAR_M = 0.45
CURB_GUTTER_M = 0.3
SIDEWALK_M = 2.0
# A car's half width plus a metre: an edge line or curb nearer than this to an exit's path is in the
# way of the cars that drive it.
EXIT_CLEARANCE_M = 2.0
# Lanes whose headings differ by more than this are not side by side (a crossing road is not a neighbour).
NEIGHBOUR_MAX_ANGLE_RAD = math.radians(30.0)

F64 = npt.NDArray[np.float64]

# (offset from the boundary, paint) of each line of a boundary, positive away from the lane
_LINES: dict[str, tuple[tuple[float, Surface], ...]] = {
    "solid_white": ((0.0, Surface.PAINT_WHITE),),
    "broken_white": ((0.0, Surface.PAINT_WHITE),),
    "solid_yellow": ((0.0, Surface.PAINT_YELLOW),),
    "double_yellow": (
        (-0.5 * (LINE_WIDTH_M + DOUBLE_GAP_M), Surface.PAINT_YELLOW),
        (0.5 * (LINE_WIDTH_M + DOUBLE_GAP_M), Surface.PAINT_YELLOW),
    ),
}


@dataclass(frozen=True)
class _Lane:
    lane_id: LaneId
    width_m: float
    boundaries: tuple[str | None, str | None]  # left, right as the RNDF gives them
    s_m: F64
    x_m: F64
    y_m: F64
    heading_rad: F64

    def side(self, sign: float, offset_m: float | F64, edge_m: float | F64 | None = None) -> tuple[F64, F64]:
        """Points `offset_m` beyond the lane's edge on the left (sign +1) or right (-1); the edge is
        `edge_m` from the centre (default: half the lane's width)."""
        edge = 0.5 * self.width_m if edge_m is None else np.asarray(edge_m)
        d = sign * (edge + np.asarray(offset_m))
        return self.x_m - d * np.sin(self.heading_rad), self.y_m + d * np.cos(self.heading_rad)


def _lanes(graph: RoadGraph) -> list[_Lane]:
    out = []
    for segment in graph.network.segments:
        for lane in segment.lanes:
            path = graph.lane_path(lane.id)
            if path is None or path.length_m < SAMPLE_M:
                continue
            s = np.linspace(0.0, path.length_m, math.ceil(path.length_m / SAMPLE_M) + 1)
            x, y, h, _ = path.sample(s)
            width = lane.width_m or DEFAULT_LANE_WIDTH_M
            out.append(_Lane(lane.id, width, (lane.left_boundary, lane.right_boundary), s, x, y, h))
    return out


@dataclass(frozen=True)
class _Beside:
    """Per sample of one side of a lane: the index of the lane beside it (-1: none), whether that lane
    runs the same way, and where the boundary is: midway to that lane's centre, else the lane's edge."""

    lane: npt.NDArray[np.int64]
    same_way: npt.NDArray[np.bool_]
    edge_m: F64


def _beside(lanes: list[_Lane]) -> list[dict[float, _Beside]]:
    """For each lane and side (+1 left, -1 right): what lies beside it. A lane beside has its centre
    about a lane width across and runs parallel or antiparallel."""
    xy = np.concatenate([np.column_stack([ln.x_m, ln.y_m]) for ln in lanes])
    owner = np.concatenate([np.full(len(ln.s_m), i) for i, ln in enumerate(lanes)])
    heading = np.concatenate([ln.heading_rad for ln in lanes])
    tree = cKDTree(xy)
    cos_max = math.cos(NEIGHBOUR_MAX_ANGLE_RAD)
    k = min(8, len(xy))
    out: list[dict[float, _Beside]] = []
    for i, ln in enumerate(lanes):
        sides: dict[float, _Beside] = {}
        rows = np.arange(len(ln.s_m))
        for sign in (1.0, -1.0):
            qx, qy = ln.side(sign, 0.5 * ln.width_m)
            _d, j = tree.query(np.column_stack([qx, qy]), k=k, distance_upper_bound=0.5 * ln.width_m)
            j = np.asarray(j).reshape(len(rows), k)
            valid = j < len(xy)
            jj = np.where(valid, j, 0)
            cos = np.cos(heading[jj] - ln.heading_rad[:, None])
            ok = valid & (owner[jj] != i) & (np.abs(cos) >= cos_max)
            first = np.argmax(ok, axis=1)
            found = ok[rows, first]
            nb = jj[rows, first]
            across = sign * (
                -(xy[nb, 0] - ln.x_m) * np.sin(ln.heading_rad) + (xy[nb, 1] - ln.y_m) * np.cos(ln.heading_rad)
            )
            sides[sign] = _Beside(
                np.where(found, owner[nb], -1),
                found & (cos[rows, first] > 0.0),
                np.where(found, 0.5 * across, 0.5 * ln.width_m),
            )
        out.append(sides)
    return out


class _Exits:
    """The samples of a graph's exits: where edge lines and curbs must leave a gap."""

    def __init__(self, graph: RoadGraph) -> None:
        pts = []
        for edge in graph.edges(EdgeKind.EXIT):
            path = edge.path
            s = np.linspace(0.0, path.length_m, max(2, math.ceil(path.length_m / SAMPLE_M) + 1))
            px, py, _, _ = path.sample(s)
            pts.append(np.column_stack([px, py]))
        self._tree = cKDTree(np.concatenate(pts)) if pts else None

    def clear(self, x: F64, y: F64) -> npt.NDArray[np.bool_]:
        """Per point: no exit passes within `EXIT_CLEARANCE_M`."""
        if self._tree is None:
            return np.ones(len(x), bool)
        d, _ = self._tree.query(np.column_stack([x, y]), distance_upper_bound=EXIT_CLEARANCE_M)
        return np.asarray(~np.isfinite(d))


def _lifted(ground: Ground, x: F64, y: F64, dz_m: float) -> F64:
    return np.column_stack([x, y, ground.height_m(x, y) + dz_m])


def _line(
    ground: Ground,
    lane: _Lane,
    sign: float,
    edge_m: F64,
    offset_m: float,
    keep: npt.NDArray[np.bool_],
    paint: Surface,
) -> Mesh:
    """A painted line centred `offset_m` beyond the boundary at `edge_m`, over the samples where `keep`
    (both ends)."""
    inner = lane.side(sign, offset_m - 0.5 * LINE_WIDTH_M, edge_m)
    outer = lane.side(sign, offset_m + 0.5 * LINE_WIDTH_M, edge_m)
    seg = keep[:-1] & keep[1:]
    return strip_mesh(
        _lifted(ground, *inner, PAINT_THICKNESS_M), _lifted(ground, *outer, PAINT_THICKNESS_M), seg, paint
    )


def _curb(ground: Ground, lane: _Lane, sign: float, height_m: float, keep: npt.NDArray[np.bool_]) -> Mesh:
    seg = keep[:-1] & keep[1:]
    face = lane.side(sign, CURB_GUTTER_M)
    back = lane.side(sign, CURB_GUTTER_M + SIDEWALK_M)
    return Mesh.concat(
        [
            strip_mesh(_lifted(ground, *face, 0.0), _lifted(ground, *face, height_m), seg, Surface.CURB),
            strip_mesh(_lifted(ground, *face, height_m), _lifted(ground, *back, height_m), seg, Surface.CURB),
            strip_mesh(_lifted(ground, *back, height_m), _lifted(ground, *back, 0.0), seg, Surface.CURB),
        ]
    )


def _stop_bars(graph: RoadGraph, ground: Ground, widths: dict[LaneId, float]) -> Mesh:
    bars = []
    for v in graph.vertices():
        pose = graph.vertex_pose(v) if graph.is_stop(v) else None
        if pose is None:
            continue
        hw = 0.5 * widths.get(LaneId(v.segment, v.lane), DEFAULT_LANE_WIDTH_M)
        c, s = math.cos(pose.heading_rad), math.sin(pose.heading_rad)
        along = np.array([-STOP_BAR_M, 0.0])
        # the bar lies just before the stop waypoint, where the rules want the front bumper (within 1 m)
        right = np.column_stack([pose.x_m + along * c + hw * s, pose.y_m + along * s - hw * c])
        left = np.column_stack([pose.x_m + along * c - hw * s, pose.y_m + along * s + hw * c])
        bars.append(
            strip_mesh(
                _lifted(ground, right[:, 0], right[:, 1], PAINT_THICKNESS_M),
                _lifted(ground, left[:, 0], left[:, 1], PAINT_THICKNESS_M),
                None,
                Surface.PAINT_WHITE,
            )
        )
    return Mesh.concat(bars)


def _kinds(named: str | None, beside: _Beside) -> npt.NDArray[np.str_]:
    """The marking of each sample of a boundary: as the RNDF names it, else by what lies beside."""
    if named is not None:
        return np.full(len(beside.lane), named)
    return np.where(
        beside.lane < 0, "solid_white", np.where(beside.same_way, "broken_white", "double_yellow")
    )


def road_marks_mesh(graph: RoadGraph, ground: Ground, curb_height_m: float = 0.0) -> Mesh:
    """The network's paint (and curbs, if `curb_height_m` > 0) on `ground`; see the module docstring."""
    lanes = _lanes(graph)
    if not lanes:
        return Mesh.empty()
    beside = _beside(lanes)
    exits = _Exits(graph)
    parts = []
    for i, ln in enumerate(lanes):
        for named, sign in zip(ln.boundaries, (1.0, -1.0), strict=True):
            other = beside[i][sign]
            alone = other.lane < 0
            edge_clear = alone & exits.clear(*ln.side(sign, 0.0))
            # a shared boundary is the first-listed lane's to paint
            painted = edge_clear | (~alone & (other.lane > i))
            kinds = _kinds(named, other)
            for kind, lines in _LINES.items():
                keep = painted & (kinds == kind)
                if kind == "broken_white":
                    keep &= np.mod(ln.s_m, DASH_PERIOD_M) <= DASH_M
                if keep.any():
                    parts += [_line(ground, ln, sign, other.edge_m, off, keep, paint) for off, paint in lines]
            if curb_height_m > 0.0:
                parts.append(_curb(ground, ln, sign, curb_height_m, edge_clear))
    parts.append(_stop_bars(graph, ground, {ln.lane_id: ln.width_m for ln in lanes}))
    return Mesh.concat(parts)


__all__ = ["SIDEWALK_M", "road_marks_mesh"]
