"""Local metric coordinates of a road network (seed 000 sec. 8 works in a local plane; x east, y north, m).

`TransverseMercator(lat0, lon0)` (the host's one frame, `bywire.host.geo.LocalFrame`): a transverse
Mercator projection on the WGS84 ellipsoid whose central meridian and origin are the network's first
waypoint, scale 1 there (pyproj ``+proj=tmerc``).  Over the few
kilometres of an Urban Challenge network its scale error is below 1e-6 (1 mm per km) and its grid north
departs from true north by less than 0.01 deg, so x/y are, for driving purposes, the east/north metres of
a local tangent plane (ENU) - with an exact inverse, which a plain ENU plane lacks.

The 2006 format says WGS84, the 2007 wording ITRF00/GRS80; the two differ by centimetres, below the metre
accuracy of the files, so both are read as WGS84.

`PlanarFrame`: for RNDFs written in local metres (`RoadNetwork.coordinates == "local_m"`, the Cornell
samples), the identity: the file's first number is x, the second y.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
import numpy.typing as npt

from bywire.host.geo import LocalFrame

from .rndf import RoadNetwork

FloatArray = npt.NDArray[np.float64]


class CoordinateFrame(Protocol):
    """File coordinates (lat, lon as written) <-> local metres (x east, y north)."""

    def to_xy(self, lat: npt.ArrayLike, lon: npt.ArrayLike) -> tuple[FloatArray, FloatArray]: ...

    def to_latlon(self, x_m: npt.ArrayLike, y_m: npt.ArrayLike) -> tuple[FloatArray, FloatArray]: ...


# The host's one transverse Mercator frame (bywire.host.geo), here named for what it is.
TransverseMercator = LocalFrame


@dataclass(frozen=True)
class PlanarFrame:
    """Identity frame of local-metre RNDFs: (first, second) number of a point = (x, y)."""

    def to_xy(self, lat: npt.ArrayLike, lon: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        return np.array(lat, dtype=np.float64), np.array(lon, dtype=np.float64)

    def to_latlon(self, x_m: npt.ArrayLike, y_m: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        return np.array(x_m, dtype=np.float64), np.array(y_m, dtype=np.float64)


def frame_for(network: RoadNetwork) -> CoordinateFrame:
    """The network's local frame: origin at its first waypoint (first lane's, else first perimeter's)."""
    if network.coordinates == "local_m":
        return PlanarFrame()
    first = next(network.waypoints(), None)
    if first is None:
        raise ValueError(f"{network.path}: the network has no waypoints to centre a frame on")
    return TransverseMercator(first.lat, first.lon)
