"""Branch coverage of the ECU's safety authority by its spec tests, and nothing else.

Runs only the spec test files (tools/safety_scope.py) under coverage.py with branch measurement
restricted to the safety files, then prints one row per file -- for the two files that are only
partly safety logic, the row is that part -- with the missing branches as `file:line->line`, and
writes reports/safety_coverage.{json,md}.

Only the spec tests count: a branch that some HIL scenario happens to cross is not specified.

A branch that cannot be taken is excused in the source with coverage's own pragmas,
`# pragma: no branch` (a branch that never takes one of its ways) or `# pragma: no cover` (a line
that never runs), and the reason in the same comment:

    if not math.isfinite(x):  # pragma: no branch -- x comes from a float(int) above, always finite

Every such pragma in the safety scope is listed in the report with its reason; one without a
reason fails the run, since an excuse nobody can read is an untested branch.

Usage: tools/safety_coverage.py [--jobs N] [--fail-under PCT] [--html] [--tests FILE...] [--list-tests]
"""

from __future__ import annotations

import argparse
import io
import json
import re
import shutil
import subprocess
import sys
import time
import tokenize
from dataclasses import asdict, dataclass, field
from typing import Any

from safety_scope import ROOT, SafetySource, ScopeError, coverage_test_files, qualified_ranges, safety_sources

CONFIG = ROOT / "tools" / "safety_coverage.toml"
BUILD = ROOT / "build" / "safety_coverage"
REPORTS = ROOT / "reports"

# coverage's default pragmas (kept by tools/safety_coverage.toml), to find them and their reasons.
PRAGMA = re.compile(r"#?\s*(pragma|PRAGMA)[:\s]?\s*(no|NO)\s*(cover|COVER|branch|BRANCH)")
# What is left of a comment once the pragma is cut out must hold a word to count as a reason.
REASON_WORD = re.compile(r"[A-Za-z]{2,}")

_SUMMARY_KEYS = (
    "num_statements",
    "covered_lines",
    "missing_lines",
    "excluded_lines",
    "num_branches",
    "covered_branches",
    "missing_branches",
    "num_partial_branches",
)


@dataclass
class Pragma:
    line: int
    kind: str  # "no branch" or "no cover"
    reason: str  # "" when none was written


@dataclass
class FileResult:
    path: str
    scope: str  # "whole file" or the parts measured
    statements: int
    missing_lines: int
    branches: int
    covered_branches: int
    partial_branches: int
    missing_branch_arcs: list[str] = field(default_factory=list)
    missing_line_numbers: list[int] = field(default_factory=list)
    pragmas: list[Pragma] = field(default_factory=list)

    @property
    def branch_percent(self) -> float:
        return 100.0 if self.branches == 0 else 100.0 * self.covered_branches / self.branches


def _arc(path: str, arc: list[int]) -> str:
    src, dst = arc
    # coverage writes a jump out of a function as the negated line of its `def`
    return f"{path}:{src}->{'exit' if dst < 0 else dst}"


def _pragmas(source: str, lines: set[int] | None) -> list[Pragma]:
    found: list[Pragma] = []
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type != tokenize.COMMENT or (lines is not None and tok.start[0] not in lines):
            continue
        m = PRAGMA.search(tok.string)
        if m is None:
            continue
        rest = (tok.string[: m.start()] + " " + tok.string[m.end() :]).strip(" #-–—:;,.()[]")
        reason = rest if REASON_WORD.search(rest) else ""
        found.append(Pragma(tok.start[0], f"no {m.group(3).lower()}", reason))
    return found


def _scoped(src: SafetySource, data: dict[str, Any]) -> FileResult:
    """The file's numbers, or the sum over its parts (coverage's function and class regions)."""
    source = (ROOT / src.path).read_text(encoding="utf-8")
    if not src.parts:
        regions = [data]
        lines: set[int] | None = None
    else:
        regions = []
        ranges = qualified_ranges(source)
        lines = set()
        for part in src.parts:
            region = data["functions"].get(part) or data["classes"].get(part)
            if region is None or part not in ranges:
                raise ScopeError(f"{src.path}: no function or class {part} (see tools/safety_scope.py)")
            regions.append(region)
            first, last = ranges[part]
            lines.update(range(first, last + 1))
    total = dict.fromkeys(_SUMMARY_KEYS, 0)
    arcs: list[list[int]] = []
    missing: list[int] = []
    for region in regions:
        for key in _SUMMARY_KEYS:
            total[key] += int(region["summary"][key])
        arcs.extend(region["missing_branches"])
        missing.extend(region["missing_lines"])
    return FileResult(
        path=src.path,
        scope=", ".join(src.parts) if src.parts else "whole file",
        statements=total["num_statements"],
        missing_lines=total["missing_lines"],
        branches=total["num_branches"],
        covered_branches=total["covered_branches"],
        partial_branches=total["num_partial_branches"],
        missing_branch_arcs=[_arc(src.path, a) for a in sorted(arcs)],
        missing_line_numbers=sorted(missing),
        pragmas=_pragmas(source, lines),
    )


def _run_tests(sources: list[SafetySource], tests: list[str], jobs: int) -> int:
    if BUILD.exists():
        shutil.rmtree(BUILD)
    BUILD.mkdir(parents=True)
    include = ",".join(str(ROOT / s.path) for s in sources)
    cov = [sys.executable, "-m", "coverage"]
    pytest_args = ["-q", "-rfE", "-p", "no:cacheprovider", "-m", "not slow and not hil"]
    if jobs > 1:
        # per test, not per file: test_safety.py alone is half of the time
        pytest_args += ["-n", str(jobs), "--dist", "load"]
    data_file = f"--data-file={BUILD / '.coverage'}"
    cmd = [*cov, "run", f"--rcfile={CONFIG}", data_file, f"--include={include}", "-m", "pytest"]
    rc = subprocess.run([*cmd, *pytest_args, *tests], cwd=ROOT, check=False).returncode
    subprocess.run([*cov, "combine", "--quiet", f"--rcfile={CONFIG}", data_file], cwd=ROOT, check=True)
    return rc


def _json_report(html: bool) -> dict[str, Any]:
    out = BUILD / "coverage.json"
    cov = [sys.executable, "-m", "coverage"]
    common = [f"--rcfile={CONFIG}", f"--data-file={BUILD / '.coverage'}"]
    subprocess.run([*cov, "json", "--quiet", *common, "-o", str(out)], cwd=ROOT, check=True)
    if html:
        subprocess.run([*cov, "html", "--quiet", *common, "-d", str(BUILD / "html")], cwd=ROOT, check=True)
    data: dict[str, Any] = json.loads(out.read_text(encoding="utf-8"))
    return data


def _table(results: list[FileResult]) -> list[str]:
    head = ("file", "scope", "stmts", "miss", "branches", "br miss", "partial", "branch %")
    rows = [
        (
            r.path,
            r.scope,
            str(r.statements),
            str(r.missing_lines),
            str(r.branches),
            str(r.branches - r.covered_branches),
            str(r.partial_branches),
            f"{r.branch_percent:.1f}",
        )
        for r in results
    ]
    widths = [max(len(x) for x in col) for col in zip(head, *rows, strict=True)]
    fmt = "  ".join(f"{{:{'<' if i < 2 else '>'}{w}}}" for i, w in enumerate(widths))
    return [fmt.format(*head), fmt.format(*("-" * w for w in widths)), *(fmt.format(*r) for r in rows)]


def _markdown(results: list[FileResult], summary: dict[str, Any]) -> str:
    out = [
        "# Branch coverage of the safety authority by its spec tests",
        "",
        f"Tests: {', '.join(f'`{t}`' for t in summary['tests'])}"
        f" (pytest exit code {summary['pytest_exit_code']}, {summary['seconds']:.1f} s,"
        f" coverage.py {summary['coverage_version']}).",
        "",
        "| file | scope | statements | missed | branches | branches missed | partial | branch % |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in results:
        out.append(
            f"| `{r.path}` | {r.scope} | {r.statements} | {r.missing_lines} | {r.branches}"
            f" | {r.branches - r.covered_branches} | {r.partial_branches} | {r.branch_percent:.1f} |"
        )
    out += ["", "## Missing branches", ""]
    out += [f"- `{a}`" for r in results for a in r.missing_branch_arcs] or ["None."]
    out += ["", "## Excused by a pragma", ""]
    excused = [(r.path, p) for r in results for p in r.pragmas]
    out += [f"- `{path}:{p.line}` ({p.kind}): {p.reason or '**no reason given**'}" for path, p in excused]
    out += [] if excused else ["None."]
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--jobs", "-j", type=int, default=2, help="pytest-xdist workers (1: one process)")
    parser.add_argument(
        "--fail-under",
        type=float,
        default=None,
        metavar="PCT",
        help="fail when any file's (scoped) branch coverage is below PCT; off by default",
    )
    parser.add_argument("--html", action="store_true", help="also write build/safety_coverage/html")
    parser.add_argument(
        "--tests", nargs="+", metavar="FILE", help="run these test files instead of the spec (to investigate)"
    )
    parser.add_argument("--list-tests", action="store_true", help="print the spec test files and exit")
    args = parser.parse_args(argv)

    try:
        sources = safety_sources()
        tests = args.tests or coverage_test_files()
    except ScopeError as e:
        print(f"safety coverage: {e}", file=sys.stderr)
        return 2
    if args.list_tests:
        # one a line, for a Makefile that wants to leave these out of another pytest run
        print("\n".join(tests))
        return 0

    import coverage  # after the argument check, so --help works without the extra installed

    start = time.monotonic()
    pytest_rc = _run_tests(sources, tests, args.jobs)
    data = _json_report(args.html)
    seconds = time.monotonic() - start

    results: list[FileResult] = []
    problems: list[str] = []
    for src in sources:
        file_data = data["files"].get(src.path)
        if file_data is None or not file_data["executed_lines"]:
            # Not even the module's own `def` lines ran: either no chosen test imports it, or the
            # tests imported another copy (a non-editable install), so every number would be a lie.
            problems.append(f"{src.path}: no line of it ran (not imported, or imported from another copy)")
            continue
        try:
            results.append(_scoped(src, file_data))
        except ScopeError as e:
            problems.append(str(e))

    for line in _table(results):
        print(line)
    for r in results:
        if r.missing_branch_arcs:
            print(f"\nmissing branches, {r.path} ({r.scope}):")
            print("  " + "\n  ".join(r.missing_branch_arcs))
        for p in r.pragmas:
            print(f"excused: {r.path}:{p.line} ({p.kind}) {p.reason or '-- NO REASON GIVEN'}")
            if not p.reason:
                problems.append(f"{r.path}:{p.line}: `# pragma: {p.kind}` without a reason in its comment")
    if args.fail_under is not None:
        problems += [
            f"{r.path}: branch coverage {r.branch_percent:.1f} % is under {args.fail_under} %"
            for r in results
            if r.branch_percent < args.fail_under
        ]

    summary: dict[str, Any] = {
        "tests": tests,
        "pytest_exit_code": pytest_rc,
        "seconds": round(seconds, 2),
        "coverage_version": coverage.__version__,
        "files": [asdict(r) | {"branch_percent": round(r.branch_percent, 2)} for r in results],
        "problems": problems,
    }
    REPORTS.mkdir(exist_ok=True)
    (REPORTS / "safety_coverage.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    (REPORTS / "safety_coverage.md").write_text(_markdown(results, summary), encoding="utf-8")
    print(f"\nsafety coverage: {seconds:.1f} s; reports/safety_coverage.md, reports/safety_coverage.json")
    for problem in problems:
        print(f"safety coverage: {problem}", file=sys.stderr)
    if pytest_rc != 0:
        print(f"safety coverage: the spec tests failed (pytest exit code {pytest_rc})", file=sys.stderr)
        return pytest_rc
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
