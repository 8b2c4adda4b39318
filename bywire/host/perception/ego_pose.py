"""The car's pose on the ground plane (x, y, yaw) as the occupancy grid and scan registration use it.

Seed 000 section 4 projects each revolution "into a global coordinate system under consideration of
the vehicle's motion": a 2-D rigid transform is enough for that and for scan-to-scan ego-motion
(roll, pitch and height are left to the ground model of each cell). A pose maps points of its own
frame (x forward, y left) into the frame it is given in: p_outer = R(yaw) p + (x, y).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt


@dataclass(frozen=True)
class EgoPose:
    """A 2-D rigid transform: position (metres) and yaw (radians, counter-clockwise from x)."""

    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0

    def compose(self, other: EgoPose) -> EgoPose:
        """`self` after `other`: the pose of `other`'s frame when `other` is given in `self`'s frame."""
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return EgoPose(
            self.x_m + c * other.x_m - s * other.y_m,
            self.y_m + s * other.x_m + c * other.y_m,
            wrap_angle(self.yaw_rad + other.yaw_rad),
        )

    def inverse(self) -> EgoPose:
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return EgoPose(-c * self.x_m - s * self.y_m, s * self.x_m - c * self.y_m, -self.yaw_rad)

    def apply(self, xy_m: npt.NDArray[np.floating]) -> npt.NDArray[np.float64]:
        """Points (N, 2) of this pose's frame in the outer frame."""
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        xy = np.asarray(xy_m, dtype=np.float64)
        x, y = xy[:, 0], xy[:, 1]
        return np.column_stack((c * x - s * y + self.x_m, s * x + c * y + self.y_m))


def wrap_angle(a_rad: float) -> float:
    """The angle in [-pi, pi)."""
    return (a_rad + math.pi) % (2.0 * math.pi) - math.pi
