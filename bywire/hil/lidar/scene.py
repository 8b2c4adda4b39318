"""The ray-casting scene: static geometry built once, moving objects replaced every revolution.

Embree (through `embreex`) does the casting; docs/perception.md "Simulated LIDAR" says why it and
not Open3D. The static part (ground, paint, curbs, buildings, parked cars) is one Embree scene
committed once per scenario. The moving cars are a second, small scene rebuilt at each revolution
(`set_moving`): embreex offers no instances and ignores geometry added after a commit. Casting every
ray twice would double the cost, so only the rays that can reach a moving object (inside the cone
from the sensor around its bounding sphere) are cast again, each only as far as its static hit.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from embreex import rtcore as embree_rtc
from embreex import rtcore_scene as embree_scene
from embreex.mesh_construction import TriangleMesh

from bywire.hil.lidar.mesh import F32, Ground, Mesh

# embreex marks "no hit" with a primitive id of -1 and leaves tfar at the distance it was given.
_NO_HIT = -1


class _Embree:
    """One committed Embree scene of one mesh and the surface of each of its triangles."""

    def __init__(self, device: object, mesh: Mesh) -> None:
        self.scene = embree_scene.EmbreeScene(device)
        self.surface = mesh.surface
        self.triangles = len(mesh)
        if len(mesh):
            TriangleMesh(
                self.scene, np.ascontiguousarray(mesh.vertices_m), np.ascontiguousarray(mesh.triangles)
            )

    def cast(self, origins: F32, directions: F32, max_range_m: F32) -> tuple[F32, npt.NDArray[np.int32]]:
        """(range or the given max, primitive id or -1) of each ray."""
        if not self.triangles or not len(directions):
            return max_range_m.copy(), np.full(len(directions), _NO_HIT, np.int32)
        out = self.scene.run(origins, directions, dists=max_range_m.copy(), output=1)
        return np.asarray(out["tfar"], np.float32), np.asarray(out["primID"], np.int32)


class LidarScene:
    """Static triangles plus this revolution's moving objects, on a `Ground` plane."""

    def __init__(self, static: Mesh, ground: Ground | None = None) -> None:
        self.ground = ground if ground is not None else Ground()
        self._device = embree_rtc.EmbreeDevice()
        self._static = _Embree(self._device, static)
        self._moving = _Embree(self._device, Mesh.empty())
        self._spheres = np.zeros((0, 4), np.float64)  # centre x, y, z, radius of each moving object

    @property
    def static_triangles(self) -> int:
        return self._static.triangles

    @property
    def moving_triangles(self) -> int:
        return self._moving.triangles

    def set_moving(self, objects: Sequence[Mesh]) -> None:
        """This revolution's moving objects (one mesh each), replacing the last revolution's."""
        objects = [m for m in objects if len(m)]
        self._moving = _Embree(self._device, Mesh.concat(objects))
        spheres = []
        for m in objects:
            lo, hi = m.vertices_m.min(axis=0).astype(np.float64), m.vertices_m.max(axis=0).astype(np.float64)
            spheres.append([*(0.5 * (lo + hi)), 0.5 * float(np.linalg.norm(hi - lo))])
        self._spheres = np.array(spheres, np.float64).reshape(-1, 4)

    def cast(
        self, origin_m: npt.ArrayLike, directions: F32, max_range_m: float
    ) -> tuple[F32, npt.NDArray[np.uint8], npt.NDArray[np.bool_]]:
        """Cast unit-length rays (N, 3) float32 from one origin: (range m, surface, hit) of each; a ray
        that meets nothing within `max_range_m` has hit False (range and surface then mean nothing)."""
        n = len(directions)
        origin = np.asarray(origin_m, np.float64).reshape(3)
        origins = np.empty((n, 3), np.float32)
        origins[:] = origin
        limit = np.full(n, max_range_m, np.float32)
        rng, prim = self._static.cast(origins, directions, limit)
        hit = prim != _NO_HIT
        surface = np.zeros(n, np.uint8)
        surface[hit] = self._static.surface[prim[hit]]
        if len(self._spheres):
            idx = self._candidates(origin, directions, max_range_m)
            if len(idx):
                r2, p2 = self._moving.cast(origins[idx], directions[idx], rng[idx])
                nearer = p2 != _NO_HIT
                sel = idx[nearer]
                rng[sel] = r2[nearer]
                surface[sel] = self._moving.surface[p2[nearer]]
                hit[sel] = True
        return rng, surface, hit

    def _candidates(
        self, origin: npt.NDArray[np.float64], directions: F32, max_range_m: float
    ) -> npt.NDArray[np.intp]:
        """Indices of the rays inside the cone from `origin` around any moving object's sphere."""
        to = self._spheres[:, :3] - origin
        dist = np.linalg.norm(to, axis=1)
        radius = self._spheres[:, 3]
        near = dist - radius < max_range_m
        inside = near & (dist <= radius)
        if inside.any():
            return np.arange(len(directions))
        sel = np.flatnonzero(near)
        if not len(sel):
            return np.zeros(0, np.intp)
        unit = (to[sel] / dist[sel, None]).astype(np.float32)
        cos_half = np.sqrt(1.0 - (radius[sel] / dist[sel]) ** 2).astype(np.float32)
        # elementwise, not `directions @ unit.T`: see velodyne._rotate on BLAS after an Embree commit
        dx, dy, dz = directions[:, 0], directions[:, 1], directions[:, 2]
        inside_cone = np.zeros(len(directions), bool)
        for u, c in zip(unit, cos_half, strict=True):
            inside_cone |= dx * u[0] + dy * u[1] + dz * u[2] >= c
        return np.flatnonzero(inside_cone)


__all__ = ["LidarScene"]
