"""The linearised string model of the follow QP (host/platoon/string_model.py): the design check
behind the GCDC configuration's `accel_ref: leader` and `accel_lead_s`."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest

from bywire.host.platoon.follow_qp import FollowParams
from bywire.host.platoon.string_model import Lags, QpGains, peak_gain, qp_gains, string_gain

GCDC = FollowParams(headway_s=0.6, reserve_m=8.0, min_gap_m=2.0)
# The lags the design must tolerate: our car's acceleration response (0.2-0.25 s measured on the plant,
# up to 0.3 s), its dead time, and the information delay of a 10 Hz world model and V2V.
LAG_CASES = [
    Lags(tau_s=tau, actuation_delay_s=act, information_delay_s=info)
    for tau, act, info in itertools.product((0.2, 0.25, 0.3), (0.0, 0.05, 0.1), (0.05, 0.1, 0.2))
]


@pytest.fixture(scope="module")
def paper_gains() -> QpGains:
    return qp_gains(GCDC)


@pytest.fixture(scope="module")
def coop_gains() -> QpGains:
    return qp_gains(replace(GCDC, accel_ref="leader"))


def test_steady_state_gains_keep_the_time_gap(paper_gains: QpGains) -> None:
    # Both cars faster by dv: the desired gap grows by t_h dv, the command is that gap error's share.
    g = paper_gains
    assert g.lead_speed_per_s + g.host_speed_per_s == pytest.approx(-GCDC.headway_s * g.gap_per_s2, rel=1e-3)
    assert g.gap_per_s2 > 0 and g.lead_speed_per_s > 0 and g.host_speed_per_s < 0


def test_unit_gain_at_low_frequency(coop_gains: QpGains) -> None:
    h = string_gain(coop_gains, Lags(), np.array([1e-4]))
    assert h[0] == pytest.approx(1.0, abs=1e-3)  # a constant-time-gap follower copies slow motion


def test_the_papers_penalty_amplifies_low_frequencies(paper_gains: QpGains) -> None:
    # w_acc a^2 passes on a quarter of the leader's acceleration: a constant-time-gap PD, |H| > 1.
    peak, f = peak_gain(paper_gains, Lags())
    assert peak > 1.1 and 0.04 < f < 0.12
    assert paper_gains.lead_accel < 0.3


def test_leader_feed_forward_alone_is_not_enough_for_slow_cars(coop_gains: QpGains) -> None:
    peak, _ = peak_gain(coop_gains, Lags(tau_s=0.3, actuation_delay_s=0.1, information_delay_s=0.2))
    assert peak > 1.05


def test_delay_compensated_feed_forward_is_string_stable_over_the_lag_range(coop_gains: QpGains) -> None:
    worst = max(peak_gain(coop_gains, replace(lags, lead_s=0.2, jerk_tau_s=0.2))[0] for lags in LAG_CASES)
    assert worst <= 1.0 + 1e-3


def test_too_much_lead_amplifies_high_frequencies(coop_gains: QpGains) -> None:
    peak, f = peak_gain(coop_gains, Lags(lead_s=0.5, jerk_tau_s=0.2))
    assert peak > 1.2 and f > 0.4
