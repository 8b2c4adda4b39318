"""The command every timed `bywire bench NAME` shares: `--seconds` and `--json`, run, print the table,
write the document. Each benchmark module keeps only what is its own: `run(seconds) -> doc` and its
table (DESIGN.md section 5: distributions and ratios from one run, never asserted)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any


def add_timed_arguments(p: argparse.ArgumentParser, default_seconds: float, what: str) -> None:
    """`--json FILE` and `--seconds S`; `what` completes the help "roughly how long ... (default S)"."""
    p.add_argument("--json", type=Path, metavar="FILE", help="write the results as JSON")
    p.add_argument(
        "--seconds",
        type=float,
        default=default_seconds,
        help=f"roughly how long {what} (default {default_seconds:g})",
    )


def run_timed(
    args: argparse.Namespace,
    name: str,
    default_seconds: float,
    run: Callable[[float], dict[str, Any]],
    print_table: Callable[[dict[str, Any]], None],
) -> int:
    """Run a benchmark as `bywire bench NAME` does: exit 2 on a bad --seconds, else 0."""
    seconds = default_seconds if getattr(args, "seconds", None) is None else float(args.seconds)
    if not (math.isfinite(seconds) and seconds > 0.0):
        print(f"bywire bench {name}: --seconds {seconds:g} must be > 0", file=sys.stderr)
        return 2
    doc = run(seconds)
    print_table(doc)
    out: Path | None = getattr(args, "json", None)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    return 0
