"""The `bywire` command behaves as a user of the field's command-line tools expects (README "Exit status").

- Building the parser, `--help`, a command's help and a tab completion import none of the heavy
  libraries (the mechanism behind `bywire --help` answering at once; its time is in `bywire bench cli`).
- Exit status: 0 done, 1 a run that failed its checks, 2 bad usage or input, 128 + N a signal; an
  error is one line, `error: WHERE: what`, never a traceback; a reader that goes away
  (`bywire hil list | head`) ends the command quietly.
- A SIL run stopped by SIGINT or SIGTERM still writes its JSON, with `"verdict": "interrupted"`.
- Progress only on a terminal: simulated time, speed and ETA; `--json -` writes only JSON to stdout.
- Shell completion through argcomplete.
"""

from __future__ import annotations

import json
import os
import pty
import re
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bywire.cli import COMMANDS, build_parser, main

HEAVY = ("numpy", "scipy", "networkx", "asn1tools", "pyproj", "fmpy", "cvxpy", "matplotlib", "rich")

# Runs `bywire ARGV` in a fresh interpreter and prints which heavy modules it imported.
IMPORTS_PROBE = """
import contextlib, io, json, sys
from bywire.cli import main
with contextlib.redirect_stdout(io.StringIO()):
    try:
        main(sys.argv[1:])
    except SystemExit:
        pass
print(json.dumps(sorted(m for m in {heavy!r} if m in sys.modules)))
"""


def _heavy_imports(argv: list[str], env: dict[str, str] | None = None) -> list[str]:
    done = subprocess.run(
        [sys.executable, "-c", IMPORTS_PROBE.format(heavy=HEAVY), *argv],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, **(env or {})},
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return list(json.loads(done.stdout.strip().splitlines()[-1]))


def _bywire(*argv: str, **kwargs: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "bywire", *argv], capture_output=True, text=True, timeout=120, **kwargs
    )  # type: ignore[call-overload, no-any-return]


# -- help and completion are light ---------------------------------------------------------------------


@pytest.mark.parametrize(
    "argv",
    [
        ["--help"],
        ["hil", "--help"],
        ["hil", "run", "--help"],
        ["hil", "list", "--help"],
        ["protocol", "table", "--help"],
        ["rndf", "check", "--help"],
        ["perception", "grid", "--help"],
        ["zone", "plan", "--help"],
        ["host", "run", "--help"],
        ["hil", "plant", "--help"],
        ["completion", "bash"],
    ],
)
def test_help_imports_none_of_the_heavy_libraries(argv: list[str]) -> None:
    assert _heavy_imports(argv) == []


def test_the_probe_sees_a_heavy_import() -> None:
    """The probe above is no tautology: a command whose module loads its subsystem shows it."""
    assert "numpy" in _heavy_imports(["platoon", "record-map", "--help"])


@pytest.mark.parametrize(
    ("argv", "loaded"),
    [
        (["--help"], []),
        (["hil", "list"], ["bywire.hil", "bywire.hil.hil_cli"]),
        (["protocol", "table"], ["bywire.protocol", "bywire.protocol.protocol_cli"]),
    ],
)
def test_the_parser_of_a_command_line_loads_only_that_command(argv: list[str], loaded: list[str]) -> None:
    probe = (
        "import sys; from bywire.cli import build_parser; build_parser(sys.argv[1:]); "
        "print(sorted(m for m in sys.modules if m.startswith('bywire.') and m != 'bywire.cli'))"
    )
    done = subprocess.run([sys.executable, "-c", probe, *argv], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == str(loaded)


def _complete(line: str, tmp_path: Path) -> list[str]:
    out = tmp_path / "completions"
    env = {
        "_ARGCOMPLETE": "1",
        "_ARGCOMPLETE_IFS": "\n",
        "COMP_LINE": line,
        "COMP_POINT": str(len(line)),
        "_ARGCOMPLETE_STDOUT_FILENAME": str(out),
    }
    done = _bywire(env={**os.environ, **env}, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    return [w.strip() for w in out.read_text().split("\n") if w.strip()]


def test_tab_completion_offers_commands_options_and_scenarios(tmp_path: Path) -> None:
    assert _complete("bywire hi", tmp_path) == ["hil"]
    assert set(_complete("bywire hil ", tmp_path)) >= {"run", "demo", "list"}
    assert "--json" in _complete("bywire hil run --js", tmp_path)
    assert "accel_steps" in _complete("bywire hil run acc", tmp_path)
    assert "flash" in _complete("bywire ecu fl", tmp_path)  # the ECU parses its own words


def test_completion_of_a_command_imports_only_its_parser() -> None:
    env = {"_ARGCOMPLETE": "1", "COMP_LINE": "bywire hil run --", "COMP_POINT": "17"}
    env["_ARGCOMPLETE_STDOUT_FILENAME"] = os.devnull
    probe = (
        "import os, sys\n"
        "from bywire.cli import main\n"
        f"heavy = {HEAVY!r}\n"
        "os._exit = lambda code: (print(sorted(m for m in heavy if m in sys.modules)), sys.stdout.flush(),"
        " sys.exit(code))\n"
        "main([])\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, env={**os.environ, **env}
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_completion_prints_the_shell_code(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["completion", "bash"]) == 0
    code = capsys.readouterr().out
    assert "complete" in code and "bywire" in code and "_ARGCOMPLETE" in code


# -- help texts and lists say what things are, not where they were asked for ---------------------------


def test_no_help_text_or_scenario_names_a_tracker_issue(capsys: pytest.CaptureFixture[str]) -> None:
    issue = re.compile(r"\bissues?\s*#?\d+", re.IGNORECASE)
    assert not [row.words for row in COMMANDS if issue.search(row.help)]
    assert main(["hil", "list"]) == 0
    listed = capsys.readouterr().out
    assert len(listed.splitlines()) > 10 and not issue.search(listed)


# -- exit status and error lines -----------------------------------------------------------------------


def test_an_output_in_a_missing_folder_is_bad_input_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "missing_dir" / "x.md"
    assert main(["protocol", "table", "--output", str(target)]) == 2
    err = capsys.readouterr().err
    assert err == f"error: {target}: No such file or directory\n"


def test_an_unknown_scenario_is_bad_input(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["hil", "run", "no_such_scenario"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: no_such_scenario: unknown scenario") and "Traceback" not in err


def test_bad_usage_exits_2() -> None:
    with pytest.raises(SystemExit) as exc:
        argv = ["hil", "run", "--mode", "sideways", "x"]
        build_parser(argv).parse_args(argv)
    assert exc.value.code == 2


def test_a_reader_that_goes_away_ends_the_command_quietly() -> None:
    """`bywire hil list | head -1`: the reader closes the pipe; no traceback, status 128 + SIGPIPE."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "bywire", "hil", "list"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # before the first line: every write of the command meets a closed pipe
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 128 + signal.SIGPIPE, err
    assert err == ""


# -- a run: JSON on stdout, progress on a terminal, interrupted by a signal ----------------------------


def test_json_dash_writes_only_json_to_stdout(capfd: pytest.CaptureFixture[str]) -> None:
    assert main(["hil", "run", "bad_calibration", "--json", "-"]) == 0
    out, err = capfd.readouterr()
    document = json.loads(out)  # the whole of stdout is one JSON document
    assert document["scenario"] == "bad_calibration" and document["verdict"] == "pass"
    assert "bad_calibration (sil): PASS" in err


def test_no_progress_when_stderr_is_not_a_terminal(capfd: pytest.CaptureFixture[str]) -> None:
    assert main(["hil", "run", "bad_calibration"]) == 0
    out, err = capfd.readouterr()
    assert "bad_calibration (sil): PASS" in out
    assert "simulated" not in err and "\r" not in err and "%" not in err


LONG_SCENARIO = """\
name: long_cruise
description: a long cruise, for stopping a run in the middle
duration_s: 600.0
vehicle: {v0_mps: 10.0}
host:
  mode: script
  engage_at_s: 0.3
  accel_profile: [[0.0, 0.0]]
checks:
  - {name: stays_engaged, metric: final_state, equals: ENGAGED}
"""

PROGRESS = re.compile(rb"(\d+\.\d)/600\.0 s simulated")


def _run_on_a_terminal_and_signal(tmp_path: Path, sig: signal.Signals) -> tuple[int, bytes, Path]:
    """A SIL run with stderr on a pseudo-terminal; `sig` once its progress line shows simulated time."""
    scenario = tmp_path / "long_cruise.yaml"
    scenario.write_text(LONG_SCENARIO)
    result = tmp_path / "run.json"
    terminal, child_side = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "bywire", "hil", "run", str(scenario), "--json", str(result)],
        stdout=subprocess.DEVNULL,
        stderr=child_side,
        env={**os.environ, "COLUMNS": "160", "TERM": "xterm"},
    )
    os.close(child_side)
    seen = b""
    signalled = False
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        ready, _, _ = select.select([terminal], [], [], 0.2)
        if ready:
            try:
                chunk = os.read(terminal, 4096)
            except OSError:  # the child closed its side: it has ended
                break
            if not chunk:
                break
            seen += chunk
        reached = [float(m) for m in PROGRESS.findall(seen)]
        if not signalled and reached and max(reached) > 1.0:
            proc.send_signal(sig)
            signalled = True
    os.close(terminal)
    assert signalled, seen[-2000:]
    return proc.wait(timeout=60), seen, result


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_run_stopped_by_a_signal_writes_its_json_as_interrupted(
    tmp_path: Path, sig: signal.Signals
) -> None:
    code, seen, result = _run_on_a_terminal_and_signal(tmp_path, sig)
    assert code == 128 + sig, seen[-2000:]
    document = json.loads(result.read_text())
    assert document["verdict"] == "interrupted" and document["signal"] == sig.name
    assert document["scenario"] == "long_cruise" and document["mode"] == "sil"
    assert 1.0 < document["simulated_s"] < 600.0 and document["duration_s"] == 600.0
    assert b"Traceback" not in seen
    assert f"INTERRUPTED by {sig.name}".encode() in seen
    # the progress line on the terminal: simulated time, speed (x real time) and time left
    assert PROGRESS.search(seen) and re.search(rb"x\d+\.\d", seen) and b"ETA" in seen
