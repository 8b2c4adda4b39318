"""The `bywire` command: one entry point for the ECU, the host, the HIL plant/runner and the tools.

Subcommands import their subsystem lazily, so `bywire ecu run` loads only the firmware and the
protocol (the ECU never imports host or HIL code), and `--help` is instant.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path


def _hil_run_arguments(p: argparse.ArgumentParser, scenario_required: bool = True) -> None:
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
        help="OpenACC or CARMA CSV: the first car's speed drives the scenario's replay leader (issue 4)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress output")


# Benchmarks taking --seconds and --json: declared here so that `--help` imports nothing heavy.
_TIMED_BENCHES = {
    "platoon": "the follow-control QP and the 10-vehicle platoon step, vs. cvxpy (issue 4)",
    "v2x": "V2X codec and hardened receiver per message, vs. struct (issue 4)",
    "world": "world model: lane-map match, vehicle prediction, pose filter (issue 4)",
    "urban": "moving-traffic check, intersection precedence, lateral controller, HSM step (issue 5)",
}
_BENCH_MODULES = {
    "platoon": "bywire.host.platoon.bench",
    "v2x": "bywire.protocol.v2x.bench",
    "world": "bywire.host.world.bench",
    "urban": "bywire.host.behaviour.bench",
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="bywire", description=__doc__.splitlines()[0])
    from bywire import __version__

    parser.add_argument("--version", action="version", version=f"bywire {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    sub.add_parser(
        "ecu",
        help="the ECU firmware: run, flash, calibrate, unlatch (see `bywire ecu --help`)",
        add_help=False,
    )

    host = sub.add_parser("host", help="the host agent").add_subparsers(dest="host_command", required=True)
    from bywire.host import main as host_main  # light: argparse-only at import time

    host_main.add_arguments(host.add_parser("run", help="run the host agent against an ECU"))

    hil = sub.add_parser("hil", help="hardware-in-the-loop and software-in-the-loop runs")
    hil_sub = hil.add_subparsers(dest="hil_command", required=True)
    _hil_run_arguments(hil_sub.add_parser("run", help="run one scenario and judge it"))
    _hil_run_arguments(hil_sub.add_parser("demo", help="the three-process HIL demo with its report"), False)
    hil_sub.add_parser("list", help="list the shipped scenarios")
    from bywire.hil import plant_main

    plant_main.add_arguments(hil_sub.add_parser("plant", help="(internal) the plant process of a HIL run"))

    bench = sub.add_parser("bench", help="benchmarks").add_subparsers(dest="bench_command", required=True)
    be = bench.add_parser("ecu", help="ECU loop timing with plant and host running (three-process HIL)")
    be.add_argument("--seconds", type=float, default=20.0, help="how long to measure (default 20)")
    be.add_argument("--json", type=Path, help="write the loop statistics as JSON")
    be.add_argument("--report", type=Path, help="directory for the run's logs and traces")

    from bywire.host.roadnet import bench as roadnet_bench  # light: the subsystem loads in main()

    roadnet_bench.add_arguments(
        bench.add_parser("roadnet", help="RNDF/MDF parse, graph and mission route on NQE and VAIL (issue 5)")
    )

    br = bench.add_parser(
        "runtime", help="object store and cross-process transport: latency and throughput, with baselines"
    )
    br.add_argument("--seconds", type=float, default=None, help="scale the measuring time (default ~30 s)")
    br.add_argument("--json", type=Path, help="write the results as JSON")

    for name, help_text in _TIMED_BENCHES.items():
        b = bench.add_parser(name, help=help_text)
        b.add_argument("--seconds", type=float, default=None, help="scale the measuring time")
        b.add_argument("--json", type=Path, help="write the results as JSON")

    log = sub.add_parser("log", help="recordings (MCAP): info, plot, replay")
    from bywire.host.runtime import log_cli

    log_cli.add_arguments(log.add_subparsers(dest="log_command", required=True, metavar="COMMAND"))

    platoon = sub.add_parser("platoon", help="platoon tools (issue 4)").add_subparsers(
        dest="platoon_command", required=True, metavar="COMMAND"
    )
    from bywire.host.platoon import platoon_cli

    platoon_cli.add_arguments(
        platoon.add_parser(
            "string-stability",
            help="string stability of a recorded platoon (OpenACC or CARMA CSV): worst spectral ratio",
        )
    )
    from bywire.hil.world import map_cli

    map_cli.add_arguments(
        platoon.add_parser("record-map", help="a lane map (JSON) from an NMEA log of a drive along the lane")
    )

    from bywire.host.roadnet import roadnet_cli  # stdlib-only imports

    rndf = sub.add_parser("rndf", help="road network files (issue 5)").add_subparsers(
        dest="rndf_command", required=True, metavar="COMMAND"
    )
    roadnet_cli.add_rndf_check_arguments(
        rndf.add_parser("check", help="parse RNDF/MDF files; each error as file:line: what was expected")
    )
    mission = sub.add_parser("mission", help="missions (issue 5)").add_subparsers(
        dest="mission_command", required=True, metavar="COMMAND"
    )
    roadnet_cli.add_mission_plan_arguments(
        mission.add_parser("plan", help="the fastest route through an MDF's checkpoints, in order")
    )

    from bywire.host.behaviour import diagram

    behaviour = sub.add_parser("behaviour", help="the urban behaviour (issue 5)").add_subparsers(
        dest="behaviour_command", required=True, metavar="COMMAND"
    )
    diagram.add_arguments(
        behaviour.add_parser(
            "diagram", help="the hierarchical state machine, generated from the code (Mermaid or PNG)"
        )
    )

    from bywire.protocol.v2x import v2x_cli

    v2x_cli.add_arguments(sub.add_parser("v2x", help="V2X link tools: meter, echo, ping, fuzz (issue 4)"))

    bus = sub.add_parser("bus", help="virtual CAN buses").add_subparsers(dest="bus_command", required=True)
    serve = bus.add_parser("serve", help="serve a python-can virtual bus to other processes on loopback")
    serve.add_argument("--port", type=int, default=54701)
    serve.add_argument("--channel", default="bywire", help="virtual channel name")
    serve.add_argument("--host", default="127.0.0.1", help="listen address (keep it on loopback)")
    serve.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="SCHED_FIFO priority for the server (0: normal scheduling); the HIL runner uses 75",
    )

    proto = sub.add_parser("protocol", help="protocol tools").add_subparsers(
        dest="protocol_command", required=True
    )
    table = proto.add_parser("table", help="print the protocol table generated from the DBC and the EDS")
    table.add_argument("--output", type=Path, help="write to this file instead of stdout")
    return parser


def _progress(label: str):  # type: ignore[no-untyped-def]
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


def _cmd_hil_run(args: argparse.Namespace, scenario_name: str, default_mode: str) -> int:
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
    )
    for check in result["checks"]:
        mark = "PASS" if check["passed"] else "FAIL"
        print(f"  {mark}  {check['name']}: {check['value']} ({check['op']} {check['limit']})")
    print(
        f"{result['scenario']} ({result['mode']}): {result['verdict'].upper()}"
        + (f" — report in {result['report_dir']}" if result.get("report_dir") else "")
    )
    return 0 if result["verdict"] == "pass" else 1


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "ecu":
        from bywire.ecu.cli import main as ecu_main

        return ecu_main(argv[1:])
    args = build_parser().parse_args(argv)
    try:
        if args.command == "host":
            from bywire.host import main as host_main

            return host_main.main(args)
        if args.command == "hil":
            if args.hil_command == "list":
                from bywire.hil.scenario import builtin_scenarios, load_scenario

                for name in builtin_scenarios():
                    print(f"{name:22s} {load_scenario(name).description}")
                return 0
            if args.hil_command == "plant":
                from bywire.hil import plant_main

                return plant_main.main(args)
            if args.hil_command == "demo":
                return _cmd_hil_run(args, "demo", "hil")
            return _cmd_hil_run(args, args.scenario, "sil")
        if args.command == "bench":
            if args.bench_command in _TIMED_BENCHES:
                import importlib

                module = importlib.import_module(_BENCH_MODULES[args.bench_command])
                if args.seconds is None:  # each benchmark has its own default
                    args.seconds = getattr(module, "DEFAULT_SECONDS", None)
                return int(module.main(args))
            if args.bench_command == "roadnet":
                from bywire.host.roadnet import bench as roadnet_bench

                return roadnet_bench.main(args)
            if args.bench_command == "runtime":
                from bywire.host.runtime import bench as runtime_bench

                return runtime_bench.main(args)
            from bywire.hil.bench import bench_ecu

            return bench_ecu(args.seconds, args.json, args.report)
        if args.command == "platoon":
            if args.platoon_command == "record-map":
                from bywire.hil.world import map_cli

                return map_cli.main(args)
            from bywire.host.platoon import platoon_cli

            return platoon_cli.main(args)
        if args.command in ("rndf", "mission"):
            from bywire.host.roadnet import roadnet_cli

            if args.command == "rndf":
                return roadnet_cli.main_rndf_check(args)
            return roadnet_cli.main_mission_plan(args)
        if args.command == "behaviour":
            from bywire.host.behaviour import diagram

            return diagram.main(args)
        if args.command == "v2x":
            from bywire.protocol.v2x import v2x_cli

            return v2x_cli.main(args)
        if args.command == "log":
            from bywire.host.runtime import log_cli

            return log_cli.main(args)
        if args.command == "bus":
            from bywire.protocol.bus_url import run_bus_server

            if args.rt_priority:
                from bywire.ecu.realtime import apply_realtime

                print(
                    f"bus: real-time: {apply_realtime(priority=args.rt_priority, freeze_gc=False).summary()}"
                )
            run_bus_server(args.port, args.channel, args.host)
            return 0
        if args.command == "protocol":
            from bywire.protocol.table import render_protocol_table

            text = render_protocol_table()
            if args.output:
                args.output.write_text(text, encoding="utf-8")
            else:
                sys.stdout.write(text)
            return 0
    except KeyboardInterrupt:
        return 130
    except RuntimeError as exc:  # a HIL process that did not start or died: its log tail says why
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except ValueError as exc:  # scenario, calibration and URL errors say what and where
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
