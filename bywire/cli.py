# PYTHON_ARGCOMPLETE_OK
"""The `bywire` command: one entry point for the ECU, the host, the HIL plant/runner and the tools.

Every command is a row of `COMMANDS`: the words that name it, its help line, and the module that
implements it, which holds its `add_arguments(parser)` and `main(args) -> int` (or, where one module
implements several commands, `add_<part>_arguments` and `main_<part>`; a module without the first
takes no arguments). A row without a module is a group: the rows under it are its commands.

Only the module of the command on the command line is imported, so `bywire ecu run` loads only the
firmware and the protocol, `bywire host run` only the host (DESIGN.md section 2: each is deployable
alone), and `--help` is instant. Three rows are this module's own, because what they join may only
be joined here, at the top: `ecu` hands its raw arguments to `bywire.ecu.cli` (also the entry point of
a flashed firmware image); `host run --scenario` is the simulator's host process (`hil.host_process`)
on the car's entry point; `log` replays a simulator's recording with the simulator's inputs. The
`bench` rows run `benchmarks/NAME.py` of the source checkout, which an installed wheel does not hold.

Exit status, for every command (README "Exit status"): 0 done (a run passed its checks), 1 a run or
check that failed, 2 bad usage or bad input (an unknown option, a file that cannot be read, parsed or
written), 128 + N stopped by signal N (130 Ctrl-C, 143 SIGTERM, 141 the reader of a pipe went away:
`bywire hil list | head`). An error is one line on stderr, `error: WHERE: what`, WHERE being the file
and line, the file and field, or the URL that failed; never a traceback for a user's mistake.
Completion: argcomplete, on the same lazy parser (`eval "$(bywire completion bash)"`).
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
import traceback
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any


@dataclass(frozen=True)
class Command:
    """One row of the command table: a command (`module` set) or a group of the rows under it."""

    words: str  # as typed: "hil run"
    help: str
    module: str | None = None
    part: str = ""  # "" -> add_arguments / main; "x" -> add_x_arguments / main_x
    metavar: str | None = None  # a group's usage names its commands so (None: as a list)
    raw: bool = False  # main(argv) parses the words after the command itself

    def add_arguments(self, p: argparse.ArgumentParser) -> None:
        assert self.module is not None
        name = f"add_{self.part}_arguments" if self.part else "add_arguments"
        add = getattr(import_command_module(self.module), name, None)
        if add is not None:  # none: the command takes no arguments
            add(p)

    def main(self, args: Any) -> int:
        """Run the command: `args` parsed by the parser `add_arguments` made (a raw row: the words)."""
        assert self.module is not None
        main = getattr(import_command_module(self.module), f"main_{self.part}" if self.part else "main")
        return int(main(args))


COMMANDS: tuple[Command, ...] = (
    Command(
        "ecu",
        "the ECU firmware: run, flash, calibrate, unlatch (see `bywire ecu --help`)",
        "bywire.ecu.cli",
        raw=True,
    ),
    Command("host", "the host agent"),
    Command("host run", "run the host agent against an ECU", "bywire.cli", "host_run"),
    Command("hil", "hardware-in-the-loop and software-in-the-loop runs"),
    Command("hil run", "run one scenario and judge it", "bywire.hil.hil_cli", "run"),
    Command("hil demo", "the three-process HIL demo with its report", "bywire.hil.hil_cli", "demo"),
    Command("hil list", "list the shipped scenarios", "bywire.hil.hil_cli", "list"),
    Command("hil plant", "(internal) the plant process of a HIL run", "bywire.cli", "hil_plant"),
    Command(
        "campaign", "many SIL runs over parameter grids, on this machine or a Ray cluster", metavar="COMMAND"
    ),
    Command(
        "campaign run",
        "run a campaign (a shipped one or a file): one Parquet row per run, resumable",
        "bywire.hil.campaign.campaign_cli",
        "run",
    ),
    Command(
        "campaign report",
        "a campaign's pass rates, worst runs with their commands, and plots",
        "bywire.hil.campaign.campaign_cli",
        "report",
    ),
    Command(
        "campaign compare",
        "two executions of a campaign run by run: regressions, fixes, changed metrics and trajectories",
        "bywire.hil.campaign.campaign_cli",
        "compare",
    ),
    Command("campaign list", "list the shipped campaigns", "bywire.hil.campaign.campaign_cli", "list"),
    Command("bench", "benchmarks"),
    Command("bench ecu", "ECU loop timing with plant and host running (three-process HIL)", "benchmarks.ecu"),
    Command(
        "bench sil",
        "whole scenarios in SIL (demo, GCDC heat, DARPA sample mission): real-time factor vs. the FMU alone",
        "benchmarks.sil",
    ),
    Command(
        "bench roadnet",
        "RNDF/MDF parse, graph and mission route on NQE and VAIL (seed 000 section 8)",
        "benchmarks.roadnet",
    ),
    Command(
        "bench runtime",
        "object store and cross-process transport: latency and throughput, with baselines",
        "benchmarks.runtime",
    ),
    Command(
        "bench platoon",
        "the follow-control QP and the 10-vehicle platoon step, vs. cvxpy (seed 003 section V)",
        "benchmarks.platoon",
    ),
    Command(
        "bench v2x",
        "V2X codec and hardened receiver per message, vs. struct (seed 003 section III)",
        "benchmarks.v2x",
    ),
    Command(
        "bench world",
        "world model: lane-map match, vehicle prediction, pose filter (seed 003 section IV)",
        "benchmarks.world",
    ),
    Command(
        "bench urban",
        "moving-traffic check, intersection precedence, lateral controller, HSM step (seed 000)",
        "benchmarks.urban",
    ),
    Command(
        "bench perception",
        "LIDAR grid, objects, tracking, markers per KITTI scan; the simulated LIDAR cast (seed 000 4-6)",
        "benchmarks.perception",
    ),
    Command(
        "bench zone",
        "the zone planner on Autoware's parking lot and a maze, beside OMPL's planners (seed 000 section 10)",
        "benchmarks.zone",
    ),
    Command(
        "bench hil",
        "the three-process HIL under a standard background load: period gaps, heartbeat gaps, spurious stops",
        "benchmarks.hil_load",
    ),
    Command(
        "bench cli",
        "how long `bywire --help`, a command's help and a tab completion take in a fresh process",
        "benchmarks.cli_startup",
    ),
    Command("log", "recordings (MCAP): info, plot, replay, export (ASC, BLF)", "bywire.cli", "log"),
    Command("perception", "LIDAR perception tools (seed 000 sections 4-6)", metavar="COMMAND"),
    Command(
        "perception grid",
        "the occupancy grid of one Velodyne scan (KITTI .bin): PNG and JSON",
        "bywire.host.perception.perception_cli",
        "grid",
    ),
    Command(
        "perception track-eval",
        "our tracker on KITTI tracking detections, scored with CLEAR-MOT against the labels",
        "bywire.host.perception.perception_cli",
        "track_eval",
    ),
    Command("platoon", "platoon tools (cooperative driving, seed 003)", metavar="COMMAND"),
    Command(
        "platoon string-stability",
        "string stability of a recorded platoon (OpenACC or CARMA CSV): worst spectral ratio",
        "bywire.host.platoon.platoon_cli",
    ),
    Command(
        "platoon record-map",
        "a lane map (JSON) from an NMEA log of a drive along the lane",
        "bywire.host.platoon.record_map",
    ),
    Command("rndf", "road network files (RNDF/MDF, seed 000 section 8)", metavar="COMMAND"),
    Command(
        "rndf check",
        "parse RNDF/MDF files; each error as file:line: what was expected",
        "bywire.host.roadnet.roadnet_cli",
        "rndf_check",
    ),
    Command("mission", "missions (MDF, seed 000 section 8)", metavar="COMMAND"),
    Command(
        "mission plan",
        "the fastest route through an MDF's checkpoints, in order",
        "bywire.host.roadnet.roadnet_cli",
        "mission_plan",
    ),
    Command("zone", "zone navigation (seed 000 section 10)", metavar="COMMAND"),
    Command(
        "zone plan",
        "hybrid A* on an occupancy grid (.npy or image): path, numbers, plot",
        "bywire.host.navigation.zone_cli",
        "plan",
    ),
    Command("behaviour", "the urban behaviour (seed 000 section 8)", metavar="COMMAND"),
    Command(
        "behaviour diagram",
        "the hierarchical state machine, generated from the code (Mermaid or PNG)",
        "bywire.host.behaviour.diagram",
    ),
    Command(
        "v2x",
        "V2X link tools: meter, echo, ping, fuzz, encode, decode (seed 003 section III)",
        "bywire.protocol.v2x.v2x_cli",
    ),
    Command("bus", "virtual CAN buses"),
    Command(
        "bus serve",
        "serve a python-can virtual bus to other processes on loopback",
        "bywire.protocol.protocol_cli",
        "serve",
    ),
    Command("protocol", "protocol tools"),
    Command(
        "protocol table",
        "print the protocol table generated from the DBC and the EDS",
        "bywire.protocol.protocol_cli",
        "table",
    ),
    Command(
        "completion",
        'print the shell code of tab completion: eval "$(bywire completion bash)"',
        "bywire.cli",
        "completion",
    ),
)


class CommandUnavailable(Exception):
    """A command whose implementation is not where this `bywire` runs from (said in one line)."""


def import_command_module(name: str) -> ModuleType:
    """A command's module; `benchmarks.*` from the source checkout's benchmarks/ folder, the one
    beside the `bywire` package (the repository root goes on sys.path, so that the processes a
    benchmark spawns import it by name too)."""
    if name.split(".")[0] == "benchmarks":
        import bywire

        folder = Path(bywire.__file__).resolve().parent.parent / "benchmarks"
        if not (folder / "__init__.py").is_file():
            raise CommandUnavailable(
                f"bywire bench needs the benchmarks/ folder of a source checkout, and there is none beside "
                f"this installation ({folder.parent}): run it from a clone of the repository"
            )
        if str(folder.parent) not in sys.path:
            sys.path.insert(0, str(folder.parent))
        found = importlib.import_module("benchmarks").__file__
        if found is None or Path(found).resolve().parent != folder:
            raise CommandUnavailable(
                f"bywire bench: `benchmarks` is imported from {found}, not from {folder}"
            )
    return importlib.import_module(name)


def benchmark(name: str) -> ModuleType:
    """The module of `bywire bench NAME` (benchmarks/NAME.py of the source checkout)."""
    return import_command_module(f"benchmarks.{name}")


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The parser of every command; given a command line, only the arguments of the command it names
    are added (and only that command's module imported)."""
    from bywire import __version__

    parser = argparse.ArgumentParser(
        prog="bywire",
        description=__doc__.splitlines()[0],
        epilog="exit status: 0 done, 1 a run or check that failed, 2 bad usage or input, 128+N stopped "
        'by signal N. Tab completion: eval "$(bywire completion bash)".',
    )
    parser.add_argument("--version", action="version", version=f"bywire {__version__}")
    groups: dict[tuple[str, ...], Any] = {
        (): parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    }
    for row in COMMANDS:
        *outer, name = words = tuple(row.words.split())
        p = groups[tuple(outer)].add_parser(name, help=row.help, add_help=not row.raw)
        if row.module is None:
            groups[words] = p.add_subparsers(dest=f"{name}_command", required=True, metavar=row.metavar)
        elif not row.raw and (argv is None or tuple(argv[: len(words)]) == words):
            row.add_arguments(p)
    return parser


def _row(args: argparse.Namespace) -> Command:
    """The row of the parsed command: a group's command, else the top-level one (which may have
    commands of its own, added by its module)."""
    rows = {row.words: row for row in COMMANDS}
    return rows.get(f"{args.command} {getattr(args, f'{args.command}_command', '')}") or rows[args.command]


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if "_ARGCOMPLETE" in os.environ:  # the shell asks for completions (argcomplete's protocol)
        _complete()
    try:
        raw = next((row for row in COMMANDS if row.raw and argv[:1] == [row.words]), None)
        if raw is not None:
            code = raw.main(argv[1:])
        else:
            args = build_parser(argv).parse_args(argv)
            code = _row(args).main(args)
        sys.stdout.flush()  # a reader gone shows here, not as a traceback in the interpreter's exit
        return code
    except CommandUnavailable as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        return 128 + int(getattr(exc, "signum", signal.SIGINT))
    except BrokenPipeError:
        # The reader went away (`bywire hil list | head`): nothing more to say, and no traceback when
        # Python flushes stdout at exit (the way the Python docs' "Note on SIGPIPE" does it).
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 128 + signal.SIGPIPE
    except RuntimeError as exc:  # a HIL process that did not start or died: its log tail says why
        print(f"error: {exc}", file=sys.stderr)
        # where it was raised: for an error that is not ours ("deque mutated during iteration") the
        # message alone does not say which code raced with which
        frames = reversed(traceback.extract_tb(exc.__traceback__)[-4:])
        where = " <- ".join(f"{f.filename.rsplit('/', 1)[-1]}:{f.lineno} {f.name}" for f in frames)
        print(f"  at {where}", file=sys.stderr)
        return 1
    except OSError as exc:  # a file given on the command line that cannot be read or written
        print(f"error: {_os_error_line(exc)}", file=sys.stderr)
        return 2
    except ValueError as exc:  # scenario, calibration and URL errors say what and where
        print(f"error: {exc}", file=sys.stderr)
        return 2


def _os_error_line(exc: OSError) -> str:
    """`PATH: what` (`/missing_dir/x.md: No such file or directory`), as the shell says it."""
    if exc.filename is None or exc.strerror is None:
        return str(exc)
    return f"{exc.filename}: {exc.strerror}"


def _complete() -> None:
    """Answer the shell's completion request and exit (argcomplete): the parser is built for the
    words typed so far, so that the command being typed has its options and nothing else loads."""
    import argcomplete
    from argcomplete import split_line

    line = os.environ.get("COMP_LINE", "")
    words = split_line(line, int(os.environ.get("COMP_POINT", len(line))))[3]
    start = int(os.environ["_ARGCOMPLETE"])  # the word after the program's name
    typed = words[start:]
    raw = next((row for row in COMMANDS if row.raw and typed[:1] == [row.words]), None)
    if raw is not None and raw.module is not None:  # `ecu` parses its own words
        os.environ["_ARGCOMPLETE"] = str(start + 1)
        argcomplete.autocomplete(import_command_module(raw.module).build_parser())
    argcomplete.autocomplete(build_parser(typed))
    sys.exit(0)  # not reached: autocomplete exits


def add_completion_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("shell", choices=("bash", "zsh", "fish", "tcsh", "powershell"))


def main_completion(args: argparse.Namespace) -> int:
    """`bywire completion SHELL`: argcomplete's registration of `bywire` for that shell (bash: put
    `eval "$(bywire completion bash)"` in ~/.bashrc)."""
    import argcomplete

    sys.stdout.write(argcomplete.shellcode(["bywire"], shell=args.shell))
    return 0


# -- the rows that join what only the top may join -------------------------------------------------------


def add_host_run_arguments(p: argparse.ArgumentParser) -> None:
    from bywire.host.main_args import add_arguments

    add_arguments(p)


def add_hil_plant_arguments(p: argparse.ArgumentParser) -> None:
    from bywire.hil.plant_args import add_arguments

    add_arguments(p)


def main_hil_plant(args: argparse.Namespace) -> int:
    from bywire.hil import plant_main

    return plant_main.main(args)


def main_host_run(args: argparse.Namespace) -> int:
    if args.scenario is not None:  # the simulator's host process: its inputs come from a scenario
        from bywire.hil import host_process

        return host_process.main(args)
    from bywire.host import main as host_main

    return host_main.main(args)


def add_log_arguments(p: argparse.ArgumentParser) -> None:
    from bywire.host import log_cli

    log_cli.add_arguments(p.add_subparsers(dest="log_command", required=True, metavar="COMMAND"))


def main_log(args: argparse.Namespace) -> int:
    from bywire.hil.host_inputs import recorded_inputs
    from bywire.host import log_cli

    return log_cli.main(args, inputs_for=recorded_inputs)


if __name__ == "__main__":
    raise SystemExit(main())
