"""Reference problems for the zone planner: the geometry other planners are measured on, rebuilt here.

- `autoware_lot`: Autoware's freespace-planner test (`test_freespace_planning_algorithms.cpp` of
  autoware_universe, Apache-2.0; the geometry re-stated, no code taken): 150 x 150 cells of 0.2 m, a
  2 m border wall, a wall 8-28 m x 9-9.5 m, four parked cars 2.75 m x 5.5 m, start (5.5, 4.0, pi/2) and
  the four goals from "easiest" to "most difficult", for their car (a Lexus 5.5 m x 2.75 m, wheelbase
  3.0 m, 1.5 m rear axle to rear bumper, 0.7 rad of steer). Cells are filled where Autoware's are
  (a cell whose lower-left corner is inside an obstacle's open rectangle).
- `maze_zone`: ours, seed 000 Fig. 19(a)'s kind of case: a 50 m x 50 m zone of staggered walls where a
  heuristic that ignores obstacles leads the search into dead ends, for the Passat.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .cspace import PASSAT_FOOTPRINT, Footprint
from .grid_map import GridMap

__all__ = ["LEXUS_FOOTPRINT", "ReferenceProblem", "autoware_lot", "maze_zone", "reference_problems"]

LEXUS_FOOTPRINT = Footprint(front_m=5.5 - 1.5, rear_m=1.5, width_m=2.75)
LEXUS_TURN_RADIUS_M = 3.0 / math.tan(0.7)  # 3.57 m


@dataclass(frozen=True)
class ReferenceProblem:
    name: str
    grid: GridMap
    footprint: Footprint
    turn_radius_m: float
    start: tuple[float, float, float]
    goals: tuple[tuple[str, tuple[float, float, float]], ...]


def _cells_in(x: np.ndarray, y: np.ndarray, x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
    return (x0 < x) & (x < x1) & (y0 < y) & (y < y1)


def autoware_lot() -> ReferenceProblem:
    n, res, pad = 150, 0.2, 10
    occ = np.zeros((n, n), dtype=bool)
    occ[:pad, :] = occ[-pad:, :] = True
    occ[:, :pad] = occ[:, -pad:] = True
    yy, xx = np.mgrid[0:n, 0:n]
    x, y = xx * res, yy * res  # each cell's lower-left corner, as Autoware tests it
    occ |= _cells_in(x, y, 8.0, 28.0, 9.0, 9.5)
    w, length = 2.75, 5.5
    for cx, cy in ((10.0, 22.0), (13.5, 22.0), (20.0, 22.0), (10.0, 10.0)):
        occ |= _cells_in(x, y, cx, cx + w, cy, cy + length)
    down = 1.5 * math.pi
    return ReferenceProblem(
        "autoware_lot",
        GridMap(occ, res, (0.0, 0.0)),
        LEXUS_FOOTPRINT,
        LEXUS_TURN_RADIUS_M,
        (5.5, 4.0, 0.5 * math.pi),
        (
            ("goal1", (8.0, 26.3, down)),
            ("goal2", (15.0, 11.6, 0.5 * math.pi)),
            ("goal3", (18.4, 26.3, down)),
            ("goal4", (25.0, 26.3, down)),
        ),
    )


def maze_zone() -> ReferenceProblem:
    """Staggered walls across a 40 m square: the way to the goal winds through three gaps."""
    size, res = 50.0, 0.2
    walls = [
        (25.0, 0.5, 0.0, 50.0, 1.0),  # border: (cx, cy, heading, length, width)
        (25.0, 49.5, 0.0, 50.0, 1.0),
        (0.5, 25.0, 0.0, 1.0, 50.0),
        (49.5, 25.0, 0.0, 1.0, 50.0),
        (17.0, 12.5, 0.0, 34.0, 0.6),  # gap on the right
        (33.0, 25.0, 0.0, 34.0, 0.6),  # gap on the left
        (17.0, 37.5, 0.0, 34.0, 0.6),  # gap on the right
        (12.0, 31.0, 0.0, 2.0, 2.0),  # pillars in the corridors
        (38.0, 19.0, 0.0, 2.0, 2.0),
    ]
    grid = GridMap.from_boxes((size, size), res, walls)
    return ReferenceProblem(
        "maze_50m",
        grid,
        PASSAT_FOOTPRINT,
        5.5,
        (5.0, 6.0, 0.0),
        (("through_the_maze", (6.0, 44.0, math.pi)), ("back_into_the_corner", (4.0, 19.0, 0.5 * math.pi))),
    )


def reference_problems() -> tuple[ReferenceProblem, ...]:
    return (autoware_lot(), maze_zone())
