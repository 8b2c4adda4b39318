"""Run a scenario in SIL or HIL, evaluate it, and write its JSON and report (`bywire hil run`)."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bywire.hil.evaluate import evaluate
from bywire.hil.report import plot_run, write_json
from bywire.hil.scenario import Scenario, load_scenario, scenario_host_config


def run_scenario(
    name_or_file: str | Scenario,
    mode: str = "sil",
    json_path: Path | None = None,
    report_dir: Path | None = None,
    record: Path | None = None,
    host_link: str = "remote",
    ecu_store: Path | None = None,
    progress: Callable[[float], None] | None = None,
    leader_profile: Path | None = None,
    perception: str | None = None,
    ecu_cpu: int | None = None,
    inspect: Callable[[Scenario, Any, dict[str, Any]], None] | None = None,
    quiet_ecu: bool = True,
) -> dict[str, Any]:
    """Run one scenario (a shipped name, a file or a loaded `Scenario`) and return the result
    document (also written to `json_path` / `report_dir`).
    `leader_profile`: a real leader's speed (OpenACC or CARMA CSV) for the world's `replay` vehicle;
    `perception`: `perfect` | `lidar`, how an urban scenario's host perceives (default: the scenario's);
    `ecu_cpu`: HIL only, the CPU the ECU process is pinned to (a CPU kept free of other work);
    `inspect(scenario, result, document)`: sees the run's traces before they go, and may add to the
    document (a campaign's digest of the trajectory);
    `quiet_ecu`: SIL runs the ECU's quiet cycles on the cheap path (`hil.sil_ecu`; False: all in full)."""
    if ecu_cpu is not None and mode != "hil":
        raise ValueError(
            f"an ECU CPU ({ecu_cpu}) applies to --mode hil only: in {mode} the ECU is no process"
        )
    if ecu_cpu is not None and ecu_cpu not in os.sched_getaffinity(0):
        raise ValueError(
            f"ECU CPU {ecu_cpu}: not one of this machine's CPUs {sorted(os.sched_getaffinity(0))}"
        )
    scenario = name_or_file if isinstance(name_or_file, Scenario) else load_scenario(name_or_file)
    if perception is not None:
        from bywire.hil.scenario import with_perception

        scenario = with_perception(scenario, perception)
    profile: tuple[tuple[float, float], ...] = ()
    if leader_profile is not None:
        from bywire.hil.world.replay import leader_profile_from_csv

        profile = leader_profile_from_csv(scenario, leader_profile)
    from bywire.hil.module_faults import check_module_faults
    from bywire.hil.scenario_vehicle import check_initial_conditions

    check_module_faults(scenario, scenario_host_config(scenario))  # before any process starts
    check_initial_conditions(scenario)
    if scenario.urban is not None:
        from bywire.hil.scenario import ScenarioError
        from bywire.hil.world.urban_spec import require_files

        require_files(scenario.urban, scenario.source, ScenarioError)
    tmp: tempfile.TemporaryDirectory[str] | None = None
    if report_dir is not None:
        run_dir = report_dir
        run_dir.mkdir(parents=True, exist_ok=True)
    else:
        tmp = tempfile.TemporaryDirectory(prefix=f"bywire-{scenario.name}-")
        run_dir = Path(tmp.name)
    try:
        if mode == "sil":
            from bywire.hil.sil import run_sil

            result = run_sil(
                scenario,
                run_dir,
                record=record,
                progress=progress,
                leader_profile=profile,
                quiet_ecu=quiet_ecu,
            )
        elif mode == "hil":
            from bywire.hil.runner import run_hil

            result = run_hil(
                scenario,
                run_dir,
                record=record,
                host_link=host_link,
                progress=progress,
                ecu_store=ecu_store,
                leader_profile=leader_profile,
                ecu_cpu=ecu_cpu,
            )
        else:
            raise ValueError(f"mode must be sil or hil, not {mode!r}")
        if progress is not None:
            progress(1.0)
        document = evaluate(scenario, result.plant, result.host, result.extra, mode, result.traffic)
        document = {
            "scenario": document["scenario"],
            "mode": mode,
            **{k: v for k, v in document.items() if k != "scenario"},
        }
        if inspect is not None:
            inspect(scenario, result, document)
        if report_dir is not None:
            plot_run(report_dir / f"{scenario.name}.png", scenario, result.plant, result.host, document)
            if scenario.world is not None and result.traffic is not None:
                from bywire.hil.platoon_report import plot_platoon

                plot_platoon(report_dir, scenario, result.traffic, result.host, document)
            if scenario.urban is not None:
                from bywire.hil.urban_report import plot_urban

                plot_urban(report_dir, scenario, result.extra.get("urban"), document)
            write_json(report_dir / f"{scenario.name}.json", document)
            document["report_dir"] = str(report_dir)
        if json_path is not None:
            write_json(json_path, document)
        return document
    finally:
        if tmp is not None:
            tmp.cleanup()
