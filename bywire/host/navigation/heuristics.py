"""The search's two costs-to-go, combined by their maximum (seed 000 Sec. 10.3).

1. Kinematic (Sec. 10.3.1): the shortest Reeds-Shepp path to the goal, ignoring obstacles
   (`reeds_shepp`). The paper used the RTR metric for its simplicity; Reeds-Shepp is the exact
   obstacle-free optimum of a car that may reverse, so it is the tightest kinematic lower bound there
   is. Far from the goal it is replaced by the straight-line distance (a weaker bound that costs
   nothing); `HeuristicField.kinematic` switches to the full metric within `rs_range_m`.
2. Obstacles (Sec. 10.3.2): the shortest distance to the goal through the orientation-invariant free
   space (`CSpace.disk_free`), by Dijkstra from the goal over the grid's 8-connected cells. It knows
   the free space's topology (no dead ends), which is what the paper wanted of its Voronoi cost. The
   paper's Voronoi cost itself (the graph distance from the point matched on the Voronoi lines, sloped
   toward them) is *not* admissible: round a corner, the Voronoi line runs down the middle of the free
   space and is longer than the shortest way hugging the corner, by up to half the corridor width per
   bend. We keep its topology and drop its overestimate: the grid distance is divided by the 8-connected
   metric's worst excess over the Euclidean (1.0824, at 22.5 deg) and has two cell diagonals taken off
   (start and goal anywhere in their cells). Without that correction the property test finds maps where
   the raw grid distance exceeds the search's own optimum; with it, none.

Both are lower bounds on the length of any collision-free path; the search's costs are lengths
weighted by factors >= 1, so A* with their maximum finds the least-cost path of its graph. The property
tests check both against the search's own optimal costs on random small maps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from . import reeds_shepp
from .cspace import CSpace

__all__ = ["HeuristicField", "free_space_distance"]

# The largest ratio of the 8-connected grid distance to the Euclidean one: cos t + (sqrt 2 - 1) sin t,
# largest at t = 22.5 deg.
OCTILE_EXCESS = math.sqrt(4.0 - 2.0 * math.sqrt(2.0))  # 1.0824


def free_space_distance(free: np.ndarray, goal_cell: tuple[int, int], res_m: float) -> np.ndarray:
    """Metres from every cell to `goal_cell` through the `free` cells, 8-connected, no corner cut
    between two blocked cells (inf: unreachable). Compiled, on the grid itself: the sparse graph
    scipy's Dijkstra needs took ~10 ms to build on a 250 x 250 map, more than the search.

    The result is scipy's to the last bit, whatever the order the cells are settled in: with positive
    steps, the distances are the one solution of "a cell's distance is the least of its neighbours'
    plus the step between them, each sum rounded" (take the least cell where two solutions differ:
    the neighbour it comes from is less and agrees), which any search that re-settles a cell whenever
    it improves reaches. So a bucket queue (Dial's) one step wide does it, at a few tens of
    nanoseconds a cell; test_search_kernel holds it equal to scipy's."""
    out = _grid_distance(
        np.ascontiguousarray(free, dtype=np.bool_), int(goal_cell[0]), int(goal_cell[1]), float(res_m),
        float(res_m * math.sqrt(2.0)),
    )  # fmt: skip
    if not free[goal_cell]:
        out[:] = np.inf
        out[goal_cell] = 0.0
    return out


_BUCKETS = 4  # a step is at most sqrt 2 buckets wide: a relaxed cell lands at most 3 buckets on


@njit(cache=True, nogil=True)
def _grid_distance(
    free: np.ndarray, goal_r: int, goal_c: int, step_m: float, diagonal_m: float
) -> np.ndarray:
    rows, cols = free.shape
    dist = np.full(rows * cols, np.inf)
    settled = np.full(rows * cols, np.inf)  # the distance a cell's neighbours were last relaxed from
    cap = max(64, rows * cols // 8)
    buckets = np.empty((_BUCKETS, cap), dtype=np.int64)  # cells, bucket b of distance [b, b + 1) steps
    count = np.zeros(_BUCKETS, dtype=np.int64)
    goal = goal_r * cols + goal_c
    dist[goal] = 0.0
    buckets[0, 0] = goal
    count[0] = 1
    pending = 1
    current = 0
    while pending > 0:
        slot = current % _BUCKETS
        while count[slot] > 0:
            count[slot] -= 1
            pending -= 1
            cell = buckets[slot, count[slot]]
            d = dist[cell]
            if d == settled[cell]:
                continue  # already relaxed from this distance
            settled[cell] = d
            r, c0 = cell // cols, cell % cols
            if not free[r, c0]:
                continue
            for dr in range(-1, 2):
                for dc in range(-1, 2):
                    if dr == 0 and dc == 0:
                        continue
                    r2, c2 = r + dr, c0 + dc
                    if r2 < 0 or r2 >= rows or c2 < 0 or c2 >= cols or not free[r2, c2]:
                        continue
                    if dr != 0 and dc != 0:
                        if not (free[r + dr, c0] or free[r, c0 + dc]):
                            continue
                        nd = d + diagonal_m
                    else:
                        nd = d + step_m
                    cell2 = r2 * cols + c2
                    if nd < dist[cell2]:
                        dist[cell2] = nd
                        # never behind the bucket being emptied (rounding of nd / step at an edge)
                        b = max(int(nd / step_m), current)
                        b = min(b, current + _BUCKETS - 1)
                        s2 = b % _BUCKETS
                        if count[s2] == buckets.shape[1]:
                            grown = np.empty((_BUCKETS, 2 * buckets.shape[1]), dtype=np.int64)
                            grown[:, : buckets.shape[1]] = buckets
                            buckets = grown
                        buckets[s2, count[s2]] = cell2
                        count[s2] += 1
                        pending += 1
        current += 1
    return dist.reshape(rows, cols)


@dataclass
class HeuristicField:
    """Cost-to-go to one goal on one configuration space."""

    cspace: CSpace
    goal: tuple[float, float, float]  # x_m, y_m, heading_rad
    turn_radius_m: float
    rs_range_m: float = 20.0  # the full Reeds-Shepp metric within this straight-line distance

    def __post_init__(self) -> None:
        grid = self.cspace.grid
        row, col = grid.cell_of(self.goal[0], self.goal[1])
        r, c = int(row), int(col)
        if not (0 <= r < grid.shape[0] and 0 <= c < grid.shape[1]):
            raise ValueError(f"HeuristicField: the goal {self.goal[:2]} is outside the map")
        free = self.cspace.disk_free.copy()
        free[r, c] = True  # the goal's own cell (the search checks the goal pose itself)
        raw = free_space_distance(free, (r, c), grid.resolution_m)
        slack = 2.0 * grid.resolution_m * math.sqrt(2.0)
        self.obstacle_m = np.maximum(raw / OCTILE_EXCESS - slack, 0.0)

    def obstacle(self, x_m: np.ndarray | float, y_m: np.ndarray | float) -> np.ndarray:
        """The obstacle-aware lower bound at positions (inf where the goal cannot be reached from)."""
        grid = self.cspace.grid
        row, col = grid.cell_of(x_m, y_m)
        ok = grid.inside(row, col)
        out = np.full(np.shape(row), np.inf)
        out[ok] = self.obstacle_m[row[ok], col[ok]]
        return out

    def kinematic(self, pose: tuple[float, float, float]) -> float:
        """The Reeds-Shepp length near the goal, the straight-line distance beyond `rs_range_m`."""
        d = math.hypot(pose[0] - self.goal[0], pose[1] - self.goal[1])
        if d > self.rs_range_m:
            return d
        return reeds_shepp.shortest_length(pose, self.goal, self.turn_radius_m)

    def value(self, pose: tuple[float, float, float]) -> float:
        return max(float(self.obstacle(pose[0], pose[1])), self.kinematic(pose))
