"""`bywire bench urban`: the moving-traffic check, precedence, the lateral controller and the HSM step, timed.

Seed 000 sections 8 (the hierarchical state machine), 9 (the moving-traffic check, eqs 8-17) and 11
(orbital lateral control).

Rows, measured interleaved in one run so that machine load hits all alike; each call is timed alone
with `time.perf_counter_ns` and the distribution reported as p50 / p99 / max in microseconds:

- ``baseline``: an empty Python function called the same way (the floor of the timing method);
- ``mtc_1`` / ``mtc_10``: `moving_traffic_check` with 1 and with 10 vehicles (random but plausible
  scenes: distances, speeds and our own state drawn per call, all five standard parameter sets);
- ``precedence_update``: one `IntersectionPrecedence.update` with three vehicles waiting and one in
  the box (the manager advances 0.1 s per call, as at 10 Hz);
- ``lateral_step``: one `lateral_step` (projection onto a 30 m path stub sampled every 0.25 m, the
  paper's "approximately 30 m ahead", plus eq. 21), with and without the s-hint window;
- ``hsm_step``: one `Behaviour.step` (the hierarchical state machine with its MTC, precedence, object
  projection and the command's stub) at a four-way stop of two crossing two-lane roads (`_HSM_RNDF`):
  we approach from the west, stop and wait while three vehicles stand at the other stop lines and
  cross in turn and a fourth follows us; the ego moves along the route closed by `longitudinal_step`
  (0.05 s per call; a fresh run once through the intersection to the next checkpoint).

Each row also gives ``ratio_p50``: its median over the baseline's. Contract (``--json``): ``{"rows":
{name: {"p50_us", "p99_us", "max_us", "n", "ratio_p50"}}, "seconds"}``.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from benchmarks.timed import add_timed_arguments, run_timed
from bywire.host.behaviour.behaviour import Behaviour
from bywire.host.behaviour.mtc import ConflictVehicle, moving_traffic_check
from bywire.host.behaviour.precedence import IntersectionPrecedence, StopLine, WaitingVehicle
from bywire.host.behaviour.rules import MTC_SITUATIONS
from bywire.host.behaviour.situation import EgoState, LaneRef, Situation, TrackedObject
from bywire.host.lateral import LateralParams, PathSamples, VehiclePose, lateral_step
from bywire.host.longitudinal import LongitudinalParams, LongitudinalState, longitudinal_step
from bywire.host.roadnet.graph import build_graph
from bywire.host.roadnet.mdf import parse_mdf, resolve_mission
from bywire.host.roadnet.rndf import parse_rndf
from bywire.host.roadnet.route import MissionPlanner

# Two crossing two-lane roads in local metres, stop signs on all four approaches (lane ends 8 m from
# the centre, lanes 2 m either side of each centre line), 150 m arms.
_HSM_RNDF = """RNDF_name\tbench_cross
num_segments\t2
num_zones\t0
format_version\t1.0
segment\t1
num_lanes\t4
lane\t1.1
num_waypoints\t4
checkpoint\t1.1.1\t1
stop\t1.1.4
exit\t1.1.4\t1.3.1
1.1.1\t-150\t-2
1.1.2\t-100\t-2
1.1.3\t-50\t-2
1.1.4\t-8\t-2
end_lane
lane\t1.2
num_waypoints\t4
stop\t1.2.4
exit\t1.2.4\t1.4.1
1.2.1\t150\t2
1.2.2\t100\t2
1.2.3\t50\t2
1.2.4\t8\t2
end_lane
lane\t1.3
num_waypoints\t3
checkpoint\t1.3.3\t2
1.3.1\t8\t-2
1.3.2\t80\t-2
1.3.3\t150\t-2
end_lane
lane\t1.4
num_waypoints\t3
1.4.1\t-8\t2
1.4.2\t-80\t2
1.4.3\t-150\t2
end_lane
end_segment
segment\t2
num_lanes\t4
lane\t2.1
num_waypoints\t3
stop\t2.1.3
exit\t2.1.3\t2.3.1
2.1.1\t2\t-150
2.1.2\t2\t-50
2.1.3\t2\t-8
end_lane
lane\t2.2
num_waypoints\t3
stop\t2.2.3
exit\t2.2.3\t2.4.1
2.2.1\t-2\t150
2.2.2\t-2\t50
2.2.3\t-2\t8
end_lane
lane\t2.3
num_waypoints\t2
2.3.1\t2\t8
2.3.2\t2\t150
end_lane
lane\t2.4
num_waypoints\t2
2.4.1\t-2\t-8
2.4.2\t-2\t-150
end_lane
end_segment
end_file
"""
_HSM_MDF = """MDF_name\tbench
RNDF\tbench_cross
checkpoints
num_checkpoints\t2
1
2
end_checkpoints
speed_limits
num_speed_limits\t2
1\t0\t25
2\t0\t25
end_speed_limits
end_file
"""


class _HsmScene:
    """The ``hsm_step`` row's world (see the module docstring)."""

    DT_S = 0.05
    RESET_S = 60.0

    def __init__(self) -> None:
        net = parse_rndf(_HSM_RNDF, "bench_cross.rndf", coordinates="local_m")
        mission = resolve_mission(net, parse_mdf(_HSM_MDF, "bench.mdf"))
        self.graph = build_graph(net, mission)
        self.planner = MissionPlanner(self.graph, mission)
        self.lon_params = LongitudinalParams()
        self._fresh()

    def _fresh(self) -> None:
        self.behaviour = Behaviour(self.planner)
        self.view = self.behaviour.route_view
        self.s = 60.0
        self.v = 8.0
        self.t = 0.0
        self.lon = LongitudinalState()

    def _objects(self) -> tuple[TrackedObject, ...]:
        t = self.t
        objs = []
        # (id, stop line x, y, heading, departs at): they stand at their lines and cross in turn
        for oid, x, y, h, t_go in (
            ("east", 10.45, 2.0, math.pi, 8.0),
            ("south", 2.0, -10.45, 0.5 * math.pi, 14.0),
            ("north", -2.0, 10.45, -0.5 * math.pi, 20.0),
        ):
            gone = max(t - t_go, 0.0) * 5.0
            objs.append(
                TrackedObject(
                    oid, x + gone * math.cos(h), y + gone * math.sin(h), h, 5.0 if gone else 0.0, 4.5, 1.8
                )
            )
        follower_s = max(self.s - 25.0, 1.0)
        fx, fy, fh = self.view.point_at(follower_s)
        edge = self.view.edges[self.view.edge_index_at(follower_s)]
        lane = LaneRef(
            edge.key, follower_s - float(self.view.edge_start[self.view.edge_index_at(follower_s)])
        )
        objs.append(TrackedObject("behind", fx, fy, fh, self.v, 4.5, 1.8, lane))
        return tuple(objs)

    def step(self) -> object:
        if self.t > self.RESET_S or self.behaviour.state == "MissionComplete":
            self._fresh()
        x, y, h = self.view.point_at(self.s)
        sit = Situation(self.t, EgoState(x, y, h, self.v), self._objects())
        cmd = self.behaviour.step(sit)
        self.lon, a, _ = longitudinal_step(self.lon, cmd.longitudinal_inputs(self.v), self.lon_params)
        self.v = max(self.v + a * self.DT_S, 0.0)
        self.s += self.v * self.DT_S
        self.t += self.DT_S
        return cmd


DEFAULT_SECONDS = 5.0
BATCH = 200  # calls of one row before switching to the next (interleaving granularity)


def _noop(*_args: object) -> None:
    return None


def _mtc_cases(rng: np.random.Generator, n_vehicles: int, count: int) -> list[tuple[Any, ...]]:
    params = list(MTC_SITUATIONS.values())
    cases = []
    for _ in range(count):
        own_dist = float(rng.uniform(0.0, 40.0))
        vehicles = [
            ConflictVehicle(
                float(rng.uniform(-30.0, 150.0)), float(rng.uniform(0.0, 15.0)), own_dist, f"b{k}"
            )
            for k in range(n_vehicles)
        ]
        cases.append((float(rng.uniform(0.0, 8.0)), vehicles, params[int(rng.integers(len(params)))]))
    return cases


def _lateral_path() -> PathSamples:
    s = np.arange(0.0, 30.0 + 1e-9, 0.25)
    kappa = 0.05 * np.sin(2.0 * math.pi * s / 30.0)
    heading = np.concatenate(([0.0], np.cumsum(0.5 * (kappa[1:] + kappa[:-1]) * 0.25)))
    x = np.concatenate(([0.0], np.cumsum(0.5 * (np.cos(heading[1:]) + np.cos(heading[:-1])) * 0.25)))
    y = np.concatenate(([0.0], np.cumsum(0.5 * (np.sin(heading[1:]) + np.sin(heading[:-1])) * 0.25)))
    return PathSamples(x, y, heading, kappa, s)


def _stats(samples_ns: list[int], baseline_p50_us: float | None) -> dict[str, float]:
    a = np.asarray(samples_ns, dtype=np.float64) / 1e3
    p50 = float(np.percentile(a, 50))
    out = {"p50_us": p50, "p99_us": float(np.percentile(a, 99)), "max_us": float(a.max()), "n": int(a.size)}
    if baseline_p50_us is not None:
        out["ratio_p50"] = p50 / baseline_p50_us if baseline_p50_us > 0 else math.inf
    return out


def run(seconds: float, seed: int = 7) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    mtc1 = _mtc_cases(rng, 1, 512)
    mtc10 = _mtc_cases(rng, 10, 512)
    path = _lateral_path()
    lat_params = LateralParams()
    poses = [
        VehiclePose(float(rng.uniform(0.0, 25.0)), float(rng.normal(0.0, 0.5)), float(rng.normal(0.0, 0.1)))
        for _ in range(512)
    ]
    lines = [
        StopLine("S", math.pi / 2),
        StopLine("E", math.pi),
        StopLine("N", -math.pi / 2),
        StopLine("W", 0.0),
    ]
    snapshot = [WaitingVehicle("e", "E", -3.0), WaitingVehicle("n", "N", -2.0), WaitingVehicle("w", "W", 5.0)]
    state: dict[str, Any] = {"pm": None, "t": 0.0}
    scene = _HsmScene()

    def precedence_update(_i: int) -> object:
        if state["pm"] is None or state["t"] > 70.0:  # a fresh intersection every minute of its clock
            state["pm"] = IntersectionPrecedence(lines, "S")
            state["pm"].arrive(10.0)
            state["t"] = 10.0
        state["t"] += 0.1
        return state["pm"].update(state["t"], snapshot, ("x",))

    rows: dict[str, Callable[[int], object]] = {
        "baseline": lambda i: _noop(i),
        "mtc_1": lambda i: moving_traffic_check(*mtc1[i % 512]),
        "mtc_10": lambda i: moving_traffic_check(*mtc10[i % 512]),
        "precedence_update": precedence_update,
        "lateral_step": lambda i: lateral_step(path, poses[i % 512], 1, lat_params),
        "lateral_step_hinted": lambda i: lateral_step(
            path, poses[i % 512], 1, lat_params, s_hint_m=poses[i % 512].x_m, window_m=3.0
        ),
        "hsm_step": lambda i: scene.step(),
    }
    samples: dict[str, list[int]] = {name: [] for name in rows}
    for fn in rows.values():  # warm-up: imports, caches
        for i in range(20):
            fn(i)
    clock = time.perf_counter_ns
    deadline = time.perf_counter() + seconds
    k = 0
    while time.perf_counter() < deadline or k < 2:
        for name, fn in rows.items():
            bucket = samples[name]
            for i in range(k * BATCH, (k + 1) * BATCH):
                t0 = clock()
                fn(i)
                bucket.append(clock() - t0)
        k += 1
    base = _stats(samples["baseline"], None)
    out_rows = {"baseline": base}
    for name in rows:
        if name != "baseline":
            out_rows[name] = _stats(samples[name], base["p50_us"])
    return {"rows": out_rows, "seconds": seconds}


def _print_table(doc: dict[str, Any]) -> None:
    print(f"{'':22} {'p50 [us]':>10} {'p99 [us]':>10} {'max [us]':>10} {'n':>8} {'p50 / baseline':>15}")
    for name, r in doc["rows"].items():
        ratio = f"{r['ratio_p50']:14.1f}x" if "ratio_p50" in r else f"{'':15}"
        print(f"{name:22} {r['p50_us']:10.2f} {r['p99_us']:10.2f} {r['max_us']:10.1f} {r['n']:8d} {ratio}")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_timed_arguments(p, DEFAULT_SECONDS, "to measure")


def main(args: argparse.Namespace) -> int:
    return run_timed(args, "urban", DEFAULT_SECONDS, run, _print_table)
