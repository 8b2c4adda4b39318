"""The search graph's edges (seed 000 Sec. 10.2, Fig. 17): the kinematic one-track model driven a fixed
arc length while the front wheels turn uniformly from one of `n_steer` equidistant steering angles to
another ("clothoid-like arcs"), forward and backward: n_steer² successors each way, computed once for a
node at the origin and moved to each node by a rotation and a translation.

The steering is carried as the path curvature kappa = tan(delta) / l, equidistant in kappa from -1/R to
+1/R (R: the smallest turning radius). The steering rate along an edge is (kappa_to - kappa_from) / s;
`max_kappa_rate_per_m2` bounds it, and transitions faster than that are not in the graph.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

__all__ = ["MotionPrimitives", "build_primitives"]


# eq=False: equal and hashed by identity (its fields are arrays), so a set can key a cache of what is
# derived from it (the compiled search's padded arrays)
@dataclass(frozen=True, eq=False)
class MotionPrimitives:
    kappas: np.ndarray  # (n_steer,) curvatures, 1/m
    arc_m: float
    # per steering index `from`: the successors' (to index, direction +-1) and their samples in the
    # node's frame: samples (n_succ, m, 3) of x, y, heading (the last sample is the successor)
    to_index: tuple[np.ndarray, ...]
    direction: tuple[np.ndarray, ...]
    samples: tuple[np.ndarray, ...]

    @property
    def n_steer(self) -> int:
        return int(self.kappas.size)


def _integrate(k0: float, k1: float, signed_arc_m: float, n: int, sub: int = 8) -> np.ndarray:
    """x, y, heading at n equal steps along a linear-curvature arc (fine sub-steps, midpoint rule)."""
    out = np.zeros((n, 3))
    x = y = th = 0.0
    steps = n * sub
    ds = signed_arc_m / steps
    for i in range(steps):
        frac = (i + 0.5) / steps
        k = k0 + (k1 - k0) * frac
        th_mid = th + 0.5 * k * ds
        x += ds * math.cos(th_mid)
        y += ds * math.sin(th_mid)
        th += k * ds
        if (i + 1) % sub == 0:
            out[(i + 1) // sub - 1] = (x, y, th)
    return out


@functools.lru_cache(maxsize=16)
def build_primitives(
    turn_radius_m: float,
    arc_m: float,
    n_steer: int = 5,
    sample_step_m: float = 0.1,
    max_kappa_rate_per_m2: float | None = None,
    reverse: bool = True,
) -> MotionPrimitives:
    """The successor set (see the module docstring). `sample_step_m` spaces the collision checks.

    Kept for the next call with the same arguments (its arrays read-only): integrating the arcs costs
    ~9 ms of Python, as much as a whole compiled search of a few hundred expansions."""
    if not (turn_radius_m > 0.0 and arc_m > 0.0 and sample_step_m > 0.0):
        raise ValueError("build_primitives: turn_radius_m, arc_m and sample_step_m must be > 0")
    if n_steer < 3 or n_steer % 2 == 0:
        raise ValueError(
            f"build_primitives: n_steer = {n_steer} must be odd and >= 3 (straight ahead in the set)"
        )
    kappas = np.linspace(-1.0 / turn_radius_m, 1.0 / turn_radius_m, n_steer)
    m = max(2, math.ceil(arc_m / sample_step_m))
    to_index, direction, samples = [], [], []
    for i in range(n_steer):
        ti, di, si = [], [], []
        for d in (1.0, -1.0) if reverse else (1.0,):
            for j in range(n_steer):
                if (
                    max_kappa_rate_per_m2 is not None
                    and abs(kappas[j] - kappas[i]) / arc_m > max_kappa_rate_per_m2 + 1e-12
                ):
                    continue
                ti.append(j)
                di.append(d)
                si.append(_integrate(float(kappas[i]), float(kappas[j]), d * arc_m, m))
        to_index.append(np.asarray(ti, dtype=np.int64))
        direction.append(np.asarray(di))
        samples.append(np.asarray(si))
    for a in (kappas, *to_index, *direction, *samples):
        a.setflags(write=False)
    return MotionPrimitives(kappas, arc_m, tuple(to_index), tuple(direction), tuple(samples))
