"""The urban world (seed 000): an RNDF/MDF road network, our car placed on it, traffic driving its lanes
by simple rules, and the ground-truth bookkeeping the urban scenarios are judged by.

Stepped by the plant at its events (~100 Hz, never every millisecond; `UrbanWorld.step`). Every lane and
exit of the network is a `host.roadnet.path.Path` of the `RoadGraph` (`build_graph`), in the network's
local metres; the host builds the same graph from the same files, so the object list needs no frame
conversion.

Our car: the FMU starts at its origin heading +x with its CG there (vehicle_models/passat: lr = 1.42 m).
The world maps that onto the start waypoint (the mission's first checkpoint, or `urban.start`) with the
waypoint's lane heading, the *rear axle* on the waypoint (a rigid transform), as the behaviour expects
its pose (seed 000 Sec. 11.1: the rear axle is the reference point of the orbital controller).

Traffic drivers (`lane`): along their route at `speed_mps` (1.5 m/s² up, 3 m/s² down, up to 8 in an
emergency); they keep a 1.2 s time gap with 4 m standstill to anything ahead on their path (our car
included); at a stop line they stop 0.3 m short, wait at least 1 s (rules 5.2) and go first-come-
first-served: when nobody who arrived earlier at that intersection still waits (unless that one has let
`STUCK_GRACE_S` pass since its turn came: a car that never moves) and nobody is inside the box. `stuck`
cars stand where they are placed forever (at a stop line they count as waiting). `parked` cars stand
(one with `appears_ahead_m` only from when our front bumper comes that close: an obstacle appearing
just ahead).

Bookkeeping, every step, all from ground truth: arrivals at and departures from every stop line of every
vehicle (precedence), our stop-line stops (front bumper vs line), box-to-box separation of our car to
every other car and collisions of every pair (separating axes), MDF checkpoints passed in order (front
bumper or car centre within `CHECKPOINT_TOLERANCE_M`), the speed limit of the lane we are on, our rear
axle's lateral offset from the nearest lane/exit, how far a corner of our car ever left the road (the
lanes and exits at their RNDF widths and the zones, `host.roadnet.road_area`) and, every sample, its own
side of it (the lanes and exits running its way), and the tracks for the report.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path as FilePath
from typing import Any

import numpy as np

from bywire.hil.world.urban_spec import UrbanSpec, UrbanVehicleSpec
from bywire.host.roadnet import network as roadnet_network
from bywire.host.roadnet.graph import EdgeKind, RoadGraph
from bywire.host.roadnet.ids import WaypointId
from bywire.host.roadnet.lane_index import LaneIndex
from bywire.host.roadnet.mdf import ResolvedMission
from bywire.host.roadnet.path import Path, concat
from bywire.host.roadnet.road_area import RoadArea
from bywire.protocol.objects import EgoPoseRecord, ObjectList, ObjectRecord

FMU_CG_TO_REAR_AXLE_M = 1.42  # vehicle_models/passat: lr
EGO_REAR_OVERHANG_M = 1.10  # Passat B6 Variant: rear bumper to rear axle
EGO_REAR_AXLE_TO_FRONT_M = 2.72 + 0.95  # wheelbase + front overhang (host.behaviour.rules)
DECISION_PERIOD_S = 0.05  # traffic drivers decide at 20 Hz; kinematics every step
STOP_SHORT_M = 0.3  # traffic stops this far before the line
MIN_STOP_S = 1.0  # rules 5.2: a full stop before going on
STUCK_GRACE_S = 10.0  # host.behaviour.rules.PRECEDENCE_STUCK_S: a car that lets its turn pass this long
TIE_S = 0.5  # arrivals this close count as simultaneous (host.behaviour.rules.PRECEDENCE_TIE_S)
ARRIVE_SPEED_MPS = 0.3
ARRIVE_BEHIND_M = 4.0  # a front bumper up to this far before the line ...
ARRIVE_PAST_M = 2.0  # ... or this far past it counts as at the line
DEPART_PAST_M = 3.0  # past the line by this much: in the intersection
LINE_LATERAL_M = 2.0
LINE_HEADING_RAD = math.radians(45.0)
INTERSECTION_CLUSTER_M = 40.0
CHECKPOINT_TOLERANCE_M = 1.5
LATERAL_SAMPLE_S = 0.1
TRACK_SAMPLE_S = 0.5
SPEED_EPISODE_S = 0.5  # a speed-limit violation lasts at least this long
FOLLOW_HEADWAY_S = 1.2
FOLLOW_STANDSTILL_M = 4.0
SENSE_M = 60.0


def load_network(rndf: str, mdf: str) -> tuple[RoadGraph, ResolvedMission]:
    """The host's RNDF/MDF loader, with the shared data root named when a file is missing."""
    from bywire.hil.world.urban_spec import _missing

    for f in (rndf, mdf):
        if not FilePath(f).is_file():
            raise FileNotFoundError(_missing(FilePath(f)))
    return roadnet_network.load_network(rndf, mdf)


def route_path(graph: RoadGraph, waypoints: tuple[str, ...], where: str) -> tuple[Path, list[float]]:
    """The path through consecutive waypoints and the arc length of each waypoint on it; ValueError
    naming the pair that is not an edge."""
    ids = []
    for i, w in enumerate(waypoints):
        try:
            ids.append(WaypointId.parse(w))
        except ValueError as exc:
            raise ValueError(f"{where}.route[{i}]: {w!r} is not a waypoint id ({exc})") from None
    paths, s_at, s = [], [0.0], 0.0
    for i in range(len(ids) - 1):
        if not graph.has_edge(ids[i], ids[i + 1]):
            raise ValueError(f"{where}.route[{i + 1}]: no lane or exit from {ids[i]} to {ids[i + 1]}")
        p = graph.edge(ids[i], ids[i + 1]).path
        paths.append(p)
        s += p.length_m
        s_at.append(s)
    return concat(paths), s_at


def _along(path: Path, x: float, y: float, hint_s: float) -> tuple[float, float, float]:
    """(arc length, lateral offset, path heading) of (x, y) on `path`, extended straight past both ends
    (a car before its route's start is behind it, not on it)."""
    proj = path.project(x, y, hint_s)
    s = proj.s_m
    end = None
    if s <= 1e-6:
        end = path.point_at(0.0)
    elif s >= path.length_m - 1e-6:
        end = path.point_at(path.length_m)
    if end is None:
        return s, proj.lateral_offset_m, path.point_at(s).heading_rad
    c, si = math.cos(end.heading_rad), math.sin(end.heading_rad)
    along = (x - end.x_m) * c + (y - end.y_m) * si
    lateral = -(x - end.x_m) * si + (y - end.y_m) * c
    return end.s_m + along, lateral, end.heading_rad


def box(x: float, y: float, h: float, length: float, width: float) -> np.ndarray:
    """The 4 corners of a car's rectangle centred at (x, y)."""
    c, s = math.cos(h), math.sin(h)
    hl, hw = 0.5 * length, 0.5 * width
    return np.array([[x + a * hl * c - b * hw * s, y + a * hl * s + b * hw * c] for a, b in _CORNERS])


_CORNERS = ((1, 1), (1, -1), (-1, -1), (-1, 1))


def boxes_overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Separating-axis test of two rectangles (4 corners each)."""
    for poly in (a, b):
        for i in range(4):
            edge = poly[(i + 1) % 4] - poly[i]
            axis = np.array([-edge[1], edge[0]])
            pa, pb = a @ axis, b @ axis
            if pa.max() < pb.min() or pb.max() < pa.min():
                return False
    return True


def box_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Smallest distance between two rectangles (0 when they overlap)."""
    if boxes_overlap(a, b):
        return 0.0
    best = math.inf
    for p, q in ((a, b), (b, a)):
        for i in range(4):
            s0, s1 = q[i], q[(i + 1) % 4]
            d = s1 - s0
            t = np.clip(((p - s0) @ d) / float(d @ d), 0.0, 1.0)
            foot = s0 + t[:, None] * d
            best = min(best, float(np.min(np.hypot(*(p - foot).T))))
    return best


@dataclass
class StopLine:
    vertex: str
    x_m: float
    y_m: float
    heading_rad: float
    intersection: int


@dataclass
class Intersection:
    index: int
    x_m: float
    y_m: float
    inside_m: float  # a car centre closer than this to the centre is inside the box
    waiting: dict[str, float] = field(default_factory=dict)  # vehicle -> arrival time
    last_departure_s: float = -math.inf


@dataclass
class Car:
    name: str
    spec: UrbanVehicleSpec
    path: Path | None
    s_m: float
    v_mps: float
    x_m: float
    y_m: float
    heading_rad: float
    stops: list[tuple[float, int]]  # (arc length of the line, intersection index), in order
    next_stop: int = 0
    target_mps: float = 0.0
    waiting_since_s: float | None = None

    @property
    def length_m(self) -> float:
        return self.spec.length_m

    @property
    def width_m(self) -> float:
        return self.spec.width_m


@dataclass
class Arrival:
    vehicle: str
    intersection: int
    line: str
    arrival_s: float
    departure_s: float | None = None
    front_error_m: float = 0.0  # line minus front bumper along the lane (> 0: short of it)


def cluster_stops(graph: RoadGraph) -> tuple[list[StopLine], list[Intersection]]:
    """Stop lines of the network, grouped into intersections (single linkage within 40 m)."""
    verts = sorted((v for v in graph.vertices() if graph.is_stop(v)), key=str)
    poses = []
    for v in verts:
        p = graph.vertex_pose(v)
        if p is not None:
            poses.append((str(v), p.x_m, p.y_m, p.heading_rad))
    group = list(range(len(poses)))

    def find(i: int) -> int:
        while group[i] != i:
            group[i] = group[group[i]]
            i = group[i]
        return i

    for i in range(len(poses)):
        for j in range(i + 1, len(poses)):
            if math.hypot(poses[i][1] - poses[j][1], poses[i][2] - poses[j][2]) < INTERSECTION_CLUSTER_M:
                group[find(i)] = find(j)
    roots = sorted({find(i) for i in range(len(poses))})
    index = {r: k for k, r in enumerate(roots)}
    lines = [StopLine(p[0], p[1], p[2], p[3], index[find(i)]) for i, p in enumerate(poses)]
    inters = []
    for k in range(len(roots)):
        members = [ln for ln in lines if ln.intersection == k]
        cx = sum(m.x_m for m in members) / len(members)
        cy = sum(m.y_m for m in members) / len(members)
        r = min(math.hypot(m.x_m - cx, m.y_m - cy) for m in members) if len(members) > 1 else 6.0
        inters.append(Intersection(k, cx, cy, max(r, 3.0)))
    return lines, inters


class UrbanWorld:
    """Road network + traffic + our car; see the module docstring."""

    def __init__(
        self, spec: UrbanSpec, seed: int = 1, network: tuple[RoadGraph, ResolvedMission] | None = None
    ):
        self.spec = spec
        self.graph, self.mission = network or load_network(spec.rndf, spec.mdf)
        self.index = LaneIndex(self.graph)
        self.rng = np.random.default_rng(seed)
        self.lines, self.intersections = cluster_stops(self.graph)
        self._line_xy = np.array([[ln.x_m, ln.y_m] for ln in self.lines]).reshape(-1, 2)
        start = spec.start
        if start is None:
            v0 = self.graph.checkpoint_vertex(self.mission.checkpoint_numbers[0])
        else:
            try:
                v0 = WaypointId.parse(start)
            except ValueError as exc:
                raise ValueError(f"urban.start: {start!r} is not a waypoint id ({exc})") from None
        pose = self.graph.vertex_pose(v0)
        if pose is None:
            raise ValueError(f"urban.start: {v0} is not a waypoint of {spec.rndf}")
        self.start = (pose.x_m, pose.y_m, pose.heading_rad)
        cars = [self._car(v, i) for i, v in enumerate(spec.vehicles)]
        self.cars = [c for c in cars if c.spec.appears_ahead_m <= 0.0]
        self.unseen = [c for c in cars if c.spec.appears_ahead_m > 0.0]  # not there yet
        self.t_s = 0.0
        self._next_decision_s = 0.0
        self.ego = (pose.x_m, pose.y_m, pose.heading_rad, 0.0, 0.0)  # rear axle x, y, heading, v, r
        self.arrivals: list[Arrival] = []
        self._at_line: dict[str, Arrival] = {}
        self.min_separation_m = math.inf
        self.min_separation_to = ""
        self.collisions: list[dict[str, Any]] = []
        self._contact: set[tuple[str, str]] = set()
        cps = self.mission.checkpoint_numbers
        self.checkpoint_xy = [self.graph.vertex_xy(self.graph.checkpoint_vertex(n)) for n in cps]
        self.checkpoints_reached: list[int] = []
        self.checkpoint_times: list[float] = []
        self.speed_violations: list[dict[str, Any]] = []
        self._over_since: float | None = None
        self._over_peak = 0.0
        self._next_lateral_s = 0.0
        self.lateral: list[tuple[float, float, str]] = []  # (t, lateral m, edge kind)
        self.road = RoadArea.of(self.graph)
        self.road_departure_m = 0.0  # how far a corner of our car was ever off the road (0: never)
        self.road_departure_at_s: float | None = None
        self.road_departure_xy: tuple[float, float] | None = None  # the corner farthest off
        # (t, how far a corner lay outside the lanes and exits running our way), judged by the evaluation
        # outside the manoeuvres that leave the lane on purpose
        self.own_side: list[tuple[float, float]] = []
        self._next_track_s = 0.0
        self.tracks: dict[str, list[tuple[float, float, float]]] = {"ego": []}
        self.ego_speed_limit = math.nan
        self.seq = 0
        self.appeared: list[tuple[str, float]] = []  # (name, when) of the objects that appeared

    # -- set-up -------------------------------------------------------------------------------------

    def _car(self, v: UrbanVehicleSpec, i: int) -> Car:
        where = f"urban.vehicles[{i}]"
        if v.x_m is not None and v.y_m is not None:
            h = math.radians(v.heading_deg)
            return Car(v.name, v, None, 0.0, 0.0, v.x_m, v.y_m, h, [])
        path, s_at = route_path(self.graph, v.route, where)
        stops = []
        for k, w in enumerate(v.route):
            wid = WaypointId.parse(w)
            if k > 0 and self.graph.is_stop(wid):
                for ln in self.lines:
                    if ln.vertex == str(wid):
                        stops.append((s_at[k], ln.intersection))
        s = v.s_m
        if v.at_stop_line:
            if not stops:
                raise ValueError(f"{where}.at_stop_line: no stop line on its route {list(v.route)}")
            s = stops[0][0] - STOP_SHORT_M - 0.5 * v.length_m
        p = path.point_at(min(max(s, 0.0), path.length_m))
        x, y = p.x_m, p.y_m
        if s < 0.0:
            x -= -s * math.cos(p.heading_rad)
            y -= -s * math.sin(p.heading_rad)
        speed = v.v0_mps if v.driver == "lane" else 0.0
        car = Car(v.name, v, path, s, speed, x, y, p.heading_rad, stops, target_mps=speed)
        # stop lines behind the car's front are not its business
        while car.next_stop < len(stops) and stops[car.next_stop][0] < s + 0.5 * v.length_m - 1.0:
            car.next_stop += 1
        return car

    # -- our car --------------------------------------------------------------------------------------

    def ego_from_fmu(self, x_m: float, y_m: float, heading_rad: float) -> tuple[float, float, float]:
        """The FMU's CG pose (its own frame) -> our rear axle on the network (see the module docstring)."""
        rx = x_m - FMU_CG_TO_REAR_AXLE_M * math.cos(heading_rad) + FMU_CG_TO_REAR_AXLE_M
        ry = y_m - FMU_CG_TO_REAR_AXLE_M * math.sin(heading_rad)
        x0, y0, h0 = self.start
        c, s = math.cos(h0), math.sin(h0)
        return x0 + c * rx - s * ry, y0 + s * rx + c * ry, h0 + heading_rad

    def ego_front(self) -> tuple[float, float]:
        x, y, h = self.ego[0], self.ego[1], self.ego[2]
        return x + EGO_REAR_AXLE_TO_FRONT_M * math.cos(h), y + EGO_REAR_AXLE_TO_FRONT_M * math.sin(h)

    def ego_centre(self) -> tuple[float, float]:
        x, y, h = self.ego[0], self.ego[1], self.ego[2]
        d = 0.5 * self.spec.ego_length_m - EGO_REAR_OVERHANG_M
        return x + d * math.cos(h), y + d * math.sin(h)

    # -- stepping -------------------------------------------------------------------------------------

    def step(
        self, t_s: float, x_m: float, y_m: float, heading_rad: float, speed_mps: float, yaw_rate_radps: float
    ) -> None:
        """Advance the traffic to t_s around our car at its FMU pose (the plant's ground truth)."""
        dt = t_s - self.t_s
        rx, ry, rh = self.ego_from_fmu(x_m, y_m, heading_rad)
        self.ego = (rx, ry, math.atan2(math.sin(rh), math.cos(rh)), speed_mps, yaw_rate_radps)
        if t_s >= self._next_decision_s:
            self._next_decision_s = t_s + DECISION_PERIOD_S
            for car in self.cars:
                self._decide(car, t_s)
        if dt > 0.0:
            for car in self.cars:
                self._move(car, dt)
        self.t_s = t_s
        if self.unseen:
            self._appear()
        self._book_lines(t_s)
        self._book_contacts(t_s)
        self._book_checkpoints(t_s)
        if t_s >= self._next_lateral_s:
            self._next_lateral_s = t_s + LATERAL_SAMPLE_S
            self._book_lane(t_s)
        if t_s >= self._next_track_s:
            self._next_track_s = t_s + TRACK_SAMPLE_S
            self.tracks["ego"].append((round(t_s, 3), round(rx, 2), round(ry, 2)))
            for car in self.cars:
                self.tracks.setdefault(car.name, []).append(
                    (round(t_s, 3), round(car.x_m, 2), round(car.y_m, 2))
                )

    def _appear(self) -> None:
        """Objects our front bumper has come within `appears_ahead_m` of are there from now on."""
        fx, fy = self.ego_front()
        for c in list(self.unseen):
            if math.hypot(c.x_m - fx, c.y_m - fy) - 0.5 * c.length_m <= c.spec.appears_ahead_m:
                self.unseen.remove(c)
                self.cars.append(c)
                self.appeared.append((c.name, round(self.t_s, 3)))

    def _others(self, me: str) -> list[tuple[str, float, float, float, float]]:
        """(name, centre x, y, heading, length) of every vehicle but `me`."""
        cx, cy = self.ego_centre()
        out = [("ego", cx, cy, self.ego[2], self.spec.ego_length_m)]
        out += [(c.name, c.x_m, c.y_m, c.heading_rad, c.length_m) for c in self.cars if c.name != me]
        return out

    def _decide(self, car: Car, t: float) -> None:
        spec = car.spec
        if spec.driver != "lane" or car.path is None:
            car.target_mps = 0.0
            return
        want = spec.speed_mps if t >= spec.depart_at_s else 0.0
        front_s = car.s_m + 0.5 * car.length_m
        if car.next_stop < len(car.stops) and spec.stop_at_stops:
            line_s, inter = car.stops[car.next_stop]
            d = line_s - STOP_SHORT_M - front_s
            at_line = d < 1.0 and car.v_mps < ARRIVE_SPEED_MPS
            if at_line and car.waiting_since_s is None:
                car.waiting_since_s = t
            if car.waiting_since_s is not None and self._may_go(car, inter, t):
                car.next_stop += 1
                car.waiting_since_s = None
            else:
                want = min(want, math.sqrt(2.0 * 2.0 * max(d, 0.0)) if d > 0.2 else 0.0)
        # follow anything on our path ahead
        ch, sh = math.cos(car.heading_rad), math.sin(car.heading_rad)
        for _name, ox, oy, oh, olen in self._others(car.name):
            dx, dy = ox - car.x_m, oy - car.y_m
            if abs(dx) > SENSE_M or abs(dy) > SENSE_M or dx * ch + dy * sh < -5.0:
                continue  # far, or behind us (a cheap test before projecting onto our path)
            s_o, lateral, path_heading = _along(car.path, ox, oy, car.s_m)
            ds = s_o - car.s_m
            if ds <= 0.0 or ds > SENSE_M or abs(lateral) > LINE_LATERAL_M:
                continue
            if math.cos(oh - path_heading) < 0.0:
                continue  # oncoming in our lane's geometry (an intersection): the FCFS rule handles it
            gap = ds - 0.5 * (car.length_m + olen)
            want = min(want, max(0.0, (gap - FOLLOW_STANDSTILL_M) / FOLLOW_HEADWAY_S))
        car.target_mps = want

    def _may_go(self, car: Car, inter: int, t: float) -> bool:
        if car.waiting_since_s is None or t - car.waiting_since_s < MIN_STOP_S or t < car.spec.depart_at_s:
            return False
        it = self.intersections[inter]
        mine = it.waiting.get(car.name, car.waiting_since_s)
        for who, arrived in it.waiting.items():
            if who == car.name:
                continue
            earlier = arrived < mine - TIE_S or (abs(arrived - mine) <= TIE_S and who < car.name)
            # a traffic car that waits for its scripted departure is not stuck: its turn comes then
            scripted = next((c.spec.depart_at_s for c in self.cars if c.name == who), 0.0)
            turn_came = max(arrived, it.last_departure_s, scripted)
            if earlier and t - turn_came < STUCK_GRACE_S:
                return False
        for _name, ox, oy, _oh, _ol in self._others(car.name):
            if math.hypot(ox - it.x_m, oy - it.y_m) < it.inside_m:
                return False
        return True

    def _move(self, car: Car, dt: float) -> None:
        if car.path is None or car.spec.driver != "lane":
            return
        dv = car.target_mps - car.v_mps
        decel = 8.0 if car.target_mps < 0.5 * car.v_mps else 3.0
        car.v_mps = max(0.0, car.v_mps + min(max(dv / 0.5, -decel), 1.5) * dt)
        car.s_m += car.v_mps * dt
        s = car.s_m
        p = car.path.point_at(min(max(s, 0.0), car.path.length_m))
        x, y = p.x_m, p.y_m
        extra = s - car.path.length_m if s > car.path.length_m else min(s, 0.0)
        car.x_m = x + extra * math.cos(p.heading_rad)
        car.y_m = y + extra * math.sin(p.heading_rad)
        car.heading_rad = p.heading_rad

    # -- bookkeeping ----------------------------------------------------------------------------------

    def _fronts(self) -> list[tuple[str, float, float, float, float]]:
        """(name, front bumper x, y, heading, speed) of every vehicle."""
        fx, fy = self.ego_front()
        out = [("ego", fx, fy, self.ego[2], abs(self.ego[3]))]
        for c in self.cars:
            d = 0.5 * c.length_m
            out.append(
                (
                    c.name,
                    c.x_m + d * math.cos(c.heading_rad),
                    c.y_m + d * math.sin(c.heading_rad),
                    c.heading_rad,
                    c.v_mps,
                )
            )
        return out

    def _book_lines(self, t: float) -> None:
        if not self.lines:
            return
        for name, fx, fy, h, v in self._fronts():
            cur = self._at_line.get(name)
            if cur is not None:
                ln = next(x for x in self.lines if x.vertex == cur.line)
                along = (fx - ln.x_m) * math.cos(ln.heading_rad) + (fy - ln.y_m) * math.sin(ln.heading_rad)
                lateral = -(fx - ln.x_m) * math.sin(ln.heading_rad) + (fy - ln.y_m) * math.cos(ln.heading_rad)
                if (
                    along > DEPART_PAST_M
                    or along < -3.0 * ARRIVE_BEHIND_M
                    or abs(lateral) > 2.0 * LINE_LATERAL_M
                ):
                    cur.departure_s = t
                    it = self.intersections[cur.intersection]
                    it.waiting.pop(name, None)
                    it.last_departure_s = t
                    del self._at_line[name]
                continue
            if v > ARRIVE_SPEED_MPS:
                continue
            d2 = (self._line_xy[:, 0] - fx) ** 2 + (self._line_xy[:, 1] - fy) ** 2
            k = int(np.argmin(d2))
            if d2[k] > (ARRIVE_BEHIND_M + LINE_LATERAL_M) ** 2:
                continue
            ln = self.lines[k]
            dh = math.atan2(math.sin(h - ln.heading_rad), math.cos(h - ln.heading_rad))
            along = (fx - ln.x_m) * math.cos(ln.heading_rad) + (fy - ln.y_m) * math.sin(ln.heading_rad)
            lateral = -(fx - ln.x_m) * math.sin(ln.heading_rad) + (fy - ln.y_m) * math.cos(ln.heading_rad)
            if abs(dh) > LINE_HEADING_RAD or abs(lateral) > LINE_LATERAL_M:
                continue
            if not -ARRIVE_BEHIND_M <= along <= ARRIVE_PAST_M:
                continue
            arr = Arrival(name, ln.intersection, ln.vertex, t, None, -along)
            self.arrivals.append(arr)
            self._at_line[name] = arr
            self.intersections[ln.intersection].waiting[name] = t
        # our stop-line error: the smallest front error while standing at the line
        cur = self._at_line.get("ego")
        if cur is not None and abs(self.ego[3]) < 0.05:
            ln = next(x for x in self.lines if x.vertex == cur.line)
            fx, fy = self.ego_front()
            along = (fx - ln.x_m) * math.cos(ln.heading_rad) + (fy - ln.y_m) * math.sin(ln.heading_rad)
            cur.front_error_m = -along

    def _book_contacts(self, t: float) -> None:
        cx, cy = self.ego_centre()
        boxes = [("ego", cx, cy, box(cx, cy, self.ego[2], self.spec.ego_length_m, self.spec.ego_width_m))]
        diag = [math.hypot(self.spec.ego_length_m, self.spec.ego_width_m)]
        for c in self.cars:
            boxes.append((c.name, c.x_m, c.y_m, box(c.x_m, c.y_m, c.heading_rad, c.length_m, c.width_m)))
            diag.append(math.hypot(c.length_m, c.width_m))
        for i in range(len(boxes)):
            ni, xi, yi, bi = boxes[i]
            for j in range(i + 1, len(boxes)):
                nj, xj, yj, bj = boxes[j]
                # the centre distance less both half diagonals bounds the box distance from below: where
                # it cannot touch, or cannot beat the smallest separation so far, nothing exact is needed
                bound = math.hypot(xi - xj, yi - yj) - 0.5 * (diag[i] + diag[j])
                if i == 0 and (bound <= 0.0 or bound < self.min_separation_m):
                    d = box_distance(bi, bj)
                    if d < self.min_separation_m:
                        self.min_separation_m, self.min_separation_to = d, nj
                    touching = d <= 0.0
                elif i != 0 and bound <= 0.0:
                    touching = boxes_overlap(bi, bj)
                else:
                    touching = False
                key = (ni, nj)
                if touching and key not in self._contact:
                    self._contact.add(key)
                    self.collisions.append({"t_s": round(t, 2), "a": ni, "b": nj})
                elif not touching:
                    self._contact.discard(key)

    def _book_checkpoints(self, t: float) -> None:
        k = len(self.checkpoints_reached)
        if k >= len(self.checkpoint_xy):
            return
        cx, cy = self.checkpoint_xy[k]
        fx, fy = self.ego_front()
        mx, my = self.ego_centre()
        rx, ry = self.ego[0], self.ego[1]
        near = min(math.hypot(fx - cx, fy - cy), math.hypot(mx - cx, my - cy))
        if k == 0:
            near = min(near, math.hypot(rx - cx, ry - cy))  # we start with the rear axle on it
        if near < CHECKPOINT_TOLERANCE_M:
            self.checkpoints_reached.append(self.mission.checkpoint_numbers[k])
            self.checkpoint_times.append(round(t, 2))

    def _book_lane(self, t: float) -> None:
        x, y, h, v = self.ego[0], self.ego[1], self.ego[2], self.ego[3]
        cx, cy = self.ego_centre()
        corners = box(cx, cy, h, self.spec.ego_length_m, self.spec.ego_width_m)
        own = self.road.excess_m(corners[:, 0], corners[:, 1], h)
        self.own_side.append((round(t, 2), round(max(float(np.max(own)), 0.0), 3)))
        excess = self.road.excess_m(corners[:, 0], corners[:, 1])
        k = int(np.argmax(excess))
        if excess[k] > self.road_departure_m:
            self.road_departure_m, self.road_departure_at_s = float(excess[k]), round(t, 2)
            self.road_departure_xy = (round(float(corners[k, 0]), 2), round(float(corners[k, 1]), 2))
        m = self.index.match(x, y, h)
        if m is None:
            self.ego_speed_limit = math.nan
            self.lateral.append((round(t, 2), math.nan, "none"))
            return
        self.lateral.append((round(t, 2), round(m.lateral_offset_m, 4), m.edge.kind.value))
        limit = m.edge.speed_max_mps if m.edge.kind == EdgeKind.LANE else None
        self.ego_speed_limit = math.nan if limit is None else float(limit)
        over = abs(v) - (limit if limit is not None else math.inf)
        if over > self.spec.speed_tolerance_mps:
            if self._over_since is None:
                self._over_since, self._over_peak = t, 0.0
            self._over_peak = max(self._over_peak, over)
        elif self._over_since is not None:
            if t - self._over_since >= SPEED_EPISODE_S:
                self.speed_violations.append(
                    {"t_s": round(self._over_since, 2), "duration_s": round(t - self._over_since, 2),
                     "excess_mps": round(self._over_peak, 3)}
                )  # fmt: skip
            self._over_since = None

    # -- what the host receives -------------------------------------------------------------------------

    def object_list(self, t: float, with_objects: bool) -> ObjectList:
        """Our rear-axle pose (with the pose noise) and, when due, every car within range (with noise)."""
        x, y, h, v, r = self.ego
        ps = self.spec.pose
        dx, dy = ps.map_offset_m
        x, y = x + dx, y + dy
        if ps.position_noise_m > 0.0:
            x += float(self.rng.normal(0.0, ps.position_noise_m))
            y += float(self.rng.normal(0.0, ps.position_noise_m))
        if ps.heading_noise_rad > 0.0:
            h += float(self.rng.normal(0.0, ps.heading_noise_rad))
        objects: list[ObjectRecord] = []
        if with_objects:
            ob = self.spec.objects
            for i, c in enumerate(self.cars):
                if math.hypot(c.x_m - x, c.y_m - y) > ob.range_m:
                    continue
                ox, oy, oh, ov = c.x_m + dx, c.y_m + dy, c.heading_rad, c.v_mps
                if ob.position_noise_m > 0.0:
                    ox += float(self.rng.normal(0.0, ob.position_noise_m))
                    oy += float(self.rng.normal(0.0, ob.position_noise_m))
                if ob.heading_noise_rad > 0.0:
                    oh += float(self.rng.normal(0.0, ob.heading_noise_rad))
                if ob.speed_noise_mps > 0.0:
                    ov = max(0.0, ov + float(self.rng.normal(0.0, ob.speed_noise_mps)))
                objects.append(ObjectRecord(i + 1, ox, oy, oh, ov, c.length_m, c.width_m))
        self.seq += 1
        return ObjectList(t, self.seq, EgoPoseRecord(x, y, h, v, r), tuple(objects), with_objects)

    def summary(self) -> dict[str, Any]:
        """Everything the urban evaluation needs (JSON-able)."""
        return {
            "rndf": self.spec.rndf,
            "mdf": self.spec.mdf,
            "start": list(self.start),
            "checkpoints": list(self.mission.checkpoint_numbers),
            "checkpoints_reached": list(self.checkpoints_reached),
            "checkpoint_times_s": list(self.checkpoint_times),
            "arrivals": [a.__dict__ for a in self.arrivals],
            "min_separation_m": None
            if not math.isfinite(self.min_separation_m)
            else round(self.min_separation_m, 3),
            "min_separation_to": self.min_separation_to,
            "collisions": list(self.collisions),
            "speed_violations": list(self.speed_violations),
            "lateral": [list(r) for r in self.lateral],
            "road_departure_m": round(self.road_departure_m, 3),
            "road_departure_at_s": self.road_departure_at_s,
            "road_departure_xy": self.road_departure_xy,
            "own_side": [list(r) for r in self.own_side],
            "appeared": [list(a) for a in self.appeared],
            "tracks": {k: [list(r) for r in v] for k, v in self.tracks.items()},
            "intersections": [[i.x_m, i.y_m, i.inside_m] for i in self.intersections],
        }


class UrbanWorldSim:
    """The plant's handle: steps the world at its events and sends the object list (`send`) at the
    pose rate, with the objects at the object rate. With `perception: lidar` the object list carries our
    pose only, and `lidar` (a `hil.lidar.sensor_link.LidarSender`, or anything with `due(t)` and
    `revolution(t)`) takes a revolution of the world as it is whenever one is due."""

    def __init__(
        self,
        spec: UrbanSpec,
        seed: int,
        send: Callable[[bytes], Any] | None = None,
        lidar: Any = None,
    ) -> None:
        from bywire.protocol.objects import encode

        self.world = UrbanWorld(spec, seed)
        self.send = send
        self.lidar = lidar
        self._objects = spec.perception == "perfect"
        self._encode = encode
        self._next_pose_s = 0.0
        self._next_objects_s = 0.0
        self.sent = 0

    def step(
        self, t_s: float, x_m: float, y_m: float, heading_rad: float, speed_mps: float, yaw_rate_radps: float
    ) -> None:
        self.world.step(t_s, x_m, y_m, heading_rad, speed_mps, yaw_rate_radps)
        if self.lidar is not None and self.lidar.due(t_s):
            self.lidar.revolution(self.world, t_s)
        if self.send is None or t_s < self._next_pose_s - 1e-9:
            return
        spec = self.world.spec
        self._next_pose_s = max(self._next_pose_s + 1.0 / spec.pose.rate_hz, t_s)
        with_objects = self._objects and t_s >= self._next_objects_s - 1e-9
        if with_objects:
            self._next_objects_s = max(self._next_objects_s + 1.0 / spec.objects.rate_hz, t_s)
        self.send(self._encode(self.world.object_list(t_s, with_objects)))
        self.sent += 1

    def summary(self) -> dict[str, Any]:
        out = self.world.summary()
        out["object_lists_sent"] = self.sent
        out["perception"] = self.world.spec.perception
        out["map_offset_m"] = list(self.world.spec.pose.map_offset_m)
        if self.lidar is not None:
            out["lidar"] = self.lidar.summary()
        return out


__all__ = [
    "UrbanWorld",
    "UrbanWorldSim",
    "box",
    "box_distance",
    "boxes_overlap",
    "cluster_stops",
    "load_network",
]
