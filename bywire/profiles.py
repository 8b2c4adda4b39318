"""Piecewise time profiles as files write them, ``((t_s, value), ...)`` in ascending time: a zero-order hold
(steps: requests, grades) and a linear ramp (speeds). Shared by the host's command script and the
simulator."""

from __future__ import annotations

import itertools

Profile = tuple[tuple[float, float], ...]


def step_value(profile: Profile, t_s: float, default: float = 0.0) -> float:
    """Zero-order hold of a piecewise profile: the value of the last point at or before t_s."""
    value = default
    for t_point, v_point in profile:
        if t_point > t_s:
            break
        value = v_point
    return value


def ramp_value(profile: Profile, t_s: float, default: float = 0.0) -> float:
    """Linear interpolation of a profile, held constant outside its range."""
    if not profile:
        return default
    if t_s <= profile[0][0]:
        return profile[0][1]
    for (t0, v0), (t1, v1) in itertools.pairwise(profile):
        if t_s <= t1:
            return v0 + (v1 - v0) * (t_s - t0) / (t1 - t0)
    return profile[-1][1]
