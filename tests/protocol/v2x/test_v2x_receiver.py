"""Hardened V2V receiver (seed 003 III-B / IV-B): every plausibility rule at its boundary, the
counting invariant, quarantine and blacklist, re-anchoring, road-side messages, and hostile sequences."""

from __future__ import annotations

import dataclasses
import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bywire.protocol.v2x.codec import (
    DriveDirection,
    SpeedLimit,
    TrafficLightPhase,
    VehicleState,
)
from bywire.protocol.v2x.dsrc import IntersectionMap, RoadMap, SignalGroupState, SignalPhases, StopLine
from bywire.protocol.v2x.iclcm import ControllerType, CooperativeState
from bywire.protocol.v2x.receiver import GeoPoint, ReceiverParams, V2vReceiver, haversine_m
from bywire.protocol.v2x.transport import Datagram
from bywire.protocol.v2x.wire import encode

T0_S = 1_700_000_000.0  # 22:13:20 UTC
OWN = GeoPoint(49.0, 8.4)
M_PER_DEG_LAT = 111_195.0  # the receiver's mean-radius sphere


def north_of(point: GeoPoint, metres: float) -> tuple[float, float]:
    return point.lat_deg + metres / M_PER_DEG_LAT, point.lon_deg


def state(station: int = 7, t: float = T0_S, north_m: float = 50.0, **changes: object) -> VehicleState:
    lat, lon = north_of(OWN, north_m)
    v = VehicleState(
        station_id=station,
        generation_time_s=t,
        lat_deg=lat,
        lon_deg=lon,
        heading_rad=math.pi / 2,  # driving north
        speed_mps=25.0,
        yaw_rate_radps=0.0,
        accel_mps2=0.0,
        length_m=4.5,
        width_m=1.8,
        drive_direction=DriveDirection.FORWARD,
    )
    return dataclasses.replace(v, **changes)  # type: ignore[arg-type]


def track(
    station: int, n: int, *, t0: float = T0_S, rate_hz: float = 10.0, speed_mps: float = 25.0
) -> list[bytes]:
    """A consistent sender: n messages at rate_hz driving north at speed_mps."""
    dt = 1.0 / rate_hz
    return [
        encode(state(station, t0 + k * dt, 50.0 + speed_mps * k * dt, speed_mps=speed_mps)) for k in range(n)
    ]


def feed(
    rx: V2vReceiver, frames: list[bytes], *, t0: float = T0_S, rate_hz: float = 10.0, latency_s: float = 0.02
) -> list[str | None]:
    """Receive frames latency_s after their slot; the reasons (None = accepted)."""
    return [rx.check(f, t0 + k / rate_hz + latency_s, OWN).reason for k, f in enumerate(frames)]


def invariant(rx: V2vReceiver) -> None:
    assert rx.received == rx.accepted + sum(rx.rejected.values())


# ---------------------------------------------------------------------------------------------- accept


def test_consistent_sender_is_accepted_throughout() -> None:
    rx = V2vReceiver(own_station_id=1)
    reasons = feed(rx, track(7, 100))
    assert reasons == [None] * 100
    assert rx.accepted == 100 and rx.v2v_rejected() == {}
    invariant(rx)


def test_receive_all_uses_each_datagrams_receive_time() -> None:
    rx = V2vReceiver()
    frames = track(7, 5)
    datagrams = [Datagram(f, ("127.0.0.1", 1), T0_S + 0.1 * k + 0.01, 0.0) for k, f in enumerate(frames)]
    assert [m.station_id for m in rx.receive_all(datagrams, OWN)] == [7] * 5
    stale = [Datagram(frames[0], ("127.0.0.1", 1), T0_S + 5.0, 0.0)]
    assert list(V2vReceiver().receive_all(stale, OWN)) == []


# ---------------------------------------------------------------------------------------------- time


@pytest.mark.parametrize(
    ("age_s", "reason"),
    [
        (0.0, None),
        (1.0, None),  # max_age_s
        (1.002, "too_old"),
        (-0.199, None),  # max_future_s is 0.2 s
        (-0.202, "future"),
        (30.0, "too_old"),
        # A CAM's time is TimestampIts mod 65 536 ms: a day lands on its residue, 86 400 000 ms = 1318 wraps
        # + 23 552 ms, so a day-old CAM looks 23.6 s old and a day-early one 23.6 s in the future.
        (86_400.0, "too_old"),
        (-86_400.0, "future"),
        (65.536, None),  # a whole wrap later: the time checks cannot tell (its history's checks can)
    ],
)
def test_generation_time_gates(age_s: float, reason: str | None) -> None:
    rx = V2vReceiver()
    assert rx.check(encode(state(t=T0_S - age_s)), T0_S, OWN).reason == reason


def phases(station: int = 50, t: float = T0_S, intersection: int = 17, **changes: object) -> SignalPhases:
    group = SignalGroupState(intersection, 1, TrafficLightPhase.GREEN, 20.0)
    return SignalPhases(station, t, (dataclasses.replace(group, **changes),))  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("age_s", "reason"),
    [(0.5, None), (1.5, "too_old"), (86_400.0, "another_day"), (-86_400.0, "another_day")],
)
def test_spatem_time_is_absolute(age_s: float, reason: str | None) -> None:
    assert V2vReceiver().check(encode(phases(t=T0_S - age_s)), T0_S, OWN).reason == reason


def test_midnight_is_not_another_day() -> None:
    midnight = 1_700_006_400.0  # 2023-11-15T00:00:00Z
    assert midnight % 86_400 == 0
    rx = V2vReceiver()
    assert rx.check(encode(phases(t=midnight - 0.05)), midnight + 0.02, OWN).accepted
    # Too old across midnight is "another day": the paper's test ("a timestamp of today").
    assert rx.check(encode(phases(51, t=midnight - 5.0)), midnight + 0.02, OWN).reason == "another_day"


def test_replays_are_rejected_per_sender() -> None:
    rx = V2vReceiver()
    frames = track(7, 3)
    assert feed(rx, frames) == [None, None, None]
    # The same frame again, and an older one, within max_age: replays.
    assert rx.check(frames[2], T0_S + 0.25, OWN).reason == "replayed"
    assert rx.check(frames[1], T0_S + 0.26, OWN).reason == "replayed"
    # Another sender with the same generation time is fine.
    assert rx.check(encode(state(station=8, t=T0_S + 0.2)), T0_S + 0.27, OWN).accepted
    invariant(rx)


# ---------------------------------------------------------------------------------------------- range, limits


@pytest.mark.parametrize(
    ("north_m", "reason"), [(1999.0, None), (2001.0, "out_of_range"), (-2001.0, "out_of_range")]
)
def test_vicinity(north_m: float, reason: str | None) -> None:
    v = state(north_m=north_m)
    assert v.lat_deg is not None
    assert haversine_m(OWN.lat_deg, OWN.lon_deg, v.lat_deg, OWN.lon_deg) == pytest.approx(
        abs(north_m), abs=0.01
    )
    assert V2vReceiver().check(encode(v), T0_S, OWN).reason == reason
    # No own fix yet: the range cannot be checked, everything else still is.
    assert V2vReceiver().check(encode(v), T0_S, None).accepted


def test_position_unavailable_is_rejected() -> None:
    rx = V2vReceiver()
    assert rx.check(encode(state(lat_deg=None)), T0_S, OWN).reason == "no_position"
    assert rx.check(encode(state(station=8, lon_deg=None)), T0_S, OWN).reason == "no_position"
    # Everything else unavailable is passed on as None.
    bare = state(
        station=9,
        heading_rad=None,
        speed_mps=None,
        yaw_rate_radps=None,
        accel_mps2=None,
        length_m=None,
        width_m=None,
        drive_direction=None,
    )
    got = rx.receive(encode(bare), T0_S, OWN)
    assert got is not None and got.speed_mps is None and got.heading_rad is None


@pytest.mark.parametrize(
    ("changes", "reason"),
    [
        ({"speed_mps": 70.0}, None),
        ({"speed_mps": 70.01}, "speed_implausible"),
        ({"speed_mps": 163.81}, "speed_implausible"),
        ({"accel_mps2": -12.0}, None),
        ({"accel_mps2": 12.1}, "accel_implausible"),
        ({"accel_mps2": -15.9}, "accel_implausible"),
        ({"speed_mps": 1.0, "yaw_rate_radps": 1.6}, None),
        ({"speed_mps": 1.0, "yaw_rate_radps": -1.61}, "yaw_rate_implausible"),
        ({"speed_mps": 20.0, "yaw_rate_radps": 0.599}, None),  # 11.98 m/s^2 lateral
        ({"speed_mps": 20.0, "yaw_rate_radps": 0.61}, "yaw_rate_implausible"),  # 12.2 m/s^2
        ({"length_m": 25.2, "width_m": 3.5}, None),
        ({"length_m": 25.3}, "size_implausible"),
        ({"width_m": 3.6}, "size_implausible"),
        ({"length_m": 102.1}, "size_implausible"),
    ],
)
def test_physical_limits(changes: dict[str, float], reason: str | None) -> None:
    assert V2vReceiver().check(encode(state(**changes)), T0_S, OWN).reason == reason


# ---------------------------------------------------------------------------------------------- history


def test_position_and_speed_jumps() -> None:
    rx = V2vReceiver()
    assert rx.check(encode(state(t=T0_S, north_m=50.0)), T0_S, OWN).accepted
    # 0.1 s at 25 m/s: reach = 25 * 0.1 + 0.5 * 12 * 0.01 + 5 = 7.56 m.
    assert rx.check(encode(state(t=T0_S + 0.1, north_m=57.5)), T0_S + 0.1, OWN).accepted
    assert (
        rx.check(encode(state(t=T0_S + 0.2, north_m=57.5 + 7.7)), T0_S + 0.2, OWN).reason == "position_jump"
    )
    # Speed: at most 12 m/s^2 * 0.2 s + 1 m/s = 3.4 m/s since the last accepted (t0 + 0.1).
    ok = state(t=T0_S + 0.3, north_m=57.5 + 2.5, speed_mps=28.3)
    assert rx.check(encode(ok), T0_S + 0.3, OWN).accepted
    jump = state(t=T0_S + 0.4, north_m=60.0 + 2.9, speed_mps=28.3 + 2.3)
    assert rx.check(encode(jump), T0_S + 0.4, OWN).reason == "speed_jump"
    # Reversing flips the sign: 1.5 m/s backward 0.2 s after 28.3 m/s forward is a 29.8 m/s change.
    back = state(t=T0_S + 0.5, north_m=60.0 + 5.0, speed_mps=1.5, drive_direction=DriveDirection.BACKWARD)
    assert rx.check(encode(back), T0_S + 0.5, OWN).reason == "speed_jump"
    invariant(rx)


def test_history_times_out() -> None:
    rx = V2vReceiver()
    assert rx.check(encode(state(t=T0_S, north_m=0.0)), T0_S, OWN).accepted
    # 3.5 s later 500 m away (a 140 m/s average): the old history no longer constrains it.
    assert rx.check(encode(state(t=T0_S + 3.5, north_m=500.0)), T0_S + 3.5, OWN).accepted


def test_reanchor_after_a_genuine_jump() -> None:
    # A GPS/INS recovering after a bridge (seed 003 Fig. 6): the position jumps 200 m, then is consistent.
    rx = V2vReceiver()
    assert feed(rx, track(7, 10)) == [None] * 10
    after = [encode(state(7, T0_S + 1.0 + 0.1 * k, 300.0 + 2.5 * k)) for k in range(6)]
    reasons = [rx.check(f, T0_S + 1.0 + 0.1 * k + 0.02, OWN).reason for k, f in enumerate(after)]
    assert reasons == ["position_jump", "position_jump", None, None, None, None]
    assert rx.events["reanchored"] == 1
    # An inconsistent stream of jumps (noise, not a new track) never re-anchors.
    rx2 = V2vReceiver()
    feed(rx2, track(7, 10))
    noisy = [encode(state(7, T0_S + 1.0 + 0.1 * k, 300.0 + (200.0 if k % 2 else 0.0))) for k in range(6)]
    assert all(rx2.check(f, T0_S + 1.0 + 0.1 * k, OWN).reason == "position_jump" for k, f in enumerate(noisy))


# ------------------------------------------------------------------------------------------ rate, quarantine


def test_rate_limit_allows_a_burst_then_50_hz() -> None:
    rx = V2vReceiver()
    frames = track(7, 40, rate_hz=1000.0, speed_mps=1.0)
    reasons = [rx.check(f, T0_S + 1e-3 * k, OWN).reason for k, f in enumerate(frames)]
    assert reasons[:5] == [None] * 5  # rate_burst
    assert reasons[5] == "rate_limited"
    # Then one token every 20 ms: 40 datagrams in 40 ms earn about 2 more (until the sender gets quarantined).
    assert 5 <= reasons.count(None) <= 8
    # 25 Hz (the fastest GCDC sender) with no burst at all is never limited.
    ok = V2vReceiver()
    assert feed(ok, track(8, 100, rate_hz=25.0), rate_hz=25.0) == [None] * 100


def test_a_failing_sender_is_quarantined_then_forgiven() -> None:
    p = ReceiverParams()
    rx = V2vReceiver(p)
    first = encode(state(7, T0_S))
    assert rx.check(first, T0_S, OWN).accepted
    # Replays every 20 ms: a strike each, draining 0.02 in between: the 11th reaches 10 strikes
    # (11 - 10 x 0.02 = 10.8) and quarantines the sender (it is still counted as a replay).
    reasons = [rx.check(first, T0_S + 0.02 * (k + 1), OWN).reason for k in range(10)]
    assert reasons == ["replayed"] * 10 and rx.events["quarantined"] == 0
    assert rx.check(first, T0_S + 0.22, OWN).reason == "replayed"
    assert rx.events["quarantined"] == 1 and rx.is_quarantined(7, T0_S + 0.23)
    fresh = encode(state(7, T0_S + 0.3, 57.5))
    assert rx.check(fresh, T0_S + 0.3, OWN).reason == "quarantined"
    later = T0_S + 0.22 + p.quarantine_s + 0.1
    assert rx.check(encode(state(7, later, 300.0)), later, OWN).accepted
    # Other senders were never affected.
    assert rx.check(encode(state(8, T0_S + 0.3)), T0_S + 0.3, OWN).accepted
    invariant(rx)


def test_occasional_glitches_never_quarantine() -> None:
    rx = V2vReceiver()
    frames = track(7, 600)  # 60 s at 10 Hz
    for k, f in enumerate(frames):
        rx.check(f, T0_S + 0.1 * k + 0.02, OWN)
        if k % 15 == 14:  # a replay every 1.5 s: strikes drain at 1/s
            rx.check(frames[k - 1], T0_S + 0.1 * k + 0.03, OWN)
    assert rx.events["quarantined"] == 0
    assert rx.accepted == 600 and rx.rejected == {"replayed": 40}


def test_manual_blacklist_own_station_and_expiry() -> None:
    rx = V2vReceiver(ReceiverParams(blacklist=frozenset({9})), own_station_id=1)
    assert rx.check(encode(state(9)), T0_S, OWN).reason == "blacklisted"
    assert rx.check(encode(state(1)), T0_S, OWN).reason == "own_station"
    rx.blacklist(7, duration_s=5.0, now_s=T0_S)
    assert rx.check(encode(state(7, T0_S + 1.0)), T0_S + 1.0, OWN).reason == "blacklisted"
    assert rx.check(encode(state(7, T0_S + 5.5)), T0_S + 5.5, OWN).accepted
    rx.unblacklist(9)
    assert rx.check(encode(state(9, T0_S + 6.0)), T0_S + 6.0, OWN).accepted
    assert rx.v2v_rejected() == {"blacklisted": 2, "own_station": 1}


def test_garbage_is_counted_by_reason() -> None:
    rx = V2vReceiver()
    good = encode(state())
    for data in (b"", b"\x02\x02", good + b"\x00", good[:-3], b"\x09" * 40, good + bytes(2000)):
        assert rx.check(data, T0_S, OWN).message is None
    assert rx.v2v_rejected() == {
        "too_short": 2,
        "non_canonical": 1,
        "malformed": 1,
        "unknown_message": 1,
        "oversize": 1,
    }
    invariant(rx)


def test_sender_table_is_bounded() -> None:
    rx = V2vReceiver(ReceiverParams(max_senders=4))
    for sid in range(10):
        assert rx.check(encode(state(100 + sid)), T0_S, OWN).accepted
    assert rx.tracked_senders == 4 and rx.events["senders_evicted"] == 6


# ---------------------------------------------------------------------------------------------- road side


def test_traffic_lights() -> None:
    rx = V2vReceiver()
    # One RSU, four signal groups in one SPATEM: one stream per intersection.
    groups = tuple(SignalGroupState(17, g, TrafficLightPhase.GREEN, 20.0) for g in range(4))
    assert rx.check(encode(SignalPhases(50, T0_S, groups)), T0_S + 0.01, OWN).accepted
    assert rx.check(encode(SignalPhases(50, T0_S, groups)), T0_S + 0.02, OWN).reason == "replayed"
    assert rx.check(encode(phases(t=T0_S, intersection=18)), T0_S + 0.02, OWN).accepted
    assert rx.check(encode(phases(t=T0_S + 0.1, time_to_change_s=300.0)), T0_S + 0.1, OWN).accepted
    assert (
        rx.check(encode(phases(t=T0_S + 0.2, time_to_change_s=300.1)), T0_S + 0.2, OWN).reason
        == "time_to_change_implausible"
    )
    assert rx.check(encode(phases(t=T0_S + 0.3, phase=None, time_to_change_s=None)), T0_S + 0.3, OWN).accepted
    assert rx.check(encode(phases(52, t=T0_S - 2.0)), T0_S, OWN).reason == "too_old"
    invariant(rx)


def road_map(station: int, t: float = T0_S, *, north_m: float = 300.0, **zone: object) -> RoadMap:
    lat, lon = north_of(OWN, north_m)
    if zone:
        limit = SpeedLimit(station, t, 3, lat, lon, 80 / 3.6, math.pi / 2)
        return RoadMap(station, t, speed_limits=(dataclasses.replace(limit, **zone),))  # type: ignore[arg-type]
    return RoadMap(station, t, (IntersectionMap(17, (StopLine(1, lat, lon, math.pi / 2),)),))


def test_maps_and_speed_limits() -> None:
    rx = V2vReceiver()
    assert rx.check(encode(road_map(60)), T0_S + 0.5, OWN).accepted
    # A map's time is its minute (T0_S is 20 s into one): the same map again within the minute is fine.
    assert rx.check(encode(road_map(60)), T0_S + 0.6, OWN).accepted
    assert rx.check(encode(road_map(61, T0_S - 15.0)), T0_S + 0.5, OWN).accepted
    assert rx.check(encode(road_map(62, T0_S - 125.0)), T0_S + 0.5, OWN).reason == "too_old"
    assert rx.check(encode(road_map(63, limit_mps=80 / 3.6)), T0_S, OWN).accepted
    assert rx.check(encode(road_map(64, limit_mps=200 / 3.6)), T0_S, OWN).reason == "speed_limit_implausible"
    assert rx.check(encode(road_map(65, limit_mps=3 / 3.6)), T0_S, OWN).reason == "speed_limit_implausible"
    assert rx.check(encode(road_map(66, lat_deg=None)), T0_S, OWN).reason == "no_position"
    assert rx.check(encode(road_map(67, north_m=5000.0)), T0_S, OWN).reason == "out_of_range"
    far_lines = road_map(68, north_m=5000.0)
    assert rx.check(encode(far_lines), T0_S, OWN).reason == "out_of_range"
    invariant(rx)


def test_cooperative_states() -> None:
    # the iCLCM itself ends at +-10 m/s^2 and 50 m/s
    rx = V2vReceiver(ReceiverParams(max_accel_mps2=8.0, max_speed_mps=40.0))
    ok = CooperativeState(7, T0_S, ControllerType.CACC, -3.0, 0.6, 25.0)
    got = rx.receive(encode(ok), T0_S + 0.02, OWN)
    assert isinstance(got, CooperativeState) and got.target_accel_mps2 == -3.0
    assert rx.check(encode(ok), T0_S + 0.03, OWN).reason == "replayed"
    hard = dataclasses.replace(ok, station_id=8, target_accel_mps2=-9.5)
    assert rx.check(encode(hard), T0_S + 0.02, OWN).reason == "accel_implausible"
    fast = dataclasses.replace(ok, station_id=9, cruise_speed_mps=45.0)
    assert rx.check(encode(fast), T0_S + 0.02, OWN).reason == "speed_implausible"
    # A vehicle's CAM and its iCLCM are two streams of one sender.
    assert rx.check(encode(state(7, T0_S)), T0_S + 0.02, OWN).accepted
    invariant(rx)


def test_roadside_rate_is_per_message_kind() -> None:
    rx = V2vReceiver()
    # 16 SPATEMs at once is fine for an RSU (roadside_burst), the 17th back to back is limited.
    reasons = [rx.check(encode(phases(intersection=g)), T0_S, OWN).reason for g in range(17)]
    assert reasons == [None] * 16 + ["rate_limited"]
    # Its MAPEMs have their own bucket.
    assert rx.check(encode(road_map(50)), T0_S, OWN).accepted


def test_params_are_validated() -> None:
    with pytest.raises(ValueError, match=r"ReceiverParams\.max_age_s"):
        ReceiverParams(max_age_s=0.0)
    with pytest.raises(ValueError, match=r"ReceiverParams\.max_senders"):
        ReceiverParams(max_senders=0)
    with pytest.raises(ValueError, match=r"ReceiverParams\.max_rate_hz"):
        ReceiverParams(max_rate_hz=math.nan)


# ----------------------------------------------------------------------------------------- hostile sequences


@st.composite
def hostile_sequences(draw: st.DrawFn) -> list[tuple[bytes, float]]:
    base = [encode(state(s, T0_S + 0.1 * k, 50.0 + 2.5 * k)) for s in (7, 8) for k in range(5)]
    base += [encode(phases()), encode(road_map(60)), encode(road_map(61, limit_mps=25.0))]
    base += [encode(CooperativeState(9, T0_S, ControllerType.ACC, 1.0))]
    out = []
    t = T0_S
    for _ in range(draw(st.integers(1, 40))):
        t += draw(st.floats(-0.5, 2.0))
        if draw(st.booleans()):
            frame = bytearray(draw(st.sampled_from(base)))
            for _ in range(draw(st.integers(0, 3))):
                bit = draw(st.integers(0, len(frame) * 8 - 1))
                frame[bit // 8] ^= 0x80 >> (bit % 8)
            out.append((bytes(frame), t))
        else:
            out.append((draw(st.binary(max_size=64)), t))
    return out


@given(hostile_sequences())
@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_hostile_sequences_never_raise_and_always_add_up(seq: list[tuple[bytes, float]]) -> None:
    rx = V2vReceiver(ReceiverParams(max_senders=3), own_station_id=8)
    for data, t in seq:
        verdict = rx.check(data, t, OWN)
        assert (verdict.message is None) == (verdict.reason is not None)
        if verdict.message is not None:
            assert verdict.message.station_id != 8
            slack = 60.0 if isinstance(verdict.message, RoadMap) else 0.0  # a map's time is its minute
            assert abs(t - verdict.message.generation_time_s) <= 1.0 + slack + 1e-9
    invariant(rx)
    assert rx.received == len(seq)
