"""The simulated world's pieces in isolation (hil/world): road geometry, driver models in steady state and
in a string, the radar's geometry (next-lane cars, range, beam, dropouts), the gap / TTC / collision
bookkeeping, the V2V broadcaster's bad data, and the strict `world:` schema (fuzzed)."""

from __future__ import annotations

import copy
import dataclasses
import itertools
import math
import random
from typing import Any

import numpy as np
import pytest
import yaml
from fuzz_util import mutate
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.hil.scenario import ScenarioError, builtin_scenarios, parse_scenario
from bywire.hil.world.drivers import ScriptedSpeed
from bywire.hil.world.road import Road
from bywire.hil.world.sim import lead_world
from bywire.hil.world.spec import (
    BrakeSpec,
    DriverSpec,
    EgoSpec,
    GpsSpec,
    Interval,
    RadarSpec,
    RoadSpec,
    SinusoidSpec,
    V2vSenderSpec,
    V2vSpec,
    VehicleSpec,
    WorldSpec,
    parse_world,
)
from bywire.hil.world.traffic import EGO, World
from bywire.hil.world.v2v import V2vBroadcaster
from bywire.protocol.v2x.codec import VehicleState
from bywire.protocol.v2x.iclcm import ControllerType, CooperativeState
from bywire.protocol.v2x.receiver import V2vReceiver
from bywire.protocol.v2x.wire import decode, encode

EPOCH = 1305374400.0


def no_noise(_sigma: float) -> float:
    return 0.0


def world_of(*vehicles: VehicleSpec, radar: RadarSpec | None = None, ego_s: float = 100.0) -> WorldSpec:
    return WorldSpec(
        road=RoadSpec(lanes=2, length_m=20_000.0),
        ego=EgoSpec(lane=0, s_m=ego_s),
        radar=radar or RadarSpec(),
        gps=GpsSpec(enabled=False),
        v2v=V2vSpec(),
        vehicles=vehicles,
    )


def scripted(name: str, s_m: float, v: float, lane: int = 0, **kw: Any) -> VehicleSpec:
    return VehicleSpec(name, lane, s_m, v, DriverSpec(kind="scripted", speed_profile=((0.0, v),)), **kw)


def drive(world: World, seconds: float, ego_speed: float, dt: float = 0.01) -> None:
    """Our car at constant speed from the world's start, the traffic stepped every dt."""
    n = round(seconds / dt)
    t0 = world.t_s
    x0 = world.ego.s_m - world.spec.ego.s_m
    for k in range(1, n + 1):
        t = t0 + k * dt
        world.place_ego(t, x0 + ego_speed * (t - t0), 0.0, 0.0, ego_speed, 0.0)
        world.step(t)


# ------------------------------------------------------------------------------------------------ road


def test_straight_road_lanes_are_parallel_and_locate_inverts_pose_at() -> None:
    road = Road(RoadSpec(lanes=3, heading_deg=30.0, length_m=1000.0))
    for lane in range(3):
        p = road.pose_at(lane, 420.0, 0.4)
        assert road.locate(p.x_m, p.y_m) == pytest.approx((lane, 420.0, 0.4), abs=1e-9)
    a, b = road.pose_at(0, 100.0), road.pose_at(2, 100.0)
    assert math.hypot(a.x_m - b.x_m, a.y_m - b.y_m) == pytest.approx(7.0)


def test_curved_road_keeps_its_radius_and_lane_offset() -> None:
    road = Road(RoadSpec(lanes=2, radius_m=500.0, length_m=600.0))
    p0, p1 = road.pose_at(0, 0.0), road.pose_at(1, 0.0)
    assert (p0.x_m, p0.y_m, p0.heading_rad) == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)
    assert (p1.x_m, p1.y_m) == pytest.approx((0.0, 3.5), abs=1e-9)
    end = road.pose_at(0, road.lane(0).length_m)
    assert end.heading_rad == pytest.approx(600.0 / 500.0, abs=1e-3)
    # The left lane of a left curve is the inner one: radius 496.5 m around the same centre.
    q = road.pose_at(1, 300.0)
    assert math.hypot(q.x_m - 0.0, q.y_m - 500.0) == pytest.approx(496.5, abs=0.01)
    lane, s, lateral = road.locate(q.x_m, q.y_m)
    assert lane == 1 and s == pytest.approx(300.0, abs=0.05) and lateral == pytest.approx(0.0, abs=0.01)


# ------------------------------------------------------------------------------------------------ drivers


def test_scripted_profiles_sinusoid_and_emergency_brake() -> None:
    sin = ScriptedSpeed(DriverSpec(kind="scripted", sinusoid=SinusoidSpec(27.78, 2.78, 0.2, 10.0)))
    assert sin.speed(5.0) == pytest.approx(27.78)
    assert sin.speed(10.0 + 1.25) == pytest.approx(27.78 + 2.78)  # a quarter period of 0.2 Hz
    assert sin.accel(10.0) == pytest.approx(2.78 * 2 * math.pi * 0.2)
    brake = ScriptedSpeed(
        DriverSpec(kind="scripted", speed_profile=((0.0, 27.78),), brake=BrakeSpec(at_s=20.0, decel_mps2=8.0))
    )
    assert brake.speed(21.0) == pytest.approx(19.78)
    assert brake.accel(21.0) == -8.0
    assert brake.speed(25.0) == 0.0 and brake.accel(25.0) == 0.0
    # Distance over a stop: the trapezoid of a piecewise-linear profile is exact.
    total = sum(brake.distance(20.0 + k * 0.01, 20.0 + (k + 1) * 0.01) for k in range(500))
    assert total == pytest.approx(27.78**2 / 16.0, abs=0.01)


@pytest.mark.parametrize(
    ("kind", "extra"),
    [
        ("acc", {"headway_s": 1.2}),
        ("cacc", {"headway_s": 0.6}),
        ("idm", {"headway_s": 1.2, "noise_mps2": 0.0, "v_set_mps": 40.0}),
    ],
)
def test_followers_settle_at_their_steady_state_gap(kind: str, extra: dict[str, Any]) -> None:
    v = 20.0
    driver = DriverSpec(kind=kind, standstill_m=5.0, **extra)
    follower = VehicleSpec("f", 0, 300.0, v, driver, v2v=V2vSenderSpec(station_id=2))
    world = World(world_of(scripted("lead", 360.0, v, v2v=V2vSenderSpec(station_id=1)), follower, ego_s=0.0))
    drive(world, 90.0, 0.0)
    gap = world.gap[2]
    if kind == "idm":
        # s = s*(v) / sqrt(1 - (v / v0)^4) at dv = 0
        expected = (5.0 + v * 1.2) / math.sqrt(1.0 - (v / 40.0) ** 4)
    else:
        expected = 5.0 + extra["headway_s"] * v
    assert gap == pytest.approx(expected, abs=0.2)
    assert world.vehicles[1].v_mps == pytest.approx(v, abs=0.02)


def _peak_decel_along_string(kind: str, headway_s: float, n: int = 6) -> list[float]:
    v = 25.0
    gap = 5.0 + headway_s * v
    lead = VehicleSpec(
        "lead",
        0,
        1000.0,
        v,
        DriverSpec(kind="scripted", speed_profile=((0.0, v), (10.0, v), (13.0, 15.0), (30.0, 15.0))),
        v2v=V2vSenderSpec(station_id=1, latency_s=0.05),
    )
    cars = [lead]
    for i in range(1, n):
        cars.append(
            VehicleSpec(
                f"c{i}",
                0,
                1000.0 - i * (gap + 4.5),
                v,
                DriverSpec(kind=kind, headway_s=headway_s, v_set_mps=40.0, lag_s=0.3),
                v2v=V2vSenderSpec(station_id=1 + i, latency_s=0.05),
            )
        )
    world = World(world_of(*cars, ego_s=0.0))
    peaks = [0.0] * n
    for k in range(1, 3001):
        t = k * 0.01
        world.place_ego(t, 0.0, 0.0, 0.0, 0.0, 0.0)
        world.step(t)
        for i, c in enumerate(world.vehicles):
            peaks[i] = min(peaks[i], c.a_mps2)
    assert all(st.collisions == 0 for st in world.stats.values())
    return [-p for p in peaks]


def test_cacc_string_attenuates_a_braking_leader() -> None:
    cacc = _peak_decel_along_string("cacc", 0.6)
    # CACC with the predecessor's command as feed-forward: every follower brakes no harder than the one
    # ahead (string stable in the peak-deceleration sense), and none collides (checked inside).
    assert all(b <= a + 1e-3 for a, b in itertools.pairwise(cacc[1:])), cacc
    acc = _peak_decel_along_string("acc", 1.2)
    assert max(acc) < 5.0  # a radar ACC at 1.2 s brakes harder than its leader but stays controlled


# ------------------------------------------------------------------------------------------------ radar


def test_radar_reports_the_nearest_car_ahead_in_our_lane_only() -> None:
    spec = world_of(
        scripted("next_lane_close", 112.0, 20.0, lane=1),  # beside us, 5 m ahead: not in our lane
        scripted("ahead", 130.0, 18.0),
        scripted("farther", 150.0, 20.0),
        scripted("behind", 80.0, 20.0),
        ego_s=100.0,
    )
    world = World(spec)
    world.place_ego(0.01, 0.2, 0.0, 0.0, 20.0, 0.0)
    world.step(0.01)
    ret = world.radar(no_noise, 0.0)
    assert ret.valid and ret.target == 2
    # Centres 30 m apart, lengths 4.77 (ours) and 4.5: bumper to bumper 25.365 m at t = 0; after 10 ms
    # it moved 0.18 m and we 0.2 m; closing at 2 m/s.
    assert ret.range_m == pytest.approx(30.0 - 4.77 / 2 - 4.5 / 2 - 0.02, abs=1e-9)
    assert ret.range_rate_mps == pytest.approx(-2.0, abs=1e-6)
    assert ret.azimuth_rad == pytest.approx(0.0, abs=1e-9)


def test_radar_range_limit_and_dropouts() -> None:
    far = World(world_of(scripted("far", 160.0, 20.0), radar=RadarSpec(range_m=50.0), ego_s=100.0))
    far.place_ego(0.0, 0.0, 0.0, 0.0, 20.0, 0.0)
    far.step(0.01)
    assert not far.radar(no_noise, 0.0).valid  # 55 m bumper to bumper: beyond 50 m
    lossy = World(world_of(scripted("a", 130.0, 20.0), radar=RadarSpec(dropout=0.3), ego_s=100.0), seed=4)
    lossy.place_ego(0.0, 0.0, 0.0, 0.0, 20.0, 0.0)
    lossy.step(0.01)
    valid = [lossy.radar(no_noise, 0.0).valid for _ in range(4000)]
    assert 1.0 - np.mean(valid) == pytest.approx(0.3, abs=0.03)
    rng = random.Random(1)
    ranges = [lossy.radar(lambda s: rng.gauss(0.0, s), 0.2).range_m for _ in range(4000)]
    ranges = [r for r in ranges if r > 0.0]
    assert np.std(ranges) == pytest.approx(0.2, rel=0.1)


def test_legacy_lead_world_reproduces_the_spines_radar() -> None:
    world = World(lead_world(35.0, ((0.0, 11.0),), 4.8, 40.0))
    world.place_ego(0.0, 0.0, 0.0, 0.0, 14.0, 0.0)
    world.step(0.001)
    assert world.lead_of_ego() is not None
    assert world.lead_of_ego()[0] == pytest.approx(35.0 + 0.011, abs=1e-6)  # 11 m/s x 1 ms
    ret = world.radar(no_noise, 0.0)
    assert ret.range_m == pytest.approx(35.011, abs=1e-6) and ret.range_rate_mps == pytest.approx(-3.0)
    drive(world, 40.0, 0.0)
    assert world.lead_of_ego() is None  # it left the road at 40 s


# ------------------------------------------------------------------------------------------------ bookkeeping


def test_collision_counted_once_per_contact_and_ttc_while_closing() -> None:
    world = World(world_of(scripted("slow", 140.0, 10.0), ego_s=100.0))
    drive(world, 1.0, 20.0)
    st = world.stats[EGO]
    # Gap 35.365 m at t=0 closing at 10 m/s: TTC 3.54 s, decreasing.
    assert st.min_ttc_s == pytest.approx((35.365 - 10.0) / 10.0, abs=0.02)
    drive(world, 10.0, 20.0)  # we drive through it: one contact, not one per step
    assert world.stats[EGO].collisions == 1
    assert world.stats[EGO].min_gap_m < 0.0


# ------------------------------------------------------------------------------------------------ V2V


def _broadcast_all(world: World, seconds: float) -> list[tuple[float, VehicleState | CooperativeState]]:
    bc = V2vBroadcaster(world, lambda t: EPOCH + t, seed=3)
    out: list[tuple[float, VehicleState | CooperativeState]] = []
    for k in range(1, round(seconds / 0.01) + 1):
        t = k * 0.01
        world.place_ego(t, 0.0, 0.0, 0.0, 0.0, 0.0)
        world.step(t)
        for payload in bc.due(t):
            msg = decode(payload, EPOCH + t)
            assert isinstance(msg, VehicleState | CooperativeState)
            out.append((t, msg))
    return out


def _broadcast(sender: V2vSenderSpec, seconds: float) -> list[tuple[float, VehicleState]]:
    """The CAMs one scripted car sends."""
    world = World(
        world_of(
            VehicleSpec(
                "v", 0, 200.0, 20.0, DriverSpec(kind="scripted", speed_profile=((0.0, 20.0),)), v2v=sender
            )
        )
    )
    return [(t, m) for t, m in _broadcast_all(world, seconds) if isinstance(m, VehicleState)]


def test_broadcast_rate_latency_and_that_the_receiver_accepts_it() -> None:
    msgs = _broadcast(V2vSenderSpec(station_id=7, rate_hz=10.0, latency_s=0.05), 5.0)
    assert len(msgs) == pytest.approx(50, abs=1)
    ages = [t - (m.generation_time_s - EPOCH) for t, m in msgs]
    assert min(ages) >= 0.05 - 1e-9 and max(ages) <= 0.05 + 0.011
    rx = V2vReceiver()
    accepted = [rx.check(_reencode(m), m.generation_time_s + 0.05).accepted for _, m in msgs]
    assert all(accepted), rx.v2v_rejected()


def _reencode(m: VehicleState) -> bytes:
    return encode(m)


def test_frozen_sender_repeats_its_position_exactly_silent_sends_nothing_late_is_older() -> None:
    sender = V2vSenderSpec(
        station_id=8,
        position_noise_m=0.5,
        frozen=(Interval(1.0, 2.0),),
        silent=(Interval(3.5, 1.0),),
        late_s=((Interval(5.0, 1.0), 0.4),),
    )
    msgs = _broadcast(sender, 7.0)
    frozen = [m for t, m in msgs if 1.0 <= m.generation_time_s - EPOCH < 3.0]
    assert len({(m.lat_deg, m.lon_deg) for m in frozen}) == 1
    assert frozen[-1].generation_time_s > frozen[0].generation_time_s  # time goes on
    moving = [m for t, m in msgs if m.generation_time_s - EPOCH < 1.0]
    assert len({(m.lat_deg, m.lon_deg) for m in moving}) == len(moving)
    assert not [m for t, m in msgs if 3.5 <= m.generation_time_s - EPOCH < 4.5]
    late = [t - (m.generation_time_s - EPOCH) for t, m in msgs if 5.0 <= m.generation_time_s - EPOCH < 6.0]
    assert min(late) >= 0.43 - 1e-9


def test_channel_loss_drops_datagrams_on_their_own_draws_and_changes_nothing_sent() -> None:
    """`world.v2v.loss`: each datagram lost on its own draw, the states sent (and their noise) the same at
    every loss rate: what arrives with loss is a subset of what arrives without, in the same order."""

    def received(loss: float) -> tuple[list[bytes], int]:
        car = VehicleSpec(
            "v", 0, 200.0, 20.0, DriverSpec(kind="scripted", speed_profile=((0.0, 20.0),)),
            v2v=V2vSenderSpec(station_id=7, position_noise_m=0.5),
        )  # fmt: skip
        spec = dataclasses.replace(world_of(car), v2v=V2vSpec(loss=loss))
        world = World(spec)
        bc = V2vBroadcaster(world, lambda t: EPOCH + t, seed=3)
        out: list[bytes] = []
        for k in range(1, 2001):
            world.place_ego(k * 0.01, 0.0, 0.0, 0.0, 0.0, 0.0)
            world.step(k * 0.01)
            out += bc.due(k * 0.01)
        return out, bc.lost

    clean, lost0 = received(0.0)
    lossy, lost = received(0.3)
    assert lost0 == 0 and len(clean) == 400  # 20 s of CAM + iCLCM at 10 Hz
    assert len(lossy) + lost == len(clean) and 0.2 < lost / len(clean) < 0.4
    it = iter(clean)
    assert all(any(d == c for c in it) for d in lossy)  # a subsequence: nothing sent differs
    assert received(0.3) == (lossy, lost)  # deterministic for a seed


def test_every_communicating_car_sends_its_iclcm_beside_its_cam() -> None:
    cacc = DriverSpec(kind="cacc", v_set_mps=30.0, headway_s=0.6)
    world = World(
        world_of(
            scripted("leader", 300.0, 20.0, v2v=V2vSenderSpec(station_id=101)),
            VehicleSpec("cacc", 0, 280.0, 20.0, cacc, v2v=V2vSenderSpec(station_id=102)),
            VehicleSpec("human", 1, 250.0, 20.0, DriverSpec(kind="idm"), v2v=V2vSenderSpec(station_id=103)),
            VehicleSpec("mute", 0, 150.0, 20.0, DriverSpec(kind="acc"), v2v=None),
            VehicleSpec(
                "silent", 0, 120.0, 20.0, DriverSpec(kind="acc"),
                v2v=V2vSenderSpec(station_id=105, silent=(Interval(0.0, 10.0),)),
            ),
        )
    )  # fmt: skip
    msgs = _broadcast_all(world, 3.0)
    cams = {(m.station_id, m.generation_time_s): t for t, m in msgs if isinstance(m, VehicleState)}
    iclcms = [(t, m) for t, m in msgs if isinstance(m, CooperativeState)]
    # one beside each CAM: the same stamp, delivered with it, right after it
    assert {(m.station_id, m.generation_time_s): t for t, m in iclcms} == cams
    assert {m.station_id for _, m in iclcms} == {101, 102, 103}
    last = {m.station_id: m for _, m in iclcms}
    leader, follower, human = last[101], last[102], last[103]
    assert leader.controller_type is ControllerType.CC and leader.target_accel_mps2 == pytest.approx(0.0)
    assert leader.mio_station_id == 0 and leader.mio_range_m is None and leader.time_headway_s is None
    assert follower.controller_type is ControllerType.CACC and follower.platoon_id == 1
    assert (follower.time_headway_s, follower.cruise_speed_mps) == pytest.approx((0.6, 30.0))
    assert follower.mio_station_id == 101
    assert follower.mio_range_m == pytest.approx(world.gap[2], abs=0.5)  # 20 m/s: 0.4 m within a delivery
    assert follower.target_accel_mps2 is not None and abs(follower.target_accel_mps2) < 3.0
    assert human.controller_type is ControllerType.MANUAL and human.target_accel_mps2 is None
    assert human.platoon_id == 2  # the other lane
    # the receiver takes them (the cars are ours to hear)
    rx = V2vReceiver()
    assert all(rx.check(encode(m), m.generation_time_s + 0.05).accepted for _, m in iclcms), rx.v2v_rejected()


# ------------------------------------------------------------------------------------------------ schema


def _heat() -> dict[str, Any]:
    return yaml.safe_load(builtin_scenarios()["gcdc_heat"].read_text())


@pytest.mark.parametrize(
    ("path", "value", "words"),
    [
        (("vehicles", 2, "driver", "headway_s"), 0.0, "world.vehicles[2].driver.headway_s"),
        (("vehicles", 0, "driver", "kind"), "robot", "world.vehicles[0].driver.kind"),
        (("road", "radius_m"), 50.0, "world.road.radius_m"),
        (("gps", "outages", 0, "kind"), "solar_flare", "world.gps.outages[0].kind"),
        (("vehicles", 1, "v2v", "station_id"), 101, "station ids must be unique"),
        (("ego", "lane"), 5, "world.ego.lane"),
        (("fuzz", "rate_hz"), "fast", "world.fuzz.rate_hz"),
    ],
)
def test_bad_world_fields_are_named(path: tuple[Any, ...], value: Any, words: str) -> None:
    doc = _heat()
    node = doc["world"]
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    with pytest.raises(ScenarioError) as err:
        parse_scenario(doc, "heat.yaml")
    assert words in str(err.value) and "heat.yaml" in str(err.value)


def test_unknown_world_key_and_lead_beside_a_world_are_refused() -> None:
    doc = _heat()
    doc["world"]["vehicles"][0]["colour"] = "red"
    with pytest.raises(ScenarioError, match=r"world\.vehicles\[0\]\.colour: unknown key"):
        parse_scenario(doc, "heat.yaml")
    doc = _heat()
    doc["host"]["lead"] = {"gap0_m": 30.0, "speed_profile": 10.0}
    with pytest.raises(ScenarioError, match=r"host\.lead"):
        parse_scenario(doc, "heat.yaml")


def test_every_shipped_world_parses() -> None:
    worlds = 0
    for name, path in builtin_scenarios().items():
        sc = parse_scenario(yaml.safe_load(path.read_text()), str(path))
        if sc.world is not None:
            worlds += 1
            assert parse_world(yaml.safe_load(path.read_text())["world"], name) == sc.world
    assert worlds >= 5


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_mutated_worlds_parse_or_name_the_field(data: st.DataObject) -> None:
    doc = copy.deepcopy(_heat())
    doc["world"] = mutate(doc["world"], data.draw)
    try:
        sc = parse_scenario(doc, "heat.yaml")
    except ScenarioError as exc:
        assert "heat.yaml" in str(exc)
        return
    assert sc.world is None or dataclasses.is_dataclass(sc.world)


def test_road_side_broadcasts_decode_and_pass_the_receiver() -> None:
    from bywire.hil.world.spec import RoadsideSpec
    from bywire.protocol.v2x.codec import TrafficLightPhase
    from bywire.protocol.v2x.dsrc import RoadMap, SignalPhases
    from bywire.protocol.v2x.roadside import RoadsideView

    light = RoadsideSpec("traffic_light", 500.0, 9001, phases=((0.0, "green"), (3.0, "amber"), (6.0, "red")))
    limit = RoadsideSpec("speed_limit", 800.0, 9002, limit_mps=19.44)
    world = World(dataclasses.replace(world_of(), roadside=(light, limit)))
    bc = V2vBroadcaster(world, lambda t: EPOCH + t)
    rx = V2vReceiver()
    view = RoadsideView()
    lights, limits, maps = [], [], 0
    for k in range(1, 801):
        t = 0.01 * k
        world.place_ego(t, 0.0, 0.0, 0.0, 0.0, 0.0)
        world.step(t)
        for payload in bc.due(t):
            verdict = rx.check(payload, EPOCH + t)
            assert verdict.accepted, verdict
            if isinstance(verdict.message, RoadMap):
                limits.extend(view.learn(verdict.message))
                maps += 1
            else:
                assert isinstance(verdict.message, SignalPhases)
                lights.extend(view.place(verdict.message))
    # SPATEMs at 10 Hz, each light's MAPEM at 1 Hz from the start: every phase is placed.
    assert len(lights) == pytest.approx(80, abs=1) and view.unplaced == 0
    assert maps == 2 * 8 and len(limits) == 8
    at_4s = min(lights, key=lambda m: abs(m.generation_time_s - EPOCH - 4.0))
    assert at_4s.phase == TrafficLightPhase.AMBER and at_4s.time_to_change_s == pytest.approx(2.0, abs=0.05)
    x, y = world.road.frame.to_local(at_4s.lat_deg, at_4s.lon_deg)
    assert (x, y) == pytest.approx((500.0, 0.0), abs=0.01)
    x, y = world.road.frame.to_local(limits[0].lat_deg, limits[0].lon_deg)
    assert (x, y) == pytest.approx((800.0, 0.0), abs=0.01)
    assert limits[0].limit_mps == pytest.approx(19.44, abs=0.01)
