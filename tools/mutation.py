"""Mutation testing of the safety authority's spec tests with mutmut (3.x): `make mutation`.

Each mutant is one small change to a safety file (`<` for `<=`, `and` for `or`, a constant off by
one, ...). A spec that lets a mutant pass has a hole: either a test is missing, or the mutant does
not change behaviour at all (an equivalent mutant), which is then written down with the reason in
docs/mutation_equivalents.toml.

Why a staging tree: mutmut copies the code into `mutants/` and puts that folder first on sys.path,
and it names each mutant after the file's path. Here the folders are not the import names (folder
`ecu/` is `bywire.ecu` through setuptools' package-dir, installed editable), so in the checkout
mutmut's copy would never be imported, and its names (`ecu.safety...`) would not match the
modules the tests call (`bywire.ecu.safety...`). So the script lays the package out under
build/mutation/stage the way Python imports it (bywire/ecu/safety.py, from pyproject.toml's own
mapping) with the tests beside it, and runs mutmut there: the mutated copy shadows the editable
install, and nothing in the checkout is ever modified (others may be editing it meanwhile).
Each mutant runs in a fresh import of the package (mutmut's forkserver isolation; see _stage).

Prints `mutation score: K/N killed`, the count of killed, equivalent and surviving mutants, and
every survivor with its file, line and diff; writes reports/mutation/report.{md,json} and
mutmut's own log.

Usage: tools/mutation.py [--mutate PATH]... [--tests FILE]... [--rev REV] [--jobs N]
                         [--max-minutes M] [--timeout-multiplier X] [--isolation forkserver|fork]
                         [--fail-under PCT]
       tools/mutation.py --report-only   (the last run again, after editing the equivalents)
"""

from __future__ import annotations

import argparse
import importlib.util
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tarfile
import time
import tomllib
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from safety_scope import (
    DEFAULT_MUTATE,
    ROOT,
    ScopeError,
    module_name,
    package_dirs,
    qualified_ranges,
    spec_test_files,
)

BUILD = ROOT / "build" / "mutation"
STAGE = BUILD / "stage"
REPORTS = ROOT / "reports" / "mutation"
EQUIVALENTS = ROOT / "docs" / "mutation_equivalents.toml"
PLUGIN = ROOT / "tools" / "mutation_pytest_plugin.py"
PRELOAD = "preload_modules.txt"  # in the staging tree

# mutmut is driven through its click group in a fresh interpreter; `python -m mutmut` would import
# its __main__ twice (mutmut warns), and the `mutmut` script may not be on PATH outside the venv.
MUTMUT = [sys.executable, "-c", "import sys; from mutmut.__main__ import cli; sys.exit(cli())"]
LIST_IMPORTS = (
    "import os, sys, pytest\n"
    "pytest.main(['--collect-only', '-qq', '-p', 'no:cacheprovider', *sys.argv[1:]])\n"
    "stage = os.path.realpath(os.getcwd()) + os.sep\n"
    "for name in sorted({m.partition('.')[0] for m in list(sys.modules)}):\n"
    "    f = getattr(sys.modules.get(name), '__file__', None)\n"
    "    if name in sys.stdlib_module_names or name.startswith('_') or name == 'bywire' or not f:\n"
    "        continue\n"
    "    if not os.path.realpath(f).startswith(stage):\n"
    "        print(name)\n"
)
SHOW_ALL = (
    "import sys\n"
    "from mutmut.__main__ import cli\n"
    "for name in sys.argv[1:]:\n"
    "    print('@@mutant ' + name, flush=True)\n"
    "    cli.main(['show', name], standalone_mode=False)\n"
)

# mutmut's statuses (mutmut/stats.py), sorted into what the score counts. A timeout, a crash or a
# type error is a detected mutant; "no tests" means no spec test even calls the function.
KILLED = {"killed", "timeout", "segfault", "caught by type check"}
SURVIVED = {"survived", "no tests"}

MUTANT_NAME = re.compile(r"^(?P<module>[\w.]+)\.x(?P<mangled>[^.]+)__mutmut_(?P<n>\d+)$")
HUNK = re.compile(r"^@@ -(\d+)(?:,(\d+))? \+(\d+)(?:,(\d+))? @@")


@dataclass
class Mutant:
    name: str  # mutmut's, e.g. bywire.ecu.safety.x_safety_step__mutmut_9: shifts with every edit
    status: str
    file: str = ""  # folder path in the checkout, e.g. ecu/safety.py
    function: str = ""  # qualified, e.g. safety_step or TxGuard.check
    line: int = 0  # first changed line in the file as it was staged
    original: str = ""  # the changed source line(s), stripped: with `mutant`, the stable identity
    mutant: str = ""
    # the changed line's text may appear more than once in its function (the same guard in two
    # branches): then which appearance, counted from the top, is part of the identity
    occurrence: int = 1
    occurrences: int = 1
    diff: str = ""
    reason: str = ""  # why it is equivalent, from docs/mutation_equivalents.toml


@dataclass
class Equivalent:
    file: str
    function: str
    original: str
    mutant: str
    reason: str
    occurrence: int | None = None  # needed only when the original line appears twice in the function
    matched: list[str] = field(default_factory=list)
    ambiguous: list[str] = field(default_factory=list)


def _toml_value(v: object) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, str):
        # a JSON string is a TOML basic string (same escapes); non-ASCII stays UTF-8 text
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} as TOML")


def _toml_table(name: str, table: dict[str, Any]) -> str:
    return f"[{name}]\n" + "".join(f"{k} = {_toml_value(v)}\n" for k, v in table.items())


def _export(rev: str, dest: Path) -> Path:
    """The tree of a commit, without touching the checkout or git's state (`git archive`)."""
    folders = sorted(set(package_dirs().values()))
    cmd = ["git", "-C", str(ROOT), "archive", "--format=tar", rev, "--", "pyproject.toml", "tests", *folders]
    tar = subprocess.run(cmd, check=True, capture_output=True).stdout
    dest.mkdir(parents=True)
    with tarfile.open(fileobj=io.BytesIO(tar)) as t:
        t.extractall(dest, filter="data")
    return dest


def _third_party_modules(tests: list[str]) -> list[str]:
    """Top-level modules that collecting the tests imports from outside the staging tree and the
    standard library: what the fork server may import once for every mutant (numpy, cantools, ...)."""
    out = subprocess.run(
        [sys.executable, "-c", LIST_IMPORTS, *tests], cwd=STAGE, capture_output=True, text=True, check=False
    )
    names = [line for line in out.stdout.splitlines() if re.fullmatch(r"[A-Za-z]\w*", line)]
    if out.returncode != 0 or not names:
        # only the speed of the run depends on this list, so carry on without it
        print(f"mutation: could not list the tests' imports; each mutant imports all:\n{out.stderr[-2000:]}")
    return names


def _stage(src: Path, mutate: list[str], tests: list[str], args: argparse.Namespace) -> dict[str, str]:
    """Lay out the package as Python imports it; returns staged path -> checkout path of each file
    to mutate."""
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", ".hypothesis", ".pytest_cache", "build")
    # parents before children: bywire/ first, then ecu/ into bywire/ecu
    for package, folder in sorted(package_dirs(src).items(), key=lambda kv: kv[0].count(".")):
        shutil.copytree(src / folder, STAGE.joinpath(*package.split(".")), ignore=ignore, dirs_exist_ok=True)
    shutil.copytree(src / "tests", STAGE / "tests", ignore=ignore)
    shutil.copy2(PLUGIN, STAGE / PLUGIN.name)

    staged = {module_name(p, src).replace(".", "/") + ".py": p for p in mutate}
    with (src / "pyproject.toml").open("rb") as f:
        pytest_ini = tomllib.load(f)["tool"]["pytest"]["ini_options"]
    mutmut = {
        "source_paths": ["bywire"],
        "only_mutate": sorted(staged),
        "pytest_add_cli_args_test_selection": tests,
        "pytest_add_cli_args": [
            "-p",
            "no:cacheprovider",
            "-p",
            PLUGIN.stem,
            "-m",
            "not slow and not hil",
        ],
        "also_copy": [PLUGIN.name],
        # A mutant gets 2 * multiplier * (its tests' clean time + constant) seconds of CPU, then
        # SIGXCPU: a mutant that turns a loop endless is a timeout (counted as killed), not a hang.
        "timeout_multiplier": args.timeout_multiplier,
        "timeout_constant": 1.0,
    }
    if args.isolation == "forkserver":
        # Each mutant's tests run in a child of a server that has imported only third-party
        # modules, so the mutated module is imported afresh under the mutant: code that runs at
        # import (tables built once) and state a module keeps (caches) are the mutant's own. In
        # mutmut's default `fork` mode children inherit the parent's modules, already imported
        # and warmed by the clean run, and such mutants survive without being tested (protocol/
        # e2e.py: 88 of 132 killed under fork, 120 under forkserver).
        mutmut |= {
            "process_isolation": "forkserver",
            "forkserver_warmup": "import",
            "preload_modules_file": PRELOAD,
        }
    (STAGE / "pyproject.toml").write_text(
        "# Written by tools/mutation.py for one run; edit that script, not this file.\n\n"
        + _toml_table("tool.pytest.ini_options", pytest_ini)
        + "\n"
        + _toml_table("tool.mutmut", mutmut),
        encoding="utf-8",
    )
    if args.isolation == "forkserver":
        # after the pyproject.toml above: without it pytest would take the checkout's, and its
        # `pythonpath = ["tests"]` would import the checkout's test helpers
        (STAGE / PRELOAD).write_text("\n".join(_third_party_modules(tests)) + "\n", encoding="utf-8")
    return staged


def _run_mutmut(jobs: int, max_minutes: float, log: Path) -> int:
    deadline = time.monotonic() + max_minutes * 60
    next_note = time.monotonic() + 30
    with log.open("wb") as out:
        # its own session, so that the whole group (mutmut forks a worker per mutant) can be
        # stopped by this one id at the deadline
        proc = subprocess.Popen(
            [*MUTMUT, "run", "--max-children", str(jobs)],
            cwd=STAGE,
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        while True:
            try:
                return proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                pass
            now = time.monotonic()
            if now > deadline:
                print(f"mutation: stopping mutmut after {max_minutes:g} min (--max-minutes)", flush=True)
                os.killpg(proc.pid, signal.SIGTERM)
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
                return -1
            if now > next_note:
                next_note = now + 30
                print(f"mutation: {_progress(log)}", flush=True)


def _progress(log: Path) -> str:
    """mutmut's last spinner line ("12/209 🎉 10 ..."), which it redraws with carriage returns."""
    tail = log.read_bytes()[-4000:].decode("utf-8", "replace")
    parts = [p.strip() for p in re.split(r"[\r\n]", tail) if p.strip()]
    return parts[-1].lstrip("⠋⠙⠹⠸⠼⠴⠦⠧⠇⠏ ") if parts else "starting"


def _log_tail(log: Path, lines: int = 40) -> str:
    text = log.read_bytes().decode("utf-8", "replace")
    kept = [
        p for p in re.split(r"\r|\n", text) if p.strip() and not p.lstrip().startswith(tuple("⠋⠙⠹⠸⠼⠴⠦⠧⠇⠏"))
    ]
    return "\n".join(kept[-lines:])


def _results() -> list[Mutant]:
    out = subprocess.run([*MUTMUT, "results", "--all", "true"], cwd=STAGE, capture_output=True, text=True)
    mutants = []
    for line in out.stdout.splitlines():
        name, sep, status = line.strip().rpartition(": ")
        if sep and MUTANT_NAME.match(name):
            mutants.append(Mutant(name=name, status=status))
    if out.returncode != 0 or not mutants:
        raise RuntimeError(f"`mutmut results` gave nothing readable:\n{out.stdout}\n{out.stderr}")
    return mutants


def _function(mangled: str) -> str:
    # mutmut mangles a function f as `_f` and a method C.m as `ǁCǁm` (after the leading x)
    if mangled.startswith("ǁ"):
        return ".".join(p for p in mangled.split("ǁ") if p)
    return mangled.removeprefix("_")


def _describe(mutants: list[Mutant], staged: dict[str, str]) -> None:
    """Fill in file, function, line, the changed text and a diff numbered like the file."""
    by_module = {path.removesuffix(".py").replace("/", "."): path for path in staged}
    shown = subprocess.run(
        [sys.executable, "-c", SHOW_ALL, *(m.name for m in mutants)],
        cwd=STAGE,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    diffs: dict[str, list[str]] = {}
    current: list[str] = []
    for line in shown.splitlines():
        if line.startswith("@@mutant "):
            current = diffs.setdefault(line.removeprefix("@@mutant "), [])
        else:
            current.append(line)
    sources: dict[str, list[str]] = {}
    ranges: dict[str, dict[str, tuple[int, int]]] = {}
    for m in mutants:
        match = MUTANT_NAME.match(m.name)
        assert match is not None  # _results keeps only names that match
        staged_path = by_module[match["module"]]
        m.file = staged[staged_path]
        m.function = _function(match["mangled"])
        if staged_path not in sources:
            sources[staged_path] = (STAGE / staged_path).read_text(encoding="utf-8").splitlines()
            ranges[staged_path] = qualified_ranges((STAGE / staged_path).read_text(encoding="utf-8"))
        _locate(m, diffs.get(m.name, []), sources[staged_path], ranges[staged_path])


def _locate(m: Mutant, lines: list[str], source: list[str], ranges: dict[str, tuple[int, int]]) -> None:
    """mutmut's diff is numbered from the function's first line; renumber it like the file. The
    removed text is looked up in the function's lines, nearest to where the numbering says, since
    libcst may count a comment above the `def` as part of the function."""
    removed: list[tuple[int, str]] = []
    added: list[str] = []
    old = 0
    for line in lines:
        if (h := HUNK.match(line)) is not None:
            old = int(h[1])
        elif line.startswith("-") and not line.startswith("---"):
            removed.append((old, line[1:]))
            old += 1
        elif line.startswith("+") and not line.startswith("+++"):
            added.append(line[1:])
        elif line.startswith(" "):
            old += 1
    m.original = "\n".join(text.strip() for _, text in removed)
    m.mutant = "\n".join(text.strip() for text in added)
    first, last = ranges.get(m.function, (1, len(source)))
    offset = first - 1
    if removed:
        rel, text = removed[0]
        candidates = [n for n in range(first, last + 1) if source[n - 1] == text]
        if candidates:
            at = min(candidates, key=lambda n: abs(n - (first - 1 + rel)))
            offset = at - rel
            m.occurrence, m.occurrences = candidates.index(at) + 1, len(candidates)
        m.line = rel + offset
    else:
        m.line = first
    body = []
    for line in lines:
        if (h := HUNK.match(line)) is not None:
            a, b, c, d = h.groups()
            b = f",{b}" if b is not None else ""
            d = f",{d}" if d is not None else ""
            body.append(f"@@ -{int(a) + offset}{b} +{int(c) + offset}{d} @@ {m.function}")
        elif not line.startswith(("# ", "---", "+++")) and (body or line.startswith("@@")):
            body.append(line)
    m.diff = "\n".join([f"--- {m.file}", f"+++ {m.file} (mutant)", *body])


def _load_equivalents(path: Path) -> list[Equivalent]:
    if not path.is_file():
        return []
    with path.open("rb") as f:
        entries = tomllib.load(f).get("equivalent", [])
    out = []
    for i, e in enumerate(entries, 1):
        missing = {"file", "function", "original", "mutant", "reason"} - set(e)
        if missing:
            raise ValueError(f"{path}: entry {i} lacks {', '.join(sorted(missing))}")
        if not re.search(r"[A-Za-z]{2,}", e["reason"]) or e["reason"].strip().upper().startswith("TODO"):
            raise ValueError(f"{path}: entry {i} ({e['file']} {e['function']}) has no reason yet")
        occurrence = e.get("occurrence")
        if occurrence is not None and (not isinstance(occurrence, int) or occurrence < 1):
            raise ValueError(f"{path}: entry {i}: occurrence must be a whole number from 1")
        out.append(
            Equivalent(
                e["file"], e["function"], e["original"].strip(), e["mutant"].strip(), e["reason"], occurrence
            )
        )
    return out


def _snippet(m: Mutant) -> str:
    """The entry that marks this mutant equivalent, for the author to paste and explain."""
    return "\n".join(
        [
            "[[equivalent]]",
            f"file = {_toml_value(m.file)}",
            f"function = {_toml_value(m.function)}",
            f"original = {_toml_value(m.original)}",
            f"mutant = {_toml_value(m.mutant)}",
            *([f"occurrence = {m.occurrence}"] if m.occurrences > 1 else []),
            'reason = "TODO: why no test can tell this mutant from the original"',
        ]
    )


def _report(
    mutants: list[Mutant],
    equivalents: list[Equivalent],
    meta: dict[str, Any],
) -> tuple[str, dict[str, Any]]:
    killed = [m for m in mutants if m.status in KILLED]
    equivalent = [m for m in mutants if m.status in SURVIVED and m.reason]
    surviving = [m for m in mutants if m.status in SURVIVED and not m.reason]
    unresolved = [m for m in mutants if m.status not in KILLED | SURVIVED]
    # an entry about a file this run did not mutate, or did not finish, is not stale: not judged
    stale = [
        e
        for e in equivalents
        if not e.matched and not e.ambiguous and e.file in meta["mutate"] and meta["completed"]
    ]
    ambiguous = [e for e in equivalents if e.ambiguous]
    timeouts = sum(m.status != "killed" for m in killed)
    counts = (
        f"{len(killed)} killed"
        + (f" ({timeouts} by timeout or crash)" if timeouts else "")
        + f", {len(equivalent)} equivalent (explained), {len(surviving)} surviving"
        + (f", {len(unresolved)} unresolved (not run or suspicious)" if unresolved else "")
    )
    score = f"mutation score: {len(killed)}/{len(mutants)} killed"

    md = [
        "# Mutation testing of the safety authority",
        "",
        f"- files mutated: {', '.join(f'`{f}`' for f in meta['mutate'])}",
        f"- tests: {', '.join(f'`{t}`' for t in meta['tests'])}",
        f"- code: {meta['code']}; mutmut {meta['mutmut_version']} ({meta['isolation']}),"
        f" {meta['jobs']} workers, {meta['seconds']:.0f} s, {meta['date']}",
        "",
        f"**{score}**: {counts}.",
        "",
        "| file | function | mutants | killed | equivalent | surviving |",
        "|---|---|---:|---:|---:|---:|",
    ]
    per_function: dict[tuple[str, str], list[Mutant]] = {}
    for m in mutants:
        per_function.setdefault((m.file, m.function), []).append(m)
    for (file, function), ms in sorted(per_function.items()):
        n_eq = sum(m in equivalent for m in ms)
        n_sv = sum(m in surviving for m in ms)
        md.append(
            f"| `{file}` | `{function}` | {len(ms)} | {sum(m in killed for m in ms)} | {n_eq} | {n_sv} |"
        )
    md += ["", "## Surviving mutants", ""]
    for m in surviving:
        note = " (no spec test calls this function)" if m.status == "no tests" else ""
        md += [f"### `{m.file}:{m.line}` in `{m.function}`{note}", "", f"mutmut: `{m.name}`", ""]
        md += ["```diff", m.diff, "```", "", "Equivalent? Add to `docs/mutation_equivalents.toml`:", ""]
        md += ["```toml", _snippet(m), "```", ""]
    if not surviving:
        md += ["None.", ""]
    md += ["## Equivalent mutants (explained)", ""]
    for m in equivalent:
        md += [f"### `{m.file}:{m.line}` in `{m.function}`", "", m.reason, "", "```diff", m.diff, "```", ""]
    if not equivalent:
        md += ["None.", ""]
    if stale:
        md += [
            "## Stale entries in docs/mutation_equivalents.toml",
            "",
            "They match no surviving mutant now:",
            "",
        ]
        md += [f"- `{e.file}` `{e.function}`: `{e.original}` -> `{e.mutant}`" for e in stale]
        md += [""]
    if ambiguous:
        md += ["## Ambiguous entries in docs/mutation_equivalents.toml (not applied)", ""]
        md += [
            f"- `{e.file}` `{e.function}`: `{e.original}` -> `{e.mutant}` appears more than once in"
            " the function: add `occurrence = N` (1 = the topmost)"
            for e in ambiguous
        ]
        md += [""]
    if unresolved:
        md += ["## Unresolved", ""]
        md += [f"- `{m.file}:{m.line}` `{m.function}`: {m.status} (`{m.name}`)" for m in unresolved]
        md += [""]

    data = {
        **meta,
        "score": score,
        "killed": len(killed),
        "timeouts": timeouts,
        "equivalent": len(equivalent),
        "surviving": len(surviving),
        "unresolved": len(unresolved),
        "total": len(mutants),
        "mutants": [asdict(m) for m in mutants],
        "counts": counts,
        "stale_equivalents": [asdict(e) for e in stale],
        "ambiguous_equivalents": [asdict(e) for e in ambiguous],
    }
    return "\n".join(md), data


def _mutate(args: argparse.Namespace) -> int:
    """Stage, run mutmut, and record what the report needs in build/mutation/run.json."""
    try:
        mutate = args.mutate or [p for p in DEFAULT_MUTATE if (ROOT / p).is_file()]
        tests = args.tests or spec_test_files()
    except ScopeError as e:
        print(f"mutation: {e}", file=sys.stderr)
        return 2
    if BUILD.exists():
        shutil.rmtree(BUILD)
    STAGE.mkdir(parents=True)
    REPORTS.mkdir(parents=True, exist_ok=True)
    src = _export(args.rev, BUILD / "src") if args.rev else ROOT
    for path in [*mutate, *tests]:
        if not (src / path).is_file():
            print(f"mutation: {path} does not exist in {'the checkout' if src == ROOT else args.rev}")
            return 2
    staged = _stage(src, mutate, tests, args)

    start = time.monotonic()
    log = REPORTS / "mutmut.log"
    print(
        f"mutation: mutmut on {', '.join(mutate)} with {len(tests)} test files; log {log.relative_to(ROOT)}"
    )
    rc = _run_mutmut(args.jobs, args.max_minutes, log)
    seconds = time.monotonic() - start
    if rc > 0:
        # clean tests failing, or the forced-fail check: nothing below would mean anything
        print(_log_tail(log), file=sys.stderr)
        print(f"mutation: mutmut failed (exit code {rc}); see {log.relative_to(ROOT)}", file=sys.stderr)
        return rc

    git = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--short", args.rev or "HEAD"], capture_output=True
    )
    commit = git.stdout.decode().strip()
    import mutmut

    run = {
        "mutate": mutate,
        "tests": tests,
        "staged": staged,
        "code": f"commit {commit}" if args.rev else f"working tree (on {commit}, edits included)",
        "mutmut_version": getattr(mutmut, "__version__", "?"),
        "jobs": args.jobs,
        "isolation": args.isolation,
        "seconds": round(seconds, 1),
        "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "completed": rc == 0,
    }
    (BUILD / "run.json").write_text(json.dumps(run, indent=2) + "\n", encoding="utf-8")
    return 0


def _summarise(equivalents: list[Equivalent], fail_under: float | None) -> int:
    """Read the last run's verdicts from its stage, subtract the equivalents, print and write."""
    run = json.loads((BUILD / "run.json").read_text(encoding="utf-8"))
    staged: dict[str, str] = run.pop("staged")
    mutants = _results()
    not_killed = [m for m in mutants if m.status not in KILLED]
    _describe(not_killed, staged)
    module_file = {path.removesuffix(".py").replace("/", "."): p for path, p in staged.items()}
    for m in mutants:
        if not m.file:  # killed: the file and function are enough, no diff asked of mutmut
            match = MUTANT_NAME.match(m.name)
            assert match is not None  # _results keeps only names that match
            m.file, m.function = module_file[match["module"]], _function(match["mangled"])
    for m in not_killed:
        if m.status not in SURVIVED:
            continue
        for e in equivalents:
            if (e.file, e.function, e.original, e.mutant) != (m.file, m.function, m.original, m.mutant):
                continue
            if e.occurrence is None and m.occurrences > 1:
                e.ambiguous.append(m.name)  # would excuse every appearance at once: refuse
            elif e.occurrence in (None, m.occurrence):
                m.reason = e.reason
                e.matched.append(m.name)

    md, data = _report(mutants, equivalents, run)
    REPORTS.mkdir(parents=True, exist_ok=True)
    (REPORTS / "report.md").write_text(md + "\n", encoding="utf-8")
    (REPORTS / "report.json").write_text(
        json.dumps(data, indent=2, ensure_ascii=False) + "\n", encoding="utf-8"
    )

    print(f"mutation: mutmut ran {run['seconds']:.0f} s; full report in reports/mutation/report.md")
    print(data["score"])
    print(data["counts"])
    for m in mutants:
        if m.status in SURVIVED and not m.reason:
            note = " (no spec test calls it)" if m.status == "no tests" else ""
            print(f"\nsurviving: {m.file}:{m.line} in {m.function}{note}  [{m.name}]")
            print(m.diff)
    for e in data["stale_equivalents"]:
        print(
            f"\nstale equivalent (no survivor matches): {e['file']} {e['function']}:"
            f" {e['original']!r} -> {e['mutant']!r}"
        )
    for e in data["ambiguous_equivalents"]:
        print(
            f"\nambiguous equivalent, not applied: {e['file']} {e['function']}: {e['original']!r}"
            " appears more than once in the function; add occurrence = N (1 = the topmost)",
            file=sys.stderr,
        )
    if data["ambiguous_equivalents"]:
        return 1
    if not run["completed"]:
        print("mutation: incomplete run (--max-minutes); mutants not run are unresolved", file=sys.stderr)
        return 1
    if fail_under is not None:
        judged = data["total"] - data["equivalent"]
        if judged and 100.0 * data["killed"] / judged < fail_under:
            print(f"mutation: killed {data['killed']}/{judged} is under {fail_under} %", file=sys.stderr)
            return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--mutate", action="append", metavar="PATH", help="file to mutate, as in the checkout"
    )
    parser.add_argument("--tests", action="append", metavar="FILE", help="test file to run (repeatable)")
    parser.add_argument("--rev", help="mutate this commit's tree (git archive) instead of the working tree")
    parser.add_argument("--jobs", "-j", type=int, default=os.cpu_count() or 2, help="mutants run at once")
    parser.add_argument("--max-minutes", type=float, default=30.0, help="stop mutmut after this long")
    parser.add_argument(
        "--timeout-multiplier",
        type=float,
        default=3.0,
        help="a mutant's CPU budget is 2 * this * (its tests' clean time + 1 s)",
    )
    parser.add_argument(
        "--isolation",
        choices=("forkserver", "fork"),
        default="forkserver",
        help="forkserver (default): every mutant imports the package afresh; fork: faster, but"
        " code run at import and cached state are not mutated",
    )
    parser.add_argument("--equivalents", type=Path, default=EQUIVALENTS, help="explained equivalent mutants")
    parser.add_argument(
        "--report-only",
        action="store_true",
        help="no new run: report the last one again (after editing the equivalents)",
    )
    parser.add_argument(
        "--fail-under", type=float, metavar="PCT", help="fail when killed/(all-equivalent) < PCT"
    )
    args = parser.parse_args(argv)

    if importlib.util.find_spec("mutmut") is None:
        print("mutation: mutmut is not installed: pip install -e '.[mutation]'", file=sys.stderr)
        return 2
    try:
        equivalents = _load_equivalents(args.equivalents)
    except ValueError as e:
        print(f"mutation: {e}", file=sys.stderr)
        return 2
    if args.report_only:
        if not (BUILD / "run.json").is_file():
            print("mutation: no earlier run in build/mutation to report", file=sys.stderr)
            return 2
    else:
        rc = _mutate(args)
        if rc != 0:
            return rc
    return _summarise(equivalents, args.fail_under)


if __name__ == "__main__":
    sys.exit(main())
