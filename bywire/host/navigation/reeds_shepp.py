"""Reeds-Shepp paths: the shortest path of a car that drives forward and backward at a bounded curvature
(Reeds & Shepp 1990), in closed form. Seed 000 Sec. 10.3.1 names them as the optimal local metric and
used the simpler RTR metric instead "due to its computational simplicity"; closed-form Reeds-Shepp costs
a few microseconds more per call and is never longer than the true optimum, so the search's kinematic
heuristic is exact on an empty map (deviation from the paper, on purpose).

The formulas are those of Reeds and Shepp's section 8 as OMPL's `ReedsSheppStateSpace` writes them: the
five families CSC, CCC, CCCC, CCSC and CCSCC, each word solved in the normalised frame (start at the
origin heading along x, unit turning radius) and its mirror images by time flip (x, phi -> -x, -phi),
reflection (y, phi -> -y, -phi) and both; CCC and CCSC also backwards. A path is a tuple of `Segment`s:
a steering (`L`, `S`, `R`) and a signed arc length in radii (negative: reversing).

`shortest_length` is the heuristic's call; `shortest_path` and `sample` give the path for the search's
analytic expansion ("shot" to the goal) and for plots.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import reeds_shepp_kernel as _kernel

__all__ = [
    "RsPath", "Segment", "all_paths", "normalised", "sample", "segment_arrays", "shortest_length",
    "shortest_normalised_length", "shortest_path", "shortest_paths", "solution_path", "warm_up",
]  # fmt: skip

_ZERO = 10.0 * np.finfo(float).eps
_HALF_PI = 0.5 * math.pi
_TWO_PI = 2.0 * math.pi  # math.remainder(a, _TWO_PI): a wrapped into [-pi, pi] in one C call


@dataclass(frozen=True)
class Segment:
    steer: str  # "L" (left at the minimum radius), "S" (straight) or "R" (right)
    length: float  # arc length in turning radii; < 0 drives backwards


@dataclass(frozen=True)
class RsPath:
    segments: tuple[Segment, ...]

    @property
    def length(self) -> float:
        """Total arc length in turning radii."""
        return sum(abs(s.length) for s in self.segments)

    @property
    def direction_changes(self) -> int:
        signs = [math.copysign(1.0, s.length) for s in self.segments if abs(s.length) > 1e-9]
        return sum(1 for a, b in itertools.pairwise(signs) if a != b)


def _tau_omega(u: float, v: float, xi: float, eta: float, phi: float) -> tuple[float, float]:
    delta = math.remainder(u - v, _TWO_PI)
    a = math.sin(u) - math.sin(delta)
    b = math.cos(u) - math.cos(delta) - 1.0
    t1 = math.atan2(eta * a - xi * b, xi * a + eta * b)
    t2 = 2.0 * (math.cos(delta) - math.cos(v) - math.cos(u)) + 3.0
    tau = math.remainder(t1 + math.pi, _TWO_PI) if t2 < 0 else math.remainder(t1, _TWO_PI)
    return tau, math.remainder(tau - u + v - phi, _TWO_PI)


# ---------------------------------------------------------------------------------- the words (sec. 8)


def _lp_sp_lp(x: float, y: float, phi: float) -> tuple[float, float, float] | None:  # 8.1
    a, b = x - math.sin(phi), y - 1.0 + math.cos(phi)
    u, t = math.hypot(a, b), math.atan2(b, a)
    if t >= -_ZERO:
        v = math.remainder(phi - t, _TWO_PI)
        if v >= -_ZERO:
            return t, u, v
    return None


def _lp_sp_rp(x: float, y: float, phi: float) -> tuple[float, float, float] | None:  # 8.2
    a, b = x + math.sin(phi), y - 1.0 - math.cos(phi)
    u1, t1 = math.hypot(a, b), math.atan2(b, a)
    u1 = u1 * u1
    if u1 >= 4.0:
        u = math.sqrt(u1 - 4.0)
        theta = math.atan2(2.0, u)
        t = math.remainder(t1 + theta, _TWO_PI)
        v = math.remainder(t - phi, _TWO_PI)
        if t >= -_ZERO and v >= -_ZERO:
            return t, u, v
    return None


def _lp_rm_l(x: float, y: float, phi: float) -> tuple[float, float, float] | None:  # 8.3
    xi, eta = x - math.sin(phi), y - 1.0 + math.cos(phi)
    u1, theta = math.hypot(xi, eta), math.atan2(eta, xi)
    if u1 <= 4.0:
        u = -2.0 * math.asin(0.25 * u1)
        t = math.remainder(theta + 0.5 * u + math.pi, _TWO_PI)
        v = math.remainder(phi - t + u, _TWO_PI)
        if t >= -_ZERO and u <= _ZERO:
            return t, u, v
    return None


def _lp_rup_lum_rm(x: float, y: float, phi: float) -> tuple[float, float, float] | None:  # 8.7
    xi, eta = x + math.sin(phi), y - 1.0 - math.cos(phi)
    rho = 0.25 * (2.0 + math.hypot(xi, eta))
    if rho <= 1.0:
        u = math.acos(rho)
        t, v = _tau_omega(u, -u, xi, eta, phi)
        if t >= -_ZERO and v <= _ZERO:
            return t, u, v
    return None


def _lp_rum_lum_rp(x: float, y: float, phi: float) -> tuple[float, float, float] | None:  # 8.8
    xi, eta = x + math.sin(phi), y - 1.0 - math.cos(phi)
    rho = (20.0 - xi * xi - eta * eta) / 16.0
    if 0.0 <= rho <= 1.0:
        u = -math.acos(rho)
        if u >= -_HALF_PI:
            t, v = _tau_omega(u, u, xi, eta, phi)
            if t >= -_ZERO and v >= -_ZERO:
                return t, u, v
    return None


def _lp_rm_sm_lm(x: float, y: float, phi: float) -> tuple[float, float, float] | None:  # 8.9
    xi, eta = x - math.sin(phi), y - 1.0 + math.cos(phi)
    rho, theta = math.hypot(xi, eta), math.atan2(eta, xi)
    if rho >= 2.0:
        r = math.sqrt(rho * rho - 4.0)
        u = 2.0 - r
        t = math.remainder(theta + math.atan2(r, -2.0), _TWO_PI)
        v = math.remainder(phi - _HALF_PI - t, _TWO_PI)
        if t >= -_ZERO and u <= _ZERO and v <= _ZERO:
            return t, u, v
    return None


def _lp_rm_sm_rm(x: float, y: float, phi: float) -> tuple[float, float, float] | None:  # 8.10
    xi, eta = x + math.sin(phi), y - 1.0 - math.cos(phi)
    rho, theta = math.hypot(eta, xi), math.atan2(xi, -eta)
    if rho >= 2.0:
        t = theta
        u = 2.0 - rho
        v = math.remainder(t + _HALF_PI - phi, _TWO_PI)
        if t >= -_ZERO and u <= _ZERO and v <= _ZERO:
            return t, u, v
    return None


def _lp_rm_slm_rp(x: float, y: float, phi: float) -> tuple[float, float, float] | None:  # 8.11
    xi, eta = x + math.sin(phi), y - 1.0 - math.cos(phi)
    rho = math.hypot(xi, eta)
    if rho >= 2.0:
        u = 4.0 - math.sqrt(rho * rho - 4.0)
        if u <= _ZERO:
            t = math.remainder(math.atan2((4.0 - u) * xi - 2.0 * eta, -2.0 * xi + (u - 4.0) * eta), _TWO_PI)
            v = math.remainder(t - phi, _TWO_PI)
            if t >= -_ZERO and v >= -_ZERO:
                return t, u, v
    return None


# ---------------------------------------------------------------------------------- the families

_FLIP = str.maketrans("LR", "RL")
_CURVATURE = {"L": 1.0, "S": 0.0, "R": -1.0}


def _path(word: str, lengths: tuple[float, ...], reflect: bool) -> RsPath:
    steers = word.translate(_FLIP) if reflect else word
    return RsPath(tuple(Segment(s, v) for s, v in zip(steers, lengths, strict=True)))


_MIRRORS = ((1.0, 1.0, False), (-1.0, 1.0, False), (1.0, -1.0, True), (-1.0, -1.0, True))


def _shape(shape: str, r: tuple[float, float, float], sign: float) -> tuple[float, ...]:
    t, u, v = r
    if shape == "tuv":
        out: tuple[float, ...] = (t, u, v)
    elif shape == "vut":
        out = (v, u, t)
    elif shape == "tuUv":  # CCCC with u then -u
        out = (t, u, -u, v)
    elif shape == "tuuv":
        out = (t, u, u, v)
    elif shape == "tHuv":  # CCSC: t, -pi/2, u, v
        out = (t, -_HALF_PI, u, v)
    elif shape == "vuHt":  # CCSC backwards: v, u, -pi/2, t
        out = (v, u, -_HALF_PI, t)
    elif shape == "tHuHv":  # CCSCC
        out = (t, -_HALF_PI, u, -_HALF_PI, v)
    else:  # pragma: no cover - a programming error
        raise ValueError(shape)
    return tuple(sign * a for a in out)


# (solver, word, frame, shape) of every word, in the order of Reeds and Shepp's section 8; each is solved
# with its three mirror images (`_MIRRORS`: time flip, reflection, both), `shape` maps (t, u, v) and the
# sign of time to the segment lengths
_Solver = Callable[[float, float, float], "tuple[float, float, float] | None"]
_WORDS: tuple[tuple[_Solver, str, bool, str], ...] = (
    (_lp_sp_lp, "LSL", False, "tuv"), (_lp_sp_rp, "LSR", False, "tuv"), (_lp_rm_l, "LRL", False, "tuv"),
    (_lp_rm_l, "LRL", True, "vut"), (_lp_rup_lum_rm, "LRLR", False, "tuUv"),
    (_lp_rum_lum_rp, "LRLR", False, "tuuv"), (_lp_rm_sm_lm, "LRSL", False, "tHuv"),
    (_lp_rm_sm_rm, "LRSR", False, "tHuv"), (_lp_rm_sm_lm, "LSRL", True, "vuHt"),
    (_lp_rm_sm_rm, "RSRL", True, "vuHt"), (_lp_rm_slm_rp, "LRSLR", False, "tHuHv"),
)  # fmt: skip
_EXTRA = {
    "tuv": 0.0,
    "vut": 0.0,
    "tuUv": 0.0,
    "tuuv": 0.0,
    "tHuv": _HALF_PI,
    "vuHt": _HALF_PI,
    "tHuHv": math.pi,
}
_U_TWICE = {"tuUv", "tuuv"}
_Solution = tuple[float, str, str, tuple[float, float, float], float, bool]


def _solutions_reference(x: float, y: float, phi: float) -> list[_Solution]:
    """(length in radii, word, shape, (t, u, v), sign of time, reflected) of every word's solution, in
    the order of `_WORDS` and `_MIRRORS`; paths are built only for those that are wanted. In Python: the
    reference the compiled words (`reeds_shepp_kernel`, what `_solutions` runs) are held equal to."""
    c, s = math.cos(phi), math.sin(phi)
    xb, yb = x * c + y * s, x * s - y * c
    out: list[_Solution] = []
    for solve, word, backwards, shape in _WORDS:
        px, py = (xb, yb) if backwards else (x, y)
        twice = shape in _U_TWICE
        extra = _EXTRA[shape]
        for sx, sy, reflect in _MIRRORS:
            r = solve(sx * px, sy * py, phi * sx * sy)
            if r is not None:
                t, u, v = r
                length = abs(t) + abs(u) * (2.0 if twice else 1.0) + abs(v) + extra
                out.append((length, word, shape, r, sx, reflect))
    return out


_SOLVERS = (
    _lp_sp_lp, _lp_sp_rp, _lp_rm_l, _lp_rup_lum_rm, _lp_rum_lum_rp, _lp_rm_sm_lm, _lp_rm_sm_rm, _lp_rm_slm_rp,
)  # fmt: skip
# The word table as the compiled kernel takes it, one entry per word of `_WORDS`
_K_SOLVER = np.array([_SOLVERS.index(w[0]) for w in _WORDS], dtype=np.int64)
_K_BACKWARDS = np.array([w[2] for w in _WORDS], dtype=np.bool_)
_K_TWICE = np.array([w[3] in _U_TWICE for w in _WORDS], dtype=np.bool_)
_K_EXTRA = np.array([_EXTRA[w[3]] for w in _WORDS], dtype=np.float64)
_K_MIRRORS = np.array([(sx, sy) for sx, sy, _ in _MIRRORS], dtype=np.float64)
# How a solution row becomes segments in compiled code (`search_kernel`): each word's steerings as
# curvature signs (padded), its shape as an index of `_SHAPES`, and whether a mirror reflects
_SHAPES = ("tuv", "vut", "tuUv", "tuuv", "tHuv", "vuHt", "tHuHv")
_K_STEERS = np.array(
    [[int(_CURVATURE[c]) for c in w[1].ljust(5, "S")] for w in _WORDS], dtype=np.int64
)  # fmt: skip
_K_SHAPES = np.array([_SHAPES.index(w[3]) for w in _WORDS], dtype=np.int64)
_K_REFLECT = np.array([reflect for _, _, reflect in _MIRRORS], dtype=np.bool_)


def _solutions(x: float, y: float, phi: float) -> list[_Solution]:
    """`_solutions_reference`'s list, from the compiled words."""
    rows = np.empty((_kernel.MAX_SOLUTIONS, 6))
    n = _kernel.solutions(x, y, phi, _K_SOLVER, _K_BACKWARDS, _K_TWICE, _K_EXTRA, _K_MIRRORS, rows)
    out: list[_Solution] = []
    for length, w, m, t, u, v in rows[:n].tolist():
        _, word, _, shape = _WORDS[int(w)]
        sx, _, reflect = _MIRRORS[int(m)]
        out.append((length, word, shape, (t, u, v), sx, reflect))
    return out


def solution_path(word: int, mirror: int, t: float, u: float, v: float) -> RsPath:
    """The path of a compiled solution row (`reeds_shepp_kernel.solutions`: word and mirror indices,
    t, u, v), as `all_paths` builds it."""
    _, name, _, shape = _WORDS[word]
    sx, _, reflect = _MIRRORS[mirror]
    return _path(name, _shape(shape, (t, u, v), sx), reflect)


def _build(solution: _Solution) -> RsPath:
    _, word, shape, r, sign, reflect = solution
    return _path(word, _shape(shape, r, sign), reflect)


def all_paths(x: float, y: float, phi: float) -> list[RsPath]:
    """Every Reeds-Shepp candidate from (0, 0, 0) to (x, y, phi), unit turning radius."""
    return [_build(sol) for sol in _solutions(x, y, phi)]


def shortest_paths(x: float, y: float, phi: float, count: int) -> list[RsPath]:
    """The `count` shortest candidates (in the normalised frame), shortest first."""
    ranked = sorted(_solutions(x, y, phi), key=lambda sol: sol[0])
    return [_build(sol) for sol in ranked[:count]]


def shortest_normalised_length(x: float, y: float, phi: float) -> float:
    """The shortest path's length in radii, in the normalised frame (what `all_paths` finds, faster)."""
    return float(_kernel.shortest_length(x, y, phi, _K_SOLVER, _K_BACKWARDS, _K_TWICE, _K_EXTRA, _K_MIRRORS))


def normalised(
    start: tuple[float, float, float], goal: tuple[float, float, float], radius_m: float
) -> tuple[float, float, float]:
    if not (math.isfinite(radius_m) and radius_m > 0.0):
        raise ValueError(f"reeds_shepp: radius_m = {radius_m} must be finite and > 0")
    dx, dy = goal[0] - start[0], goal[1] - start[1]
    c, s = math.cos(start[2]), math.sin(start[2])
    phi = math.remainder(goal[2] - start[2], _TWO_PI)
    return (c * dx + s * dy) / radius_m, (-s * dx + c * dy) / radius_m, phi


def shortest_path(
    start: tuple[float, float, float], goal: tuple[float, float, float], radius_m: float
) -> RsPath:
    """The shortest Reeds-Shepp path between two poses (x_m, y_m, heading_rad); lengths in radii."""
    x, y, phi = normalised(start, goal, radius_m)
    paths = all_paths(x, y, phi)
    if not paths:  # pragma: no cover - CSC always has a solution
        raise RuntimeError(f"reeds_shepp: no path to ({x}, {y}, {phi})")
    return min(paths, key=lambda p: p.length)


def shortest_length(
    start: tuple[float, float, float], goal: tuple[float, float, float], radius_m: float
) -> float:
    """Length in metres of the shortest Reeds-Shepp path between two poses."""
    return shortest_normalised_length(*normalised(start, goal, radius_m)) * radius_m


def segment_arrays(path: RsPath, radius_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(curvature in 1/m, signed length in m) of each segment, as `sample` drives them."""
    curvature = np.array([_CURVATURE[seg.steer] / radius_m for seg in path.segments], dtype=np.float64)
    return curvature, np.array([seg.length * radius_m for seg in path.segments], dtype=np.float64)


def sample(
    start: tuple[float, float, float], path: RsPath, radius_m: float, step_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Poses along `path` from `start` every `step_m` or closer (each segment's end exactly):
    (N x 3 array of x_m, y_m, heading_rad, N signs: +1 forward, -1 reversing)."""
    x, y, th = start
    parts = [np.array([[x, y, th]])]
    sign_parts = [np.array([1.0])]
    curvatures, lengths = segment_arrays(path, radius_m)
    for k, length_m in zip(curvatures.tolist(), lengths.tolist(), strict=True):
        if abs(length_m) < 1e-12:
            continue
        n = max(1, math.ceil(abs(length_m) / step_m))
        ds = np.arange(1, n + 1) * (length_m / n)
        if k == 0.0:
            px, py, pth = x + ds * math.cos(th), y + ds * math.sin(th), np.full(n, th)
        else:
            pth = th + k * ds
            px = x + (np.sin(pth) - math.sin(th)) / k
            py = y - (np.cos(pth) - math.cos(th)) / k
        parts.append(np.column_stack((px, py, pth)))
        sign_parts.append(np.full(n, math.copysign(1.0, length_m)))
        x, y, th = float(px[-1]), float(py[-1]), float(pth[-1])
    signs = np.concatenate(sign_parts)
    if signs.size > 1:
        signs[0] = signs[1]
    return np.vstack(parts), signs


def warm_up() -> None:
    """Compile the words and the shot's collision walk (`reeds_shepp_kernel`), or load them from numba's
    cache: a process's first plan otherwise pays for it (about a second; several on a machine that
    never compiled them). The planner's worker calls it before its first request."""
    shortest_normalised_length(1.0, 1.0, 1.0)
    _solutions(1.0, 1.0, 1.0)
    blocked = np.zeros((1, 1, 1), dtype=bool)
    curvature, length_m = segment_arrays(RsPath((Segment("L", 0.1),)), 1.0)
    _kernel.path_collides(0.0, 0.0, 0.0, curvature, length_m, 0.5, blocked, 0.0, 0.0, 1.0)
