"""`bywire host run --scenario NAME`: the host process of a HIL run, on the entry point a car runs.

The scenario becomes the host's inputs (`hil.host_inputs`) and its module faults the host's fault hooks;
the process's own faults (freeze, kill) the runner applies from outside, with signals.
"""

from __future__ import annotations

import argparse
import logging

from bywire.hil.host_inputs import host_inputs
from bywire.hil.module_faults import ModuleFaultInjector, check_module_faults
from bywire.hil.scenario import load_scenario, scenario_host_config, with_perception
from bywire.host.main import run_host


def main(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    for flag in ("rndf", "mdf", "lane_map", "commands", "cruise"):
        if getattr(args, flag) is not None:
            raise SystemExit(f"host run: --{flag.replace('_', '-')} and --scenario exclude each other")
    scenario = load_scenario(args.scenario)
    if args.perception is not None:
        scenario = with_perception(scenario, args.perception)
    config = scenario_host_config(scenario, args.config)
    check_module_faults(scenario, config)
    faults = ModuleFaultInjector(scenario, 0.0, in_process=False)
    return run_host(args, config, host_inputs(scenario), faults)
