"""A V2X network fuzzer in the spirit of AnnieWAY's CALM fuzzer (seed 003, Sec. III-B.3 (3), VI).

Seed 003: "all data received from the outside must be considered unsafe, potentially broken, or even
maliciously crafted"; their fuzzer "floods the network with either completely random data or slightly
mutated GCDC payload packages with a very high frequency" and found crashes and infinite loops in the CALM
stack; a crafted broadcast put unmodified GCDC clients into an infinite loop or a crash (Sec. VI).

`V2xFuzzer.next(now_s)` returns one hostile datagram and its kind; deterministic for a seed and the
sequence of times it is asked at. Kinds (FuzzKind): random bytes of random length; empty and oversize
datagrams; a valid header over random bytes; bit-flipped, truncated and extended valid frames; valid CAMs
with extreme values (the encodable limits), with CDD marker values (outOfRange / unavailable, encoded
raw past our dataclass checks), or with everything unavailable; replays of frames sent earlier; frames
spoofing our own station id or fresh random ids; a fleet vehicle teleporting (position / speed jump);
frames stamped in the future or too old (a CAM's GenerationDeltaTime wraps every 65.536 s: a day's offset
lands on its residue); mutated road-side SPATEMs / MAPEMs and iCLCMs; and floods from one sender (a burst
of valid frames far above 50 Hz). The fleet (`fleet_size` fake vehicles around
`center`) moves consistently, so its clean frames pass decoding and reach the receiver's deeper checks.

`avoid_station_ids` keeps the fuzzer off station ids it must not touch (a legitimate sender in a test);
our own id is spoofed on purpose when `own_station_id` is given. `fuzz_receiver` feeds a receiver directly
on simulated time; `flood` sends over UDP at a paced high rate for a bounded count and time.
"""

from __future__ import annotations

import dataclasses
import math
import random
import time
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from .codec import (
    ACCEL_OUT_OF_RANGE,
    ACCEL_UNAVAILABLE,
    HEADING_UNAVAILABLE,
    LAT_UNAVAILABLE,
    LENGTH_OUT_OF_RANGE,
    LON_UNAVAILABLE,
    SPEED_OUT_OF_RANGE,
    SPEED_UNAVAILABLE,
    WIDTH_OUT_OF_RANGE,
    YAW_RATE_OUT_OF_RANGE,
    YAW_RATE_UNAVAILABLE,
    DriveDirection,
    SpeedLimit,
    TrafficLightPhase,
    VehicleState,
    generation_delta,
)
from .dsrc import IntersectionMap, RoadMap, SignalGroupState, SignalPhases, StopLine
from .etsi_cam import cam_value, encode_cam_value
from .iclcm import ControllerType, CooperativeState
from .receiver import GeoPoint, V2vReceiver
from .transport import V2xEndpoint, V2xTransport
from .wire import encode

_M_PER_DEG_LAT = 111_195.0  # mean-sphere metres per degree of latitude (fleet placement only)
DEFAULT_CENTER = GeoPoint(49.0, 8.4)  # Karlsruhe, AnnieWAY's home


class FuzzKind(StrEnum):
    RANDOM = "random_bytes"
    EMPTY = "empty"
    OVERSIZE = "oversize"
    HEADER_GARBAGE = "header_then_garbage"
    BIT_FLIP = "bit_flip"
    TRUNCATED = "truncated"
    EXTENDED = "extended"
    EXTREME = "extreme_values"
    MARKERS = "marker_values"
    UNAVAILABLE = "all_unavailable"
    REPLAY = "replay"
    SPOOF_OWN = "spoof_own_id"
    SPOOF_RANDOM = "spoof_random_id"
    TELEPORT = "position_speed_jump"
    BAD_TIME = "bad_time"
    ROADSIDE = "roadside_mutated"
    FLOOD = "flood_one_sender"


DEFAULT_WEIGHTS: Mapping[FuzzKind, float] = {
    FuzzKind.RANDOM: 3.0,
    FuzzKind.EMPTY: 0.2,
    FuzzKind.OVERSIZE: 0.2,
    FuzzKind.HEADER_GARBAGE: 2.0,
    FuzzKind.BIT_FLIP: 4.0,
    FuzzKind.TRUNCATED: 1.0,
    FuzzKind.EXTENDED: 1.0,
    FuzzKind.EXTREME: 1.0,
    FuzzKind.MARKERS: 1.0,
    FuzzKind.UNAVAILABLE: 0.5,
    FuzzKind.REPLAY: 1.0,
    FuzzKind.SPOOF_OWN: 0.5,
    FuzzKind.SPOOF_RANDOM: 1.0,
    FuzzKind.TELEPORT: 1.0,
    FuzzKind.BAD_TIME: 1.0,
    FuzzKind.ROADSIDE: 1.0,
    FuzzKind.FLOOD: 0.05,  # each one is a burst of FLOOD_BURST datagrams
}
FLOOD_BURST = 60  # one sender, back to back: far above the 50 Hz limit
OVERSIZE_BYTES = 1600  # > the receiver's 1500-byte limit
CLEAN_REUSE_S = 0.05  # a fleet vehicle's clean frame is re-encoded at 20 Hz of fuzz time, re-stamped between
# GenerationDeltaTime of a CAM and an iCLCM: the 16 bits right after the 6-byte ItsPduHeader (their
# bodies begin with it, with no extension marker or OPTIONAL before it).
_GEN_DELTA_BYTES = slice(6, 8)


def restation(frame: bytes, station_id: int) -> bytes:
    """A message with another ItsPduHeader.stationId (bytes 2..5)."""
    return frame[:2] + station_id.to_bytes(4, "big") + frame[6:]


def retime(frame: bytes, t_s: float) -> bytes:
    """A CAM or iCLCM with its GenerationDeltaTime replaced (byte surgery: no ASN.1 round trip)."""
    delta = generation_delta("retime", t_s).to_bytes(2, "big")
    return frame[: _GEN_DELTA_BYTES.start] + delta + frame[_GEN_DELTA_BYTES.stop :]


@dataclass
class _FakeVehicle:
    """Straight at constant speed from (east0_m, north0_m) at the fleet's first time."""

    station_id: int
    east0_m: float
    north0_m: float
    heading_rad: float
    speed_mps: float

    def position(self, dt_s: float) -> tuple[float, float]:
        d = self.speed_mps * dt_s
        return self.east0_m + d * math.cos(self.heading_rad), self.north0_m + d * math.sin(self.heading_rad)


class V2xFuzzer:
    """Hostile datagrams, one per `next(now_s)` call (see the module docstring)."""

    def __init__(
        self,
        seed: int = 0,
        *,
        center: GeoPoint = DEFAULT_CENTER,
        fleet_size: int = 8,
        own_station_id: int | None = None,
        avoid_station_ids: frozenset[int] | set[int] = frozenset(),
        weights: Mapping[FuzzKind, float] | None = None,
    ) -> None:
        self.rng = random.Random(seed)
        self.center = center
        self.own_station_id = own_station_id
        self.avoid = frozenset(avoid_station_ids) | (
            {own_station_id} if own_station_id is not None else set()
        )
        w = dict(DEFAULT_WEIGHTS if weights is None else weights)
        if own_station_id is None:
            w.pop(FuzzKind.SPOOF_OWN, None)
        self._kinds = [k for k, v in w.items() if v > 0]
        if not self._kinds:
            raise ValueError("V2xFuzzer: no fuzz kind with a positive weight")
        self._weights = [w[k] for k in self._kinds]
        self.fleet = [
            _FakeVehicle(
                self._fresh_id(),
                self.rng.uniform(-500.0, 500.0),
                self.rng.uniform(-500.0, 500.0),
                self.rng.uniform(-math.pi, math.pi),
                self.rng.uniform(0.0, 35.0),
            )
            for _ in range(fleet_size)
        ]
        self._fleet_t: float | None = None
        self._history: deque[bytes] = deque(maxlen=256)  # clean frames sent, for replays
        self._pending: deque[tuple[FuzzKind, bytes]] = deque()
        self._clean_cache: dict[int, tuple[float, bytes]] = {}
        self.generated: Counter[str] = Counter()

    # ------------------------------------------------------------------------------------------ helpers

    def _fresh_id(self) -> int:
        while True:
            sid = self.rng.randrange(1, 0xFFFF_FFFF)
            if sid not in self.avoid:
                return sid

    def _start(self, now_s: float) -> None:
        if self._fleet_t is None:  # the fleet's positions are relative to the first time asked
            self._fleet_t = now_s

    def _latlon(self, east_m: float, north_m: float) -> tuple[float, float]:
        lat = self.center.lat_deg + north_m / _M_PER_DEG_LAT
        lon = self.center.lon_deg + east_m / (_M_PER_DEG_LAT * math.cos(math.radians(self.center.lat_deg)))
        return max(-90.0, min(90.0, lat)), (lon + 180.0) % 360.0 - 180.0

    def _state(self, v: _FakeVehicle, now_s: float) -> VehicleState:
        assert self._fleet_t is not None
        lat, lon = self._latlon(*v.position(max(0.0, now_s - self._fleet_t)))
        return VehicleState(
            station_id=v.station_id,
            generation_time_s=now_s,
            lat_deg=lat,
            lon_deg=lon,
            heading_rad=v.heading_rad,
            speed_mps=v.speed_mps,
            yaw_rate_radps=0.0,
            accel_mps2=0.0,
            length_m=4.5,
            width_m=1.8,
            drive_direction=DriveDirection.FORWARD,
        )

    def _fleet_frame(self, now_s: float) -> bytes:
        """A valid frame of a fleet vehicle. Encoded at most every CLEAN_REUSE_S per vehicle and re-stamped
        in between (asn1tools' encode is most of a fuzz datagram's cost; a flood needs thousands a second)."""
        v = self.rng.choice(self.fleet)
        cached = self._clean_cache.get(v.station_id)
        if cached is not None and 0.0 <= now_s - cached[0] <= CLEAN_REUSE_S:
            return retime(cached[1], now_s)
        frame = encode(self._state(v, now_s))
        self._clean_cache[v.station_id] = (now_s, frame)
        return frame

    def _clean(self, now_s: float) -> bytes:
        """A fleet frame that is remembered for later replays."""
        frame = self._fleet_frame(now_s)
        self._history.append(frame)
        return frame

    def _raw_vehicle(self, station_id: int, now_s: float, **fields: int | str) -> bytes:
        """A CAM from raw CDD integers: past the dataclass range checks on purpose."""
        lat, lon = self._latlon(self.rng.uniform(-300, 300), self.rng.uniform(-300, 300))
        state = VehicleState(station_id, now_s, lat, lon, math.pi / 2, 10.0, 0.0, 0.0, 4.5, 1.8)
        value = cam_value(state, low_frequency=False)
        params = value["cam"]["camParameters"]
        ref = params["basicContainer"]["referencePosition"]
        hf = params["highFrequencyContainer"][1]
        setters: dict[str, Callable[[Any], None]] = {
            "generationDeltaTime": lambda v: value["cam"].__setitem__("generationDeltaTime", v),
            "latitude": lambda v: ref.__setitem__("latitude", v),
            "longitude": lambda v: ref.__setitem__("longitude", v),
            "heading": lambda v: hf["heading"].__setitem__("headingValue", v),
            "speed": lambda v: hf["speed"].__setitem__("speedValue", v),
            "driveDirection": lambda v: hf.__setitem__("driveDirection", v),
            "yawRate": lambda v: hf["yawRate"].__setitem__("yawRateValue", v),
            "longitudinalAcceleration": lambda v: hf["longitudinalAcceleration"].__setitem__(
                "longitudinalAccelerationValue", v
            ),
            "vehicleLength": lambda v: hf["vehicleLength"].__setitem__("vehicleLengthValue", v),
            "vehicleWidth": lambda v: hf.__setitem__("vehicleWidth", v),
        }
        for name, v in fields.items():
            setters[name](v)
        return encode_cam_value(value)

    # ------------------------------------------------------------------------------------------ kinds

    def _make(self, kind: FuzzKind, now_s: float) -> bytes:
        rng = self.rng
        if kind is FuzzKind.RANDOM:
            return rng.randbytes(rng.randrange(1, 200))
        if kind is FuzzKind.EMPTY:
            return b""
        if kind is FuzzKind.OVERSIZE:
            return self._clean(now_s) + rng.randbytes(OVERSIZE_BYTES)
        if kind is FuzzKind.HEADER_GARBAGE:
            head = self._clean(now_s)[:6]
            return head + rng.randbytes(rng.randrange(0, 60))
        if kind is FuzzKind.BIT_FLIP:
            flipped = bytearray(self._clean(now_s))
            for _ in range(rng.choice((1, 1, 1, 2, 3, 8))):
                bit = rng.randrange(len(flipped) * 8)
                flipped[bit // 8] ^= 0x80 >> (bit % 8)
            return bytes(flipped)
        if kind is FuzzKind.TRUNCATED:
            frame = self._clean(now_s)
            return frame[: rng.randrange(0, len(frame))]
        if kind is FuzzKind.EXTENDED:
            return self._clean(now_s) + rng.randbytes(rng.randrange(1, 40))
        if kind is FuzzKind.EXTREME:
            v = self._state(rng.choice(self.fleet), now_s)
            extremes: tuple[dict[str, float], ...] = (
                {"speed_mps": 163.81},
                {"accel_mps2": rng.choice((-15.9, 15.9))},
                {"yaw_rate_radps": rng.choice((-1.0, 1.0)) * math.radians(327.65)},
                {"lat_deg": rng.choice((-90.0, 90.0))},
                {"lon_deg": rng.choice((-180.0, 180.0))},
                {"length_m": 102.1, "width_m": 6.0},
                {"speed_mps": 60.0, "yaw_rate_radps": 1.5},
            )
            changes: dict[str, Any] = {"station_id": self._fresh_id(), **rng.choice(extremes)}
            return encode(dataclasses.replace(v, **changes))
        if kind is FuzzKind.MARKERS:
            marker = rng.choice(
                (
                    {"speed": SPEED_OUT_OF_RANGE},
                    {"yawRate": rng.choice((-YAW_RATE_OUT_OF_RANGE, YAW_RATE_OUT_OF_RANGE))},
                    {"longitudinalAcceleration": rng.choice((-ACCEL_OUT_OF_RANGE, ACCEL_OUT_OF_RANGE))},
                    {"vehicleLength": LENGTH_OUT_OF_RANGE},
                    {"vehicleWidth": WIDTH_OUT_OF_RANGE},
                    {"heading": 3600},
                    {"latitude": LAT_UNAVAILABLE},
                    {"longitude": LON_UNAVAILABLE},
                    {"generationDeltaTime": rng.choice((0, 65_535))},
                )
            )
            return self._raw_vehicle(self._fresh_id(), now_s, **marker)
        if kind is FuzzKind.UNAVAILABLE:
            return self._raw_vehicle(
                self._fresh_id(),
                now_s,
                latitude=LAT_UNAVAILABLE,
                longitude=LON_UNAVAILABLE,
                heading=HEADING_UNAVAILABLE,
                speed=SPEED_UNAVAILABLE,
                driveDirection="unavailable",
                yawRate=YAW_RATE_UNAVAILABLE,
                longitudinalAcceleration=ACCEL_UNAVAILABLE,
                vehicleLength=1023,
                vehicleWidth=62,
            )
        if kind is FuzzKind.REPLAY:
            return rng.choice(self._history) if self._history else self._clean(now_s - 5.0)
        if kind is FuzzKind.SPOOF_OWN:
            assert self.own_station_id is not None
            return restation(self._fleet_frame(now_s), self.own_station_id)
        if kind is FuzzKind.SPOOF_RANDOM:
            return restation(self._fleet_frame(now_s), self._fresh_id())
        if kind is FuzzKind.TELEPORT:
            v = self._state(rng.choice(self.fleet), now_s)
            assert v.lat_deg is not None and v.speed_mps is not None
            if rng.random() < 0.5:
                return encode(dataclasses.replace(v, lat_deg=v.lat_deg + rng.choice((-1, 1)) * 0.002))
            return encode(dataclasses.replace(v, speed_mps=min(69.0, v.speed_mps + 30.0)))
        if kind is FuzzKind.BAD_TIME:
            offset = rng.choice((86_400.0, -86_400.0, 3.0, -30.0, 1e5))
            if rng.random() < 0.3:  # a SPATEM's time is absolute in the year: another day shows
                group = SignalGroupState(rng.randrange(65536), 1, TrafficLightPhase.GREEN, 5.0)
                return encode(SignalPhases(self._fresh_id(), now_s + offset, (group,)))
            return retime(restation(self._fleet_frame(now_s), self._fresh_id()), now_s + offset)
        if kind is FuzzKind.ROADSIDE:
            return self._roadside(now_s)
        raise AssertionError(kind)

    def _roadside(self, now_s: float) -> bytes:
        """A SPATEM, MAPEM or iCLCM of random content, half of them with a flipped bit."""
        rng = self.rng
        lat, lon = self._latlon(rng.uniform(-300, 300), rng.uniform(-300, 300))
        heading = rng.choice((None, rng.uniform(-math.pi, math.pi)))
        msg: SignalPhases | RoadMap | CooperativeState
        pick = rng.random()
        if pick < 0.4:
            group = SignalGroupState(
                rng.randrange(65536),
                rng.randrange(256),
                rng.choice([*TrafficLightPhase, None]),
                rng.choice((None, 0.0, 12.3, 3599.0)),
            )
            msg = SignalPhases(self._fresh_id(), now_s, (group,))
        elif pick < 0.8:
            station = self._fresh_id()
            if rng.random() < 0.5:
                line = StopLine(rng.randrange(256), lat, lon, heading)
                msg = RoadMap(station, now_s, intersections=(IntersectionMap(rng.randrange(65536), (line,)),))
            else:
                zone = SpeedLimit(
                    station, now_s, rng.randrange(65536), lat, lon, rng.uniform(0.3, 70.0), heading
                )
                msg = RoadMap(station, now_s, speed_limits=(zone,))
        else:
            msg = CooperativeState(
                self._fresh_id(),
                now_s,
                rng.choice(list(ControllerType)),
                rng.choice((None, rng.uniform(-10.0, 10.0))),
                rng.choice((None, 0.6, 36.0)),
                rng.choice((None, rng.uniform(0.0, 50.0))),
                mio_station_id=rng.randrange(1 << 32),
                platoon_id=rng.randrange(256),
            )
        frame = bytearray(encode(msg))
        if rng.random() < 0.5:
            bit = rng.randrange(len(frame) * 8)
            frame[bit // 8] ^= 0x80 >> (bit % 8)
        return bytes(frame)

    def _flood(self, now_s: float) -> None:
        frame = encode(self._state(self.rng.choice(self.fleet), now_s))
        for i in range(FLOOD_BURST):
            self._pending.append((FuzzKind.FLOOD, retime(frame, now_s + i * 1e-4)))

    # ------------------------------------------------------------------------------------------ API

    def next(self, now_s: float) -> tuple[FuzzKind, bytes]:
        """One hostile datagram for wall time now_s (UNIX s), and what kind it is."""
        self._start(now_s)
        if not self._pending:
            kind = self.rng.choices(self._kinds, self._weights)[0]
            if kind is FuzzKind.FLOOD:
                self._flood(now_s)
            else:
                self._pending.append((kind, self._make(kind, now_s)))
        kind, frame = self._pending.popleft()
        self.generated[kind.value] += 1
        return kind, frame


def fuzz_receiver(
    receiver: V2vReceiver,
    fuzzer: V2xFuzzer,
    count: int,
    *,
    start_s: float,
    step_s: float = 1e-3,
    own: GeoPoint | None = None,
) -> Counter[str]:
    """Feed `count` fuzz datagrams to a receiver on simulated time (start_s + i * step_s); returns how
    many were accepted per fuzz kind."""
    accepted: Counter[str] = Counter()
    for i in range(count):
        t = start_s + i * step_s
        kind, frame = fuzzer.next(t)
        if receiver.check(frame, t, own).accepted:
            accepted[kind.value] += 1
    return accepted


@dataclass(frozen=True)
class FloodReport:
    sent: int
    send_errors: int
    elapsed_s: float
    by_kind: dict[str, int]

    @property
    def rate_hz(self) -> float:
        return self.sent / self.elapsed_s if self.elapsed_s > 0 else math.nan


def flood(
    address: V2xEndpoint | str,
    count: int,
    seconds: float,
    *,
    seed: int = 0,
    fuzzer: V2xFuzzer | None = None,
    clock: Callable[[], float] = time.time,
) -> FloodReport:
    """Send `count` fuzz datagrams to address spread evenly over `seconds` (paced in ~1 ms batches).

    Bounded both ways: it stops after `count` datagrams, or at seconds + max(0.5 s, 10 %) if the machine
    cannot keep the pace (the report says how many went out).
    """
    if count < 0 or not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"flood: count {count} must be >= 0 and seconds {seconds!r} > 0")
    fz = fuzzer or V2xFuzzer(seed)
    by_kind: Counter[str] = Counter()
    with V2xTransport(address, receive=False) as tx:
        start = time.monotonic()
        hard_stop = start + seconds + max(0.5, 0.1 * seconds)
        period = seconds / count if count else 0.0
        i = 0
        while i < count:
            now = time.monotonic()
            if now >= hard_stop:
                break
            due = min(count, int((now - start) / period) + 1) if period > 0 else count
            if due <= i:
                time.sleep(min(1e-3, start + i * period - now))
                continue
            while i < due:
                kind, frame = fz.next(clock())
                if tx.send(frame):
                    by_kind[kind.value] += 1
                i += 1
        elapsed = time.monotonic() - start
        return FloodReport(tx.sent, tx.send_errors, elapsed, dict(by_kind))
