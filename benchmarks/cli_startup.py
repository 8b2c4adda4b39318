"""`bywire bench cli`: how long the `bywire` command takes to answer, as a user's shell sees it.

Target: `bywire --help` under 0.3 s, like the field's other command-line tools (`candump`, `cantools
--help`); before the parser was built lazily it took 3-4.5 s, because building it imported numpy,
scipy, networkx, asn1tools, pyproj, fmpy and cvxpy. Each row is a fresh process (the cost a user
pays every time), timed `--repeats` times interleaved with the others so that machine load hits all
rows alike (median / p99 / max, ms):

- ``python``: `python -c pass`, the interpreter's own start: the floor, and the baseline of the ratios;
- ``--help``: `bywire --help`, the contract's row;
- ``hil run --help``, ``protocol table --help``, ``v2x --help``, ``completion bash``: a command's own
  parser (only that command's module is imported), and the shell's completion code;
- ``complete``: one tab completion (`bywire hil r<TAB>`), argcomplete's request as bash sends it.

JSON (``--json``): ``{"repeats", "target_s", "rows": {name: {"median_ms", "p99_ms", "max_ms"}},
"over_python": {name: ratio of medians}, "help_within_target": bool}``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

TARGET_S = 0.3
DEFAULT_REPEATS = 20

# (row, argv after the interpreter, extra environment)
ROWS: tuple[tuple[str, tuple[str, ...], dict[str, str]], ...] = (
    ("python", ("-c", "pass"), {}),
    ("--help", ("-m", "bywire", "--help"), {}),
    ("hil run --help", ("-m", "bywire", "hil", "run", "--help"), {}),
    ("protocol table --help", ("-m", "bywire", "protocol", "table", "--help"), {}),
    ("v2x --help", ("-m", "bywire", "v2x", "--help"), {}),
    ("completion bash", ("-m", "bywire", "completion", "bash"), {}),
    (
        "complete",
        ("-m", "bywire"),
        {
            "_ARGCOMPLETE": "1",
            "_ARGCOMPLETE_IFS": " ",
            "COMP_LINE": "bywire hil r",
            "COMP_POINT": str(len("bywire hil r")),
            "_ARGCOMPLETE_STDOUT_FILENAME": os.devnull,
        },
    ),
)


def _stats_ms(samples_s: list[float]) -> dict[str, float]:
    ms = sorted(s * 1e3 for s in samples_s)
    return {
        "median_ms": round(statistics.median(ms), 1),
        "p99_ms": round(ms[int(0.99 * (len(ms) - 1))], 1),
        "max_ms": round(ms[-1], 1),
    }


def _time_once(argv: tuple[str, ...], env: dict[str, str]) -> float:
    t0 = time.perf_counter()
    done = subprocess.run(
        [sys.executable, *argv],
        env={**os.environ, **env},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        check=False,
    )
    elapsed = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} exited {done.returncode}: {done.stderr.decode()[-500:]}")
    return elapsed


def run(repeats: int) -> dict[str, object]:
    samples: dict[str, list[float]] = {name: [] for name, _, _ in ROWS}
    for _ in range(repeats):
        for name, argv, env in ROWS:
            samples[name].append(_time_once(argv, env))
    rows = {name: _stats_ms(s) for name, s in samples.items()}
    floor = rows["python"]["median_ms"]
    return {
        "repeats": repeats,
        "target_s": TARGET_S,
        "rows": rows,
        "over_python": {name: round(r["median_ms"] / floor, 2) for name, r in rows.items()},
        "help_within_target": rows["--help"]["median_ms"] <= TARGET_S * 1e3,
    }


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--repeats", type=int, default=DEFAULT_REPEATS, help="processes per row")
    p.add_argument("--json", type=Path, help="write the figures as JSON to this file")


def main(args: argparse.Namespace) -> int:
    result = run(args.repeats)
    rows = result["rows"]
    assert isinstance(rows, dict)
    print(f"{'row':24s} {'median ms':>10s} {'p99 ms':>8s} {'max ms':>8s} {'/python':>8s}")
    for name, r in rows.items():
        ratio = result["over_python"][name]  # type: ignore[index]
        print(f"{name:24s} {r['median_ms']:10.1f} {r['p99_ms']:8.1f} {r['max_ms']:8.1f} {ratio:8.2f}")
    verdict = "within" if result["help_within_target"] else "OVER"
    print(f"bywire --help: {verdict} the {TARGET_S * 1e3:.0f} ms target (median)")
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(parser)
    raise SystemExit(main(parser.parse_args()))
