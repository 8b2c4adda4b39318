"""Triangle meshes of the simulated world as the LIDAR sees it, each triangle tagged with its surface.

The Velodyne measures range and reflectivity (seed 000 Sec. 2.3 and 4); the range comes from the
geometry, the reflectivity from the surface the ray hits (`Surface`, `REFLECTANCE`). Lane paint is
a thin film of triangles `PAINT_THICKNESS_M` above the asphalt rather than a texture: a hit's
triangle then says paint or asphalt without a lookup by position, and the film is as thick as real
road paint. The ground is a plane, level or on a constant grade (`Ground`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
import numpy.typing as npt

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]

# Thermoplastic road paint is 1.5-3 mm thick; 1 mm keeps a grazing return (a beam at -1 deg) within
# 6 cm of the asphalt behind it, under the sensor's own 2 cm noise times three.
PAINT_THICKNESS_M = 0.001


class Surface(IntEnum):
    """What a triangle is made of; the index into `REFLECTANCE`."""

    ASPHALT = 0
    PAINT_WHITE = 1
    PAINT_YELLOW = 2
    CURB = 3
    VEHICLE = 4
    BUILDING = 5


# Mean reflectance (0..1) of a return from each surface. The order is what lane-marker detection
# relies on (seed 000 Sec. 6: markings are found as intensities above each laser's median): white
# retro-reflective paint well above asphalt, yellow paint between, concrete curbs and car paint darker
# than asphalt at the HDL-64E's 905 nm.
REFLECTANCE = np.array([0.25, 0.75, 0.55, 0.18, 0.15, 0.30], dtype=np.float32)


@dataclass(frozen=True)
class Mesh:
    """Triangles: vertices (V, 3) float32 metres, triangles (T, 3) int32 vertex indices, surface (T,)
    uint8 (`Surface`)."""

    vertices_m: F32
    triangles: npt.NDArray[np.int32]
    surface: npt.NDArray[np.uint8]

    def __post_init__(self) -> None:
        if self.vertices_m.ndim != 2 or self.vertices_m.shape[1] != 3:
            raise ValueError(f"vertices must be (V, 3), got {self.vertices_m.shape}")
        if self.triangles.ndim != 2 or self.triangles.shape[1] != 3:
            raise ValueError(f"triangles must be (T, 3), got {self.triangles.shape}")
        if self.surface.shape != (self.triangles.shape[0],):
            raise ValueError(f"{self.triangles.shape[0]} triangles but {self.surface.shape} surfaces")

    def __len__(self) -> int:
        return int(self.triangles.shape[0])

    @staticmethod
    def empty() -> Mesh:
        return Mesh(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32), np.zeros(0, np.uint8))

    @staticmethod
    def concat(meshes: Iterable[Mesh]) -> Mesh:
        parts = [m for m in meshes if len(m)]
        if not parts:
            return Mesh.empty()
        offsets = np.cumsum([0] + [len(m.vertices_m) for m in parts[:-1]])
        return Mesh(
            np.concatenate([m.vertices_m for m in parts]),
            np.concatenate([m.triangles + np.int32(o) for m, o in zip(parts, offsets, strict=True)]),
            np.concatenate([m.surface for m in parts]),
        )


def _mesh(vertices: npt.ArrayLike, triangles: npt.ArrayLike, surface: Surface) -> Mesh:
    tri = np.asarray(triangles, dtype=np.int32).reshape(-1, 3)
    return Mesh(
        np.asarray(vertices, dtype=np.float32).reshape(-1, 3), tri, np.full(len(tri), surface, np.uint8)
    )


@dataclass(frozen=True)
class Ground:
    """The road's plane: level, or rising `grade_pct` per 100 m toward `uphill_heading_rad` from
    `origin_xy_m` (where it is at z = 0). A car stands on it with its wheels: `frame` gives its axes."""

    grade_pct: float = 0.0
    uphill_heading_rad: float = 0.0
    origin_xy_m: tuple[float, float] = (0.0, 0.0)

    def _gradient(self) -> tuple[float, float]:
        g = self.grade_pct / 100.0
        return g * math.cos(self.uphill_heading_rad), g * math.sin(self.uphill_heading_rad)

    def height_m(self, x_m: npt.ArrayLike, y_m: npt.ArrayLike) -> F64:
        gx, gy = self._gradient()
        x0, y0 = self.origin_xy_m
        return gx * (np.asarray(x_m, np.float64) - x0) + gy * (np.asarray(y_m, np.float64) - y0)

    def frame(self, heading_rad: float) -> F64:
        """World-from-car rotation (columns: forward, left, up) of a car heading `heading_rad` on the
        plane: forward is the heading climbing with the plane, up is the plane's normal."""
        gx, gy = self._gradient()
        c, s = math.cos(heading_rad), math.sin(heading_rad)
        fwd = np.array([c, s, gx * c + gy * s])
        up = np.array([-gx, -gy, 1.0])
        fwd /= np.linalg.norm(fwd)
        up /= np.linalg.norm(up)
        return np.column_stack([fwd, np.cross(up, fwd), up])

    def mesh(self, x_min_m: float, x_max_m: float, y_min_m: float, y_max_m: float, tile_m: float) -> Mesh:
        """Asphalt over the rectangle in square tiles (a plane: the tiles only keep triangles small)."""
        nx = max(1, math.ceil((x_max_m - x_min_m) / tile_m))
        ny = max(1, math.ceil((y_max_m - y_min_m) / tile_m))
        gx, gy = np.meshgrid(
            np.linspace(x_min_m, x_max_m, nx + 1), np.linspace(y_min_m, y_max_m, ny + 1), indexing="ij"
        )
        verts = np.stack([gx, gy, self.height_m(gx, gy)], axis=-1).reshape(-1, 3)
        i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
        a = (i * (ny + 1) + j).ravel()
        b, c, d = a + (ny + 1), a + (ny + 2), a + 1
        return _mesh(verts, np.column_stack([a, b, c, a, c, d]), Surface.ASPHALT)


def prism_mesh(
    corners_xy_m: npt.ArrayLike, base_z_m: npt.ArrayLike, height_m: float, surface: Surface
) -> Mesh:
    """A vertical prism over a convex footprint (corners in order): its walls and its top, no bottom
    (nothing looks at it from below). Each corner's base is at its own height: on a grade the box
    stands on the plane."""
    xy = np.asarray(corners_xy_m, dtype=np.float64).reshape(-1, 2)
    n = len(xy)
    z0 = np.broadcast_to(np.asarray(base_z_m, dtype=np.float64), (n,))
    verts = np.concatenate([np.column_stack([xy, z0]), np.column_stack([xy, z0 + height_m])])
    k = np.arange(n)
    k1 = (k + 1) % n
    walls = np.column_stack([k, k1, k1 + n, k, k1 + n, k + n]).reshape(-1, 3)
    top = np.column_stack([np.full(n - 2, n), np.arange(n + 1, 2 * n - 1), np.arange(n + 2, 2 * n)])
    return _mesh(verts, np.concatenate([walls, top]), surface)


def strip_mesh(a_m: npt.ArrayLike, b_m: npt.ArrayLike, keep: npt.ArrayLike | None, surface: Surface) -> Mesh:
    """Quads between two polylines of 3-D points (n, 3) sampled side by side: a painted line, a curb's
    face or its top. `keep` (n - 1 bools) drops the quads of gaps (a broken line's)."""
    pa = np.asarray(a_m, dtype=np.float64).reshape(-1, 3)
    pb = np.asarray(b_m, dtype=np.float64).reshape(-1, 3)
    n = len(pa)
    if n < 2:
        return Mesh.empty()
    seg = np.arange(n - 1) if keep is None else np.flatnonzero(np.asarray(keep, dtype=bool))
    tri = np.column_stack([seg, seg + 1, seg + 1 + n, seg, seg + 1 + n, seg + n])
    return _mesh(np.concatenate([pa, pb]), tri, surface)


def box_corners(
    x_m: float, y_m: float, heading_rad: float, length_m: float, width_m: float
) -> npt.NDArray[np.float64]:
    """The 4 corners (counter-clockwise) of a rectangle centred at (x, y), its length along heading."""
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    hl, hw = 0.5 * length_m, 0.5 * width_m
    local = np.array([[hl, -hw], [hl, hw], [-hl, hw], [-hl, -hw]])
    return np.column_stack([x_m + local[:, 0] * c - local[:, 1] * s, y_m + local[:, 0] * s + local[:, 1] * c])


def box_mesh(
    ground: Ground,
    x_m: float,
    y_m: float,
    heading_rad: float,
    length_m: float,
    width_m: float,
    height_m: float,
    surface: Surface,
) -> Mesh:
    """An oriented box standing on the ground (a car, a building)."""
    xy = box_corners(x_m, y_m, heading_rad, length_m, width_m)
    return prism_mesh(xy, ground.height_m(xy[:, 0], xy[:, 1]), height_m, surface)


__all__ = [
    "PAINT_THICKNESS_M",
    "REFLECTANCE",
    "Ground",
    "Mesh",
    "Surface",
    "box_corners",
    "box_mesh",
    "prism_mesh",
    "strip_mesh",
]
