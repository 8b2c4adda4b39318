"""The Hybrid A* search loop of `hybrid_astar` compiled with numba: the Python loop spent ~100 us of
interpreter, small-array numpy calls and allocations per expansion, on the Autoware lot's hardest goal
~130 ms for 1288 expansions; the same loop compiled takes a few microseconds per expansion.

It is `hybrid_astar._search_reference` step for step, and tests/host/navigation/test_search_kernel.py
holds the two equal (expansions, every pose to the last bit, cost, length) on the reference maps and
on random small maps: the same float operations in the same order, no fastmath (LLVM then contracts
nothing into FMAs). Where the reference calls CPython's own `math.hypot` (not the C library's, which
differs in the last bit on ~0.6 % of arguments) this computes CPython's algorithm (`py_hypot`); where
it calls numpy's `np.hypot` this calls the C library's, as numpy does. The open list's order is the
reference's: both pop the least (f, tie) and ties are unique. The closed set's dictionary becomes a
dense table over (y bin, x bin, heading bin) (only poses on the map are ever stored), of which only
the pages the search touches are ever written.

The loop is resumable: `run` returns `YIELD` every `yield_every` expansions (the generator's steps)
and `GROW` when the node store or the heap may overflow in the next expansion (the caller grows the
arrays and calls again); all of the search's state is in the arrays passed in.

numba caches a compiled function by its own file only: a change to `reeds_shepp_kernel`, which this
calls, reaches this module's cache only with a change to this file (or an emptied cache): such a
change also changes `KERNEL_DEPENDS` here.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .reeds_shepp_kernel import _blocked_at, _wrap, path_collides, shortest_length, solutions

__all__ = ["DONE", "ERROR", "GROW", "YIELD", "Params", "cell_key", "py_hypot", "run"]

DONE, YIELD, GROW, ERROR = 0, 1, 2, 3
# What of reeds_shepp_kernel this file's cache was compiled against (see the module docstring)
KERNEL_DEPENDS = "reeds_shepp_kernel: sines and cosines of phi once per call"

# Columns of the node store: node_f (x, y, heading, direction, g) and node_i (steering index, parent,
# index of the primitive from the parent's steering set)
NX, NY, NTH, NDIR, NG = 0, 1, 2, 3, 4
NSTEER, NPARENT, NPRIM = 0, 1, 2
# The search's scalars: si (nodes, heap size, tie, expansions, the node expanded after a yield, the best
# shot's node, its word and mirror) and sf (its cost and its t, u, v)
S_NODES, S_HEAP, S_TIE, S_EXPANSIONS, S_PENDING, S_BEST_NODE, S_BEST_WORD, S_BEST_MIRROR = range(8)
SF_BEST_COST, SF_T, SF_U, SF_V = range(4)
EPS = 1e-9


class Params(NamedTuple):
    """The search's constants (`PlannerParams` and the geometry of the maps it reads)."""

    goal_x: float
    goal_y: float
    goal_th: float
    radius_m: float
    arc_m: float
    reverse_factor: float
    direction_change_m: float
    steer_change_weight: float
    steer_weight: float
    shot_range_m: float
    heuristic_weight: float
    goal_direction: float
    step_m: float
    xy_bin_m: float
    closed_headings: int
    bins_x: int  # the closed set's table: x bins, y bins
    bins_y: int
    max_expansions: int
    yield_every: int
    shot_every: int
    shot_candidates: int
    use_obstacle: bool
    use_kinematic: bool
    exhaustive: bool
    # the configuration space's grid
    grid_ox: float
    grid_oy: float
    grid_res: float
    # the heuristic field's goal, radius, range and grid
    h_goal_x: float
    h_goal_y: float
    h_goal_th: float
    h_radius_m: float
    h_rs_range_m: float
    h_ox: float
    h_oy: float
    h_res: float


@njit(cache=True, nogil=True)
def _split(x: float) -> tuple[float, float]:
    t = x * 134217729.0  # 2**27 + 1: Dekker's split
    hi = t - (t - x)
    return hi, x - hi


@njit(cache=True, nogil=True)
def _dl_mul(x: float, y: float) -> tuple[float, float]:
    """Dekker's mul12: x * y as a rounded product and its exact error."""
    xh, xl = _split(x)
    yh, yl = _split(y)
    p = xh * yh
    q = xh * yl + xl * yh
    z = p + q
    return z, p - z + q + xl * yl


@njit(cache=True, nogil=True)
def py_hypot(a: float, b: float) -> float:
    """CPython 3.11's `math.hypot(a, b)` to the last bit (Modules/mathmodule.c `vector_norm`: scaled,
    squared and summed losslessly, then one differential correction of the square root)."""
    a, b = abs(a), abs(b)
    big = max(a, b)
    if math.isinf(a) or math.isinf(b):
        return math.inf
    if math.isnan(a) or math.isnan(b):
        return math.nan
    if big == 0.0:
        return big
    _, e = math.frexp(big)
    if e < -1023:  # subnormal: CPython rescales by DBL_MIN first
        tiny = 2.2250738585072014e-308
        return tiny * py_hypot(a / tiny, b / tiny)
    scale = math.ldexp(1.0, -e)
    csum, frac1, frac2 = 1.0, 0.0, 0.0
    for x in (a * scale, b * scale):
        hi, lo = _dl_mul(x, x)
        s = csum + hi
        frac2 += (csum - s) + hi
        csum = s
        frac1 += lo
    h = math.sqrt(csum - 1.0 + (frac1 + frac2))
    hi, lo = _dl_mul(-h, h)
    s = csum + hi
    frac2 += (csum - s) + hi
    csum = s
    frac1 += lo
    x = csum - 1.0 + (frac1 + frac2)
    h += x / (2.0 * h)
    return h / scale


@njit(cache=True, nogil=True)
def _before(fa: float, ta: int, fb: float, tb: int) -> bool:
    return fa < fb or (fa == fb and ta < tb)


@njit(cache=True, nogil=True)
def _push(hf: np.ndarray, ht: np.ndarray, hn: np.ndarray, size: int, f: float, tie: int, nid: int) -> int:
    i = size
    while i > 0:
        up = (i - 1) >> 1
        if not _before(f, tie, hf[up], ht[up]):
            break
        hf[i], ht[i], hn[i] = hf[up], ht[up], hn[up]
        i = up
    hf[i], ht[i], hn[i] = f, tie, nid
    return size + 1


@njit(cache=True, nogil=True)
def _pop(hf: np.ndarray, ht: np.ndarray, hn: np.ndarray, size: int) -> tuple[float, int]:
    """The least (f, tie)'s f and node; the heap then holds `size` - 1."""
    f, nid = hf[0], hn[0]
    size -= 1
    if size > 0:
        lf, lt, ln = hf[size], ht[size], hn[size]
        i = 0
        while True:
            c = 2 * i + 1
            if c >= size:
                break
            if c + 1 < size and _before(hf[c + 1], ht[c + 1], hf[c], ht[c]):
                c += 1
            if not _before(hf[c], ht[c], lf, lt):
                break
            hf[i], ht[i], hn[i] = hf[c], ht[c], hn[c]
            i = c
        hf[i], ht[i], hn[i] = lf, lt, ln
    return f, nid


@njit(cache=True, nogil=True)
def cell_key(x: float, y: float, th: float, p: Params) -> int:
    """`hybrid_astar`'s closed-set key as an index of the dense table (-1: off the table)."""
    ix = math.floor((x - p.grid_ox) / p.xy_bin_m)
    iy = math.floor((y - p.grid_oy) / p.xy_bin_m)
    n_h = p.closed_headings
    ik = round(th * (n_h / (2.0 * math.pi))) % n_h
    if ix < 0 or ix >= p.bins_x or iy < 0 or iy >= p.bins_y:
        return -1
    return (iy * p.bins_x + ix) * n_h + ik


@njit(cache=True, nogil=True)
def _obstacle(x: float, y: float, obstacle_m: np.ndarray, p: Params) -> float:
    """`HeuristicField.obstacle` at one position."""
    col = math.floor((x - p.h_ox) / p.h_res)
    row = math.floor((y - p.h_oy) / p.h_res)
    if row < 0 or row >= obstacle_m.shape[0] or col < 0 or col >= obstacle_m.shape[1]:
        return math.inf
    return obstacle_m[row, col]


@njit(cache=True, nogil=True)
def _normalised(
    x: float, y: float, th: float, gx: float, gy: float, gth: float, radius_m: float
) -> tuple[float, float, float]:
    """`reeds_shepp.normalised`."""
    dx, dy = gx - x, gy - y
    c, s = math.cos(th), math.sin(th)
    phi = _wrap(gth - th)
    return (c * dx + s * dy) / radius_m, (-s * dx + c * dy) / radius_m, phi


@njit(cache=True, nogil=True)
def _kinematic(
    x: float,
    y: float,
    th: float,
    p: Params,
    solver: np.ndarray,
    backwards: np.ndarray,
    twice: np.ndarray,
    extra: np.ndarray,
    mirrors: np.ndarray,
) -> float:
    """`HeuristicField.kinematic`."""
    d = py_hypot(x - p.h_goal_x, y - p.h_goal_y)
    if d > p.h_rs_range_m:
        return d
    nx, ny, phi = _normalised(x, y, th, p.h_goal_x, p.h_goal_y, p.h_goal_th, p.h_radius_m)
    return shortest_length(nx, ny, phi, solver, backwards, twice, extra, mirrors) * p.h_radius_m


@njit(cache=True, nogil=True)
def _segments(
    row: np.ndarray,
    radius_m: float,
    steers: np.ndarray,
    shapes: np.ndarray,
    mirrors: np.ndarray,
    reflect: np.ndarray,
    radii: np.ndarray,
    curvature: np.ndarray,
    length_m: np.ndarray,
) -> int:
    """The segments of a solution row (`reeds_shepp._build` then `segment_arrays`): signed lengths in
    radii, curvatures in 1/m and signed lengths in m; returns how many."""
    w, m = int(row[1]), int(row[2])
    t, u, v = row[3], row[4], row[5]
    half_pi = 0.5 * math.pi
    shape = shapes[w]
    n = 4
    if shape == 0:  # tuv
        n = 3
        radii[0], radii[1], radii[2] = t, u, v
    elif shape == 1:  # vut
        n = 3
        radii[0], radii[1], radii[2] = v, u, t
    elif shape == 2:  # tuUv
        radii[0], radii[1], radii[2], radii[3] = t, u, -u, v
    elif shape == 3:  # tuuv
        radii[0], radii[1], radii[2], radii[3] = t, u, u, v
    elif shape == 4:  # tHuv
        radii[0], radii[1], radii[2], radii[3] = t, -half_pi, u, v
    elif shape == 5:  # vuHt
        radii[0], radii[1], radii[2], radii[3] = v, u, -half_pi, t
    else:  # tHuHv
        n = 5
        radii[0], radii[1], radii[2], radii[3], radii[4] = t, -half_pi, u, -half_pi, v
    sign = mirrors[m, 0]
    for i in range(n):
        radii[i] = sign * radii[i]
        k = steers[w, i]
        if reflect[m]:
            k = -k
        curvature[i] = k / radius_m
        length_m[i] = radii[i] * radius_m
    return n


@njit(cache=True, nogil=True)
def _n_segments(word: float, shapes: np.ndarray) -> int:
    shape = shapes[int(word)]
    return 3 if shape <= 1 else (5 if shape == 6 else 4)


@njit(cache=True, nogil=True)
def _rs_cost(radii: np.ndarray, curvature: np.ndarray, n: int, p: Params, last_dir: float) -> float:
    """`hybrid_astar._rs_cost`."""
    cost = 0.0
    d_prev = last_dir
    for i in range(n):
        length = abs(radii[i]) * p.radius_m
        if length < 1e-9:
            continue
        d = 1.0 if radii[i] > 0 else -1.0
        cost += length * (1.0 if d > 0 else p.reverse_factor)
        if curvature[i] != 0.0:
            cost += p.steer_weight * length
        if d_prev != 0.0 and d != d_prev:
            cost += p.direction_change_m
        d_prev = d
    if p.goal_direction != 0.0 and d_prev != 0.0 and d_prev != p.goal_direction:
        cost += p.direction_change_m
    return cost


@njit(cache=True, nogil=True)
def _shot(
    x: float,
    y: float,
    th: float,
    candidates: int,
    p: Params,
    blocked: np.ndarray,
    solver: np.ndarray,
    backwards: np.ndarray,
    twice: np.ndarray,
    extra: np.ndarray,
    mirrors: np.ndarray,
    steers: np.ndarray,
    shapes: np.ndarray,
    reflect: np.ndarray,
    rows: np.ndarray,
    radii: np.ndarray,
    curvature: np.ndarray,
    length_m: np.ndarray,
) -> int:
    """`hybrid_astar._shot`: the row of `rows` holding the first free of the `candidates` shortest
    Reeds-Shepp paths to the goal (ranked as a stable sort by length ranks them), -1 if none; its
    segments are left in `radii`, `curvature` and `length_m`."""
    nx, ny, phi = _normalised(x, y, th, p.goal_x, p.goal_y, p.goal_th, p.radius_m)
    n = solutions(nx, ny, phi, solver, backwards, twice, extra, mirrors, rows, False)
    used = np.zeros(n, dtype=np.bool_)
    for _ in range(min(candidates, n)):
        best = -1
        for i in range(n):
            if not used[i] and (best < 0 or rows[i, 0] < rows[best, 0]):
                best = i
        used[best] = True
        k = _segments(rows[best], p.radius_m, steers, shapes, mirrors, reflect, radii, curvature, length_m)
        if not path_collides(
            x, y, th, curvature[:k], length_m[:k], p.step_m, blocked, p.grid_ox, p.grid_oy, p.grid_res
        ):
            return best
    return -1


@njit(cache=True, nogil=True)
def run(
    p: Params,
    blocked: np.ndarray,
    obstacle_m: np.ndarray,
    samples: np.ndarray,
    n_succ: np.ndarray,
    to_index: np.ndarray,
    direction: np.ndarray,
    kappas: np.ndarray,
    solver: np.ndarray,
    backwards: np.ndarray,
    twice: np.ndarray,
    extra: np.ndarray,
    mirrors: np.ndarray,
    steers: np.ndarray,
    shapes: np.ndarray,
    reflect: np.ndarray,
    node_f: np.ndarray,
    node_i: np.ndarray,
    full_h: np.ndarray,
    hf: np.ndarray,
    ht: np.ndarray,
    hn: np.ndarray,
    best_g: np.ndarray,
    seen: np.ndarray,
    si: np.ndarray,
    sf: np.ndarray,
) -> int:
    """Search on from the state in `node_*`, the heap (`hf`, `ht`, `hn`: f, tie, node), the closed set
    (`best_g` where `seen`) and the scalars `si`, `sf`, until the search ends (`DONE`), a step ends
    (`YIELD`) or the arrays must grow (`GROW`); `ERROR`: a key off the closed set's table (a bug).

    `samples` (n_steer, max successors, m, 3), `n_succ`, `to_index`, `direction`: the primitives by
    steering index, padded; `solver` ... `mirrors`: `reeds_shepp`'s word table; `steers`, `shapes`,
    `reflect`: how a solution row becomes segments."""
    rows = np.empty((44, 6))
    radii = np.empty(5)
    curvature = np.empty(5)
    length_m = np.empty(5)
    w = p.heuristic_weight
    radius = p.radius_m
    max_succ = samples.shape[1]
    m = samples.shape[2]
    n_nodes = si[S_NODES]
    size = si[S_HEAP]
    tie = si[S_TIE]
    expansions = si[S_EXPANSIONS]
    status = DONE
    while True:
        nid = si[S_PENDING]
        if nid >= 0:  # a yield came between this node's pop and its expansion
            si[S_PENDING] = -1
        else:
            if size == 0:
                break
            if n_nodes + max_succ > node_f.shape[0] or size + max_succ + 1 > hf.shape[0]:
                status = GROW
                break
            f, nid = _pop(hf, ht, hn, size)
            size -= 1
            if si[S_BEST_NODE] >= 0 and f >= sf[SF_BEST_COST] - EPS:
                break
            key = cell_key(node_f[nid, NX], node_f[nid, NY], node_f[nid, NTH], p)
            if key < 0:
                status = ERROR
                break
            g = node_f[nid, NG]
            if g > (best_g[key] if seen[key] else math.inf) + EPS:
                continue  # a cheaper node took this cell
            if p.use_kinematic and not full_h[nid]:
                full_h[nid] = True
                f_full = g + w * _kinematic(
                    node_f[nid, NX], node_f[nid, NY], node_f[nid, NTH], p, solver, backwards, twice, extra,
                    mirrors,
                )  # fmt: skip
                if f_full > f + EPS:
                    size = _push(hf, ht, hn, size, f_full, tie, nid)
                    tie += 1
                    continue
            expansions += 1
            if expansions > p.max_expansions:
                break
            if expansions % p.yield_every == 0:
                si[S_PENDING] = nid
                status = YIELD
                break
        x, y, th = node_f[nid, NX], node_f[nid, NY], node_f[nid, NTH]
        g = node_f[nid, NG]
        key = cell_key(x, y, th, p)
        d_node = node_f[nid, NDIR]
        dist = py_hypot(x - p.goal_x, y - p.goal_y)
        near = dist < 2.0 * radius
        if dist <= p.shot_range_m and (p.exhaustive or near or expansions % p.shot_every == 1):
            candidates = p.shot_candidates if p.exhaustive or near else 1
            r = _shot(
                x, y, th, candidates, p, blocked, solver, backwards, twice, extra, mirrors, steers, shapes,
                reflect, rows, radii, curvature, length_m,
            )  # fmt: skip
            if r >= 0:
                c = g + _rs_cost(radii, curvature, _n_segments(rows[r, 1], shapes), p, d_node)
                if si[S_BEST_NODE] < 0 or c < sf[SF_BEST_COST]:
                    si[S_BEST_NODE] = nid
                    si[S_BEST_WORD] = int(rows[r, 1])
                    si[S_BEST_MIRROR] = int(rows[r, 2])
                    sf[SF_BEST_COST] = c
                    sf[SF_T], sf[SF_U], sf[SF_V] = rows[r, 3], rows[r, 4], rows[r, 5]
                if not p.exhaustive:
                    break
        steer = node_i[nid, NSTEER]
        c, s = math.cos(th), math.sin(th)
        for j in range(n_succ[steer]):
            # the edge's samples moved to the node (`hybrid_astar._edge_samples`), the last one the
            # successor. The reference checks them all, then the closed set and the heuristic; any
            # order gives the same successors, and the end pose first, then the closed set, then the
            # rest of the edge skips most lookups (the end is the likeliest to collide, and most
            # successors of a dense search fall in cells already reached more cheaply).
            lx, ly = samples[steer, j, m - 1, 0], samples[steer, j, m - 1, 1]
            ex = x + c * lx - s * ly
            ey = y + s * lx + c * ly
            eth = th + samples[steer, j, m - 1, 2]
            if _blocked_at(ex, ey, eth, blocked, p.grid_ox, p.grid_oy, p.grid_res):
                continue
            d = direction[steer, j]
            to = to_index[steer, j]
            cost = p.arc_m * (1.0 if d > 0 else p.reverse_factor)
            cost += p.steer_change_weight * abs(kappas[to] - kappas[steer]) * radius
            cost += p.steer_weight * abs(kappas[to]) * radius * p.arc_m
            if d_node != 0.0 and d != d_node:
                cost += p.direction_change_m
            g2 = g + cost
            k2 = cell_key(ex, ey, eth, p)
            if k2 < 0:
                status = ERROR
                break
            if k2 == key or g2 >= (best_g[k2] if seen[k2] else math.inf) - EPS:
                continue
            h2 = 0.0
            if p.use_obstacle:
                h2 = max(h2, _obstacle(ex, ey, obstacle_m, p))
            if p.use_kinematic:
                h2 = max(h2, math.hypot(ex - p.goal_x, ey - p.goal_y))
            if not math.isfinite(h2):
                continue
            hit = False
            for i in range(m - 1):
                lx, ly, lth = samples[steer, j, i, 0], samples[steer, j, i, 1], samples[steer, j, i, 2]
                px, py = x + c * lx - s * ly, y + s * lx + c * ly
                if _blocked_at(px, py, th + lth, blocked, p.grid_ox, p.grid_oy, p.grid_res):
                    hit = True
                    break
            if hit:
                continue
            best_g[k2] = g2
            seen[k2] = True
            child = n_nodes
            n_nodes += 1
            node_f[child, NX], node_f[child, NY], node_f[child, NTH] = ex, ey, eth
            node_f[child, NDIR], node_f[child, NG] = d, g2
            node_i[child, NSTEER], node_i[child, NPARENT], node_i[child, NPRIM] = to, nid, j
            full_h[child] = False
            size = _push(hf, ht, hn, size, g2 + w * h2, tie, child)
            tie += 1
        if status == ERROR:
            break
    si[S_NODES] = n_nodes
    si[S_HEAP] = size
    si[S_TIE] = tie
    si[S_EXPANSIONS] = expansions
    return status
