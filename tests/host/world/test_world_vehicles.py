"""Vehicle manager (seed 003 II-f, IV-C): CYRA prediction known answers and properties against
numerical integration, the per-station filter, latency abstraction, message checks, silent and frozen
senders (the bridge), jumps, and predict_trajectory for the platoon MPC."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.host.geo import LocalFrame
from bywire.host.world.vehicles import (
    VehicleManager,
    VehicleManagerConfig,
    VehicleMessage,
    cyra_predict,
)


def _numeric_cyra(x0, y0, psi0, v0, w, a, t_end, v_max, n=40001):  # type: ignore[no-untyped-def]
    """Reference: trapezoidal integration of the clipped model on a fine grid."""
    s = np.linspace(0.0, t_end, n)
    v = np.clip(v0 + a * s, 0.0, v_max)
    # Heading turns only while moving.
    moving = v > 0.0
    dpsi = np.concatenate(([0.0], np.cumsum(w * np.diff(s) * moving[1:])))
    psi = psi0 + dpsi
    x = x0 + np.trapezoid(v * np.cos(psi), s)
    y = y0 + np.trapezoid(v * np.sin(psi), s)
    return x, y, v[-1]


def test_cyra_circle() -> None:
    # 10 m/s at 0.1 rad/s: a circle of radius 100 m, counter-clockwise from heading east.
    t = np.array([0.0, 0.5 * math.pi / 0.1, math.pi / 0.1, 2 * math.pi / 0.1])
    p = cyra_predict(0.0, 0.0, 0.0, 10.0, 0.1, 0.0, t)
    np.testing.assert_allclose(p.x_m, [0.0, 100.0, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(p.y_m, [0.0, 100.0, 200.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(p.heading_rad, [0.0, 0.5 * math.pi, -math.pi, 0.0], atol=1e-9)


def test_cyra_braking_stops_and_never_reverses() -> None:
    p = cyra_predict(0.0, 0.0, 0.0, 10.0, 0.0, -2.0, np.array([1.0, 5.0, 10.0, 100.0]))
    np.testing.assert_allclose(p.x_m, [9.0, 25.0, 25.0, 25.0])  # v^2 / (2 |a|) = 25 m
    np.testing.assert_allclose(p.speed_mps, [8.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(p.accel_mps2, [-2.0, 0.0, 0.0, 0.0])


def test_cyra_speed_cropped_at_v_max_keeps_turning() -> None:
    p = cyra_predict(0.0, 0.0, 0.0, 25.0, 0.05, 1.0, np.array([0.0, 2.0, 10.0]), speed_max_mps=27.0)
    np.testing.assert_allclose(p.speed_mps, [25.0, 27.0, 27.0])
    np.testing.assert_allclose(p.accel_mps2, [1.0, 0.0, 0.0])
    np.testing.assert_allclose(p.heading_rad, [0.0, 0.1, 0.5])
    ref = _numeric_cyra(0.0, 0.0, 0.0, 25.0, 0.05, 1.0, 10.0, 27.0)
    assert (float(p.x_m[2]), float(p.y_m[2])) == pytest.approx(ref[:2], abs=1e-4)


def test_cyra_heading_stops_turning_at_standstill() -> None:
    p = cyra_predict(0.0, 0.0, 0.0, 4.0, 0.2, -2.0, np.array([2.0, 10.0]))
    assert float(p.heading_rad[0]) == pytest.approx(0.4) and float(p.heading_rad[1]) == pytest.approx(0.4)
    still = cyra_predict(1.0, 2.0, 0.3, 0.0, 0.2, 0.0, np.array([5.0]))
    assert (float(still.x_m[0]), float(still.y_m[0]), float(still.heading_rad[0])) == pytest.approx(
        (1.0, 2.0, 0.3)
    )


def test_cyra_straight_line_limit_is_continuous() -> None:
    t = np.array([10.0])
    straight = cyra_predict(0.0, 0.0, 0.7, 20.0, 0.0, -0.5, t)
    for w in (1e-12, 1e-6, 9e-5, 1.1e-4, 1e-3):  # both sides of the series switch at |w t| = 1e-3
        p = cyra_predict(0.0, 0.0, 0.7, 20.0, w, -0.5, t)
        ref = _numeric_cyra(0.0, 0.0, 0.7, 20.0, w, -0.5, 10.0, 100.0)
        assert (float(p.x_m[0]), float(p.y_m[0])) == pytest.approx(ref[:2], abs=1e-5)
        assert float(np.hypot(p.x_m - straight.x_m, p.y_m - straight.y_m)[0]) <= 200.0 * w * 10.0 + 1e-9


@settings(max_examples=80, deadline=None)
@given(
    v0=st.floats(0.0, 40.0),
    a=st.floats(-8.0, 3.0),
    w=st.one_of(st.floats(-0.5, 0.5), st.floats(-1e-4, 1e-4)),
    psi0=st.floats(-math.pi, math.pi),
    t_end=st.floats(0.0, 12.0),
)
def test_cyra_matches_numerical_integration(v0: float, a: float, w: float, psi0: float, t_end: float) -> None:
    v_max = 36.0
    p = cyra_predict(1.0, -2.0, psi0, v0, w, a, np.array([t_end]), speed_max_mps=v_max)
    x, y, v = _numeric_cyra(1.0, -2.0, psi0, min(v0, v_max), w, a, t_end, v_max)
    assert float(p.x_m[0]) == pytest.approx(x, abs=2e-3)
    assert float(p.y_m[0]) == pytest.approx(y, abs=2e-3)
    assert float(p.speed_mps[0]) == pytest.approx(v, abs=1e-6)
    assert 0.0 <= float(p.speed_mps[0]) <= v_max


def _msgs(
    n: int,
    dt: float = 0.1,
    speed: float = 15.0,
    w: float = 0.03,
    noise_m: float = 0.5,
    seed: int = 0,
    sid: int = 7,
    latency_s: float = 0.05,
    accel_noise: float = 0.2,
) -> list[tuple[VehicleMessage, float, tuple[float, float]]]:
    """A sender on a circle arc broadcasting noisy states at 1/dt; (message, receive time, true x/y)."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        t = k * dt
        p = cyra_predict(0.0, 0.0, 0.0, speed, w, 0.0, np.array([t]))
        tx, ty = float(p.x_m[0]), float(p.y_m[0])
        msg = VehicleMessage(
            sid,
            t,
            tx + rng.normal(0.0, noise_m),
            ty + rng.normal(0.0, noise_m),
            float(p.heading_rad[0]) + rng.normal(0.0, 0.02),
            speed + rng.normal(0.0, 0.1),
            w + rng.normal(0.0, 0.005),
            rng.normal(0.0, accel_noise),
        )
        out.append((msg, t + latency_s + rng.uniform(0.0, 0.05), (tx, ty)))
    return out


def test_filter_reduces_position_noise_and_predicts_through_latency() -> None:
    m = VehicleManager()
    raw, filt, pred = [], [], []
    for msg, t_rx, (tx, ty) in _msgs(200):
        assert m.receive(msg, t_rx)
        st_ = m.state(7, msg.t_gen_s)
        assert st_ is not None
        raw.append(math.hypot(msg.x_m - tx, msg.y_m - ty))
        filt.append(math.hypot(st_.x_m - tx, st_.y_m - ty))
        # Latency abstraction: the state at the receive time, not at the generation time.
        now = m.state(7, t_rx)
        p = cyra_predict(0.0, 0.0, 0.0, 15.0, 0.03, 0.0, np.array([t_rx]))
        assert now is not None
        pred.append(math.hypot(now.x_m - float(p.x_m[0]), now.y_m - float(p.y_m[0])))
    rms = lambda e: float(np.sqrt(np.mean(np.square(e[50:]))))  # noqa: E731
    assert rms(filt) < 0.5 * rms(raw)
    assert rms(pred) < 0.5 * rms(raw)
    last = m.state(7, 19.9)
    assert last is not None and last.speed_mps == pytest.approx(15.0, abs=0.2)
    assert last.yaw_rate_radps == pytest.approx(0.03, abs=0.005) and not last.low_confidence


def test_predict_trajectory_on_the_controller_grid() -> None:
    m = VehicleManager()
    for msg, t_rx, _ in _msgs(50, noise_m=0.0, accel_noise=0.0):
        m.receive(msg, t_rx)
    grid = 5.0 + np.arange(101) * 0.1
    tr = m.predict_trajectory(7, grid)
    assert tr is not None and tr.x_m.shape == (101,) and not tr.low_confidence
    ref = cyra_predict(0.0, 0.0, 0.0, 15.0, 0.03, 0.0, grid)
    # 10 s (150 m) ahead on a circle: the estimated yaw rate's error (~0.001 rad/s from 0.005 rad/s noise on
    # 50 messages) bends the prediction by ~0.5 v dw t^2; 3 m is 2 % of the distance.
    err = np.hypot(tr.x_m - ref.x_m, tr.y_m - ref.y_m)
    assert float(err[0]) < 0.2 and float(np.max(err)) < 3.0
    for k in (0, 50, 100):
        s = m.state(7, float(grid[k]))
        assert s is not None and (s.x_m, s.y_m) == pytest.approx((tr.x_m[k], tr.y_m[k]), abs=1e-9)
    alltr = m.predict_all(grid)
    assert set(alltr) == {7}


def test_message_checks_are_counted() -> None:
    m = VehicleManager()
    good = VehicleMessage(1, 10.0, 0.0, 0.0, 0.0, 10.0)
    assert m.receive(good, 10.05)
    assert not m.receive(good, 10.1)  # duplicate
    assert not m.receive(VehicleMessage(1, 9.9, 0.0, 0.0, 0.0, 10.0), 10.1)  # out of order
    assert not m.receive(VehicleMessage(1, 11.0, 0.0, 0.0, 0.0, 10.0), 10.2)  # from the future
    assert not m.receive(VehicleMessage(1, 5.0, 0.0, 0.0, 0.0, 10.0), 10.2)  # too old
    assert not m.receive(VehicleMessage(1, 10.2, math.nan, 0.0, 0.0, 10.0), 10.2)
    assert not m.receive(VehicleMessage(1, 10.2, 0.0, 0.0, 0.0, 10.0, accel_mps2=math.inf), 10.2)
    assert not m.receive(VehicleMessage(1, 10.2, 0.0, 0.0, 0.0, -1.0), 10.2)
    assert m.counts == {
        "new": 1,
        "out_of_order": 2,
        "from_future": 1,
        "too_old": 1,
        "nonfinite": 2,
        "implausible_speed": 1,
    }


def test_optional_fields_may_be_missing() -> None:
    m = VehicleManager()
    for k in range(20):
        t = 0.1 * k
        m.receive(VehicleMessage(3, t, 10.0 * t, 0.0, 0.0, 10.0), t)
    s = m.state(3, 2.0)
    assert (
        s is not None
        and s.x_m == pytest.approx(20.0, abs=0.2)
        and s.yaw_rate_radps == pytest.approx(0, abs=0.01)
    )


def test_silent_sender_flagged_then_aged_out() -> None:
    m = VehicleManager()
    for msg, t_rx, _ in _msgs(20, noise_m=0.0):
        m.receive(msg, t_rx)
    last_rx = m.tracks[7].last_rx_s
    s = m.state(7, last_rx + 0.3)
    assert s is not None and not s.silent
    s = m.state(7, last_rx + 1.0)
    assert s is not None and s.silent and s.low_confidence
    tr = m.predict_trajectory(7, last_rx + 1.0 + np.arange(3) * 0.1)
    assert tr is not None and tr.low_confidence
    assert m.prune(last_rx + 4.0) == []
    assert m.prune(last_rx + 5.5) == [7] and m.state(7, 10.0) is None


def test_frozen_sender_under_a_bridge_dead_reckons_on_its_speed() -> None:
    # Seed 003 Fig. 6: under a bridge a sender keeps broadcasting a constant position (and here a
    # constant speed) while it actually drives on at 20 m/s.
    m = VehicleManager()
    speed = 20.0
    for k in range(100):  # 10 s of good data, straight east
        t = 0.1 * k
        m.receive(VehicleMessage(9, t, speed * t, 0.0, 0.0, speed, 0.0, 0.0), t + 0.05)
    frozen_x = speed * 9.9
    flagged_at = None
    for k in range(100, 150):  # 5 s under the bridge
        t = 0.1 * k
        m.receive(VehicleMessage(9, t, frozen_x, 0.0, 0.0, speed, 0.0, 0.0), t + 0.05)
        s = m.state(9, t)
        assert s is not None
        if s.frozen and flagged_at is None:
            flagged_at = t
        # The prediction continues from the last good state at the sender's own speed.
        assert s.x_m == pytest.approx(speed * t, abs=1.5)
    assert flagged_at is not None and flagged_at <= 10.1  # 1 m of expected travel: within 0.1 s at 20 m/s
    s = m.state(9, 14.9)
    assert s is not None and s.frozen and s.low_confidence
    tr = m.predict_trajectory(9, 14.9 + np.arange(11) * 0.1)
    assert tr is not None and tr.low_confidence
    # The position moves again after the bridge: no longer frozen, back on the true track.
    for k in range(150, 170):
        t = 0.1 * k
        m.receive(VehicleMessage(9, t, speed * t, 0.0, 0.0, speed, 0.0, 0.0), t + 0.05)
    s = m.state(9, 16.9)
    assert s is not None and not s.frozen and s.x_m == pytest.approx(speed * 16.9, abs=0.5)
    assert m.tracks[9].counts["frozen"] == 1 and m.tracks[9].counts["unfrozen"] == 1


def test_standing_vehicle_is_not_frozen() -> None:
    m = VehicleManager()
    for k in range(50):
        t = 0.1 * k
        m.receive(VehicleMessage(4, t, 5.0, 5.0, 1.0, 0.0, 0.0, 0.0), t)
    s = m.state(4, 4.9)
    assert s is not None and not s.frozen and s.speed_mps == pytest.approx(0.0, abs=0.05)


def test_position_jump_ignored_once_reinitialised_when_persistent() -> None:
    m = VehicleManager()
    for k in range(30):
        t = 0.1 * k
        m.receive(VehicleMessage(5, t, 10.0 * t, 0.0, 0.0, 10.0, 0.0, 0.0), t)
    m.receive(VehicleMessage(5, 3.0, 30.0 + 25.0, 0.0, 0.0, 10.0, 0.0, 0.0), 3.0)  # one wild fix
    s = m.state(5, 3.0)
    assert s is not None and s.x_m == pytest.approx(30.0, abs=0.5)
    assert m.tracks[5].counts["position_jump"] == 1
    for k in range(31, 34):  # the sender really is 25 m ahead (its own filter reset)
        t = 0.1 * k
        m.receive(VehicleMessage(5, t, 10.0 * t + 25.0, 0.0, 0.0, 10.0, 0.0, 0.0), t)
    s = m.state(5, 3.3)
    assert s is not None and s.x_m == pytest.approx(58.0, abs=0.5)
    assert m.tracks[5].counts["reinit"] == 1


def test_from_geodetic_message() -> None:
    fr = LocalFrame(51.4708, 5.6230)
    lat, lon = fr.to_geodetic(100.0, 50.0)
    msg = VehicleMessage.from_geodetic(fr, 12, 1.0, lat, lon, 90.0, 12.0, 0.01, -0.5, 4.2, 1.7)
    assert (msg.x_m, msg.y_m) == pytest.approx((100.0, 50.0), abs=1e-6)
    assert msg.heading_rad == pytest.approx(0.0, abs=1e-4)  # due east (convergence at 100 m is tiny)
    assert (msg.length_m, msg.width_m, msg.accel_mps2) == (4.2, 1.7, -0.5)


def test_config_speed_limit_applies_to_predictions() -> None:
    m = VehicleManager(VehicleManagerConfig(speed_max_mps=20.0))
    m.receive(VehicleMessage(1, 0.0, 0.0, 0.0, 0.0, 19.0, 0.0, 2.0), 0.0)
    tr = m.predict_trajectory(1, np.array([0.0, 1.0, 5.0]))
    assert tr is not None and float(np.max(tr.speed_mps)) == pytest.approx(20.0)
