"""The traffic: vehicles on lanes with their drivers, our car placed on the road, and the bookkeeping.

`World.step(t_s, ego)` advances every traffic vehicle from the previous step to t_s (sub-steps of at most
`MAX_SUBSTEP_S`; the plant calls it at its events, ~100 Hz, never every millisecond), then books, for every
pair of successive vehicles on a lane (our car included), the gap (rear bumper of the one ahead to the
front bumper of the follower, along the lane), the time to collision ``gap / (v_follower - v_ahead)`` while
closing, and a collision each time a gap reaches 0 (counted once per contact, as the spine's plant did).

Our car is the FMU's pose placed on the road: the FMU starts at its own origin heading along +x; the
world maps that origin onto the start lane at `ego.s_m` with the lane's heading (a rigid transform) and
locates the car on the nearest lane each step (arc length and lateral offset by projection). Without
lateral control (the cooperative host does not steer) a curved road is only good for the traffic; our car
keeps its heading.

Traffic dynamics per car: ``s' = v``, ``v' = a``, ``lag a' + a = u`` (exact first-order hold over a
sub-step), u the driver's command bounded by the car's own limits, v >= 0 (a car that stops stays
stopped, it does not reverse). Scripted cars are kinematic (their script's speed, integrated by the
trapezoid rule, exact for piecewise-linear profiles). A car on the next lane may wander laterally
(Ornstein-Uhlenbeck, tau 5 s): its broadcast position may then look like ours (seed 003 IV-B).

What each traffic driver perceives of the car ahead on its lane (within `SENSE_RANGE_M`): ground truth
gap and speed, and that car's commanded acceleration delayed by its V2V latency (CACC's feed-forward, as
in Ploeg et al.; a car that does not communicate gives none). For a car
behind us, our acceleration is taken from ground truth delayed by our CAM's latency (`EGO_CAM_DELAY_S`),
not decoded from the CAM the host sends: the followers' behaviour then does not depend on the host's
V2V path, which is what the scenarios test on our car.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bywire.hil.world.drivers import Ahead, Driver, ScriptedSpeed, make_driver
from bywire.hil.world.road import Pose2D, Road
from bywire.hil.world.spec import VehicleSpec, WorldSpec

MAX_SUBSTEP_S = 0.010
SENSE_RANGE_M = 150.0  # what a simulated driver (radar ACC, CACC, human) reacts to
LATERAL_TAU_S = 5.0
EGO_CAM_DELAY_S = 0.05
ACCEL_HISTORY_S = 2.0
EGO = 0  # vehicle index of our car; traffic vehicles are 1..n in scenario order

TRAFFIC_COLUMNS = (
    "t_s",
    "vid",
    "lane",
    "s_m",
    "x_m",
    "y_m",
    "speed_mps",
    "accel_mps2",
    "gap_m",
    "pred_vid",
)


@dataclass
class EgoTruth:
    """Our car as the world sees it (ground truth from the FMU), placed on the road."""

    t_s: float
    x_m: float
    y_m: float
    heading_rad: float
    speed_mps: float
    accel_mps2: float
    yaw_rate_radps: float
    lane: int
    s_m: float
    lateral_m: float
    length_m: float
    width_m: float


@dataclass
class PairStats:
    """Bookkeeping of one follower against whatever was ahead of it on its lane."""

    min_gap_m: float = math.inf
    min_ttc_s: float = math.inf
    collisions: int = 0
    in_contact: bool = False


@dataclass
class TrafficVehicle:
    index: int
    spec: VehicleSpec
    driver: Driver
    lane: int
    s_m: float
    v_mps: float
    a_mps2: float = 0.0
    u_mps2: float = 0.0  # the driver's command: what a CACC car broadcasts as its acceleration
    lateral_m: float = 0.0
    present: bool = True
    accel_history: deque[tuple[float, float]] = field(default_factory=deque)

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def length_m(self) -> float:
        return self.spec.length_m


@dataclass(frozen=True)
class RadarReturn:
    """The radar's target this cycle (RADAR_Target's fields), and whom it saw (truth, for tests)."""

    valid: bool
    range_m: float = 0.0
    range_rate_mps: float = 0.0
    azimuth_rad: float = 0.0
    target: int | None = None


class World:
    """Road + traffic + our car; see the module docstring."""

    def __init__(
        self,
        spec: WorldSpec,
        seed: int = 1,
        replay_profile: Sequence[tuple[float, float]] = (),
    ) -> None:
        self.spec = spec
        self.road = Road(spec.road)
        self.rng = np.random.default_rng(seed)
        self.t_s = 0.0
        self.vehicles: list[TrafficVehicle] = []
        for i, vs in enumerate(spec.vehicles):
            driver = make_driver(vs.driver, seed * 1000 + i, replay_profile)
            v0 = driver.speed(0.0) if isinstance(driver, ScriptedSpeed) else vs.v0_mps
            self.vehicles.append(TrafficVehicle(i + 1, vs, driver, vs.lane, vs.s_m, v0))
        start = self.road.pose_at(spec.ego.lane, spec.ego.s_m)
        self._origin = start
        self._oc, self._os = math.cos(start.heading_rad), math.sin(start.heading_rad)
        self.ego = EgoTruth(
            0.0, start.x_m, start.y_m, start.heading_rad, 0.0, 0.0, 0.0, spec.ego.lane, spec.ego.s_m, 0.0,
            spec.ego.length_m, spec.ego.width_m,
        )  # fmt: skip
        self._ego_accel: deque[tuple[float, float]] = deque()
        self.stats: dict[int, PairStats] = {EGO: PairStats()} | {v.index: PairStats() for v in self.vehicles}
        self.pred: dict[int, int] = {}
        self.gap: dict[int, float] = {}
        self.steps = 0

    # -- our car --------------------------------------------------------------------------------------

    def place_ego(
        self, t_s: float, x_m: float, y_m: float, heading_rad: float, speed_mps: float, accel_mps2: float,
        yaw_rate_radps: float = 0.0,
    ) -> EgoTruth:  # fmt: skip
        """The FMU's state (its own frame) on the road; also remembered as `self.ego`."""
        o = self._origin
        wx = o.x_m + self._oc * x_m - self._os * y_m
        wy = o.y_m + self._os * x_m + self._oc * y_m
        lane, s, lateral = self.road.locate(wx, wy, self.ego.s_m)
        e = self.ego
        e.t_s, e.x_m, e.y_m, e.heading_rad = t_s, wx, wy, o.heading_rad + heading_rad
        e.speed_mps, e.accel_mps2, e.yaw_rate_radps = speed_mps, accel_mps2, yaw_rate_radps
        e.lane, e.s_m, e.lateral_m = lane, s, lateral
        self._ego_accel.append((t_s, accel_mps2))
        while self._ego_accel and self._ego_accel[0][0] < t_s - ACCEL_HISTORY_S:
            self._ego_accel.popleft()
        return e

    # -- stepping -------------------------------------------------------------------------------------

    def step(self, t_s: float) -> None:
        """Advance the traffic to t_s (our car must have been placed at t_s), then book the pairs."""
        if t_s <= self.t_s:
            return
        t = self.t_s
        n = max(1, math.ceil((t_s - t) / MAX_SUBSTEP_S - 1e-9))
        dt = (t_s - t) / n
        for k in range(n):
            self._substep(t + k * dt, t + (k + 1) * dt)
        self.t_s = t_s
        self.steps += 1
        self._book()

    def _substep(self, t0: float, t1: float) -> None:
        dt = t1 - t0
        for v in self.vehicles:
            if v.present and v.spec.leaves_at_s is not None and t1 >= v.spec.leaves_at_s:
                v.present = False
        ahead = self._ahead_all(t0)
        for v in self.vehicles:
            if not v.present:
                continue
            d = v.driver
            if isinstance(d, ScriptedSpeed):
                v.s_m += d.distance(t0, t1)
                v.v_mps = d.speed(t1)
                v.a_mps2 = v.u_mps2 = d.accel(t1)
            else:
                sp = v.spec.driver
                u = d.command(t0, v.v_mps, v.a_mps2, ahead.get(v.index), dt)
                u = min(max(u, -sp.max_decel_mps2), sp.max_accel_mps2)
                v.u_mps2 = u
                a0 = v.a_mps2
                phi = math.exp(-dt / sp.lag_s)
                a1 = u + (a0 - u) * phi
                # Exact integrals of the first-order lag over dt: dv = u dt + (a0 - u) lag (1 - phi).
                dv = u * dt + (a0 - u) * sp.lag_s * (1.0 - phi)
                if v.v_mps + dv < 0.0:  # stops within the step: it stays stopped, no reverse
                    v.s_m += 0.5 * v.v_mps * v.v_mps / max(1e-6, -min(a0, u, -1e-6))
                    v.v_mps, v.a_mps2 = 0.0, 0.0
                else:
                    v.s_m += v.v_mps * dt + 0.5 * dv * dt
                    v.v_mps += dv
                    v.a_mps2 = a1 if v.v_mps > 0.0 or a1 > 0.0 else 0.0
            v.accel_history.append((t1, v.u_mps2))
            while v.accel_history and v.accel_history[0][0] < t1 - ACCEL_HISTORY_S:
                v.accel_history.popleft()
            if v.spec.lateral_noise_m > 0.0:
                phi = math.exp(-dt / LATERAL_TAU_S)
                v.lateral_m = phi * v.lateral_m + math.sqrt(1.0 - phi * phi) * v.spec.lateral_noise_m * float(
                    self.rng.standard_normal()
                )

    @staticmethod
    def _delayed(history: deque[tuple[float, float]], t_s: float) -> float:
        """The newest value at or before t_s (the oldest one if none is that old); searched from the
        newest end, since the delays are a few samples."""
        for t, a in reversed(history):
            if t <= t_s:
                return a
        return history[0][1] if history else 0.0

    def _ahead_all(self, t_s: float) -> dict[int, Ahead]:
        """For each traffic vehicle, the nearest car ahead on its lane within SENSE_RANGE_M."""
        out: dict[int, Ahead] = {}
        e = self.ego
        for lane, members in self._lanes().items():
            for k in range(len(members) - 1):
                f, lead = members[k], members[k + 1]
                if f == EGO:
                    continue
                fv = self.vehicles[f - 1]
                gap = self._s(lead) - 0.5 * self._length(lead) - fv.s_m - 0.5 * fv.length_m
                if gap > SENSE_RANGE_M:
                    continue
                if lead == EGO:
                    speed = e.speed_mps
                    acc = self._delayed(self._ego_accel, t_s - EGO_CAM_DELAY_S)
                else:
                    lv = self.vehicles[lead - 1]
                    speed = lv.v_mps
                    latency = lv.spec.v2v.latency_s if lv.spec.v2v is not None else None
                    acc = 0.0 if latency is None else self._delayed(lv.accel_history, t_s - latency)
                out[f] = Ahead(gap, speed, acc)
            del lane
        return out

    def _s(self, vid: int) -> float:
        return self.ego.s_m if vid == EGO else self.vehicles[vid - 1].s_m

    def _length(self, vid: int) -> float:
        return self.ego.length_m if vid == EGO else self.vehicles[vid - 1].length_m

    def _speed(self, vid: int) -> float:
        return self.ego.speed_mps if vid == EGO else self.vehicles[vid - 1].v_mps

    def _lanes(self) -> dict[int, list[int]]:
        lanes: dict[int, list[tuple[float, int]]] = {}
        lanes.setdefault(self.ego.lane, []).append((self.ego.s_m, EGO))
        for v in self.vehicles:
            if v.present:
                lanes.setdefault(v.lane, []).append((v.s_m, v.index))
        return {k: [vid for _, vid in sorted(m)] for k, m in lanes.items()}

    def _book(self) -> None:
        self.pred = {}
        self.gap = {}
        for members in self._lanes().values():
            for k in range(len(members) - 1):
                f, lead = members[k], members[k + 1]
                gap = self._s(lead) - 0.5 * self._length(lead) - self._s(f) - 0.5 * self._length(f)
                self.pred[f] = lead
                self.gap[f] = gap
                st = self.stats[f]
                st.min_gap_m = min(st.min_gap_m, gap)
                closing = self._speed(f) - self._speed(lead)
                if closing > 0.0:
                    st.min_ttc_s = min(st.min_ttc_s, max(gap, 0.0) / closing)
                if gap <= 0.0 and not st.in_contact:
                    st.collisions += 1
                st.in_contact = gap <= 0.0

    # -- what the sensors and the evaluation see ----------------------------------------------------------

    def pose_of(self, v: TrafficVehicle) -> Pose2D:
        return self.road.pose_at(v.lane, v.s_m, v.lateral_m)

    def lead_of_ego(self) -> tuple[float, float] | None:
        """(gap, speed) of the car ahead of us on our lane (truth), or None."""
        pred = self.pred.get(EGO)
        if pred is None:
            return None
        return self.gap[EGO], self._speed(pred)

    def radar(self, noise: Callable[[float], float], range_noise_m: float) -> RadarReturn:
        """The ACC radar at our front bumper: the nearest car ahead in our lane within range and beam.

        `noise(sigma)` draws the measurement noise (the plant's generator, so that a scenario without a
        world draws the same numbers as before); dropouts come from the world's own generator.
        """
        rs = self.spec.radar
        e = self.ego
        if rs.dropout > 0.0 and float(self.rng.random()) < rs.dropout:
            return RadarReturn(False)
        ch, sh = math.cos(e.heading_rad), math.sin(e.heading_rad)
        fx0, fy0 = e.x_m + 0.5 * e.length_m * ch, e.y_m + 0.5 * e.length_m * sh
        best: tuple[float, float, float, int] | None = None
        half_fov = math.radians(rs.fov_deg) / 2.0
        for v in self.vehicles:
            if not v.present or v.lane != e.lane or v.s_m <= e.s_m:
                continue
            p = self.pose_of(v)
            rx = p.x_m - 0.5 * v.length_m * math.cos(p.heading_rad) - fx0
            ry = p.y_m - 0.5 * v.length_m * math.sin(p.heading_rad) - fy0
            fwd, left = rx * ch + ry * sh, -rx * sh + ry * ch
            rng_m = math.hypot(fwd, left)
            if fwd <= 0.0 or rng_m <= rs.min_range_m or rng_m >= rs.range_m:
                continue
            az = math.atan2(left, fwd)
            if abs(az) > half_fov:
                continue
            if best is None or rng_m < best[0]:
                ux, uy = rx / rng_m, ry / rng_m
                rate = (v.v_mps * math.cos(p.heading_rad) - e.speed_mps * ch) * ux + (
                    v.v_mps * math.sin(p.heading_rad) - e.speed_mps * sh
                ) * uy
                best = (rng_m, rate, az, v.index)
        if best is None:
            return RadarReturn(False)
        rng_m, rate, az, vid = best
        return RadarReturn(
            True, max(0.0, rng_m + noise(range_noise_m)), rate + noise(rs.range_rate_noise_mps), az, vid
        )

    def trace_rows(self) -> list[tuple[float, ...]]:
        """One row per vehicle present (TRAFFIC_COLUMNS), our car first."""
        e = self.ego
        t = self.t_s
        rows: list[tuple[float, ...]] = [
            (t, float(EGO), float(e.lane), e.s_m, e.x_m, e.y_m, e.speed_mps, e.accel_mps2,
             self.gap.get(EGO, math.nan), float(self.pred.get(EGO, -1))),
        ]  # fmt: skip
        for v in self.vehicles:
            if not v.present:
                continue
            p = self.pose_of(v)
            pred = self.pred.get(v.index)
            rows.append(
                (t, float(v.index), float(v.lane), v.s_m, p.x_m, p.y_m, v.v_mps, v.a_mps2,
                 self.gap.get(v.index, math.nan), -1.0 if pred is None else float(pred))
            )  # fmt: skip
        return rows

    def summary(self) -> dict[str, dict[str, Any]]:
        """Per-vehicle bookkeeping for the JSON: name -> min gap, min TTC, collisions."""
        names = {EGO: "ego"} | {v.index: v.name for v in self.vehicles}
        out: dict[str, dict[str, Any]] = {}
        for vid, st in self.stats.items():
            out[names[vid]] = {
                "min_gap_m": None if math.isinf(st.min_gap_m) else round(st.min_gap_m, 3),
                "min_ttc_s": None if math.isinf(st.min_ttc_s) else round(st.min_ttc_s, 3),
                "collisions": st.collisions,
            }
        return out

    @property
    def names(self) -> list[str]:
        return ["ego"] + [v.name for v in self.vehicles]


__all__ = ["EGO", "TRAFFIC_COLUMNS", "EgoTruth", "PairStats", "RadarReturn", "TrafficVehicle", "World"]
