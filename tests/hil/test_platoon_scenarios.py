"""Platoon runs in SIL (cooperative driving, seed 003), bounded: what `tests/hil/test_sil_scenarios.py` (which
runs every shipped scenario, the five platoon ones included, and judges its checks) does not already show.

- String stability with V2V at the GCDC headway of 0.6 s: the Plexe sinusoid around 80 km/h (below the
  GCDC's 100 km/h cap, which binds the shipped 100 km/h version on every crest), long enough for the
  estimator: our car's estimate (predecessor -> us) <= 1, and the real ACC strings worse, same code.
- The V2V flood changes nothing: the same run with and without the fuzzer gives the same trajectory.
- `--leader-profile`: a real leader's speed replayed (OpenACC AstaZero), skipped where the data is absent.
- A heat recording replays exactly (`bywire log replay --check`).
- A platoon recording holds every car's iCLCM, and ours carries the platoon's request of that release.
- The evaluation's definitions on hand-made traces (limit violations, speed-limit excess).
Full-length scenarios with every check run under `-m slow`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from shared_data import shared_data_dir

from bywire.hil.evaluate import evaluate
from bywire.hil.host_inputs import recorded_inputs
from bywire.hil.platoon_eval import limit_violations, speed_limit_excess
from bywire.hil.run import run_scenario
from bywire.hil.scenario import Scenario, load_scenario
from bywire.hil.sil import run_sil
from bywire.hil.world.spec import FuzzSpec, SinusoidSpec, VehicleSpec
from bywire.host.modules.gcdc_messages import IclcmSent, PlatoonStatus, V2vBatch, V2vCooperative
from bywire.host.replay import replay
from bywire.host.runtime.mcap_reader import read_objects
from bywire.host.trace import CONTROLLERS

PLATOON_SCENARIOS = ("gcdc_heat", "platoon_sinusoid", "platoon_braking", "platoon_bridge_outage", "v2v_fuzz")


def _with_world(sc: Scenario, **changes: object) -> Scenario:
    assert sc.world is not None
    return dataclasses.replace(sc, world=dataclasses.replace(sc.world, **changes))


def _sinusoid_80(duration_s: float) -> Scenario:
    """platoon_sinusoid shifted to 80 +- 10 km/h, every car at its steady-state gap for that speed."""
    sc = load_scenario("platoon_sinusoid")
    assert sc.world is not None
    v = 22.22
    cacc_gap, our_gap = 5.0 + 0.6 * v, 8.0 + 0.6 * v  # the CACC cars' and ours (gcdc: reserve 8 m)
    s = {"leader": 320.0}
    s["cacc2"] = s["leader"] - 4.5 - cacc_gap
    s["cacc3"] = s["cacc2"] - 4.5 - cacc_gap
    ego_s = s["cacc3"] - 2.25 - our_gap - 4.77 / 2
    s["cacc5"] = ego_s - 4.77 / 2 - cacc_gap - 2.25
    s["cacc6"] = s["cacc5"] - 4.5 - cacc_gap
    cars: list[VehicleSpec] = []
    for car in sc.world.vehicles:
        if car.name == "leader":
            drv = dataclasses.replace(car.driver, sinusoid=SinusoidSpec(v, 2.78, 0.2, 10.0))
            cars.append(dataclasses.replace(car, s_m=s["leader"], driver=drv))
        else:
            cars.append(dataclasses.replace(car, s_m=s[car.name], v0_mps=v))
    sc = _with_world(sc, vehicles=tuple(cars), ego=dataclasses.replace(sc.world.ego, s_m=ego_s))
    return dataclasses.replace(sc, duration_s=duration_s, v0_mps=v)


def test_our_string_stability_with_v2v_is_at_most_one_and_the_real_strings_are_worse() -> None:
    sc = _sinusoid_80(60.0)
    r = run_sil(sc)
    doc = evaluate(sc, r.plant, r.host, r.extra, "sil", r.traffic)
    m = doc["metrics"]
    assert m["collisions"] == 0 and m["limit_violations"] == 0
    assert m["string_order"] == ["leader", "cacc2", "cacc3", "ego", "cacc5", "cacc6"]
    ours = next(p for p in m["string"]["pairs"] if p["follower"] == "ego")
    assert ours["peak_hz"] == pytest.approx(0.2, abs=0.03) and ours["coherence"] > 0.9  # the excitation
    assert m["string_stability"] <= 1.0, m["string"]
    # The leader-referenced acceleration penalty follows the constant-acceleration prediction, which on
    # a 0.2 Hz sinusoid is wrong within half a period: ~2.9 m RMS here (the paper's penalty: < 1.5 m,
    # but string-unstable in the heat). A predictor that knows the leader's plan is the cure.
    assert m["headway_error_rms_m"] < 3.5
    real = m["real_strings"]
    if any("error" in v for v in real.values()):
        pytest.skip(f"shared platoon data not found at {shared_data_dir() / 'platoon'}")
    assert min(v["string_stability"] for v in real.values()) > 1.0 >= m["string_stability"]


def test_a_v2v_flood_changes_nothing_in_the_platoons_behaviour() -> None:
    base = dataclasses.replace(load_scenario("v2v_fuzz"), duration_s=9.0)
    quiet = _with_world(base, fuzz=None)
    flooded = _with_world(base, fuzz=FuzzSpec(at_s=2.0, duration_s=6.0, rate_hz=2000.0, seed=3))
    a, b = run_sil(quiet), run_sil(flooded)
    assert b.extra["world"]["fuzz_sent"] >= 11_000
    rejected = sum(b.extra["gcdc"]["v2v_rejected"].values())
    assert rejected > 5_000
    assert b.extra["gcdc"]["v2v_received"] == b.extra["gcdc"]["v2v_accepted"] + rejected
    # Hostile datagrams never touch the legitimate senders' histories nor reach the map: our car drives
    # exactly the same (SIL is deterministic).
    for key in ("speed_mps", "accel_mps2", "distance_m"):
        np.testing.assert_array_equal(a.plant[key], b.plant[key])
    np.testing.assert_array_equal(a.host["accel_request_mps2"], b.host["accel_request_mps2"])
    assert not b.extra["host_runtime"]["events"]


def test_a_real_leader_profile_is_replayed(tmp_path: Path) -> None:
    csv = shared_data_dir() / "platoon" / "openacc_astazero" / "OpenACC_trajectory_1.csv"
    if not csv.exists():
        pytest.skip(f"OpenACC AstaZero data not found at {csv}")
    from bywire.hil.world.replay import leader_profile_from_csv
    from bywire.host.platoon.string_stability import load_platoon_csv

    sc = dataclasses.replace(load_scenario("gcdc_heat"), duration_s=12.0)
    profile = leader_profile_from_csv(sc, csv)
    r = run_sil(sc, leader_profile=profile)
    lead = r.traffic["vid"] == 1
    truth = load_platoon_csv(csv)
    t = r.traffic["t_s"][lead]
    expected = np.interp(t, truth.time_s - truth.time_s[0], truth.vehicles[0].speed_mps)
    assert np.max(np.abs(r.traffic["speed_mps"][lead] - expected)) < 0.05
    assert r.extra["world"]["collisions"] == 0


def test_leader_profile_needs_a_replay_vehicle(tmp_path: Path) -> None:
    from bywire.hil.scenario import ScenarioError
    from bywire.hil.world.replay import leader_profile_from_csv

    with pytest.raises(ScenarioError, match="replay: true"):
        leader_profile_from_csv(load_scenario("platoon_braking"), tmp_path / "x.csv")
    bad = tmp_path / "bad.csv"
    bad.write_text("time,speed\n0,abc\n")
    with pytest.raises(ScenarioError, match=r"bad\.csv"):
        leader_profile_from_csv(load_scenario("gcdc_heat"), bad)


def test_a_heat_recording_replays_exactly(tmp_path: Path) -> None:
    sc = dataclasses.replace(load_scenario("gcdc_heat"), duration_s=5.0)
    rec = tmp_path / "heat.mcap"
    run_sil(sc, record=rec)
    result = replay(rec, inputs_for=recorded_inputs)
    assert result.matches, result.to_json()
    assert {"/ego/pose", "/world/leads", "/control/request", "/platoon/status"} <= set(result.topics)


def test_a_platoon_recording_holds_every_cars_iclcm_and_ours_is_the_platoons(tmp_path: Path) -> None:
    sc = dataclasses.replace(load_scenario("platoon_braking"), duration_s=3.0)
    rec = tmp_path / "braking.mcap"
    run_sil(sc, record=rec)
    received: dict[int, list[V2vCooperative]] = {}
    sent: list[IclcmSent] = []
    platoon: list[PlatoonStatus] = []
    for e in read_objects(rec, ("/v2v/received", "/v2v/iclcm_sent", "/platoon/status")):
        if isinstance(e.obj, V2vBatch):
            for c in e.obj.cooperative:
                received.setdefault(c.station_id, []).append(c)
        elif isinstance(e.obj, IclcmSent):
            sent.append(e.obj)
        else:
            assert isinstance(e.obj, PlatoonStatus)
            platoon.append(e.obj)
    assert sorted(received) == [101, 102, 104, 105]  # every other car, decoded into its type
    assert all(len(cs) >= 25 for cs in received.values())  # 10 Hz for 3 s
    assert {c.controller_type for c in received[102]} == {"cacc"} and received[101][0].controller_type == "cc"
    ours = [s.iclcm for s in sent if s.sent and s.iclcm is not None]
    assert len(ours) >= 29 and sent[-1].count == len(ours)
    driving = [c for c in ours if c.t_gen_s > 1.0]  # engaged at 0.5 s
    assert driving and {c.controller_type for c in driving} == {"cacc"}
    for c in driving:  # the platoon's request at that release (it runs just before us in the chain)
        status = max((p for p in platoon if p.t_s <= c.t_gen_s + 1e-9), key=lambda p: p.t_s)
        assert c.target_accel_mps2 == status.accel_cmd_mps2
        assert c.time_headway_s == 0.6 and c.cruise_speed_mps == status.v_des_mps
        assert c.mio_station_id == 102 and 15.0 < c.mio_range_m < 30.0  # cacc2, 0.6 s + 8 m ahead
        assert c.platoon_id == 1


def test_evaluation_definitions_on_hand_made_traces() -> None:
    t = np.arange(0.0, 10.0, 0.01)
    plant = {"t_s": t, "accel_mps2": np.zeros_like(t), "speed_mps": np.full_like(t, 20.0)}
    plant["accel_mps2"][300:400] = -6.0  # 1 s beyond -4.5
    plant["accel_mps2"][600:650] = 2.6  # 0.5 s beyond +2.0
    plant["speed_mps"][800:900] = 28.5  # above 100 km/h + 0.5
    host = {"t_s": t[::2], "controller": np.full(t[::2].size, float(CONTROLLERS.index("platoon")))}
    lv = limit_violations(plant, host, 0.5)
    assert (lv["accel"], lv["speed"]) == (2, 1)
    host["controller"][140:210] = CONTROLLERS.index("emergency")  # 2.8 .. 4.2 s: an emergency stop
    assert limit_violations(plant, host, 0.5)["accel"] == 1
    sc = load_scenario("gcdc_heat")
    assert sc.world is not None
    zone = sc.world.roadside[0]
    ego = {"t_s": t, "s_m": zone.s_m - 10.0 + 20.0 * t, "speed_mps": np.full_like(t, zone.limit_mps + 0.3)}
    ego["speed_mps"][:130] = 25.0  # the front enters at 0.38 s; still fast until 1.3 s: within the grace
    assert speed_limit_excess(sc.world, ego) == pytest.approx(0.3)


@pytest.mark.slow
@pytest.mark.parametrize("name", PLATOON_SCENARIOS)
def test_full_platoon_scenarios_with_report(tmp_path: Path, name: str) -> None:
    doc = run_scenario(name, mode="sil", report_dir=tmp_path)
    assert doc["verdict"] == "pass", [c for c in doc["checks"] if not c["passed"]]
    m = doc["metrics"]
    for key in ("string_stability", "min_gap_m", "min_ttc_s", "headway_error_rms_m", "collisions",
                "limit_violations", "v2v_rejected", "platoon_length_m"):  # fmt: skip
        assert key in m, key
    for suffix in ("path_time", "headway", "string_stability"):
        assert (tmp_path / f"{name}_{suffix}.png").stat().st_size > 10_000
    if name == "gcdc_heat":
        assert m["real_time_factor"] > 1.5  # several times real time on an idle machine; bounded here


def test_our_cams_are_counted_over_a_restart_of_the_sender() -> None:
    """The sender raises at 10 s and the supervisor restarts it: `cam_sent` counts every CAM of the run,
    not only the new instance's (a restart had hidden 22 s of CAMs in a three-process heat)."""
    sc = load_scenario(
        "platoon_braking",
        {"duration_s": 20.0, "faults": [{"at_s": 10.0, "kind": "module_exception", "module": "v2v_tx"}]},
    )
    result = run_sil(sc)
    sender = result.extra["host_runtime"]["modules"]["v2v_tx"]
    assert sender["restarts"] == 1 and sender["releases"] == 100  # the new instance: the last 10 s
    gcdc = result.extra["gcdc"]
    assert gcdc["cam_sent"] >= 190 and gcdc["iclcm_sent"] == gcdc["cam_sent"], gcdc
