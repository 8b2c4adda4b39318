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
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from . import reeds_shepp
from .cspace import CSpace

__all__ = ["HeuristicField", "free_space_distance"]

# The largest ratio of the 8-connected grid distance to the Euclidean one: cos t + (sqrt 2 - 1) sin t,
# largest at t = 22.5 deg.
OCTILE_EXCESS = math.sqrt(4.0 - 2.0 * math.sqrt(2.0))  # 1.0824


def free_space_distance(free: np.ndarray, goal_cell: tuple[int, int], res_m: float) -> np.ndarray:
    """Metres from every cell to `goal_cell` through the `free` cells, 8-connected (inf: unreachable)."""
    rows, cols = free.shape
    idx = np.arange(rows * cols).reshape(rows, cols)
    src: list[np.ndarray] = []
    dst: list[np.ndarray] = []
    wts: list[np.ndarray] = []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        r0, r1 = max(0, -dr), rows - max(0, dr)
        c0, c1 = max(0, -dc), cols - max(0, dc)
        a = free[r0:r1, c0:c1] & free[r0 + dr : r1 + dr, c0 + dc : c1 + dc]
        if dr and dc:  # no corner cutting between two blocked cells
            a &= free[r0 + dr : r1 + dr, c0:c1] | free[r0:r1, c0 + dc : c1 + dc]
        i = idx[r0:r1, c0:c1][a]
        j = idx[r0 + dr : r1 + dr, c0 + dc : c1 + dc][a]
        w = res_m * (math.sqrt(2.0) if dr and dc else 1.0)
        src += [i, j]
        dst += [j, i]
        wts += [np.full(i.size, w), np.full(i.size, w)]
    n = rows * cols
    graph = coo_matrix(
        (np.concatenate(wts), (np.concatenate(src), np.concatenate(dst))), shape=(n, n)
    ).tocsr()
    goal = int(idx[goal_cell])
    dist = dijkstra(graph, directed=False, indices=goal)
    out = np.asarray(dist, dtype=float).reshape(rows, cols)
    if not free[goal_cell]:
        out[:] = np.inf
        out[goal_cell] = 0.0
    return out


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
