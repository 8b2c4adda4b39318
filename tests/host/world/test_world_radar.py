"""Radar fusion (seed 003 IV-B, VI) on synthetic tracks: association under noise and dropouts, the
bridge (frozen and silent senders), the next-lane car, a non-communicating car in between, switching
leaders, the blacklist, and the hand-over to the platoon strategy."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pytest

from bywire.host.geo import LocalFrame
from bywire.host.world.lanemap import LaneMap, record_lane
from bywire.host.world.pose import Pose
from bywire.host.world.radar_fusion import (
    Confidence,
    FusionConfig,
    FusionResult,
    RadarFusion,
    RadarMeasurement,
    Source,
)
from bywire.host.world.vehicles import VehicleManager, VehicleMessage

FRAME = LocalFrame(51.4708, 5.6230)
HOST_SPEED = 15.0
HOST_LEN = FusionConfig().host_length_m
CAR_LEN = 4.5
DT = 0.05  # fusion and radar at 20 Hz; V2V at 10 Hz


def _road() -> LaneMap:
    xs = np.linspace(-200.0, 3000.0, 6401)
    return record_lane(np.column_stack((xs, np.zeros_like(xs))), FRAME).with_offset_lane(0, 3.5, 1, "left")


ROAD = _road()


@dataclass
class Car:
    """A simulated car: centre x(t) on the lane at y, and what it broadcasts."""

    station: int | None  # None: no V2V
    x_of_t: Callable[[float], float]
    speed_of_t: Callable[[float], float]
    y_of_t: Callable[[float], float] = lambda t: 0.0
    accel: float = 0.0
    # V2V faults: (start, end) intervals
    frozen: tuple[float, float] | None = None
    frozen_speed: float | None = None  # what a frozen sender reports as speed (None: its last one)
    silent: tuple[float, float] | None = None
    y_bias_m: float = 0.0  # broadcast position error toward another lane
    _last: VehicleMessage | None = None

    def message(self, t: float, rng: np.random.Generator, noise_m: float) -> VehicleMessage | None:
        if self.station is None or (self.silent and self.silent[0] <= t < self.silent[1]):
            return None
        if self.frozen and self.frozen[0] <= t < self.frozen[1] and self._last is not None:
            last = self._last
            speed = last.speed_mps if self.frozen_speed is None else self.frozen_speed
            return VehicleMessage(self.station, t, last.x_m, last.y_m, 0.0, speed, 0.0, 0.0)
        msg = VehicleMessage(
            self.station,
            t,
            self.x_of_t(t) + rng.normal(0.0, noise_m),
            self.y_of_t(t) + self.y_bias_m + rng.normal(0.0, noise_m),
            0.0,
            self.speed_of_t(t) + rng.normal(0.0, 0.1),
            0.0,
            self.accel,
        )
        self._last = msg
        return msg


@dataclass
class Scenario:
    cars: list[Car]
    radar_dropout: float = 0.1
    radar_noise_m: float = 0.1
    v2v_noise_m: float = 0.5
    latency_s: float = 0.05
    radar_sees_next_lane: bool = False
    clutter_times: tuple[float, ...] = ()  # single spurious echoes at 8 m
    config: FusionConfig = field(default_factory=FusionConfig)
    seed: int = 0

    def host_x(self, t: float) -> float:
        return HOST_SPEED * t

    def radar(self, t: float, rng: np.random.Generator) -> RadarMeasurement:
        front = self.host_x(t) + 0.5 * HOST_LEN
        best: tuple[float, Car] | None = None
        for car in self.cars:
            y = car.y_of_t(t)
            in_lane = abs(y) < 1.75 or (self.radar_sees_next_lane and abs(y) < 5.0)
            rng_m = car.x_of_t(t) - 0.5 * CAR_LEN - front
            if in_lane and 0.0 < rng_m <= 50.0 and (best is None or rng_m < best[0]):
                best = (rng_m, car)
        if any(abs(t - tc) < 0.5 * DT for tc in self.clutter_times):
            return RadarMeasurement(t, True, 8.0, -HOST_SPEED, 0.0)
        if best is None or rng.random() < self.radar_dropout:
            return RadarMeasurement(t, False)
        r, car = best
        y = car.y_of_t(t)
        return RadarMeasurement(
            t,
            True,
            math.hypot(r, y) + rng.normal(0.0, self.radar_noise_m),
            car.speed_of_t(t) - HOST_SPEED + rng.normal(0.0, 0.05),
            math.atan2(y, r),
        )

    def run(self, duration_s: float, use_radar: bool = True) -> list[FusionResult]:
        rng = np.random.default_rng(self.seed)
        vm = VehicleManager()
        fusion = RadarFusion(ROAD, self.config)
        out = []
        pending: list[tuple[float, VehicleMessage]] = []
        for k in range(round(duration_s / DT) + 1):
            t = k * DT
            if k % 2 == 0:
                for car in self.cars:
                    msg = car.message(t, rng, self.v2v_noise_m)
                    if msg is not None:
                        pending.append((t + self.latency_s, msg))
            for t_rx, msg in [p for p in pending if p[0] <= t + 1e-9]:
                vm.receive(msg, t_rx)
            pending = [p for p in pending if p[0] > t + 1e-9]
            pose = Pose(t, self.host_x(t), 0.0, 0.0, HOST_SPEED, 0.0, 0.0, math.nan, math.nan, 0.02, 0.001,
                        True, True, False, False, 4)  # fmt: skip
            radar = self.radar(t, rng) if use_radar else None
            out.append(fusion.update(t, pose, radar, vm))
        self.fusion = fusion
        return out


def _true_gap(car: Car, t: float) -> float:
    return car.x_of_t(t) - 0.5 * CAR_LEN - (HOST_SPEED * t + 0.5 * HOST_LEN)


def _leader_30m(station: int = 1, **kw: object) -> Car:
    x0 = 30.0 + 0.5 * (HOST_LEN + CAR_LEN)
    return Car(station, lambda t: x0 + HOST_SPEED * t, lambda t: HOST_SPEED, accel=0.3, **kw)  # type: ignore[arg-type]


def test_association_under_noise_and_dropouts() -> None:
    car = _leader_30m()
    sc = Scenario([car], radar_dropout=0.2)
    out = sc.run(6.0)
    confident_at = next(r.t_s for r in out if r.association_confident)
    assert confident_at < 1.0  # 5 consistent cycles at 20 Hz, some dropped
    later = [r for r in out if r.t_s > 2.0]
    assert all(r.association_confident and r.associated_station == 1 for r in later)
    for r in later:
        lead = r.leader
        assert lead is not None and lead.source is Source.FUSED and lead.station_id == 1
        assert lead.gap_m == pytest.approx(_true_gap(car, r.t_s), abs=0.3)
        assert lead.speed_mps == pytest.approx(HOST_SPEED, abs=0.2)
        assert lead.accel_mps2 == pytest.approx(0.3, abs=0.15)  # intent from V2V
        assert lead.confidence in (Confidence.HIGH, Confidence.MEDIUM)
    # Before confidence: the V2V estimate.
    first = out[2].leader
    assert first is not None and first.source is Source.V2V


def test_bridge_frozen_sender_does_not_stop_us() -> None:
    # The leader's GPS freezes under a bridge from 5 s to 10 s and it reports speed 0 (seed 003 Fig. 6):
    # by V2V alone its predicted gap collapses; with the radar associated beforehand the gap is kept.
    def make() -> Car:
        return _leader_30m(frozen=(5.0, 10.0), frozen_speed=0.0)

    car = make()
    out = Scenario([car]).run(12.0)
    v2v_only = Scenario([make()]).run(12.0, use_radar=False)
    under = [(r, q) for r, q in zip(out, v2v_only, strict=True) if 6.0 <= r.t_s < 10.0]
    for r, _ in under:
        lead = r.leader
        assert lead is not None and lead.source is Source.FUSED and lead.station_id == 1
        assert lead.gap_m == pytest.approx(_true_gap(car, r.t_s), abs=0.5)
        assert lead.speed_mps == pytest.approx(HOST_SPEED, abs=0.3)
    # Without radar, the frozen sender reporting speed 0 drags its predicted gap down by metres.
    worst = min(q.leader.gap_m - _true_gap(car, q.t_s) for _, q in under if q.leader is not None)
    assert worst < -5.0
    low = [q.leader for _, q in under if q.leader is not None]
    assert all(lead.confidence is Confidence.LOW for lead in low[10:])  # flagged frozen


def test_single_clutter_echoes_do_not_break_the_association() -> None:
    car = _leader_30m()
    sc = Scenario([car], clutter_times=(3.0, 4.5, 4.6))
    out = sc.run(6.0)
    assert all(r.association_confident for r in out if r.t_s > 2.0)
    assert all(r.leader is not None and r.leader.source is Source.FUSED for r in out if r.t_s > 2.0)
    assert sc.fusion.counts["radar_track_replaced"] == 0


def test_silent_sender_keeps_radar_gap() -> None:
    car = _leader_30m(silent=(4.0, 7.0))
    out = Scenario([car]).run(8.0)
    for r in out:
        if 4.5 <= r.t_s < 7.0:
            lead = r.leader
            assert lead is not None and lead.source is Source.FUSED
            assert lead.gap_m == pytest.approx(_true_gap(car, r.t_s), abs=0.5)


def test_next_lane_car_is_never_our_leader() -> None:
    # A car on the left lane 18 m ahead broadcasts positions 1.2 m toward our lane; our real leader is 40 m
    # ahead. The radar also reports the next-lane car now and then (a wide beam).
    neighbour = Car(2, lambda t: 25.0 + HOST_SPEED * t, lambda t: HOST_SPEED, lambda t: 3.5, y_bias_m=-1.2)
    x0 = 40.0 + 0.5 * (HOST_LEN + CAR_LEN)
    leader = Car(1, lambda t: x0 + HOST_SPEED * t, lambda t: HOST_SPEED)
    sc = Scenario([neighbour, leader], radar_sees_next_lane=True)
    out = sc.run(5.0)
    for r in out[5:]:
        assert all(lead.station_id != 2 for lead in r.leads)
        assert r.leader is not None and r.leader.station_id in (1, None)
        assert r.leader.gap_m > 30.0
    assert sc.fusion.counts["radar_off_lane"] > 10


def test_non_communicating_car_in_between() -> None:
    x_v2v = 45.0 + 0.5 * (HOST_LEN + CAR_LEN)
    x_mute = 20.0 + 0.5 * (HOST_LEN + CAR_LEN)
    v2v = Car(1, lambda t: x_v2v + HOST_SPEED * t, lambda t: HOST_SPEED)
    mute = Car(None, lambda t: x_mute + (HOST_SPEED - 1.0) * t, lambda t: HOST_SPEED - 1.0)
    out = Scenario([v2v, mute]).run(4.0)
    for r in out[10:]:
        assert len(r.leads) == 2
        first, second = r.leads
        assert first.source is Source.RADAR and first.station_id is None
        assert first.gap_m == pytest.approx(_true_gap(mute, r.t_s), abs=0.4)
        assert first.speed_mps == pytest.approx(HOST_SPEED - 1.0, abs=0.2)
        assert second.source is Source.V2V and second.station_id == 1
        assert second.gap_m == pytest.approx(_true_gap(v2v, r.t_s), abs=1.0)
        assert not r.association_confident
    assert out[-1].leads[0].confidence is Confidence.HIGH


def test_switching_leaders_on_a_cut_in() -> None:
    # Leader A 35 m ahead; at 4 s car B (V2V) cuts in from the left lane 12 m ahead of us.
    x_a = 35.0 + 0.5 * (HOST_LEN + CAR_LEN)
    x_b = 12.0 + 0.5 * (HOST_LEN + CAR_LEN)
    a = Car(1, lambda t: x_a + HOST_SPEED * t, lambda t: HOST_SPEED)
    b = Car(2, lambda t: x_b + HOST_SPEED * t, lambda t: HOST_SPEED, lambda t: 3.5 if t < 4.0 else 0.0)
    sc = Scenario([a, b])
    out = sc.run(8.0)
    before = [r for r in out if 2.0 <= r.t_s < 4.0]
    assert all(r.associated_station == 1 and r.association_confident for r in before)
    assert all(r.leader is not None and r.leader.station_id == 1 for r in before)
    after = [r for r in out if r.t_s >= 5.5]
    assert all(r.associated_station == 2 and r.association_confident for r in after)
    for r in after:
        assert [lead.station_id for lead in r.leads] == [2, 1]
        assert r.leads[0].source is Source.FUSED and r.leads[1].source is Source.V2V
    assert sc.fusion.counts["association_lost_radar"] >= 1


def test_blacklisted_station_is_ignored() -> None:
    car = _leader_30m(station=5)
    out = Scenario([car], config=FusionConfig(blacklist=frozenset({5}))).run(3.0)
    last = out[-1]
    # The radar still sees the car: a radar-only leader, never the blacklisted station's broadcast.
    assert last.leader is not None and last.leader.source is Source.RADAR and last.leader.station_id is None


def test_predictions_feed_the_platoon_strategy() -> None:
    from bywire.host.platoon.follow_qp import FollowParams
    from bywire.host.platoon.strategy import PlatoonStrategy

    x0 = 30.0 + 0.5 * (HOST_LEN + CAR_LEN)
    a = Car(1, lambda t: x0 + HOST_SPEED * t, lambda t: HOST_SPEED, accel=-1.0)
    x1 = 55.0 + 0.5 * (HOST_LEN + CAR_LEN)
    b = Car(2, lambda t: x1 + HOST_SPEED * t, lambda t: HOST_SPEED)
    r = Scenario([a, b]).run(3.0)[-1]
    assert [lead.station_id for lead in r.leads] == [1, 2]
    params = FollowParams()
    preds = r.leader_predictions(params)
    fused = r.leads[0]
    # Constant acceleration (V2V's -1 m/s^2) from the radar's gap and speed, until it stops.
    t = params.time_grid_s()
    assert fused.accel_mps2 == pytest.approx(-1.0, abs=0.1)
    t_stop = fused.speed_mps / -fused.accel_mps2
    te = np.minimum(t, t_stop)
    expected = fused.gap_m + fused.speed_mps * te + 0.5 * fused.accel_mps2 * te**2
    np.testing.assert_allclose(preds[0].positions_m, expected, atol=1e-6)
    assert preds[1].positions_m[0] == pytest.approx(r.leads[1].gap_m, abs=0.05)
    assert preds[1].speeds_mps[-1] == pytest.approx(HOST_SPEED, abs=0.5)
    decision = PlatoonStrategy(params).step(HOST_SPEED, preds)
    assert decision.accel_cmd_mps2 < 0.0  # the braking leader binds
    with pytest.raises(ValueError, match="horizon"):
        r.leads[0].leader_prediction(FollowParams(horizon_s=20.0))


def test_radar_target_from_can_frame_fields() -> None:
    from bywire.protocol.vehicle_can import RadarTarget

    m = RadarMeasurement.from_target(1.5, RadarTarget(True, 23.4, -1.2, 0.01))
    assert m == RadarMeasurement(1.5, True, 23.4, -1.2, 0.01)


def test_no_vehicles_no_radar_no_leads() -> None:
    fusion = RadarFusion(ROAD)
    pose = Pose(0.0, 0.0, 0.0, 0.0, 10.0, 0.0, 0.0, math.nan, math.nan, 0.02, 0.001,
                True, True, False, False, 4)  # fmt: skip
    r = fusion.update(0.0, pose, RadarMeasurement(0.0, False), VehicleManager())
    assert r.leads == () and r.leader is None and r.host_lane_id == 0 and r.radar_gap_m is None
    off = Pose(0.0, 0.0, 50.0, 0.0, 10.0, 0.0, 0.0, math.nan, math.nan, 0.02, 0.001,
               True, True, False, False, 4)  # fmt: skip
    r = fusion.update(0.05, off, RadarMeasurement(0.05, True, 20.0, 0.0, 0.0), VehicleManager())
    assert r.host_lane_id is None and fusion.counts["host_off_map"] == 1
