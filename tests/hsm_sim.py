"""Closed-loop harness for the behaviour layer (a test tool, not product code).

- Small hand-made road networks in local metres (`cross_network`, `ring_network`, `two_lane_network`,
  `zone_network`), written as RNDF/MDF text and read by the real parsers.
- `Sim`: a kinematic ego (the single-track model of host/lateral.py, rear axle, exact arcs) closed by
  the orbital lateral controller and `longitudinal_step` at 20 Hz, with a 0.3 s first-order lag on
  the acceleration (a drivetrain) and a gear that changes only at standstill; scripted traffic
  (`ScriptedCar`: a path and a target speed as a function of time and position); objects matched to
  lanes with `LaneIndex` as the world model would; box-overlap collision checks; a trace of states,
  commands and distances for the tests to judge.

Nothing here is timed against the wall clock.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from bywire.hil.world.urban import box, boxes_overlap  # the plant world's own collision test
from bywire.host.behaviour.behaviour import Behaviour
from bywire.host.behaviour.context import BehaviourParams
from bywire.host.behaviour.situation import (
    BehaviourCommand,
    BlockedRoad,
    EdgeKey,
    EgoState,
    EStop,
    LaneRef,
    Situation,
    TrackedObject,
    match_objects,
)
from bywire.host.lateral import LateralParams, VehiclePose, kinematic_step, lateral_step
from bywire.host.longitudinal import LongitudinalParams, LongitudinalState, longitudinal_step
from bywire.host.roadnet.graph import RoadGraph, build_graph
from bywire.host.roadnet.ids import WaypointId
from bywire.host.roadnet.lane_index import LaneIndex
from bywire.host.roadnet.mdf import ResolvedMission, parse_mdf, resolve_mission
from bywire.host.roadnet.path import Path, concat
from bywire.host.roadnet.rndf import parse_rndf
from bywire.host.roadnet.route import MissionPlanner

W = WaypointId.parse
EGO_LENGTH_M = 4.77
EGO_WIDTH_M = 1.82
EGO_REAR_OVERHANG_M = 1.10
ACTUATOR_LAG_S = 0.3
NO_LANE = LaneRef((W("0.0.0"), W("0.0.0")), 0.0)  # marker: known to be on no lane


# ------------------------------------------------------------------------------------------- networks


@dataclass
class LaneSpec:
    points: list[tuple[float, float]]
    stops: tuple[int, ...] = ()  # waypoint numbers (1-based)
    checkpoints: dict[int, int] = field(default_factory=dict)  # waypoint number -> checkpoint number
    exits: tuple[tuple[int, str], ...] = ()  # (waypoint number, entry waypoint id)
    width_ft: int = 12


@dataclass
class ZoneSpec:
    perimeter: list[tuple[float, float]]
    exits: tuple[tuple[int, str], ...]  # (perimeter point number, entry waypoint id)
    spots: list[tuple[tuple[float, float], tuple[float, float], int]]  # (wp1, wp2, checkpoint)


def rndf_text(
    name: str, segments: dict[int, dict[int, LaneSpec]], zones: dict[int, ZoneSpec] | None = None
) -> str:
    zones = zones or {}
    out = [
        f"RNDF_name\t{name}",
        f"num_segments\t{len(segments)}",
        f"num_zones\t{len(zones)}",
        "format_version\t1.0",
    ]
    for sid, lanes in segments.items():
        out += [f"segment\t{sid}", f"num_lanes\t{len(lanes)}"]
        for lid, lane in lanes.items():
            out += [
                f"lane\t{sid}.{lid}",
                f"num_waypoints\t{len(lane.points)}",
                f"lane_width\t{lane.width_ft}",
            ]
            out += [f"checkpoint\t{sid}.{lid}.{w}\t{n}" for w, n in lane.checkpoints.items()]
            out += [f"stop\t{sid}.{lid}.{w}" for w in lane.stops]
            out += [f"exit\t{sid}.{lid}.{w}\t{entry}" for w, entry in lane.exits]
            out += [f"{sid}.{lid}.{i + 1}\t{x:g}\t{y:g}" for i, (x, y) in enumerate(lane.points)]
            out.append("end_lane")
        out.append("end_segment")
    for zid, zone in zones.items():
        out += [f"zone\t{zid}", f"num_spots\t{len(zone.spots)}", f"perimeter\t{zid}.0"]
        out.append(f"num_perimeterpoints\t{len(zone.perimeter)}")
        out += [f"exit\t{zid}.0.{p}\t{entry}" for p, entry in zone.exits]
        out += [f"{zid}.0.{i + 1}\t{x:g}\t{y:g}" for i, (x, y) in enumerate(zone.perimeter)]
        out.append("end_perimeter")
        for k, (p1, p2, cp) in enumerate(zone.spots, start=1):
            out += [f"spot\t{zid}.{k}", "spot_width\t10", f"checkpoint\t{zid}.{k}.2\t{cp}"]
            out += [f"{zid}.{k}.1\t{p1[0]:g}\t{p1[1]:g}", f"{zid}.{k}.2\t{p2[0]:g}\t{p2[1]:g}", "end_spot"]
        out.append("end_zone")
    out.append("end_file")
    return "\n".join(out) + "\n"


def mdf_text(rndf_name: str, checkpoints: Sequence[int], limits: dict[int, tuple[int, int]]) -> str:
    body = "\n".join(str(c) for c in checkpoints)
    lim = "\n".join(f"{k}\t{lo}\t{hi}" for k, (lo, hi) in limits.items())
    return (
        f"MDF_name\ttest_mdf\nRNDF\t{rndf_name}\ncheckpoints\nnum_checkpoints\t{len(checkpoints)}\n{body}\n"
        f"end_checkpoints\nspeed_limits\nnum_speed_limits\t{len(limits)}\n{lim}\nend_speed_limits\nend_file\n"
    )


@dataclass
class Network:
    graph: RoadGraph
    mission: ResolvedMission
    planner: MissionPlanner
    lane_index: LaneIndex


def network(rndf: str, checkpoints: Sequence[int], limits: dict[int, tuple[int, int]]) -> Network:
    net = parse_rndf(rndf, "test.rndf", coordinates="local_m")
    mission = resolve_mission(net, parse_mdf(mdf_text(net.name, checkpoints, limits), "test.mdf"))
    graph = build_graph(net, mission)
    return Network(graph, mission, MissionPlanner(graph, mission), LaneIndex(graph))


def cross_network(checkpoints: Sequence[int], stops: str = "all", mph: int = 25) -> Network:
    """Four two-lane arms of 150 m meeting at the origin, lanes 2 m either side of each centre line.

    Checkpoints: 1 = west arm's far end eastbound (1.1.1), 2 = east arm's far end (2.1.4), 3 = north
    arm's far end (4.1.4), 4 = south arm's far end (3.2.4), 5 = west arm's far end westbound (1.2.4),
    6 = east arm's start westbound (2.2.1), 7 = south arm's start northbound (3.1.1), 8 = north arm's
    start southbound (4.2.1). `stops`: "all" (a four-way stop), "ns" (stops on the north-south arms
    only: east-west is the priority road) or "none".
    """
    ns = stops in ("all", "ns")
    ew = stops == "all"
    segments = {
        1: {
            1: LaneSpec(
                [(-150, -2), (-100, -2), (-50, -2), (-8, -2)],
                (4,) if ew else (),
                {1: 1},
                ((4, "2.1.1"), (4, "4.1.1"), (4, "3.2.1")),
            ),
            2: LaneSpec([(-8, 2), (-50, 2), (-100, 2), (-150, 2)], (), {4: 5}),
        },
        2: {
            1: LaneSpec([(8, -2), (50, -2), (100, -2), (150, -2)], (), {4: 2}),
            2: LaneSpec(
                [(150, 2), (100, 2), (50, 2), (8, 2)],
                (4,) if ew else (),
                {1: 6},
                ((4, "1.2.1"), (4, "3.2.1"), (4, "4.1.1")),
            ),
        },
        3: {
            1: LaneSpec(
                [(2, -150), (2, -100), (2, -50), (2, -8)],
                (4,) if ns else (),
                {1: 7},
                ((4, "4.1.1"), (4, "1.2.1"), (4, "2.1.1")),
            ),
            2: LaneSpec([(-2, -8), (-2, -50), (-2, -100), (-2, -150)], (), {4: 4}),
        },
        4: {
            1: LaneSpec([(2, 8), (2, 50), (2, 100), (2, 150)], (), {4: 3}),
            2: LaneSpec(
                [(-2, 150), (-2, 100), (-2, 50), (-2, 8)],
                (4,) if ns else (),
                {1: 8},
                ((4, "3.2.1"), (4, "2.1.1"), (4, "1.2.1")),
            ),
        },
    }
    return network(rndf_text("cross", segments), checkpoints, {k: (0, mph) for k in segments})


def ring_network(checkpoints: Sequence[int] = (1, 2), mph: int = 25) -> Network:
    """A 200 m x 100 m block of two-lane roads (corners without stop signs) with a spur east from its
    north-east corner. Checkpoints: 1 = south road's west end eastbound (1.1.1, x=12), 2 = the spur's
    east end (5.1.3, x=300), 3 = south road's eastbound 1.1.5 (x=188)."""
    segments = {
        1: {  # south road, y = 0
            1: LaneSpec(
                [(12, -2), (60, -2), (100, -2), (140, -2), (188, -2)], (), {1: 1, 5: 3}, ((5, "2.1.1"),)
            ),
            2: LaneSpec([(188, 2), (140, 2), (100, 2), (60, 2), (12, 2)], (), {}, ((5, "4.2.1"),)),
        },
        2: {  # east road, x = 200
            1: LaneSpec([(202, 12), (202, 50), (202, 88)], (), {}, ((3, "3.1.1"), (3, "5.1.1"))),
            2: LaneSpec([(198, 88), (198, 50), (198, 12)], (), {}, ((3, "1.2.1"),)),
        },
        3: {  # north road, y = 100
            1: LaneSpec([(188, 102), (140, 102), (100, 102), (60, 102), (12, 102)], (), {}, ((5, "4.1.1"),)),
            2: LaneSpec(
                [(12, 98), (60, 98), (100, 98), (140, 98), (188, 98)], (), {}, ((5, "2.2.1"), (5, "5.1.1"))
            ),
        },
        4: {  # west road, x = 0
            1: LaneSpec([(-2, 88), (-2, 50), (-2, 12)], (), {}, ((3, "1.1.1"),)),
            2: LaneSpec([(2, 12), (2, 50), (2, 88)], (), {}, ((3, "3.2.1"),)),
        },
        5: {  # spur east from the north-east corner
            1: LaneSpec([(212, 98), (260, 98), (300, 98)], (), {3: 2}),
            2: LaneSpec([(300, 102), (260, 102), (212, 102)], (), {}, ((3, "3.1.1"), (3, "2.2.1"))),
        },
    }
    return network(rndf_text("ring", segments), checkpoints, {k: (0, mph) for k in segments})


def two_lane_network(checkpoints: Sequence[int] = (1, 2), mph: int = 25) -> Network:
    """Two eastbound lanes side by side, 1.1 at y = 0 and 1.2 at y = -3.66, 300 m long.
    Checkpoints: 1 = 1.1.1, 2 = 1.2.7 (the east end of the right lane), 3 = 1.1.7."""
    xs = [0, 50, 100, 150, 200, 250, 300]
    segments = {
        1: {
            1: LaneSpec([(x, 0.0) for x in xs], (), {1: 1, 7: 3}),
            2: LaneSpec([(x, -3.66) for x in xs], (), {7: 2}),
        }
    }
    return network(rndf_text("twolane", segments), checkpoints, {1: (0, mph)})


def zone_network(checkpoints: Sequence[int] = (1, 2, 3), mph: int = 20, zone_mph: int = 5) -> Network:
    """A lane east into a parking lot (zone 2) with one spot facing east, and a lane west out of it.
    Checkpoints: 1 = 1.1.1, 2 = the spot (2.1.2), 3 = the exit lane's west end (3.1.3)."""
    segments = {
        1: {1: LaneSpec([(0, 0), (50, 0), (100, 0)], (), {1: 1}, ((3, "2.0.1"),))},
        3: {1: LaneSpec([(100, 30), (50, 30), (0, 30)], (), {3: 3})},
    }
    zones = {
        2: ZoneSpec(
            perimeter=[(110, 0), (110, -20), (170, -20), (170, 40), (110, 40), (110, 30)],
            exits=((6, "3.1.1"),),
            spots=[((140, 0), (145.5, 0), 2)],
        )
    }
    return network(
        rndf_text("lot", segments, zones), checkpoints, {1: (0, mph), 2: (0, zone_mph), 3: (0, mph)}
    )


def lane_path(graph: RoadGraph, waypoints: Sequence[str]) -> Path:
    """The path through consecutive vertices (each pair must be an edge of the graph)."""
    ids = [W(w) for w in waypoints]
    return concat(graph.edge(a, b).path for a, b in itertools.pairwise(ids))


def edge_spans(graph: RoadGraph, waypoints: Sequence[str]) -> list[tuple[EdgeKey, float, float]]:
    """(edge key, start s, end s) of each edge along `lane_path(graph, waypoints)`."""
    ids = [W(w) for w in waypoints]
    out, s = [], 0.0
    for a, b in itertools.pairwise(ids):
        length = graph.edge(a, b).length_m
        out.append(((a, b), s, s + length))
        s += length
    return out


# ------------------------------------------------------------------------------------------- traffic


SpeedProfile = Callable[[float, float], float]  # (t, s) -> target speed


@dataclass
class ScriptedCar:
    """A car on a fixed path: it accelerates (1.5 m/s²) or brakes (3 m/s²) toward `target(t, s)`."""

    object_id: str
    path: Path
    s_m: float
    target: SpeedProfile
    speed_mps: float = 0.0
    length_m: float = 4.5
    width_m: float = 1.8
    # the graph edges its path runs along, for its lane match (the world model's LaneIndex.match,
    # known exactly here); None: match it with the LaneIndex
    spans: list[tuple[EdgeKey, float, float]] | None = None
    appears_at_s: float = 0.0  # seen (and there) from this time on: a box set down in the car's way

    def step(self, t_s: float, dt_s: float) -> None:
        want = max(self.target(t_s, self.s_m), 0.0)
        dv = want - self.speed_mps
        self.speed_mps += min(max(dv, -3.0 * dt_s), 1.5 * dt_s)
        self.s_m += self.speed_mps * dt_s

    def tracked(self) -> TrackedObject:
        p = self.path.point_at(self.s_m)
        ahead = self.s_m - self.path.length_m
        x, y = p.x_m, p.y_m
        if ahead > 0.0:  # past the path's end: straight on
            x += ahead * math.cos(p.heading_rad)
            y += ahead * math.sin(p.heading_rad)
        lane = None
        if self.spans is not None:
            for key, s0, s1 in self.spans:
                if s0 <= self.s_m <= s1:
                    lane = LaneRef(key, self.s_m - s0)
                    break
            else:
                lane = NO_LANE
        return TrackedObject(
            self.object_id, x, y, p.heading_rad, self.speed_mps, self.length_m, self.width_m, lane
        )


def car_on(
    graph: RoadGraph,
    object_id: str,
    waypoints: Sequence[str],
    s_m: float,
    target: SpeedProfile,
    speed_mps: float = 0.0,
) -> ScriptedCar:
    """A car along the lanes/exits through `waypoints`, `s_m` along them, with its lane match."""
    return ScriptedCar(
        object_id, lane_path(graph, waypoints), s_m, target, speed_mps, spans=edge_spans(graph, waypoints)
    )


def parked(
    object_id: str, x: float, y: float, heading: float, length: float = 4.5, width: float = 1.8
) -> ScriptedCar:
    path = Path([x, x + math.cos(heading)], [y, y + math.sin(heading)], [heading, heading], [0.0, 0.0])
    return ScriptedCar(object_id, path, 0.0, lambda t, s: 0.0, 0.0, length, width)


def constant(v: float) -> SpeedProfile:
    return lambda t, s: v


def depart_at(t_go: float, v: float = 5.0) -> SpeedProfile:
    return lambda t, s: v if t >= t_go else 0.0


# ------------------------------------------------------------------------------------------- the ego


def _box(x: float, y: float, h: float, length: float, width: float, centre_ahead: float) -> np.ndarray:
    c, s = math.cos(h), math.sin(h)
    cx, cy = x + centre_ahead * c, y + centre_ahead * s
    hl, hw = 0.5 * length, 0.5 * width
    return np.array(
        [
            [cx + a * hl * c - b * hw * s, cy + a * hl * s + b * hw * c]
            for a, b in ((1, 1), (1, -1), (-1, -1), (-1, 1))
        ]
    )


@dataclass
class Frame:
    t_s: float
    state: str
    x_m: float
    y_m: float
    heading_rad: float
    speed_mps: float  # signed
    command: BehaviourCommand
    min_gap_m: float  # smallest centre distance to any car minus both half lengths (rough)


def corners(f: Frame, params: BehaviourParams | None = None) -> np.ndarray:
    """The 4 corners (4, 2) of our car's outline at frame `f` (rear-axle pose, the behaviour's size)."""
    p = params or BehaviourParams()
    d = p.rear_axle_to_front_m - 0.5 * p.vehicle_length_m  # rear axle to the outline's centre
    c, s = math.cos(f.heading_rad), math.sin(f.heading_rad)
    return box(f.x_m + d * c, f.y_m + d * s, f.heading_rad, p.vehicle_length_m, p.vehicle_width_m)


class Sim:
    """The closed loop (see the module docstring). `run_until` steps until a predicate or a time limit."""

    def __init__(
        self,
        net: Network,
        *,
        start: tuple[float, float, float] | None = None,
        cars: Sequence[ScriptedCar] = (),
        dt_s: float = 0.05,
        behaviour: Behaviour | None = None,
        params: BehaviourParams | None = None,
        estop: Callable[[float], EStop] | None = None,
        blocked: Callable[[float], tuple[BlockedRoad, ...]] | None = None,
        speed0_mps: float = 0.0,
    ) -> None:
        self.net = net
        self.behaviour = behaviour or Behaviour(net.planner, params=params, lane_index=net.lane_index)
        if start is None:
            view = self.behaviour.route_view
            x, y, h = view.point_at(0.0)
            start = (x, y, h)
        self.pose = VehiclePose(*start)
        self.speed = speed0_mps  # magnitude
        self.gear = 1
        self.accel = 0.0
        self.cars = list(cars)
        self.dt = dt_s
        self.t = 0.0
        self.estop = estop
        self.blocked = blocked
        self.lat_params = LateralParams()
        self.lon_params = LongitudinalParams()
        self.lon_state = LongitudinalState()
        self.frames: list[Frame] = []
        self.collisions: list[tuple[float, str]] = []
        self.faults: list[str] = []
        self._matched: dict[tuple[object, ...], TrackedObject] = {}

    @property
    def front_xy(self) -> tuple[float, float]:
        d = EGO_LENGTH_M - EGO_REAR_OVERHANG_M
        return self.pose.x_m + d * math.cos(self.pose.heading_rad), self.pose.y_m + d * math.sin(
            self.pose.heading_rad
        )

    def situation(self) -> Situation:
        tracked = [c.tracked() for c in self.cars if self.t >= c.appears_at_s]
        # off its spans a scripted car has no lane; cars without spans are matched like the world model
        # (a standing car's match is kept: the same pose gives the same match)
        by_id: dict[str, TrackedObject] = {}
        for o in tracked:
            if o.lane is not None:
                continue
            key = (o.object_id, round(o.x_m, 3), round(o.y_m, 3), round(o.heading_rad, 4))
            if key not in self._matched:
                self._matched[key] = match_objects(self.net.lane_index, [o])[0]
            by_id[o.object_id] = replace(o, lane=self._matched[key].lane)
        objects = tuple(
            replace(o, lane=None) if o.lane is NO_LANE else by_id.get(o.object_id, o) for o in tracked
        )
        return Situation(
            t_s=self.t,
            ego=EgoState(
                self.pose.x_m, self.pose.y_m, self.pose.heading_rad, self.gear * self.speed, self.accel
            ),
            objects=objects,
            blocked=self.blocked(self.t) if self.blocked else (),
            estop=self.estop(self.t) if self.estop else EStop.RUN,
        )

    def step(self) -> Frame:
        sit = self.situation()
        cmd = self.behaviour.step(sit)
        if cmd.fault:
            self.faults.append(f"{self.t:.2f}: {cmd.fault}")
        path = cmd.path_samples()
        steer = lateral_step(path, self.pose, cmd.direction, self.lat_params).steer_rad
        self.lon_state, a_cmd, _ = longitudinal_step(
            self.lon_state, cmd.longitudinal_inputs(self.speed), self.lon_params
        )
        if cmd.direction != self.gear:
            a_cmd = -3.0  # stop before changing gear
            if self.speed < 0.05:
                self.gear = cmd.direction
                self.speed = 0.0
        if sit.estop != EStop.RUN:
            a_cmd = -4.5  # the ECU's E-stop brake
        self.accel += (a_cmd - self.accel) * min(self.dt / ACTUATOR_LAG_S, 1.0)
        self.speed = max(self.speed + self.accel * self.dt, 0.0)
        if self.speed == 0.0 and self.accel < 0.0:
            self.accel = 0.0
        self.pose = kinematic_step(
            self.pose, self.gear * self.speed, steer, self.dt, self.lat_params.wheelbase_m
        )
        for car in self.cars:
            car.step(self.t, self.dt)
        gap = self._check_collisions(sit)
        frame = Frame(
            sit.t_s, cmd.state, sit.ego.x_m, sit.ego.y_m, sit.ego.heading_rad, sit.ego.speed_mps, cmd, gap
        )
        self.frames.append(frame)
        self.t = round(self.t + self.dt, 9)
        return frame

    def _check_collisions(self, sit: Situation) -> float:
        ego_box = _box(
            self.pose.x_m,
            self.pose.y_m,
            self.pose.heading_rad,
            EGO_LENGTH_M,
            EGO_WIDTH_M,
            0.5 * EGO_LENGTH_M - EGO_REAR_OVERHANG_M,
        )
        best = math.inf
        cx = self.pose.x_m + (0.5 * EGO_LENGTH_M - EGO_REAR_OVERHANG_M) * math.cos(self.pose.heading_rad)
        cy = self.pose.y_m + (0.5 * EGO_LENGTH_M - EGO_REAR_OVERHANG_M) * math.sin(self.pose.heading_rad)
        for obj in sit.objects:
            box = _box(obj.x_m, obj.y_m, obj.heading_rad, obj.length_m, obj.width_m, 0.0)
            if boxes_overlap(ego_box, box):
                self.collisions.append((self.t, obj.object_id))
            best = min(best, math.hypot(obj.x_m - cx, obj.y_m - cy) - 0.5 * (EGO_LENGTH_M + obj.length_m))
        return best

    def run_until(self, done: Callable[[Sim], bool], max_t_s: float) -> bool:
        """Step until `done(self)` (True) or `max_t_s` of simulated time (False)."""
        while self.t < max_t_s:
            self.step()
            if done(self):
                return True
        return False

    # ----------------------------------------------------------------------------------- reading

    def states(self) -> list[str]:
        """The sequence of distinct consecutive state paths."""
        out: list[str] = []
        for f in self.frames:
            if not out or out[-1] != f.state:
                out.append(f.state)
        return out

    def leaves(self) -> list[str]:
        return [s.rsplit("/", 1)[-1] for s in self.states()]

    def first_time(self, leaf: str, after: float = -math.inf) -> float | None:
        """When the leaf state `leaf` was first active (at or after `after`), None if never."""
        for f in self.frames:
            if f.t_s >= after and f.state.rsplit("/", 1)[-1] == leaf:
                return f.t_s
        return None

    @property
    def state(self) -> str:
        return self.frames[-1].state if self.frames else ""


# ------------------------------------------------------------------------------------------- scripted runs


class Script:
    """Scripted situations (no physics): the ego is placed where the test says, objects as the test says."""

    def __init__(self, net: Network, params: BehaviourParams | None = None) -> None:
        self.net = net
        self.behaviour = Behaviour(net.planner, params=params, lane_index=net.lane_index)
        self.view = self.behaviour.route_view
        self.commands: list[BehaviourCommand] = []

    def ego_at(self, s_m: float, speed_mps: float = 0.0) -> EgoState:
        """The rear axle on the *first* route at arc length `s_m`, heading along it (a replan does not
        move the scripted ego)."""
        x, y, h = self.view.point_at(s_m)
        return EgoState(x, y, h, speed_mps)

    def step(
        self,
        t_s: float,
        ego: EgoState,
        objects: Sequence[TrackedObject] = (),
        estop: EStop = EStop.RUN,
        blocked: Sequence[BlockedRoad] = (),
    ) -> BehaviourCommand:
        cmd = self.behaviour.step(Situation(t_s, ego, tuple(objects), tuple(blocked), estop))
        self.commands.append(cmd)
        return cmd

    def first(self, leaf: str) -> BehaviourCommand | None:
        for c in self.commands:
            if c.state.rsplit("/", 1)[-1] == leaf:
                return c
        return None

    def leaves(self) -> list[str]:
        out: list[str] = []
        for c in self.commands:
            leaf = c.state.rsplit("/", 1)[-1]
            if not out or out[-1] != leaf:
                out.append(leaf)
        return out


def at_stop_line(
    graph: RoadGraph,
    line: str,
    object_id: str,
    t_s: float,
    depart_s: float | None = None,
    speed_mps: float = 5.0,
) -> TrackedObject:
    """A car standing with its front 0.3 m before stop line `line`, from `depart_s` on driving straight
    across the intersection at `speed_mps` (as a tracker would report it: no lane match)."""
    pose = graph.vertex_pose(W(line))
    assert pose is not None
    c, s = math.cos(pose.heading_rad), math.sin(pose.heading_rad)
    back = 0.5 * 4.5 + 0.3
    moved = 0.0 if depart_s is None or t_s < depart_s else (t_s - depart_s) * speed_mps
    v = 0.0 if depart_s is None or t_s < depart_s else speed_mps
    return TrackedObject(
        object_id, pose.x_m + (moved - back) * c, pose.y_m + (moved - back) * s, pose.heading_rad, v, 4.5, 1.8
    )
