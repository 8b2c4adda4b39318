"""Delay-compensated leader prediction for the follow controller (beyond seed 003 Sec. V).

Seed 003 IV-C predicts a leader with constant acceleration, "abstracting from latency": the received
state is predicted to the query time. What that cannot remove is the lag *behind* the query time on our
side: the controller's command reaches the road through the ECU's acceleration loop and the drivetrain
(~0.2-0.25 s first-order lag measured on the Passat plant) after the world model's and the
controller's sampling (~0.1 s together). A follower whose feed-forward is the leader's present
acceleration therefore answers a change ~0.3 s late, and at a 0.6 s headway that lag alone makes a
cooperative follower amplify its leader's acceleration (|H| ~ 1.1 near 0.12 Hz; Ploeg et al., IEEE
T-ITS 15(2) 2014 show the same minimum-headway/delay trade-off for CACC).

The compensation predicts the leader's acceleration ``lead_s`` ahead from its jerk,
``a_c = a + lead_s * j``, and shifts the whole predicted trajectory to that acceleration: speeds by
``(a_c - a) t``, kept within [0, v_max], and positions by the integral of that change. In the frequency
domain the feed-forward gets the phase lead ``(1 + lead_s s) / (1 + tau_j s)``, with ``tau_j`` the jerk
filter below. With the follow QP's gains and lead_s = 0.3 s the linearised string
(host/modules/control/platoon.py has the numbers) has ``|H| <= 1`` over the band for total lags of
0.25-0.5 s; much more lead (>= 0.4 s) over-compensates and amplifies near 0.7-0.9 Hz.

The jerk comes from successive accelerations of the same vehicle, as the world model reports them
(one estimate per update), through a first-order low-pass of time constant ``jerk_tau_s``: the
accelerations are V2V values (10 Hz, 0.01 m/s^2 resolution) or radar-track estimates, and a raw
difference of those would turn their noise into jerk spikes. The result is bounded (``max_jerk_mps3``)
and the compensated acceleration to ``accel_bounds_mps2`` (never past the measured one): a lost or wrong
jerk estimate can shift the prediction only that much.
"""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from bywire.host.limits import ACCEL_MAX_MPS2, ACCEL_MIN_MPS2

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class LeadCompensationParams:
    lead_s: float = 0.3
    """How far ahead the leader's acceleration is predicted (our actuation and sampling lag), s."""
    jerk_tau_s: float = 0.2
    """Time constant of the jerk low-pass, s."""
    max_jerk_mps3: float = 10.0
    accel_bounds_mps2: tuple[float, float] = (ACCEL_MIN_MPS2, ACCEL_MAX_MPS2)  # host.limits
    max_update_gap_s: float = 0.5
    """A vehicle not reported for longer restarts its estimate (a gap is not a jerk)."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.lead_s <= 2.0:
            raise ValueError(f"lead_s must be within 0 .. 2 s, got {self.lead_s}")
        if not self.jerk_tau_s > 0.0:
            raise ValueError(f"jerk_tau_s must be > 0 s, got {self.jerk_tau_s}")
        if not self.max_jerk_mps3 > 0.0:
            raise ValueError(f"max_jerk_mps3 must be > 0, got {self.max_jerk_mps3}")
        lo, hi = self.accel_bounds_mps2
        if not lo < 0.0 < hi:
            raise ValueError(f"accel_bounds_mps2 must bracket 0, got {self.accel_bounds_mps2}")


@dataclass
class _JerkState:
    t_s: float
    accel_mps2: float
    jerk_mps3: float


class JerkEstimator:
    """Filtered jerk per vehicle from the accelerations of successive world-model updates."""

    def __init__(self, params: LeadCompensationParams) -> None:
        self.params = params
        self._state: dict[Hashable, _JerkState] = {}

    def update(self, t_s: float, accels: dict[Hashable, float]) -> dict[Hashable, float]:
        """Feed one update (vehicle key -> acceleration at t_s); returns the jerk of every key in it.

        Vehicles absent from the update are forgotten; a repeated t_s (the same update seen twice)
        changes nothing."""
        p = self.params
        out: dict[Hashable, float] = {}
        new: dict[Hashable, _JerkState] = {}
        for key, a in accels.items():
            st = self._state.get(key)
            if st is None or not np.isfinite(a) or t_s - st.t_s > p.max_update_gap_s or t_s < st.t_s:
                new[key] = _JerkState(t_s, a if np.isfinite(a) else 0.0, 0.0)
            elif t_s == st.t_s:
                new[key] = st
            else:
                dt = t_s - st.t_s
                raw = (a - st.accel_mps2) / dt
                alpha = dt / (p.jerk_tau_s + dt)
                jerk = st.jerk_mps3 + alpha * (raw - st.jerk_mps3)
                jerk = min(max(jerk, -p.max_jerk_mps3), p.max_jerk_mps3)
                new[key] = _JerkState(t_s, a, jerk)
            out[key] = new[key].jerk_mps3
        self._state = new
        return out


def _shift_speeds(
    rel_t: FloatArray, positions_m: FloatArray, speeds_mps: FloatArray, new_speeds: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Positions consistent with changed speeds: plus the trapezoidal integral of the change (exact for
    a linear change, consistent where clipped)."""
    dv = new_speeds - speeds_mps
    shift = np.concatenate(([0.0], np.cumsum(0.5 * (dv[1:] + dv[:-1]) * np.diff(rel_t))))
    return positions_m + shift, new_speeds


def cap_prediction_speed(
    t_s: FloatArray, positions_m: FloatArray, speeds_mps: FloatArray, speed_max_mps: float
) -> tuple[FloatArray, FloatArray]:
    """The prediction with its speeds capped at ``speed_max_mps`` (positions follow).

    The world model predicts every vehicle up to the vehicle manager's own bound (130 km/h); the follow
    QP keeps *us* below the GCDC's 100 km/h. A leader predicted to accelerate through our limit looks
    like one pulling away for good, and the QP answers with more acceleration now than following it
    needs (then brakes back: ~0.4 m/s^2 of overshoot at the end of a speed-up in the heat). Seed 003
    IV-C's prediction respects "the velocity limits": for our controller those are ours."""
    if not np.any(speeds_mps > speed_max_mps):
        return positions_m, speeds_mps
    return _shift_speeds(t_s - t_s[0], positions_m, speeds_mps, np.minimum(speeds_mps, speed_max_mps))


def compensate_prediction(
    t_s: FloatArray,
    positions_m: FloatArray,
    speeds_mps: FloatArray,
    accel_mps2: float,
    jerk_mps3: float,
    params: LeadCompensationParams,
    speed_max_mps: float,
) -> tuple[FloatArray, FloatArray]:
    """The prediction (positions, speeds on times t_s >= 0, t_s[0] the present) shifted from the
    leader's acceleration ``accel_mps2`` to ``accel_mps2 + lead_s * jerk_mps3`` (bounded)."""
    if not (np.isfinite(accel_mps2) and np.isfinite(jerk_mps3)):
        return positions_m, speeds_mps  # nothing to predict from: the uncompensated prediction
    # Anticipate within the GCDC's envelope only: the lead may push the prediction up to the bounds but
    # not beyond them, and never undoes what the leader is measured to do (a leader braking at -8 stays
    # predicted at -8). Anticipating an emergency brake beyond -4.5 would turn the onset's jerk into an
    # earlier, harder emergency than the measured braking warrants.
    lo, hi = params.accel_bounds_mps2
    a_c = min(max(accel_mps2 + params.lead_s * jerk_mps3, min(lo, accel_mps2)), max(hi, accel_mps2))
    delta = a_c - accel_mps2
    if delta == 0.0:
        return positions_m, speeds_mps
    rel = t_s - t_s[0]
    speeds = np.clip(speeds_mps + delta * rel, 0.0, max(speed_max_mps, float(np.max(speeds_mps))))
    return _shift_speeds(rel, positions_m, speeds_mps, speeds)


__all__ = ["JerkEstimator", "LeadCompensationParams", "cap_prediction_speed", "compensate_prediction"]
