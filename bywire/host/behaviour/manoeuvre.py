"""Manoeuvre geometry off the lane graph: K-turn arcs, the passing shift, the zone stand-in (Secs. 8, 10).

A manoeuvre is a sequence of `Leg`s, each a densely sampled path driven in one direction and ending in
a stop (where the gear may change). Samples are in driving order with the *body* heading (the nose, also
reversing) and the steering curvature tan(delta)/l, as `host/lateral.PathSamples` wants them (for a
reversing leg kappa = -dheading/ds, see `host/lateral.py`). Each leg runs on 1 m past its end point
(`end_s_m` marks the end) so that a stop point at the end lies inside the stub.

K-turn (`kturn_legs`, DriveKTurn): the three-point turn onto the adjacent opposite lane `offset_m` to
the left, from AnnieWAY's published planner (`c2_kturn`), derived here. In the start frame (rear axle
at the origin, heading +x) with turning radius r and offset delta < 2r:

    leg 1, forward, left:   circle C1 = (0, r), angle -pi/2 -> theta1 = atan2(-(r - delta/2), w),
    leg 2, reverse, right:  circle C2 = (w, delta/2), angle pi + theta1 -> pi - theta1,
    leg 3, forward, left:   circle C3 = (0, delta - r), angle -theta1 -> pi/2,

with w = sqrt(4 r² - (r - delta/2)²). |C1 C2| = |C3 C2| = 2r, so consecutive arcs touch where the gear
changes (same position and heading, a cusp), and the turn ends at (0, delta) heading pi: on the
opposite lane, alongside the start, facing back. The three arcs turn the heading by 2 (pi/2 + theta1) +
(-2 theta1) = pi. With delta >= 2r a single forward half circle of radius delta/2 does it. The swept
area reaches about r + L_front beyond the start lane's left edge (5.5 m radius, 3.7 m lanes: 1.5 m past
a 30 ft street): whether the road is wide enough is the navigation layer's check (Sec. 10's hybrid A*
plans multi-point turns in tight streets); this planner does not look at road edges.

Passing (`shifted_leg`, PassObstacle): the lane's own path shifted sideways by d(s), a quintic
smoothstep d = D (10 u³ - 15 u⁴ + 6 u⁵) out and back (continuous curvature), D the lane spacing.

Planned path (`path_leg`, Zone): one stretch of the zone planner's path (`host.navigation`, Sec. 10:
rear-axle poses driven in one direction), its curvature from the heading's change along it.

Zone stand-in (`polyline_leg`, Zone, where the planner finds no path): straight lines between given
points, heading constant per line and curvature 0 (the controller takes the corners as they come).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from .route_view import locate_on
from .situation import Direction, PathStub, stub_from_arrays

__all__ = [
    "Leg",
    "kturn_legs",
    "path_leg",
    "polyline_leg",
    "quintic_step",
    "shifted_leg",
    "steering_speed_cap",
]

FloatArray = npt.NDArray[np.float64]
SAMPLE_M = 0.25  # like the road graph's paths
RUN_ON_M = 1.0  # each leg runs on this far past its end point
STEER_PREVIEW_M = 8.0  # beyond this a jump of full lock costs nothing at the zone speed (5 m)


@dataclass(frozen=True, eq=False)
class Leg:
    """One leg of a manoeuvre (see the module docstring). `base_s` maps a shifted leg to route arc length."""

    x: FloatArray
    y: FloatArray
    heading: FloatArray  # body heading, unwrapped
    kappa: FloatArray  # steering curvature
    s: FloatArray
    direction: Direction
    end_s_m: float  # where the leg's end point lies (the samples run on past it)
    base_s: FloatArray | None = field(default=None)

    @property
    def travel_heading(self) -> FloatArray:
        return self.heading if self.direction == 1 else self.heading + np.pi

    def locate(self, x_m: float, y_m: float, s_hint_m: float) -> tuple[float, float]:
        """(s, lateral offset) of the rear axle on this leg, searched around the last arc length."""
        s, lateral, _ = locate_on(self.x, self.y, self.s, self.travel_heading, x_m, y_m, s_hint_m, 5.0, 10.0)
        return s, lateral

    def locate_anywhere(self, x_m: float, y_m: float) -> float:
        """Arc length of the foot of (x, y), searched over the whole leg (for points of the leg itself)."""
        s, _, _ = locate_on(
            self.x, self.y, self.s, self.travel_heading, x_m, y_m, 0.0, 0.0, float(self.s[-1]) + 1.0
        )
        return s

    def stub(self, s0_m: float, length_m: float, back_m: float) -> tuple[PathStub, float]:
        lo, hi = max(s0_m - back_m, 0.0), min(s0_m + length_m, float(self.s[-1]))
        keep = (self.s > lo) & (self.s < hi)
        ss = np.concatenate(([lo], self.s[keep], [hi])) if hi > lo else np.array([lo])
        stub = stub_from_arrays(
            np.interp(ss, self.s, self.x),
            np.interp(ss, self.s, self.y),
            np.interp(ss, self.s, self.heading),
            np.interp(ss, self.s, self.kappa),
            self.direction,
        )
        return stub, min(max(s0_m - lo, 0.0), stub.length_m)

    def route_s(self, s_m: float) -> float:
        """The route arc length of a point of a shifted leg (ValueError for other legs)."""
        if self.base_s is None:
            raise ValueError("Leg.route_s: this leg is not a shifted lane")
        return float(np.interp(s_m, self.s, self.base_s))

    def point_at(self, s_m: float) -> tuple[float, float, float]:
        return (
            float(np.interp(s_m, self.s, self.x)),
            float(np.interp(s_m, self.s, self.y)),
            float(np.interp(s_m, self.s, self.heading)),
        )


def _with_run_on(x: FloatArray, y: FloatArray, h: FloatArray, k: FloatArray, direction: Direction) -> Leg:
    """Arc length, and RUN_ON_M of straight continuation in the travel direction past the end."""
    travel = float(h[-1]) + (0.0 if direction == 1 else math.pi)
    n_on = max(round(RUN_ON_M / SAMPLE_M), 1)
    step = np.arange(1, n_on + 1) * (RUN_ON_M / n_on)
    x = np.concatenate((x, x[-1] + step * math.cos(travel)))
    y = np.concatenate((y, y[-1] + step * math.sin(travel)))
    h = np.concatenate((h, np.full(n_on, h[-1])))
    k = np.concatenate((k, np.zeros(n_on)))
    s = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))))
    return Leg(x, y, h, k, s, direction, float(s[-1 - n_on]))


def _arc(
    cx: float, cy: float, r: float, phi0: float, phi1: float, direction: Direction
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Samples of a counter-clockwise arc (phi increasing) in the start frame: body heading and kappa.

    Forward, the body heading is the travel heading phi + pi/2 and kappa = +1/r (steer left); reversing
    along the same counter-clockwise arc the nose points against the travel, phi - pi/2, and kappa =
    -dheading/ds = -1/r (steer right).
    """
    n = max(math.ceil(r * abs(phi1 - phi0) / SAMPLE_M) + 1, 3)
    phi = np.linspace(phi0, phi1, n)
    x = cx + r * np.cos(phi)
    y = cy + r * np.sin(phi)
    if direction == 1:
        return x, y, phi + 0.5 * np.pi, np.full(n, 1.0 / r)
    return x, y, phi - 0.5 * np.pi, np.full(n, -1.0 / r)


def kturn_legs(
    x_m: float, y_m: float, heading_rad: float, offset_m: float, radius_m: float
) -> tuple[Leg, ...]:
    """The K-turn from the rear-axle pose onto the lane `offset_m` to the left (see the docstring)."""
    if not (math.isfinite(offset_m) and offset_m > 0.0):
        raise ValueError(f"kturn_legs: offset_m = {offset_m} must be > 0 (the opposite lane lies left)")
    if not (math.isfinite(radius_m) and radius_m > 0.0):
        raise ValueError(f"kturn_legs: radius_m = {radius_m} must be > 0")
    r, d = radius_m, offset_m
    pieces: list[tuple[tuple[FloatArray, FloatArray, FloatArray, FloatArray], Direction]]
    if d >= 2.0 * r:
        pieces = [(_arc(0.0, 0.5 * d, 0.5 * d, -0.5 * math.pi, 0.5 * math.pi, 1), 1)]
    else:
        w = math.sqrt(4.0 * r * r - (r - 0.5 * d) ** 2)
        theta1 = math.atan2(-(r - 0.5 * d), w)
        pieces = [
            (_arc(0.0, r, r, -0.5 * math.pi, theta1, 1), 1),
            (_arc(w, 0.5 * d, r, math.pi + theta1, math.pi - theta1, -1), -1),
            (_arc(0.0, d - r, r, -theta1, 0.5 * math.pi, 1), 1),
        ]
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    legs = []
    for (lx, ly, lh, lk), direction in pieces:
        wx = x_m + c * lx - s * ly
        wy = y_m + s * lx + c * ly
        legs.append(_with_run_on(wx, wy, lh + heading_rad, lk, direction))
    return tuple(legs)


def path_leg(x: FloatArray, y: FloatArray, heading: FloatArray, direction: Direction) -> Leg:
    """A leg along planned rear-axle poses (driving order, body headings), resampled every ~SAMPLE_M."""
    seg = np.hypot(np.diff(x), np.diff(y))
    s = np.concatenate(([0.0], np.cumsum(seg)))
    if s[-1] < 1e-3:
        raise ValueError("path_leg: needs a path of some length")
    h = np.unwrap(heading)
    n = max(math.ceil(s[-1] / SAMPLE_M), 1) + 1
    ss = np.linspace(0.0, float(s[-1]), n)
    xs, ys, hs = np.interp(ss, s, x), np.interp(ss, s, y), np.interp(ss, s, h)
    # steering curvature: forward dheading/ds, reversing -dheading/ds (see the docstring)
    k = np.gradient(hs, ss) * (1.0 if direction == 1 else -1.0)
    return _with_run_on(xs, ys, hs, k, direction)


def polyline_leg(points: Sequence[tuple[float, float]], direction: Direction = 1) -> Leg:
    """Straight lines through `points` (in driving order), sampled every ~0.25 m (see the docstring)."""
    pts = [points[0]]
    for p in points[1:]:
        if math.hypot(p[0] - pts[-1][0], p[1] - pts[-1][1]) > 1e-3:
            pts.append(p)
    if len(pts) < 2:
        raise ValueError("polyline_leg: needs two distinct points")
    xs: list[FloatArray] = []
    ys: list[FloatArray] = []
    hs: list[FloatArray] = []
    for (x0, y0), (x1, y1) in itertools.pairwise(pts):
        length = math.hypot(x1 - x0, y1 - y0)
        n = max(math.ceil(length / SAMPLE_M), 1)
        u = np.arange(n) / n
        xs.append(x0 + u * (x1 - x0))
        ys.append(y0 + u * (y1 - y0))
        travel = math.atan2(y1 - y0, x1 - x0)
        hs.append(np.full(n, travel if direction == 1 else travel + math.pi))
    x = np.concatenate([*xs, [pts[-1][0]]])
    y = np.concatenate([*ys, [pts[-1][1]]])
    h = np.unwrap(np.concatenate([*hs, hs[-1][-1:]]))
    return _with_run_on(x, y, h, np.zeros(x.size), direction)


def quintic_step(u: FloatArray) -> FloatArray:
    """0 -> 1 with zero slope and curvature at both ends: 10 u³ - 15 u⁴ + 6 u⁵ (u clipped to [0, 1])."""
    u = np.clip(u, 0.0, 1.0)
    return np.asarray(u * u * u * (10.0 - 15.0 * u + 6.0 * u * u), dtype=np.float64)


def shifted_leg(
    x: FloatArray,
    y: FloatArray,
    heading: FloatArray,
    s: FloatArray,
    offset_m: float,
    out_start_s_m: float,
    back_start_s_m: float,
    shift_length_m: float,
) -> Leg:
    """A lane path (samples with heading and arc length) shifted `offset_m` to the left between
    `out_start` and `back_start + shift_length`, with quintic ramps of `shift_length` (forward leg)."""
    d = offset_m * (
        quintic_step((s - out_start_s_m) / shift_length_m)
        - quintic_step((s - back_start_s_m) / shift_length_m)
    )
    px = x - d * np.sin(heading)
    py = y + d * np.cos(heading)
    step = np.hypot(np.diff(px), np.diff(py))
    keep = np.concatenate(([True], step > 1e-6))
    px, py, base = px[keep], py[keep], s[keep]
    arc = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(px), np.diff(py)))))
    travel = np.unwrap(np.arctan2(np.gradient(py, arc), np.gradient(px, arc)))
    kappa = np.gradient(travel, arc)
    return Leg(px, py, travel, kappa, arc, 1, float(arc[-1]), base)


def steering_speed_cap(
    leg: Leg, s_m: float, wheelbase_m: float, rate_radps: float, allow_m: float, preview_m: float
) -> float:
    """The highest speed at which the road wheels, turning at `rate_radps` from the angle the leg asks
    for at `s_m`, reach every angle it asks for within `preview_m` ahead no later than `allow_m` past
    where it asks for it (inf where it asks for no change). A leg's curvature is the steering curvature
    tan(delta) / l, so delta = atan(l kappa)."""
    ahead = (leg.s >= s_m) & (leg.s <= s_m + preview_m)
    if not ahead.any():
        return math.inf
    now = math.atan(wheelbase_m * float(np.interp(s_m, leg.s, leg.kappa)))
    turn_s = np.abs(np.arctan(wheelbase_m * leg.kappa[ahead]) - now) / rate_radps
    room_m = leg.s[ahead] - s_m + allow_m
    need = turn_s > 1e-9
    return float(np.min(room_m[need] / turn_s[need])) if need.any() else math.inf
