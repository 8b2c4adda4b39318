"""`bywire campaign run|report|list`: many SIL runs of the shipped scenarios over grids and draws of
their parameters, on this machine's cores or a Ray cluster, and what they add up to (docs/campaigns.md).

Exit status (README "Exit status"): `run` 0 when every run passed, 1 when one failed or raised, 2 for a
bad campaign file, folder or address, 128 + N when stopped by signal N (what finished is kept: resume
with `--resume DIR`); `report` 0 when every run passed, 1 otherwise, 2 for a folder that holds no
campaign; `compare` 0 when no run that passed in BASE fails in NEW (with `--identical`: when every
matched run is the same, bit for bit, but for the wall clock's columns), 1 otherwise, 2 for folders
that hold no campaign or no run in common.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
from pathlib import Path
from typing import Any


def _complete_campaign(prefix: str, **kwargs: Any) -> list[str]:
    from argcomplete.completers import FilesCompleter

    from bywire.hil.campaign.spec import builtin_campaigns

    names = [n for n in builtin_campaigns() if n.startswith(prefix)]
    return names + list(FilesCompleter(("yaml", "yml"))(prefix, **kwargs))


def add_run_arguments(p: argparse.ArgumentParser) -> None:
    spec = p.add_argument(
        "spec", help="a shipped campaign's name (see `bywire campaign list`) or a campaign file"
    )
    spec.completer = _complete_campaign  # type: ignore[attr-defined]
    p.add_argument("--out", type=Path, help="a new or empty folder for the campaign's results")
    p.add_argument(
        "--resume",
        type=Path,
        metavar="DIR",
        help="continue the campaign in DIR (started with the same file): runs not finished there, none twice",
    )
    p.add_argument(
        "--address",
        help="run on Ray instead of this machine's process pool: ray://HOST:PORT (Ray Client), auto (the "
        "cluster this machine is in), local (a Ray instance started for the campaign); needs bywire[cluster]",
    )
    p.add_argument("--workers", type=int, help="runs at a time (default: every core of the pool or cluster)")
    p.add_argument("--quiet", action="store_true", help="no progress line (drawn only on a terminal)")


def main_run(args: argparse.Namespace) -> int:
    from bywire.hil.campaign import runner
    from bywire.hil.campaign.report import summarise, write_report
    from bywire.hil.campaign.spec import load_campaign
    from bywire.hil.run_progress import wants_progress
    from bywire.process_util import signals_interrupt

    if args.out is None and args.resume is None:
        raise ValueError("campaign run: give --out DIR (a new campaign) or --resume DIR (a stopped one)")
    if args.out is not None and args.resume is not None and args.out.resolve() != args.resume.resolve():
        raise ValueError(f"campaign run: --out {args.out} and --resume {args.resume} name two folders")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"campaign run: --workers {args.workers}: expected 1 or more")
    folder: Path = args.resume or args.out
    campaign, runs, text = load_campaign(args.spec)
    todo = runner.prepare(
        folder,
        campaign,
        runs,
        text,
        resume=args.resume is not None,
        notice=lambda line: print(f"campaign {campaign.name}: {line}", file=sys.stderr),
    )
    print(
        f"campaign {campaign.name}: {len(runs)} runs, {len(runs) - len(todo)} done before, "
        f"{len(todo)} to run on {args.address or 'this machine'} -> {folder}",
        file=sys.stderr,
    )
    display = None
    if not args.quiet and wants_progress(sys.stderr):
        from bywire.hil.campaign.progress import CampaignProgress

        display = CampaignProgress(campaign.name, len(runs), len(runs) - len(todo), sys.stderr)
    try:
        with (
            signals_interrupt(signal.SIGINT, signal.SIGTERM),
            display if display is not None else contextlib.nullcontext(),
        ):
            outcome = runner.execute(folder, todo, len(runs), args.address, args.workers, on_record=display)
    except KeyboardInterrupt as exc:
        signum = int(getattr(exc, "signum", signal.SIGINT))
        from bywire.hil.campaign import store

        done = len(store.done_ids(folder))
        print(
            f"campaign {campaign.name}: INTERRUPTED by {signal.Signals(signum).name}: {done} of {len(runs)} "
            f"runs done and kept; continue with: bywire campaign run {args.spec} --resume {folder}",
            file=sys.stderr,
        )
        return 128 + signum
    summary = summarise(folder)
    write_report(folder, summary)
    _print_summary(summary, sys.stdout)
    print(
        f"campaign {campaign.name}: {outcome.ran} run now, {outcome.skipped} before; results in "
        f"{folder / 'results.parquet'}, report in {folder / 'report'}",
        file=sys.stderr,
    )
    return 0 if summary["failed"] == 0 else 1


def add_report_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dir", type=Path, help="a campaign's folder (its results.parquet)")
    p.add_argument(
        "--json",
        type=Path,
        help="write the summary as JSON to this file (`-`: to stdout, and nothing else there)",
    )
    p.add_argument("--worst", type=int, default=10, help="how many of the worst runs to list (default 10)")


def main_report(args: argparse.Namespace) -> int:
    from bywire.hil.campaign.report import summarise, write_report

    summary = summarise(args.dir, worst=args.worst)
    write_report(args.dir, summary)
    _print_summary(summary, _write_json(summary, args.json))
    return 0 if summary["failed"] == 0 else 1


def _write_json(document: dict[str, Any], path: Path | None) -> Any:
    """`document` as JSON to `path` (`-`: stdout); the stream the text goes to (stderr when stdout is
    the JSON's)."""
    import json

    if path is None:
        return sys.stdout
    text = json.dumps(document, indent=2, default=str) + "\n"
    if str(path) == "-":
        sys.stdout.write(text)
        return sys.stderr
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return sys.stdout


def add_compare_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("base", type=Path, help="a campaign's folder: the reference (an older commit, say)")
    p.add_argument("new", type=Path, help="a folder of the same campaign, run again (this commit)")
    p.add_argument(
        "--json",
        type=Path,
        help="write the comparison as JSON to this file (`-`: to stdout, and nothing else there)",
    )
    p.add_argument(
        "--identical",
        action="store_true",
        help="fail (exit 1) unless every matched run is the same but for the wall clock's columns: a change "
        "meant to keep behaviour (a speed-up, a refactoring) proved on a whole campaign",
    )


def main_compare(args: argparse.Namespace) -> int:
    from bywire.hil.campaign.compare import compare

    result = compare(args.base, args.new)
    _print_comparison(result, _write_json(result, args.json))
    if result["regressions"]:
        return 1
    if args.identical and (result["identical"] != result["matched"] or result["only_in_base"]):
        return 1
    return 0


def _print_comparison(result: dict[str, Any], out: Any) -> None:
    base, new = result["base"], result["new"]
    print(
        f"{base['campaign']} ({', '.join(base['code_versions'])}) -> {new['campaign']} "
        f"({', '.join(new['code_versions'])}): runs matched {result['matched']}, "
        f"{len(result['only_in_base'])} only in {base['folder']}, {len(result['only_in_new'])} only in "
        f"{new['folder']}",
        file=out,
    )
    print(f"  identical but for the wall clock: {result['identical']} of {result['matched']}", file=out)
    t = result["trajectories"]
    if t["compared"]:
        print(f"  trajectories: {t['same']} the same, {len(t['changed'])} changed", file=out)
    print(f"  regressions: {len(result['regressions'])}, fixes: {len(result['fixes'])}", file=out)
    for kind in ("regressions", "fixes"):
        for r in result[kind]:
            checks = r["newly_failed_checks"] if kind == "regressions" else r["newly_passed_checks"]
            what = ", ".join(checks) or r.get("new_error") or r.get("base_error") or ""
            print(
                f"  {kind[:-1]} #{r['index']} {r['sweep']}: {r['base_verdict']} -> {r['new_verdict']} {what}",
                file=out,
            )
            print(f"    {r['command']}", file=out)
    for metric, m in result["metrics"].items():
        line = f"  metric {metric}: changed in {m['runs_changed']} runs"
        if m["max_abs_change"] is not None:
            at = m["at"]
            line += f", most by {m['max_abs_change']:.6g} (#{at['index']}: {at['base']:.6g}"
            line += f" -> {at['new']:.6g})"
        if "worse" in m:
            line += f"; towards its limit in {m['worse']}, away in {m['better']}"
        print(line, file=out)


def main_list(args: argparse.Namespace) -> int:
    import yaml

    from bywire.hil.campaign.spec import builtin_campaigns

    for name, path in builtin_campaigns().items():
        data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
        first = str(data.get("description", "")).strip().splitlines()
        print(f"{name:12s} {first[0] if first else ''}")
    return 0


def _print_summary(summary: dict[str, Any], out: Any) -> None:
    print(
        f"{summary['campaign']}: {summary['runs']} runs, {summary['passed']} passed, "
        f"{summary['failed']} failed ({summary['errors']} raised)",
        file=out,
    )
    for name, s in summary["by_scenario"].items():
        print(
            f"  {name:28s} {s['passed']:5d}/{s['runs']:<5d} pass ({100.0 * s['pass_rate']:.1f} %)", file=out
        )
    for inv in summary["invariants"]:
        mark = "HOLDS" if inv["holds"] else f"BROKEN in {len(inv['differing'])} runs"
        print(f"  invariant {inv['sweep']}.{inv['metric']}: {mark}", file=out)
    if summary["worst"]:
        print("worst runs (rerun one alone with its command):", file=out)
    for w in summary["worst"]:
        what = w["failed_checks"] or w.get("error") or f"closest: {w['closest_check']} ({w['margin']:+.3g})"
        print(f"  #{w['index']} {w['sweep']} {w['verdict'].upper()}: {what}", file=out)
        print(f"    {w['command']}", file=out)


__all__ = [
    "add_compare_arguments",
    "add_report_arguments",
    "add_run_arguments",
    "main_compare",
    "main_list",
    "main_report",
    "main_run",
]
