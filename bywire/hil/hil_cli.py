"""`bywire hil run|demo|list`: run one scenario and judge it, the three-process HIL demo, and the
shipped scenarios.

The plant, the scenario and its evaluation are DESIGN.md section 1's third program; `run` is SIL by
default (one process on simulated time), `demo` is HIL (plant, ECU and host as their own processes).
The subsystem is imported when a command runs, not when `bywire` builds its parser.

Exit status (README "Exit status"): 0 the run passed its checks, 1 it failed them, 2 bad usage or a
bad scenario, 128 + N stopped by signal N (130 Ctrl-C, 143 SIGTERM); a stopped run still writes its
JSON, with `"verdict": "interrupted"`. `--json -` puts the JSON alone on stdout (the lines for
people go to stderr).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any, TextIO

STDOUT = Path("-")


def _run_arguments(p: argparse.ArgumentParser, scenario_required: bool = True) -> None:
    if scenario_required:
        scenario = p.add_argument(
            "scenario", help="a shipped scenario's bare name (see `bywire hil list`) or a scenario file"
        )
        scenario.completer = _complete_scenario  # type: ignore[attr-defined]
    p.add_argument(
        "--mode",
        choices=("sil", "hil"),
        default=None,
        help="sil: one process on simulated time; hil: plant, ECU and host as real processes "
        "on a loopback virtual bus (default: hil for the demo, sil otherwise)",
    )
    p.add_argument(
        "--json",
        type=Path,
        help="write the verdict and metrics as JSON to this file (`-`: to stdout, and nothing else there)",
    )
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
    if scenario_required:
        p.add_argument(
            "--set",
            action="append",
            default=[],
            metavar="FIELD=VALUE",
            help="set a field of the scenario first, VALUE in YAML (vehicle.v0_mps=25, "
            "'faults[0].at_s=3.5'); repeatable: a campaign's run alone",
        )
    p.add_argument(
        "--ecu-cpu",
        type=int,
        metavar="N",
        help="HIL: pin the ECU process to CPU N (keep the machine's other work off it: README "
        '"When a process falls behind")',
    )
    p.add_argument(
        "--every-ecu-cycle",
        action="store_true",
        help="SIL: run every ECU cycle in full, including those in which nothing reaches or leaves the "
        "ECU (by default run as the controller's recurrence alone: the same results, bit for bit)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress line (drawn only on a terminal)")


def _complete_scenario(prefix: str, **kwargs: Any) -> list[str]:
    """Tab completion of a scenario: the shipped names, and files."""
    from argcomplete.completers import FilesCompleter

    from bywire.hil.scenario import builtin_scenarios

    names = [name for name in builtin_scenarios() if name.startswith(prefix)]
    return names + list(FilesCompleter(("yaml", "yml", "toml"))(prefix, **kwargs))


class _Reached:
    """The fraction of the scenario's duration a run has reached (the runner's progress reports),
    forwarded to a terminal's progress line where there is one."""

    def __init__(self, display: Any = None) -> None:
        self.fraction = 0.0
        self.display = display

    def __call__(self, fraction: float) -> None:
        self.fraction = fraction
        if self.display is not None:
            self.display(fraction)


@contextlib.contextmanager
def _stdout_to_stderr() -> Iterator[None]:
    """Everything the run writes to stdout goes to stderr, down to the file descriptor (its child
    processes and C libraries write there too), so that stdout holds only the JSON."""
    sys.stdout.flush()
    saved = os.dup(1)
    os.dup2(2, 1)
    try:
        with contextlib.redirect_stdout(sys.stderr):
            yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


@contextlib.contextmanager
def _signals_ignored(*signums: int) -> Iterator[None]:
    before = {s: signal.signal(s, signal.SIG_IGN) for s in signums}
    try:
        yield
    finally:
        for s, handler in before.items():
            signal.signal(s, handler)


def _json_default(value: Any) -> Any:
    item = getattr(value, "item", None)  # numpy scalars
    if item is None:
        raise TypeError(f"not JSON serialisable: {type(value).__name__}")
    return item()


def _write_document(path: Path, document: dict[str, Any]) -> None:
    text = json.dumps(document, indent=2, default=_json_default) + "\n"
    if path == STDOUT:
        sys.stdout.write(text)
        sys.stdout.flush()
    else:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")


def interrupted_document(
    scenario: str, mode: str, signum: int, simulated_s: float, duration_s: float
) -> dict[str, Any]:
    """The result of a run stopped by a signal: no checks judged, how far it came."""
    return {
        "scenario": scenario,
        "mode": mode,
        "verdict": "interrupted",
        "signal": signal.Signals(signum).name,
        "simulated_s": round(simulated_s, 3),
        "duration_s": duration_s,
        "checks": [],
        "metrics": {},
    }


def _run(args: argparse.Namespace, scenario_name: str, default_mode: str) -> int:
    from bywire.hil.run import run_scenario
    from bywire.hil.run_progress import RunProgress, wants_progress
    from bywire.hil.scenario import load_scenario
    from bywire.hil.scenario_overrides import parse_assignment
    from bywire.process_util import signals_interrupt

    mode = args.mode or default_mode
    overrides = dict(parse_assignment(a) for a in getattr(args, "set", []))
    if overrides and mode != "sil":
        # the HIL processes each read the scenario's file, which knows nothing of --set
        raise ValueError("--set: SIL only (--mode sil); for HIL, write the fields into a scenario file")
    # a bad name, file or field stops here, before any process starts
    scenario = load_scenario(scenario_name, overrides)
    json_to_stdout = args.json == STDOUT
    out: TextIO = sys.stderr if json_to_stdout else sys.stdout
    display = None
    if not args.quiet and wants_progress(sys.stderr):
        display = RunProgress(f"{scenario.name} ({mode})", scenario.duration_s, sys.stderr)
    reached = _Reached(display)
    try:
        with (
            signals_interrupt(signal.SIGINT, signal.SIGTERM),
            display if display is not None else contextlib.nullcontext(),
            _stdout_to_stderr() if json_to_stdout else contextlib.nullcontext(),
        ):
            result = run_scenario(
                scenario if overrides else scenario_name,
                mode=mode,
                json_path=None if json_to_stdout else args.json,
                report_dir=args.report,
                record=args.record,
                host_link=args.host_link,
                ecu_store=args.ecu_store,
                progress=reached,
                leader_profile=args.leader_profile,
                perception=args.perception,
                ecu_cpu=args.ecu_cpu,
                quiet_ecu=not args.every_ecu_cycle,
            )
    except KeyboardInterrupt as exc:
        signum = int(getattr(exc, "signum", signal.SIGINT))
        document = interrupted_document(
            scenario.name, mode, signum, reached.fraction * scenario.duration_s, scenario.duration_s
        )
        with _signals_ignored(signal.SIGINT, signal.SIGTERM):  # a second Ctrl-C does not cut the file
            for path in (args.json, args.report and args.report / f"{scenario.name}.json"):
                if path is not None:
                    _write_document(path, document)
        print(
            f"{scenario.name} ({mode}): INTERRUPTED by {document['signal']} at "
            f"{document['simulated_s']:.1f} of {scenario.duration_s:.1f} s simulated",
            file=sys.stderr,
        )
        return 128 + signum
    if json_to_stdout:
        _write_document(STDOUT, result)
    for check in result["checks"]:
        mark = "PASS" if check["passed"] else "FAIL"
        print(f"  {mark}  {check['name']}: {check['value']} ({check['op']} {check['limit']})", file=out)
    for c in result.get("watchdog_culprits", []):
        machine = c.get("machine_stall_ms")
        also = f"; a CPU was withheld {machine} ms (its SCHED_FIFO 99 probe woke late)" if machine else ""
        print(
            f"  watchdog {c['fault']} at {c['at_s']:.3f} s: fell behind: {', '.join(c['fell_behind'])}{also}",
            file=out,
        )
        for process, recs in c["stalls"].items():
            for r in recs:
                where = " <- ".join(reversed(r["suspect_stack"] or [])) or "?"
                print(
                    f"    {process}: {r['channel']} silent {r['gap_ms']} ms from {r['from_s']:.3f} s, "
                    f"busiest thread {r['busiest_thread']} at {where}",
                    file=out,
                )
    rhythm = rhythm_line(result)
    if rhythm:
        print(f"  rhythm (gap p99/max ms): {rhythm}", file=out)
    print(
        f"{result['scenario']} ({result['mode']}): {result['verdict'].upper()}"
        + (f" — report in {result['report_dir']}" if result.get("report_dir") else ""),
        file=out,
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
    machine = result["metrics"].get("machine")
    if machine and machine.get("wakes"):
        late = machine["late_ms"]
        parts.append(f"machine (FIFO 99 probe late) {late['p99']:.1f}/{late['max']:.1f}")
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
