"""Mission planning: the fastest route through all MDF checkpoints in order (seed 000 sec. 8, Fig. 10c).

"It finds the optimal route from one checkpoint to another using an optimal graph search algorithm
operating on the geometric graph representation of the road network. The criterion that is minimized by
the search process is travel time. The search process is repeated for every pair of subsequent
checkpoints in the MDF. [...] Generally the mission planner runs only once while loading the mission file
and whenever AnnieWAY has to diverge from the planned route for situation-dependent reasons (e.g., blocked
roads)."

Search: A* on the `RoadGraph` (networkx), one leg per checkpoint.  Legs are independent: the state of the
search is the vertex alone, so the concatenation of the fastest legs is the fastest mission.

Travel time of an edge (`MissionPlanner.edge_time_s`): the integral of ds / v over its path, with v the
edge's MDF maximum speed (`RouteCosts.default_speed_mps` where the MDF gives none) capped by the speed at
which the path's curvature gives `RouteCosts.lateral_accel_mps2` of lateral acceleration, v = sqrt(a / |k|)
(deviation: the paper names only "travel time"; without the cap a tight exit would cost as much as a
straight one).  Penalties, in seconds, for what takes time beyond driving (or is to be avoided): a lane
change, a U-turn the RNDF asks for (dead end), a K-turn it does not (derived UTURN edges: for replanning
around a blocked road, hence a high cost), a full stop at a stop line.

Heuristic: straight-line distance to the leg's goal over the fastest speed of any edge.  Admissible and
consistent: an edge's path is never shorter than the chord between its vertices, its speed never above
that maximum, and penalties are >= 0.

Blockades (`RoadGraph.block_edge`) are skipped.  When a checkpoint cannot be reached with them, the planner
forgets all of them (`RoadGraph.unblock_all`) and searches again, as the AnnieWAY planner did rather than
fail; `Route.blockades_forgotten` says it happened.  A checkpoint that stays unreachable is reported with
``reached=False`` and the next leg starts from where the previous one ended.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property

import networkx as nx
import numpy as np

from .graph import Edge, EdgeKind, RoadGraph
from .ids import WaypointId
from .lane_index import LaneIndex
from .mdf import ResolvedMission
from .path import Path, concat
from .rndf import MPH_TO_MPS

# Edges that are not driven along a lane: zone navigation (sec. 10) or a K-turn plans the real motion.
MANOEUVRES = frozenset({EdgeKind.ZONE, EdgeKind.PARK, EdgeKind.UNPARK, EdgeKind.UTURN})


@dataclass(frozen=True)
class RouteCosts:
    # 30 mph, the Urban Challenge's top speed (rules sec. 1.5), where the MDF gives no maximum.
    default_speed_mps: float = 30.0 * MPH_TO_MPS
    # Comfortable lateral acceleration: the speed cap in curves (2 m/s^2 is what a passenger accepts).
    lateral_accel_mps2: float = 2.0
    # Indicate, check the gap, move over: a few seconds (and a risk the planner should not take lightly).
    lane_change_penalty_s: float = 5.0
    # A U-turn the RNDF asks for (an exit into the opposite lane at a dead end): a K-turn on a 30 ft
    # street (rules: a series of 3-point turns) takes half a minute.
    uturn_penalty_s: float = 30.0
    # A K-turn the RNDF does not ask for (a derived UTURN edge) is for getting around a blocked road: the
    # rules allow no U-turn in the middle of a road otherwise. Five minutes: taken only when the way
    # around is that much longer, or there is none.
    kturn_penalty_s: float = 300.0
    # Brake to a standstill, wait for precedence, start again.
    stop_penalty_s: float = 5.0


@dataclass(frozen=True)
class Leg:
    """The way to one mission checkpoint: `edges` from the previous leg's end to `target`."""

    index: int  # position of the checkpoint in the mission (0-based)
    checkpoint: int  # checkpoint number
    target: WaypointId
    edges: tuple[Edge, ...]
    reached: bool
    length_m: float
    time_s: float


@dataclass(frozen=True)
class Route:
    start: WaypointId
    legs: tuple[Leg, ...]
    blockades_forgotten: bool = False
    forgotten_blockades: int = 0
    start_xy: tuple[float, float] = field(default=(0.0, 0.0), compare=False)

    @property
    def edges(self) -> tuple[Edge, ...]:
        return tuple(e for leg in self.legs for e in leg.edges)

    @property
    def vertices(self) -> tuple[WaypointId, ...]:
        return (self.start, *(e.end for e in self.edges))

    @property
    def length_m(self) -> float:
        return sum(leg.length_m for leg in self.legs)

    @property
    def time_s(self) -> float:
        return sum(leg.time_s for leg in self.legs)

    @property
    def checkpoints(self) -> tuple[int, ...]:
        return tuple(leg.checkpoint for leg in self.legs)

    @property
    def reached(self) -> tuple[bool, ...]:
        return tuple(leg.reached for leg in self.legs)

    @property
    def reached_all(self) -> bool:
        return all(self.reached)

    def drive_pieces(self) -> list[tuple[Edge, ...]]:
        """The route cut where the car stops driving along lanes: before and after every zone, parking
        and K-turn edge (each of those is a piece of its own). Within a lane piece heading and curvature
        are continuous; the manoeuvre pieces are for zone navigation and K-turn planning."""
        pieces: list[tuple[Edge, ...]] = []
        current: list[Edge] = []
        for e in self.edges:
            if e.kind in MANOEUVRES:
                if current:
                    pieces.append(tuple(current))
                    current = []
                pieces.append((e,))
            else:
                current.append(e)
        if current:
            pieces.append(tuple(current))
        return pieces

    @cached_property
    def path(self) -> Path:
        """The whole route as one path (Fig. 10c); a single point when the route has no edges.

        Continuous in position everywhere; heading and curvature are continuous within every lane piece of
        `drive_pieces` (where zone, parking and K-turn edges begin or end they need not be: the car
        stops, reverses, or leaves the road network there)."""
        edges = self.edges
        if not edges:
            return Path.point(self.start_xy[0], self.start_xy[1], 0.0)
        return edges[0].path if len(edges) == 1 else concat(e.path for e in edges)


class MissionPlanner:
    """Plans and re-plans routes through a mission's checkpoints on one `RoadGraph`."""

    def __init__(
        self,
        graph: RoadGraph,
        mission: ResolvedMission | Sequence[WaypointId],
        costs: RouteCosts | None = None,
        checkpoint_numbers: Sequence[int] | None = None,
    ) -> None:
        self.graph = graph
        self.costs = costs or RouteCosts()
        if isinstance(mission, ResolvedMission):
            self.targets = tuple(mission.waypoints)
            numbers: Sequence[int] = mission.checkpoint_numbers
        else:
            self.targets = tuple(mission)
            numbers = checkpoint_numbers or [graph.checkpoint_at(w) or 0 for w in self.targets]
        if len(numbers) != len(self.targets):
            raise ValueError("one checkpoint number per target waypoint")
        self.numbers = tuple(numbers)
        for w in self.targets:
            if w not in graph.digraph:
                raise ValueError(f"checkpoint waypoint {w} is not a vertex of the graph")
        self._time: dict[int, float] = {}
        self._vmax = max(
            [self.costs.default_speed_mps]
            + [e.speed_max_mps for e in graph.edges() if e.speed_max_mps is not None]
        )

    # -- costs

    def edge_time_s(self, edge: Edge) -> float:
        """Travel time of `edge` with its penalties (cached; speed limits are read once per edge)."""
        key = id(edge)
        cached = self._time.get(key)
        if cached is not None:
            return cached
        c = self.costs
        v_limit = edge.speed_max_mps or c.default_speed_mps
        path = edge.path
        if len(path) > 1:
            ds = np.diff(path.s_m)
            k = np.maximum(np.abs(path.curvature_1pm[:-1]), np.abs(path.curvature_1pm[1:]))
            with np.errstate(divide="ignore"):
                v = np.minimum(v_limit, np.sqrt(c.lateral_accel_mps2 / np.maximum(k, 1e-12)))
            t = float(np.sum(ds / v))
        else:
            t = 0.0
        if edge.kind == EdgeKind.LANE_CHANGE:
            t += c.lane_change_penalty_s
        elif edge.kind == EdgeKind.UTURN:
            t += c.uturn_penalty_s if edge.from_rndf else c.kturn_penalty_s
        if edge.stop_at_end:
            t += c.stop_penalty_s
        self._time[key] = t
        return t

    def reset_costs(self) -> None:
        """Forget cached edge times (after `RoadGraph.apply_speed_limits` changed the limits)."""
        self._time.clear()
        self._vmax = max(
            [self.costs.default_speed_mps]
            + [e.speed_max_mps for e in self.graph.edges() if e.speed_max_mps is not None]
        )

    # -- search

    def _weight(self, u: WaypointId, v: WaypointId, data: dict[str, Edge]) -> float | None:
        edge = data["edge"]
        return None if edge.blocked else self.edge_time_s(edge)

    def shortest(self, start: WaypointId, goal: WaypointId) -> tuple[Edge, ...] | None:
        """Fastest edges from `start` to `goal` avoiding blocked edges, or None if there is no way."""
        if start == goal:
            return ()
        gx, gy = self.graph.vertex_xy(goal)
        vmax = self._vmax

        def heuristic(a: WaypointId, _b: WaypointId) -> float:
            ax, ay = self.graph.vertex_xy(a)
            return math.hypot(ax - gx, ay - gy) / vmax

        try:
            nodes = nx.astar_path(self.graph.digraph, start, goal, heuristic=heuristic, weight=self._weight)
        except nx.NetworkXNoPath:
            return None
        return tuple(self.graph.edge(a, b) for a, b in itertools.pairwise(nodes))

    def plan(self, start: WaypointId | None = None, first_checkpoint: int = 0) -> Route:
        """Route from `start` (default: the first checkpoint's waypoint) through the checkpoints
        `first_checkpoint`, `first_checkpoint + 1`, ... of the mission."""
        if not 0 <= first_checkpoint <= len(self.targets):
            raise ValueError(f"first_checkpoint {first_checkpoint} outside 0..{len(self.targets)}")
        if start is None:
            if not self.targets:
                raise ValueError("a mission without checkpoints needs an explicit start")
            start = (
                self.targets[first_checkpoint] if first_checkpoint < len(self.targets) else self.targets[-1]
            )
        if start not in self.graph.digraph:
            raise ValueError(f"start {start} is not a vertex of the graph")
        forgotten = 0
        legs: list[Leg] = []
        here = start
        for i in range(first_checkpoint, len(self.targets)):
            goal = self.targets[i]
            edges = self.shortest(here, goal)
            if edges is None and any(e.blocked for e in self.graph.edges()):
                forgotten += self.graph.unblock_all()
                edges = self.shortest(here, goal)
            if edges is None:
                legs.append(Leg(i, self.numbers[i], goal, (), False, 0.0, 0.0))
                continue
            legs.append(
                Leg(
                    i,
                    self.numbers[i],
                    goal,
                    edges,
                    True,
                    sum(e.length_m for e in edges),
                    sum(self.edge_time_s(e) for e in edges),
                )
            )
            here = goal
        return Route(start, tuple(legs), forgotten > 0, forgotten, self.graph.vertex_xy(start))

    def replan(self, current: WaypointId, next_checkpoint: int) -> Route:
        """Plan again from vertex `current` (e.g. after `RoadGraph.block_edge`) for the checkpoints left."""
        return self.plan(current, next_checkpoint)

    def replan_from_pose(
        self, index: LaneIndex, x_m: float, y_m: float, heading_rad: float, next_checkpoint: int
    ) -> Route:
        """Plan again from where the car is: the vertex ahead on its lane, or - if that edge is blocked -
        the vertex behind it (the blockade is between the car and the vertex ahead; turning around is
        planned from the last waypoint passed). ValueError when the car is on no lane."""
        found = index.match(x_m, y_m, heading_rad)
        if found is None:
            raise ValueError(f"({x_m:.1f}, {y_m:.1f}) is on no lane of the network; use zone navigation")
        edge = found.edge
        return self.plan(edge.start if edge.blocked else edge.end, next_checkpoint)
