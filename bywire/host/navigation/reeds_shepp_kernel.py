"""The Reeds-Shepp words of `reeds_shepp` compiled with numba: the search asks them for every node it
expands (the kinematic heuristic) and every shot at the goal, about two thousand times a plan, where the
Python words cost ~0.1 ms a call and were ~40 % of a plan's time.

The same formulas in the same order as `reeds_shepp._WORDS` x `_MIRRORS`; tests/host/navigation/
test_reeds_shepp.py holds every solution equal to the Python reference within 1e-12 (numba's sin, cos
and hypot are the C library's, CPython's hypot is its own: they differ in the last bit on a few
percent of problems). IEEE `remainder` is CPython's algorithm written out (numba has none), exact like
it. No fastmath. Compiled once per machine (`cache=True`) and released from the GIL while it runs.

`search_kernel` (the compiled Hybrid A* loop) calls these. numba keys a cached function to its own
file only: a change here reaches the search's cache only with a change to search_kernel.py (or an
emptied cache), so change that file's `KERNEL_DEPENDS` stamp with any change here.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_ZERO = 10.0 * float(np.finfo(float).eps)
_HALF_PI = 0.5 * math.pi
_TWO_PI = 2.0 * math.pi
_PI = math.pi

# Columns of a solution row: length (radii), word index (in reeds_shepp._WORDS), mirror index (in
# reeds_shepp._MIRRORS), t, u, v.
MAX_SOLUTIONS = 44


@njit(cache=True, nogil=True)
def _wrap(x: float) -> float:
    """math.remainder(x, 2 pi), as CPython computes it (Modules/mathmodule.c m_remainder): exact."""
    absx = abs(x)
    m = np.fmod(absx, _TWO_PI)
    c = _TWO_PI - m
    if m < c:
        r = m
    elif m > c:
        r = -c
    else:  # a tie: to the even multiple
        r = m - 2.0 * np.fmod(0.5 * (absx - m), _TWO_PI)
    return math.copysign(1.0, x) * r


@njit(cache=True, nogil=True)
def _tau_omega(u: float, v: float, xi: float, eta: float, phi: float) -> tuple[float, float]:
    delta = _wrap(u - v)
    a = math.sin(u) - math.sin(delta)
    b = math.cos(u) - math.cos(delta) - 1.0
    t1 = math.atan2(eta * a - xi * b, xi * a + eta * b)
    t2 = 2.0 * (math.cos(delta) - math.cos(v) - math.cos(u)) + 3.0
    tau = _wrap(t1 + _PI) if t2 < 0 else _wrap(t1)
    return tau, _wrap(tau - u + v - phi)


@njit(cache=True, nogil=True)
def _solve(
    word: int, x: float, y: float, phi: float, sin_phi: float, cos_phi: float
) -> tuple[bool, float, float, float]:
    """Word `word` of section 8 (the solver of reeds_shepp._WORDS[k]): (found, t, u, v). `sin_phi`,
    `cos_phi`: math.sin(phi), math.cos(phi), which every word needs (computed once per call, not per
    word and mirror: the same values)."""
    if word == 0:  # 8.1 LSL
        a, b = x - sin_phi, y - 1.0 + cos_phi
        u, t = math.hypot(a, b), math.atan2(b, a)
        if t >= -_ZERO:
            v = _wrap(phi - t)
            if v >= -_ZERO:
                return True, t, u, v
    elif word == 1:  # 8.2 LSR
        a, b = x + sin_phi, y - 1.0 - cos_phi
        u1, t1 = math.hypot(a, b), math.atan2(b, a)
        u1 = u1 * u1
        if u1 >= 4.0:
            u = math.sqrt(u1 - 4.0)
            theta = math.atan2(2.0, u)
            t = _wrap(t1 + theta)
            v = _wrap(t - phi)
            if t >= -_ZERO and v >= -_ZERO:
                return True, t, u, v
    elif word == 2:  # 8.3 LRL
        xi, eta = x - sin_phi, y - 1.0 + cos_phi
        u1, theta = math.hypot(xi, eta), math.atan2(eta, xi)
        if u1 <= 4.0:
            u = -2.0 * math.asin(0.25 * u1)
            t = _wrap(theta + 0.5 * u + _PI)
            v = _wrap(phi - t + u)
            if t >= -_ZERO and u <= _ZERO:
                return True, t, u, v
    elif word == 3:  # 8.7 LRLR, u then -u
        xi, eta = x + sin_phi, y - 1.0 - cos_phi
        rho = 0.25 * (2.0 + math.hypot(xi, eta))
        if rho <= 1.0:
            u = math.acos(rho)
            t, v = _tau_omega(u, -u, xi, eta, phi)
            if t >= -_ZERO and v <= _ZERO:
                return True, t, u, v
    elif word == 4:  # 8.8 LRLR, u twice
        xi, eta = x + sin_phi, y - 1.0 - cos_phi
        rho = (20.0 - xi * xi - eta * eta) / 16.0
        if 0.0 <= rho <= 1.0:
            u = -math.acos(rho)
            if u >= -_HALF_PI:
                t, v = _tau_omega(u, u, xi, eta, phi)
                if t >= -_ZERO and v >= -_ZERO:
                    return True, t, u, v
    elif word == 5:  # 8.9 LRSL
        xi, eta = x - sin_phi, y - 1.0 + cos_phi
        rho, theta = math.hypot(xi, eta), math.atan2(eta, xi)
        if rho >= 2.0:
            r = math.sqrt(rho * rho - 4.0)
            u = 2.0 - r
            t = _wrap(theta + math.atan2(r, -2.0))
            v = _wrap(phi - _HALF_PI - t)
            if t >= -_ZERO and u <= _ZERO and v <= _ZERO:
                return True, t, u, v
    elif word == 6:  # 8.10 LRSR
        xi, eta = x + sin_phi, y - 1.0 - cos_phi
        rho, theta = math.hypot(eta, xi), math.atan2(xi, -eta)
        if rho >= 2.0:
            t = theta
            u = 2.0 - rho
            v = _wrap(t + _HALF_PI - phi)
            if t >= -_ZERO and u <= _ZERO and v <= _ZERO:
                return True, t, u, v
    else:  # 8.11 LRSLR
        xi, eta = x + sin_phi, y - 1.0 - cos_phi
        rho = math.hypot(xi, eta)
        if rho >= 2.0:
            u = 4.0 - math.sqrt(rho * rho - 4.0)
            if u <= _ZERO:
                t = _wrap(math.atan2((4.0 - u) * xi - 2.0 * eta, -2.0 * xi + (u - 4.0) * eta))
                v = _wrap(t - phi)
                if t >= -_ZERO and v >= -_ZERO:
                    return True, t, u, v
    return False, 0.0, 0.0, 0.0


@njit(cache=True, nogil=True)
def solutions(
    x: float,
    y: float,
    phi: float,
    solver: np.ndarray,
    backwards: np.ndarray,
    twice: np.ndarray,
    extra: np.ndarray,
    mirrors: np.ndarray,
    out: np.ndarray,
    shortest_only: bool = False,
) -> int:
    """Every word's solution into the rows of `out` (MAX_SOLUTIONS x 6, the columns above), in the order
    of the words and their mirrors; returns how many. With `shortest_only`, only the first shortest, in
    row 0 (returns 0 or 1). The word table (`solver`, `backwards`, `twice`, `extra`: one entry per word)
    and `mirrors` (sx, sy per mirror) come from reeds_shepp."""
    c, s = math.cos(phi), math.sin(phi)
    xb, yb = x * c + y * s, x * s - y * c
    n = 0
    # a mirror's phi * sx * sy is phi or -phi exactly (sx, sy are +-1): their sines and cosines once
    neg = -phi
    sin_neg, cos_neg = math.sin(neg), math.cos(neg)
    for w in range(solver.shape[0]):
        px, py = (xb, yb) if backwards[w] else (x, y)
        for m in range(mirrors.shape[0]):
            sx, sy = mirrors[m, 0], mirrors[m, 1]
            if sx * sy > 0.0:
                found, t, u, v = _solve(solver[w], sx * px, sy * py, phi, s, c)
            else:
                found, t, u, v = _solve(solver[w], sx * px, sy * py, neg, sin_neg, cos_neg)
            if not found:
                continue
            length = abs(t) + abs(u) * (2.0 if twice[w] else 1.0) + abs(v) + extra[w]
            row = 0 if shortest_only else n
            if shortest_only and n > 0 and not length < out[0, 0]:
                continue
            out[row, 0] = length
            out[row, 1] = w
            out[row, 2] = m
            out[row, 3] = t
            out[row, 4] = u
            out[row, 5] = v
            n = 1 if shortest_only else n + 1
    return n


@njit(cache=True, nogil=True)
def shortest_length(
    x: float,
    y: float,
    phi: float,
    solver: np.ndarray,
    backwards: np.ndarray,
    twice: np.ndarray,
    extra: np.ndarray,
    mirrors: np.ndarray,
) -> float:
    """The shortest solution's length in radii (inf if none)."""
    out = np.empty((1, 6))
    n = solutions(x, y, phi, solver, backwards, twice, extra, mirrors, out, True)
    return out[0, 0] if n else math.inf


@njit(cache=True, nogil=True)
def _blocked_at(x: float, y: float, th: float, blocked: np.ndarray, ox: float, oy: float, res: float) -> bool:
    """`CSpace.collides` for one pose: its heading bin's grown footprint at its cell, or off the map."""
    n, rows, cols = blocked.shape
    col = math.floor((x - ox) / res)
    row = math.floor((y - oy) / res)
    if row < 0 or row >= rows or col < 0 or col >= cols:
        return True
    k = round(th * (n / (2.0 * math.pi))) % n
    return bool(blocked[k, row, col])


@njit(cache=True, nogil=True)
def path_collides(
    x: float,
    y: float,
    th: float,
    curvature: np.ndarray,
    length_m: np.ndarray,
    step_m: float,
    blocked: np.ndarray,
    ox: float,
    oy: float,
    res: float,
) -> bool:
    """Whether any pose `reeds_shepp.sample` gives along the segments (curvature 1/m, signed length
    m) from (x, y, th) collides in the configuration space `blocked` (heading bins x rows x cols, the
    grid's origin and cell size): the same poses, stopping at the first that collides."""
    if _blocked_at(x, y, th, blocked, ox, oy, res):
        return True
    for i in range(curvature.shape[0]):
        seg = length_m[i]
        if abs(seg) < 1e-12:
            continue
        n = max(1, math.ceil(abs(seg) / step_m))
        k = curvature[i]
        c, s = math.cos(th), math.sin(th)
        px, py, pth = x, y, th
        for j in range(1, n + 1):
            ds = j * (seg / n)
            if k == 0.0:
                px, py, pth = x + ds * c, y + ds * s, th
            else:
                pth = th + k * ds
                px = x + (math.sin(pth) - s) / k
                py = y - (math.cos(pth) - c) / k
            if _blocked_at(px, py, pth, blocked, ox, oy, res):
                return True
        x, y, th = px, py, pth
    return False
