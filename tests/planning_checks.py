"""Checks of planned paths shared by the navigation tests: the car's exact outline, not the planner's own
table, judges whether a path is free."""

from __future__ import annotations

import math

import numpy as np

from bywire.host.navigation.cspace import Footprint
from bywire.host.navigation.grid_map import GridMap


def assert_exactly_free(
    poses: np.ndarray, grid: GridMap, fp: Footprint, margin: float, every: int = 3
) -> None:
    """Every `every`-th pose's rectangle (grown by `margin`), densely sampled, is on free cells."""
    corners = fp.corners(margin)
    us = np.linspace(corners[:, 0].min(), corners[:, 0].max(), 40)
    vs = np.linspace(corners[:, 1].min(), corners[:, 1].max(), 15)
    uu, vv = (a.ravel() for a in np.meshgrid(us, vs))
    for x, y, th in poses[::every]:
        c, s = math.cos(th), math.sin(th)
        px, py = x + c * uu - s * vv, y + s * uu + c * vv
        assert not grid.occupied_at(px, py).any(), (
            f"the car at ({x:.2f}, {y:.2f}, {th:.2f}) touches an obstacle"
        )
