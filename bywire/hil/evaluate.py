"""Scenario evaluation: metrics from the plant's and the host's traces, and the scenario's checks.

The metric names are a contract (tests, benchmarks and reports read them): `accel_rms_error_mps2`,
`fault_detect_ms`, `brake_onset_ms`, `stop_distance_m`, `standstill_held`, `final_state`,
`real_time_factor`, plus a few more that the shipped scenarios judge (`settle_time_s`, `overshoot_mps2`,
`collisions`, ...). Everything is computed from ground truth (the FMU's state in the plant trace), never
from what the ECU believes, so a wrong belief cannot pass its own test.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np

from bywire.hil.scenario import MODULE_FAULTS, STATE_AT, Check, Scenario
from bywire.profiles import step_value
from bywire.protocol.ecu_types import EcuState, Fault

STANDSTILL_MPS = 0.05  # below this the car counts as stopped (wheel-speed sensor resolution ~0.03 m/s)
HOLD_CREEP_MPS = 0.1  # a held car may not creep faster than this
BRAKE_ONSET_BAR = 1.0  # measured brake pressure that counts as "brakes applied"
TRACK_DELAY_S = 1.0  # tracking is judged from 1 s after each step of the request
SETTLE_BAND_MPS2 = 0.1
STOP_STATES = (EcuState.PAUSED, EcuState.SAFE_STOP, EcuState.DISABLED, EcuState.MANUAL)
STOP_STATE_NAMES = frozenset(s.name for s in STOP_STATES)


def _first_index(mask: np.ndarray) -> int | None:
    idx = np.flatnonzero(mask)
    return int(idx[0]) if idx.size else None


def accel_rms_error(plant: dict[str, np.ndarray], scenario: Scenario) -> float | None:
    """RMS of (request - measured acceleration) from 1 s after each step until the next, while engaged."""
    profile = scenario.accel_profile
    if not profile:
        return None
    t = plant["t_s"]
    engaged = plant["ecu_state"] == int(EcuState.ENGAGED)
    request = np.array([step_value(profile, ti) for ti in t])
    edges = [p[0] for p in profile] + [scenario.duration_s]
    window = np.zeros_like(t, dtype=bool)
    for start, end in itertools.pairwise(edges):
        window |= (t >= start + TRACK_DELAY_S) & (t < end)
    mask = window & engaged
    if not mask.any():
        return None
    err = request[mask] - plant["accel_mps2"][mask]
    return float(np.sqrt(np.mean(err**2)))


def settle_and_overshoot(
    plant: dict[str, np.ndarray], scenario: Scenario
) -> tuple[float | None, float | None]:
    """After the last step of the request: time until the error stays within the band, and the overshoot.

    This is the grade test: after a long saturation the integrator must not have wound up (overshoot)
    and must still remove the steady-state error the grade causes (settle time).
    """
    profile = scenario.accel_profile
    if len(profile) < 2:
        return None, None
    t_step, a_final = profile[-1]
    t = plant["t_s"]
    after = t >= t_step
    if not after.any():
        return None, None
    err = plant["accel_mps2"][after] - a_final
    t_after = t[after]
    outside = np.flatnonzero(np.abs(err) > SETTLE_BAND_MPS2)
    settle = 0.0 if outside.size == 0 else float(t_after[outside[-1]] - t_step) + 0.01
    if outside.size and outside[-1] == err.size - 1:
        settle = math.inf
    # Overshoot: beyond the final value in the direction of travel of the step, ignoring the first
    # 0.2 s where the pedals are still moving.
    a_before = step_value(profile, t_step - 1e-6)
    direction = 1.0 if a_final >= a_before else -1.0
    late = t_after >= t_step + 0.2
    overshoot = float(max(0.0, np.max(direction * err[late]))) if late.any() else 0.0
    return settle, overshoot


def fault_metrics(plant: dict[str, np.ndarray], scenario: Scenario) -> dict[str, Any]:
    t_ref = scenario.fault_ref_s
    if t_ref is None:
        return {}
    t = plant["t_s"]
    after = t >= t_ref
    metrics: dict[str, Any] = {}
    state = plant["ecu_state"]
    i_ref = _first_index(after)
    # Detection only means something if the ECU was driving when the fault hit: a run that had
    # already stopped for another reason must not pass a fault check by accident.
    metrics["state_at_fault"] = None if i_ref is None else EcuState(int(state[i_ref])).name
    i_detect = _first_index(after & np.isin(state, [int(s) for s in STOP_STATES]))
    if metrics["state_at_fault"] in STOP_STATE_NAMES:
        i_detect = None
    metrics["fault_detect_ms"] = None if i_detect is None else round(float(t[i_detect] - t_ref) * 1000.0, 1)
    # what a stopping-distance bound starts from (hil.campaign.stop_bound): the speed and the stop
    metrics["speed_at_fault_mps"] = None if i_ref is None else round(float(plant["speed_mps"][i_ref]), 3)
    metrics["stop_state"] = None if i_detect is None else EcuState(int(state[i_detect])).name
    i_brake = _first_index(after & (plant["brake_actual_bar"] > BRAKE_ONSET_BAR))
    metrics["brake_onset_ms"] = None if i_brake is None else round(float(t[i_brake] - t_ref) * 1000.0, 1)
    i_stop = _first_index(after & (np.abs(plant["speed_mps"]) < STANDSTILL_MPS))
    if i_stop is None or i_ref is None:
        metrics["stop_distance_m"] = None
        metrics["standstill_held"] = False
        metrics["time_to_standstill_s"] = None
    else:
        metrics["stop_distance_m"] = round(float(plant["distance_m"][i_stop] - plant["distance_m"][i_ref]), 3)
        metrics["time_to_standstill_s"] = round(float(t[i_stop] - t_ref), 3)
        hold_end = scenario.hold_until_s if scenario.hold_until_s is not None else t[-1] + 1.0
        held = (t >= t[i_stop]) & (t < hold_end)
        metrics["standstill_held"] = bool(np.all(np.abs(plant["speed_mps"][held]) < HOLD_CREEP_MPS))
        metrics["standstill_duration_s"] = round(float(min(hold_end, t[-1]) - t[i_stop]), 3)
    return metrics


def rearm_metrics(
    plant: dict[str, np.ndarray], host: dict[str, np.ndarray] | None, scenario: Scenario
) -> dict[str, Any]:
    """What the ECU did after the first fault: whether (and when) it engaged again, which fault bits
    its status reported, and its state at the instants the checks ask for (`state_at_<T>s`)."""
    metrics: dict[str, Any] = {}
    t = plant["t_s"]
    state = plant["ecu_state"]
    engaged = int(EcuState.ENGAGED)
    for check in scenario.checks:
        m = STATE_AT.fullmatch(check.metric)
        if m is not None:
            i = int(np.searchsorted(t, float(m.group(1)), side="right")) - 1
            metrics[check.metric] = EcuState(int(state[i])).name if 0 <= i < t.size else None
    t_ref = scenario.fault_ref_s
    if t_ref is None:
        return metrics
    after = t >= t_ref
    i_left = _first_index(after & (state != engaged))
    i_back = None if i_left is None else _first_index((t > t[i_left]) & (state == engaged))
    metrics["reengaged_at_s"] = None if i_back is None else round(float(t[i_back]), 3)
    metrics["reengaged_after_fault"] = i_back is not None
    if host is not None and host["t_s"].size:
        bits = 0
        for f in host["ecu_faults"][host["t_s"] >= t_ref]:
            if math.isfinite(f):
                bits |= int(f)
        metrics["ecu_faults_seen"] = [f.name for f in Fault if f and bits & int(f)]
    return metrics


def supervisor_metrics(scenario: Scenario, runtime: dict[str, Any]) -> dict[str, Any]:
    """What the host's supervisor made of the scenario's module faults (a contract:
    `detect_ms`, `action`): the first detection at or after the first module fault.

    `detect_ms` is the supervisor's own detection time, from the failure's onset as it can know it
    (the release that hung, the exception's instant, the first late release, the last sign of life
    of a killed worker); `detect_from_injection_ms` counts from the instant the scenario armed the
    fault, which may precede the module's next release by up to one period.
    """
    faults = scenario.faults_of(*MODULE_FAULTS)
    events = runtime.get("events", [])
    metrics: dict[str, Any] = {"supervisor_events": len(events)}
    if not faults:
        return metrics
    fault = min(faults, key=lambda f: f.at_s)
    first = next(
        (
            e
            for e in events
            if e["module"] == fault.module
            and e["t_rel_s"] >= fault.at_s - 1e-9
            and e["cause"] not in ("dependant", "recovered")
        ),
        None,
    )
    metrics["supervisor_detected"] = first is not None
    if first is None:
        metrics.update(detect_ms=None, action=None, supervisor_cause=None)
        return metrics
    metrics["detect_ms"] = first["detect_ms"]
    metrics["detect_from_injection_ms"] = round((first["t_rel_s"] - fault.at_s) * 1e3, 3)
    metrics["action"] = first["action"]
    metrics["supervisor_cause"] = first["cause"]
    metrics["supervisor_detail"] = first["detail"]
    recovered = next(
        (
            e
            for e in events
            if e["module"] == fault.module and e["cause"] == "recovered" and e["t_s"] >= first["t_s"]
        ),
        None,
    )
    metrics["recovered"] = recovered is not None
    metrics["recover_ms"] = None if recovered is None else round((recovered["t_s"] - first["t_s"]) * 1e3, 3)
    return metrics


def evaluate(
    scenario: Scenario,
    plant: dict[str, np.ndarray],
    host: dict[str, np.ndarray] | None,
    extra: dict[str, Any] | None = None,
    mode: str = "sil",
    traffic: dict[str, np.ndarray] | None = None,
) -> dict[str, Any]:
    """The JSON document of a run: scenario, verdict, checks and metrics (a contract).
    `mode` picks each check's limit (a check may allow more in HIL, see `Check.hil_limit`).
    A scenario with a world (cooperative driving) adds the platoon metrics of `hil.platoon_eval` from
    `traffic`."""
    metrics: dict[str, Any] = {}
    if plant["t_s"].size == 0:
        metrics["final_state"] = "NO_DATA"
    else:
        metrics["final_state"] = EcuState(int(plant["ecu_state"][-1])).name
        states = sorted({EcuState(int(s)).name for s in np.unique(plant["ecu_state"])})
        metrics["states_seen"] = states
        metrics["engaged_s"] = round(float(np.sum(plant["ecu_state"] == int(EcuState.ENGAGED)) * 0.01), 2)
        metrics["max_speed_mps"] = round(float(np.max(plant["speed_mps"])), 3)
        metrics["min_speed_mps"] = round(float(np.min(plant["speed_mps"])), 3)
        metrics["final_speed_mps"] = round(float(plant["speed_mps"][-1]), 3)
        metrics["distance_m"] = round(float(plant["distance_m"][-1]), 2)
        both = (plant["throttle_applied_pct"] > 0.0) & (plant["brake_cmd_bar"] > 0.0) & (plant["engage"] > 0)
        metrics["throttle_and_brake_cycles"] = int(np.sum(both))
        rms = accel_rms_error(plant, scenario)
        if rms is not None:
            metrics["accel_rms_error_mps2"] = round(rms, 4)
        settle, overshoot = settle_and_overshoot(plant, scenario)
        if settle is not None:
            metrics["settle_time_s"] = settle if math.isfinite(settle) else None
            metrics["overshoot_mps2"] = round(overshoot or 0.0, 4)
        metrics.update(fault_metrics(plant, scenario))
        metrics.update(rearm_metrics(plant, host, scenario))
        gaps = plant["lead_gap_m"][np.isfinite(plant["lead_gap_m"])]
        if gaps.size:
            metrics["min_gap_m"] = round(float(np.min(gaps)), 3)
            metrics["collisions"] = int(np.sum(np.diff((gaps <= 0.0).astype(int)) == 1) + int(gaps[0] <= 0.0))
        if scenario.stop_line_m is not None:
            stopped = np.abs(plant["speed_mps"]) < STANDSTILL_MPS
            moved = plant["distance_m"] > 1.0
            i_final = _first_index(
                stopped
                & moved
                & (plant["t_s"] > scenario.engage_at_s + 1.0)
                & (plant["distance_m"] > scenario.stop_line_m - 30.0)
            )
            if i_final is not None:
                metrics["stop_line_error_m"] = round(
                    float(scenario.stop_line_m - plant["distance_m"][i_final]), 3
                )
            metrics["crossed_stop_line"] = bool(np.any(plant["distance_m"] > scenario.stop_line_m + 0.05))
    if host is not None and host["t_s"].size:
        metrics["host_requests"] = int(host["t_s"].size)
    extra = dict(extra or {})
    runtime = extra.pop("host_runtime", None)
    if runtime is not None:
        metrics.update(supervisor_metrics(scenario, runtime))
    service = extra.get("service_tool")
    if service:
        metrics["unlatch_result"] = next((a["result"] for a in service if a["what"] == "unlatch"), None)
    world = extra.pop("world", None)
    gcdc = extra.pop("gcdc", None)
    urban = extra.pop("urban", None)
    urban_host = extra.pop("urban_host", None)
    stalls = extra.pop("stalls", None)  # HIL: the processes' stall records (bywire.stall_recorder)
    culprits = extra.pop("watchdog_culprits", None)
    if stalls is not None:
        metrics["host_stalls"] = stalls.get("host", {}).get("count", 0)
        metrics["plant_stalls"] = stalls.get("plant", {}).get("count", 0)
        # The longest gaps of each process's rhythm (HIL: the stall recorders' histograms).
        for metric, process, channel in (
            ("host_link_gap_max_ms", "host", "ecu_link"),
            ("plant_step_gap_max_ms", "plant", "step"),
        ):
            rhythm = stalls.get(process, {}).get("rhythm_ms", {}).get(channel)
            if rhythm is not None:
                metrics[metric] = rhythm["max"]
    machine = extra.get("machine")  # HIL: bywire.hil.machine_probe, the machine's own stalls
    if machine is not None:
        metrics["machine_late_max_ms"] = machine["late_ms"]["max"]
    heard = (extra.get("ecu_loop") or {}).get("host_link", {}).get("heartbeat_gap_ms")
    if heard is not None:
        metrics["heartbeat_gap_at_ecu_max_ms"] = heard["max"]  # what the ECU's watchdog judged
    metrics.update(extra)
    urban_details: dict[str, Any] = {}
    if scenario.urban is not None:
        from bywire.hil.urban_eval import evaluate_urban

        urban_metrics, urban_details = evaluate_urban(
            scenario, plant, urban or {}, urban_host or {}, float((urban_host or {}).get("t0_s", 0.0))
        )
        metrics.update(urban_metrics)
    if scenario.world is not None and plant["t_s"].size:
        from bywire.hil.platoon_eval import evaluate_platoon

        metrics.update(
            evaluate_platoon(scenario, plant, host, traffic, {"world": world or {}, "gcdc": gcdc or {}})
        )
    checks = [run_check(c, metrics, mode) for c in scenario.checks]
    verdict = "pass" if checks and all(c["passed"] for c in checks) else "fail"
    if not checks:
        verdict = "pass" if metrics.get("final_state") != "NO_DATA" else "fail"
    document: dict[str, Any] = {
        "scenario": scenario.name,
        "verdict": verdict,
        "checks": checks,
        "metrics": metrics,
    }
    document.update(urban_details)
    if runtime is not None:
        document["host_runtime"] = runtime
    if culprits is not None:
        document["watchdog_culprits"] = culprits  # which process fell behind when a watchdog fired
    if stalls is not None:
        document["stalls"] = stalls
    return document


def run_check(check: Check, metrics: dict[str, Any], mode: str = "sil") -> dict[str, Any]:
    value = metrics.get(check.metric)
    limit = check.limit_for(mode)
    passed = False
    if value is not None:
        if check.op == "max":
            passed = isinstance(value, int | float) and value <= float(limit)
        elif check.op == "min":
            passed = isinstance(value, int | float) and value >= float(limit)
        elif check.op == "includes":
            passed = isinstance(value, list | tuple) and limit in value
        else:
            passed = value == limit
    return {"name": check.name, "passed": bool(passed), "value": value, "limit": limit, "op": check.op}
