"""`bywire hil run|demo|list`: run one scenario and judge it, the three-process HIL demo, and the
shipped scenarios.

The plant, the scenario and its evaluation are DESIGN.md section 1's third program; `run` is SIL by
default (one process on simulated time), `demo` is HIL (plant, ECU and host as their own processes).
The subsystem is imported when a command runs, not when `bywire` builds its parser.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any


def _run_arguments(p: argparse.ArgumentParser, scenario_required: bool = True) -> None:
    if scenario_required:
        p.add_argument(
            "scenario", help="a shipped scenario's bare name (see `bywire hil list`) or a scenario file"
        )
    p.add_argument(
        "--mode",
        choices=("sil", "hil"),
        default=None,
        help="sil: one process on simulated time; hil: plant, ECU and host as real processes "
        "on a loopback virtual bus (default: hil for the demo, sil otherwise)",
    )
    p.add_argument("--json", type=Path, help="write the verdict and metrics as JSON to this file")
    p.add_argument("--report", type=Path, help="directory for the report: plots, traces, logs, JSON")
    p.add_argument(
        "--record",
        type=Path,
        help="record the run: FILE.mcap holds every bus frame and every host topic (bywire log ...); "
        "other suffixes (.log .asc .blf .csv) record the frames with python-can",
    )
    p.add_argument(
        "--host-link",
        choices=("remote", "udp"),
        default="remote",
        help="HIL host<->ECU link: a second virtual CAN bus, or CAN frames over UDP (Ethernet)",
    )
    p.add_argument(
        "--ecu-store", type=Path, help="HIL: boot the ECU from this flashed store (bywire ecu flash)"
    )
    p.add_argument(
        "--leader-profile",
        type=Path,
        help="OpenACC or CARMA CSV: the first car's speed drives the scenario's replay leader",
    )
    p.add_argument(
        "--perception",
        choices=("perfect", "lidar"),
        help="urban scenarios: the host perceives the traffic from the simulator's object list (perfect) "
        "or from the simulated Velodyne (lidar); default: the scenario's `perception:`",
    )
    p.add_argument("--quiet", action="store_true", help="no progress output")


def _progress(label: str) -> Callable[[float], None]:
    def report(fraction: float) -> None:
        width = 30
        done = int(fraction * width)
        print(
            f"\r{label} [{'#' * done}{'.' * (width - done)}] {fraction * 100:5.1f} %",
            end="",
            file=sys.stderr,
            flush=True,
        )
        if fraction >= 1.0:
            print(file=sys.stderr)

    return report


def _run(args: argparse.Namespace, scenario_name: str, default_mode: str) -> int:
    from bywire.hil.run import run_scenario

    mode = args.mode or default_mode
    progress = None if args.quiet else _progress(f"{scenario_name} ({mode})")
    result = run_scenario(
        scenario_name,
        mode=mode,
        json_path=args.json,
        report_dir=args.report,
        record=args.record,
        host_link=args.host_link,
        ecu_store=args.ecu_store,
        progress=progress,
        leader_profile=args.leader_profile,
        perception=args.perception,
    )
    for check in result["checks"]:
        mark = "PASS" if check["passed"] else "FAIL"
        print(f"  {mark}  {check['name']}: {check['value']} ({check['op']} {check['limit']})")
    for c in result.get("watchdog_culprits", []):
        print(f"  watchdog {c['fault']} at {c['at_s']:.3f} s: fell behind: {', '.join(c['fell_behind'])}")
        for process, recs in c["stalls"].items():
            for r in recs:
                where = " <- ".join(reversed(r["suspect_stack"] or [])) or "?"
                print(
                    f"    {process}: {r['channel']} silent {r['gap_ms']} ms from {r['from_s']:.3f} s, "
                    f"busiest thread {r['busiest_thread']} at {where}"
                )
    rhythm = rhythm_line(result)
    if rhythm:
        print(f"  rhythm (gap p99/max ms): {rhythm}")
    print(
        f"{result['scenario']} ({result['mode']}): {result['verdict'].upper()}"
        + (f" — report in {result['report_dir']}" if result.get("report_dir") else "")
    )
    return 0 if result["verdict"] == "pass" else 1


def rhythm_line(result: dict[str, Any]) -> str:
    """Each process's rhythm in one line (HIL runs: the stall recorders' and the ECU's histograms)."""
    parts = []
    stalls = result.get("stalls", {})
    for label, process, channel in (
        ("host ECU link", "host", "ecu_link"),
        ("host tick", "host", "scheduler"),
        ("plant step", "plant", "step"),
    ):
        r = stalls.get(process, {}).get("rhythm_ms", {}).get(channel)
        if r and r.get("count"):
            parts.append(f"{label} {r['p99']:.1f}/{r['max']:.1f}")
    heard = result["metrics"].get("ecu_loop", {}).get("host_link", {}).get("heartbeat_gap_ms")
    if heard and heard.get("count"):
        parts.append(f"heartbeat at the ECU {heard['p99']:.1f}/{heard['max']:.1f}")
    return "; ".join(parts)


def add_run_arguments(p: argparse.ArgumentParser) -> None:
    _run_arguments(p)


def main_run(args: argparse.Namespace) -> int:
    return _run(args, args.scenario, "sil")


def add_demo_arguments(p: argparse.ArgumentParser) -> None:
    _run_arguments(p, scenario_required=False)


def main_demo(args: argparse.Namespace) -> int:
    return _run(args, "demo", "hil")


def main_list(args: argparse.Namespace) -> int:
    from bywire.hil.scenario import builtin_scenarios, load_scenario

    for name in builtin_scenarios():
        print(f"{name:22s} {load_scenario(name).description}")
    return 0
