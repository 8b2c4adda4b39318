"""Synthetic HDL-64E revolutions of a flat road with painted lines and a curb, for the lane-marker tests.

The road runs along the sensor's x axis turned by `road_angle_rad`; "lateral" is the signed distance to
the left of the road axis through the sensor. Each ray of 64 beams (+2 .. -24.8 deg) x `n_azimuth`
azimuths is cast analytically onto the road (z = -height), the curb's vertical face or the raised
sidewalk beyond it; rays that hit nothing within `max_range_m` give no return (as a real sensor's
upward beams do). Points come beam by beam in azimuth order, like KITTI's files, or interleaved across
beams in firing order (`interleaved=True`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from bywire.host.perception.scan import (
    HDL64E_BEAMS,
    HDL64E_ELEVATION_BOTTOM_DEG,
    HDL64E_ELEVATION_TOP_DEG,
    Scan,
)

ASPHALT = 0.3
PAINT = 0.75
SIDEWALK = 0.4


def road_scan(
    *,
    lines_lateral_m: Sequence[float] = (-1.75, 1.75, 5.25),
    line_width_m: float = 0.15,
    curb_lateral_m: float | None = -3.0,
    curb_height_m: float = 0.15,
    road_angle_rad: float = 0.0,
    sensor_height_m: float = 1.73,
    n_azimuth: int = 2000,
    max_range_m: float = 60.0,
    reflectance_noise: float = 0.03,
    beam_gain_spread: float = 0.3,
    interleaved: bool = False,
    stamp_s: float = 0.0,
    seed: int = 0,
) -> Scan:
    """One revolution; see the module docstring. The curb's sidewalk lies beyond `curb_lateral_m` (on the
    side of its sign). Each beam reads the road with its own gain (1 +- `beam_gain_spread` / 2): what the
    per-beam median has to absorb."""
    rng = np.random.default_rng(seed)
    el = np.radians(np.linspace(HDL64E_ELEVATION_TOP_DEG, HDL64E_ELEVATION_BOTTOM_DEG, HDL64E_BEAMS))
    az = np.arange(n_azimuth) * (2.0 * math.pi / n_azimuth) - math.pi
    elg, azg = np.meshgrid(el, az, indexing="ij")  # (beams, azimuths)
    dx, dy, dz = np.cos(elg) * np.cos(azg), np.cos(elg) * np.sin(azg), np.sin(elg)
    # lateral coordinate of the ray per unit t: n . d with n the road's left normal
    nx, ny = -math.sin(road_angle_rad), math.cos(road_angle_rad)
    dl = nx * dx + ny * dy
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(dz < 0.0, -sensor_height_m / dz, np.inf)  # the road plane
        kind = np.zeros(dz.shape, np.int8)  # 0 road, 1 curb face, 2 sidewalk
        if curb_lateral_m is not None:
            side = math.copysign(1.0, curb_lateral_m)
            beyond = (t * dl - curb_lateral_m) * side > 0.0
            t_face = curb_lateral_m / dl
            z_face = t_face * dz
            face = beyond & (z_face <= -sensor_height_m + curb_height_m)
            top = beyond & ~face
            t = np.where(face, t_face, t)
            t = np.where(top, (-sensor_height_m + curb_height_m) / dz, t)
            kind[face] = 1
            kind[top] = 2
    hit = np.isfinite(t) & (t * np.cos(elg) <= max_range_m) & (t > 0.0)
    t = np.where(hit, t, 0.0)
    x, y, z = t * dx, t * dy, t * dz
    lateral = t * dl
    gain = 1.0 + beam_gain_spread * (rng.random(HDL64E_BEAMS) - 0.5)
    refl = np.full(dz.shape, ASPHALT)
    refl[kind == 2] = SIDEWALK
    on_road = kind == 0
    for lat in lines_lateral_m:
        refl[on_road & (np.abs(lateral - lat) <= line_width_m / 2.0)] = PAINT
    refl = np.clip(refl * gain[:, None] + reflectance_noise * rng.standard_normal(dz.shape), 0.0, 1.0)
    beam = np.broadcast_to(np.arange(HDL64E_BEAMS, dtype=np.int16)[:, None], dz.shape)
    if interleaved:  # firing order: all beams at one azimuth, then the next azimuth
        x, y, z, refl, beam, hit = (a.T for a in (x, y, z, refl, beam, hit))
    sel = hit.ravel()
    xyz = np.column_stack((x.ravel()[sel], y.ravel()[sel], z.ravel()[sel])).astype(np.float32)
    return Scan(
        xyz_m=xyz,
        reflectance=refl.ravel()[sel].astype(np.float32),
        beam=np.ascontiguousarray(beam.ravel()[sel]).astype(np.int16),
        stamp_s=stamp_s,
        sensor_height_m=sensor_height_m,
    )


def lateral_of(xy_m: np.ndarray, road_angle_rad: float = 0.0) -> np.ndarray:
    """Signed lateral position (left > 0) of sensor-frame points relative to the road axis."""
    return -math.sin(road_angle_rad) * xy_m[:, 0] + math.cos(road_angle_rad) * xy_m[:, 1]
