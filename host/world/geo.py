"""The world model's local frame: `bywire.host.geo` (one transverse Mercator frame for the whole host)."""

from bywire.host.geo import TWO_PI, FloatArray, LocalFrame, wrap_angle, wrap_angles

__all__ = ["TWO_PI", "FloatArray", "LocalFrame", "wrap_angle", "wrap_angles"]
