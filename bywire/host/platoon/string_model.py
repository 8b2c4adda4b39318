"""Linearised string stability of the follow QP (the design check behind seed 003 Sec. V-C/D).

Away from its constraints the follow QP (`follow_qp.FollowQP`) is a linear map of its inputs. For a host
at speed v behind a leader predicted with constant acceleration, its command is

    u = k_gap (gap - r - t_h v) + k_vl v_lead + k_vh v + k_al a_lead        (k_vl + k_vh = -t_h k_gap)

(`qp_gains` finds the four gains by finite differences of the real solver, so whatever the weights,
the horizon or ``accel_ref`` do is in them). Closing the loop through our car, a first-order
acceleration lag ``tau`` after a dead time ``theta_act`` (the ECU's acceleration loop and drivetrain),
with the leader's state reaching the controller ``theta_info`` late and its acceleration fed through
``1 + lead s / (1 + tau_j s)`` (`lead_compensation`: the jerk low-passed), gives the transfer from
the leader's motion to ours

    H(s) = A(s) D(s) (k_gap + k_vl s + k_al F(s) s^2) / (s^2 + A(s) D(s) (k_gap - k_vh s))

where A = e^{-theta_act s} / (tau s + 1), D = e^{-theta_info s}. Successive vehicles' accelerations (and
speeds, and positions) relate by the same H, so ``max |H(j w)|`` over the band is what the heat's
`string_stability` estimates from data (host/platoon/string_stability.py). A follower is string
stable when it is <= 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .follow_qp import FollowParams, FollowQP, LeaderPrediction

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class QpGains:
    gap_per_s2: float  # k_gap
    lead_speed_per_s: float  # k_vl
    host_speed_per_s: float  # k_vh
    lead_accel: float  # k_al


@dataclass(frozen=True)
class Lags:
    """Our car and our information, as the string sees them."""

    tau_s: float = 0.2  # acceleration response of the car (measured on the Passat plant: 0.2-0.25 s)
    actuation_delay_s: float = 0.05
    information_delay_s: float = 0.1  # world model (10 Hz) and controller sampling
    lead_s: float = 0.0  # the feed-forward's prediction lead (lead_compensation)
    jerk_tau_s: float = 0.2


def qp_gains(params: FollowParams, speed_mps: float = 22.0, step: float = 0.05) -> QpGains:
    """The follow QP's command sensitivities at the steady state of a host at `speed_mps`."""
    qp = FollowQP(params)
    gap0 = params.reserve_m + params.headway_s * speed_mps

    def cmd(gap: float = gap0, v_lead: float = speed_mps, v_host: float = speed_mps, a: float = 0.0) -> float:
        lead = LeaderPrediction.constant_accel(gap, v_lead, a, params)
        res = qp.solve(v_host, lead)
        if not res.feasible:
            raise ValueError(f"the follow QP is infeasible at the linearisation point ({res.status})")
        return res.accel_cmd_mps2

    c0 = cmd()
    return QpGains(
        gap_per_s2=(cmd(gap=gap0 + step) - c0) / step,
        lead_speed_per_s=(cmd(v_lead=speed_mps + step) - c0) / step,
        host_speed_per_s=(cmd(v_host=speed_mps + step) - c0) / step,
        lead_accel=(cmd(a=step) - c0) / step,
    )


def string_gain(gains: QpGains, lags: Lags, freq_hz: FloatArray) -> FloatArray:
    """|H(j 2 pi f)| of the docstring at each frequency (f > 0)."""
    s = 2j * np.pi * np.asarray(freq_hz, dtype=np.float64)
    act = np.exp(-s * lags.actuation_delay_s) / (lags.tau_s * s + 1.0)
    info = np.exp(-s * lags.information_delay_s)
    # a + lead * j, j the low-passed derivative of a: a (1 + lead s / (1 + tau_j s))
    ff = gains.lead_accel * (1.0 + lags.lead_s * s / (1.0 + lags.jerk_tau_s * s))
    loop = act * info
    num = loop * (gains.gap_per_s2 + gains.lead_speed_per_s * s + ff * s**2)
    den = s**2 + loop * (gains.gap_per_s2 - gains.host_speed_per_s * s)
    return np.asarray(np.abs(num / den), dtype=np.float64)


def peak_gain(
    gains: QpGains, lags: Lags, band_hz: tuple[float, float] = (0.01, 1.0), n: int = 2000
) -> tuple[float, float]:
    """(max |H|, the frequency in Hz) over the band."""
    f = np.linspace(band_hz[0], band_hz[1], n)
    h = string_gain(gains, lags, f)
    k = int(np.argmax(h))
    return float(h[k]), float(f[k])


__all__ = ["Lags", "QpGains", "peak_gain", "qp_gains", "string_gain"]
