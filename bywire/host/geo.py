"""The host's one local metric frame: the world model's (seed 003 Sec. IV-A: "a local Mercator coordinate
system with its origin anchored at the first point of the GPS track") and the road network's (seed 000
Sec. 8 works in a local plane; the origin is the network's first waypoint, `roadnet.geo.frame_for`).

`LocalFrame` is a transverse Mercator projection (pyproj, WGS84, scale 1, no false easting/northing)
centred on a configurable origin: x east, y north, in metres. Within a few km of the origin its scale
error is below 1e-6 (1 mm per km), so distances in this plane are metric for our purposes.

Headings: the world model uses the mathematical convention on the local plane, ``heading_rad`` counter-
clockwise from the x (east) axis, as the vehicle model does. NMEA headings and courses are true azimuths
(degrees clockwise from true north). Grid north of the projection differs from true north by the meridian
convergence ``gamma = (lon - lon0) * sin(lat)`` (first order; 0.08 deg at 7 km east of the origin at
51.6 deg N, and exact to < 1e-7 rad within tens of km, checked against pyproj's factors in the tests), so
``heading = pi/2 - (azimuth_true - gamma)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
import pyproj

FloatArray = npt.NDArray[np.float64]
TWO_PI = 2.0 * math.pi


def wrap_angle(angle_rad: float) -> float:
    """Angle wrapped to [-pi, pi)."""
    return (angle_rad + math.pi) % TWO_PI - math.pi


def wrap_angles(angle_rad: FloatArray) -> FloatArray:
    return np.asarray((angle_rad + math.pi) % TWO_PI - math.pi, dtype=np.float64)


@dataclass(frozen=True)
class LocalFrame:
    """Transverse Mercator plane around (origin_lat_deg, origin_lon_deg); x east, y north [m]."""

    origin_lat_deg: float
    origin_lon_deg: float
    _fwd: pyproj.Transformer = field(init=False, repr=False, compare=False)
    _inv: pyproj.Transformer = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        lat, lon = self.origin_lat_deg, self.origin_lon_deg
        if not (
            math.isfinite(lat) and math.isfinite(lon) and -85.0 <= lat <= 85.0 and -180.0 <= lon <= 180.0
        ):
            raise ValueError(f"LocalFrame origin out of range: lat {lat!r}, lon {lon!r} (degrees)")
        # The pipeline PROJ builds from EPSG:4326 -> this tmerc, written out: pyproj keeps one PROJ
        # object per thread and builds it at a thread's first call; from CRS definitions that looks
        # them up in proj.db (20-100 ms holding the GIL, a stall of the whole host each time a module
        # thread starts or restarts), from a pipeline it takes 0.2 ms. Same coordinates to the bit.
        tmerc = f"+proj=tmerc +lat_0={lat!r} +lon_0={lon!r} +k=1 +x_0=0 +y_0=0 +ellps=WGS84"
        deg = "+proj=unitconvert +xy_in=deg +xy_out=rad"
        fwd = pyproj.Transformer.from_pipeline(f"+proj=pipeline +step {deg} +step {tmerc}")
        inv = pyproj.Transformer.from_pipeline(f"+proj=pipeline +step +inv {tmerc} +step +inv {deg}")
        object.__setattr__(self, "_fwd", fwd)
        object.__setattr__(self, "_inv", inv)

    def to_local(self, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        x, y = self._fwd.transform(lon_deg, lat_deg)
        return float(x), float(y)

    def to_geodetic(self, x_m: float, y_m: float) -> tuple[float, float]:
        """(lat_deg, lon_deg) of a local point."""
        lon, lat = self._inv.transform(x_m, y_m)
        return float(lat), float(lon)

    def to_local_many(self, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        x, y = self._fwd.transform(np.asarray(lon_deg, np.float64), np.asarray(lat_deg, np.float64))
        return np.asarray(x, np.float64), np.asarray(y, np.float64)

    def to_geodetic_many(self, x_m: npt.ArrayLike, y_m: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """(lat_deg, lon_deg) arrays of local points."""
        lon, lat = self._inv.transform(np.asarray(x_m, np.float64), np.asarray(y_m, np.float64))
        return np.asarray(lat, np.float64), np.asarray(lon, np.float64)

    # The road network's names for the array conversions (`roadnet.geo.CoordinateFrame`).
    to_xy = to_local_many
    to_latlon = to_geodetic_many

    def convergence_rad(self, lat_deg: float, lon_deg: float) -> float:
        """Meridian convergence gamma: grid azimuth = true azimuth - gamma."""
        return math.radians(lon_deg - self.origin_lon_deg) * math.sin(math.radians(lat_deg))

    def heading_from_true_azimuth(self, azimuth_deg: float, lat_deg: float, lon_deg: float) -> float:
        """Local heading (rad, CCW from east) of a true azimuth (deg, CW from true north) at a point."""
        grid_az = math.radians(azimuth_deg) - self.convergence_rad(lat_deg, lon_deg)
        return wrap_angle(math.pi / 2.0 - grid_az)

    def true_azimuth_from_heading(self, heading_rad: float, lat_deg: float, lon_deg: float) -> float:
        """True azimuth in [0, 360) degrees of a local heading at a point."""
        grid_az = math.pi / 2.0 - heading_rad
        return math.degrees(grid_az + self.convergence_rad(lat_deg, lon_deg)) % 360.0
