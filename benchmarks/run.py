"""bywire benchmarks: one command, distributions not single numbers, baselines from the same run.

    python benchmarks/run.py [--quick] [--json FILE] [--with-hil SECONDS]

`sil_spine` (not with --quick) runs every spine scenario whole in SIL and reports the slowest
against the SIL target of 20x real time.

Each benchmark prints median / p99 / max and its ratio to a baseline measured right beside it,
because these machines are shared and noisy: an absolute figure from another day means little,
a ratio from the same minute means more. Pass/fail targets are not asserted here; the README
quotes what a run printed.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bywire.hil.scenario import CONTRACT_SCENARIOS


def distribution(samples_s: list[float]) -> dict[str, float]:
    us = sorted(s * 1e6 for s in samples_s)
    return {
        "median_us": round(statistics.median(us), 2),
        "p99_us": round(us[int(0.99 * (len(us) - 1))], 2),
        "max_us": round(us[-1], 2),
        "n": len(us),
    }


def time_calls(fn: Callable[[], object], n: int) -> list[float]:
    clock = time.perf_counter
    out = []
    for _ in range(n):
        t0 = clock()
        fn()
        out.append(clock() - t0)
    return out


def bench_core_step(n: int) -> dict[str, Any]:
    """One ECU cycle's pure core (safety + controller) vs. an empty call timed the same way."""
    from bywire.ecu.calibration import default_calibration
    from bywire.ecu.core import core_step, initial_core_state
    from bywire.ecu.safety import EcuInputs
    from bywire.protocol.ecu_types import EstopMode, RequestFlags

    cal = default_calibration()
    inputs = EcuInputs(
        estop_mode=EstopMode.RUN,
        estop_fresh=True,
        host_alive=True,
        request_accel_mps2=1.0,
        request_steer_angle_rad=0.01,
        request_flags=RequestFlags.ENGAGE | RequestFlags.STEER,
        request_fresh=True,
        vehicle_fresh=True,
        vehicle_corrupt=False,
        calibration_valid=True,
        overrun_streak=0,
        driver_brake_pressed=False,
        driver_throttle_pct=0.0,
        driver_steer_torque_nm=0.0,
        speed_mps=12.0,
        accel_meas_mps2=0.8,
        steer_angle_meas_rad=0.0,
        unlatch=False,
    )
    state = {"s": initial_core_state(0.0), "t": 0.0}

    def step() -> None:
        state["t"] += 0.001
        state["s"], _ = core_step(state["s"], inputs, state["t"], cal)

    for _ in range(2000):  # engage and settle
        step()
    core = distribution(time_calls(step, n))
    base = distribution(time_calls(lambda: None, n))
    return {
        "core_step": core,
        "baseline_empty_call": base,
        "ratio_median": round(core["median_us"] / max(base["median_us"], 1e-3), 1),
    }


def bench_codec(n: int) -> dict[str, Any]:
    """Vehicle-CAN encode+E2E and receive checks per frame vs. cantools' bare encode of the same frame."""
    from bywire.protocol.ecu_types import EcuState
    from bywire.protocol.vehicle_can import DbwCommand, VehicleCodec, VehicleTx
    from bywire.protocol.vehicle_rx import VehicleRx

    codec = VehicleCodec()
    tx = VehicleTx(codec)
    rx = VehicleRx(codec, max_age_cycles=None)
    frame = DbwCommand(
        throttle_pct=12.5,
        brake_bar=0.0,
        steer_angle_rad=0.01,
        engage=True,
        park_brake=False,
        ignition=True,
        steer_enable=True,
        ecu_state=EcuState.ENGAGED,
    )
    message = codec.info("DBW_Command").message
    raw = message.decode(bytes(tx.encode(frame).data), scaling=False)
    t = {"now": 0.0}

    def roundtrip() -> None:
        t["now"] += 0.01
        rx.feed(tx.encode(frame), t["now"])

    ours = distribution(time_calls(roundtrip, n))
    bare = distribution(time_calls(lambda: message.encode(raw, scaling=False, strict=False), n))
    return {
        "encode_e2e_feed": ours,
        "baseline_cantools_encode": bare,
        "ratio_median": round(ours["median_us"] / max(bare["median_us"], 1e-3), 1),
    }


def bench_sil(seconds: float) -> dict[str, Any]:
    """Lockstep SIL (plant + ECU + host) real-time factor vs. the FMU stepped alone at 1 kHz."""
    from bywire.hil.scenario import load_scenario
    from bywire.hil.sil import run_sil
    from bywire.vehicle_models.fmu_vehicle import VehicleInputs, open_vehicle

    scenario = dataclasses.replace(load_scenario("accel_steps"), duration_s=seconds)
    t0 = time.perf_counter()
    result = run_sil(scenario)
    wall = time.perf_counter() - t0
    vehicle = open_vehicle("passat", start_values={"v0_mps": 10.0})
    inputs = VehicleInputs(throttle_pct=20.0)
    steps = int(seconds * 1000)
    t1 = time.perf_counter()
    for _ in range(steps):
        vehicle.step(0.001, inputs)
    fmu_wall = time.perf_counter() - t1
    vehicle.close()
    return {
        "sil_real_time_factor": result.extra["real_time_factor"],
        "sil_wall_s": round(wall, 2),
        "baseline_fmu_alone_real_time_factor": round(seconds / fmu_wall, 1),
        "us_per_simulated_ms": round(wall / steps * 1e6, 1),
    }


# The spine contract's scenarios and the demo: the SIL speed target is about all of them.
SPINE_SCENARIOS = (*CONTRACT_SCENARIOS, "demo")


def bench_sil_spine(names: tuple[str, ...] = SPINE_SCENARIOS) -> dict[str, Any]:
    """Every spine scenario whole in SIL: its real-time factor, the slowest against the 20x target,
    with the FMU stepped alone at 1 kHz before and after as the machine's baseline."""
    from bywire.hil.scenario import load_scenario
    from bywire.hil.sil import run_sil
    from bywire.vehicle_models.fmu_vehicle import VehicleInputs, open_vehicle

    def fmu_alone_rtf(seconds: float = 5.0) -> float:
        vehicle = open_vehicle("passat", start_values={"v0_mps": 10.0})
        inputs = VehicleInputs(throttle_pct=20.0)
        t0 = time.perf_counter()
        for _ in range(int(seconds * 1000)):
            vehicle.step(0.001, inputs)
        wall = time.perf_counter() - t0
        vehicle.close()
        return round(seconds / wall, 1)

    before = fmu_alone_rtf()
    rtf: dict[str, float] = {}
    for name in names:
        result = run_sil(load_scenario(name))
        rtf[name] = float(result.extra["real_time_factor"])
    after = fmu_alone_rtf()
    slowest = min(rtf, key=rtf.__getitem__)
    return {
        "real_time_factor": rtf,
        "sil_factor": dict(rtf),  # the name `bywire bench sil` reports it under
        "median": round(statistics.median(rtf.values()), 2),
        "slowest": slowest,
        "min": rtf[slowest],
        "target": 20.0,
        "ratio_min_to_target": round(rtf[slowest] / 20.0, 2),
        "baseline_fmu_alone_real_time_factor": {"before": before, "after": after},
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="fewer samples (a smoke run)")
    p.add_argument("--json", type=Path, help="write all results as JSON")
    p.add_argument(
        "--with-hil",
        type=float,
        metavar="SECONDS",
        help="also run `bywire bench ecu` for this long (three processes, real time)",
    )
    args = p.parse_args(argv)
    n = 2000 if args.quick else 20000
    results: dict[str, Any] = {}
    for name, fn in (
        ("ecu_core_step", lambda: bench_core_step(n)),
        ("vehicle_can_codec", lambda: bench_codec(n)),
        ("sil", lambda: bench_sil(2.0 if args.quick else 10.0)),
        *((("sil_spine", bench_sil_spine),) if not args.quick else ()),
    ):
        print(f"== {name}", flush=True)
        results[name] = fn()
        print(json.dumps(results[name], indent=2), flush=True)
    if args.with_hil:
        import subprocess
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "ecu.json"
            subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "bywire",
                    "bench",
                    "ecu",
                    "--seconds",
                    str(args.with_hil),
                    "--json",
                    str(out),
                ],
                check=True,
            )
            results["bench_ecu"] = json.loads(out.read_text())
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
