"""Prove that a change keeps behaviour: shipped campaigns run at a base commit and at this checkout,
compared run by run (`bywire campaign compare --identical`).

A speed-up of the simulator (a compiled twin of a Python path, a cache, a cheaper data structure) must
leave every run the same, bit for bit; a few scenarios hashed before and after is a sample, a campaign
is hundreds of situations. This checks out BASE into a git worktree of its own, runs each campaign
there and here with the same campaign file (this checkout's, so that the runs and their ids are the
same), and compares. Both sides run on this machine's venv, one campaign at a time, `--workers` each.

Usage: tools/identical_campaigns.py BASE [--campaign NAME ...] [--workers N] [--out DIR] [--keep]

Exit status 0 when every campaign's runs are identical but for the wall clock, 1 when one differs (the
compare's lines say which runs and how), 2 for a BASE git does not know or a campaign that does not run.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from bywire.cli import main as bywire

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_CAMPAIGNS = ("smoke", "v2v_fuzz", "urban", "platoon", "faults")


def _git(*args: str, cwd: Path = ROOT) -> str:
    return subprocess.run(["git", *args], cwd=cwd, check=True, capture_output=True, text=True).stdout.strip()


def _campaign_file(name: str) -> Path | None:
    from bywire.hil.campaign.spec import builtin_campaigns

    shipped = builtin_campaigns()
    if name in shipped:
        return shipped[name]
    path = Path(name)
    if not path.is_file():
        print(f"error: {name}: neither a shipped campaign ({', '.join(shipped)}) nor a file", file=sys.stderr)
        return None
    return path.resolve()


def _run(source: Path, spec: Path, out: Path, workers: int) -> int:
    """`bywire campaign run SPEC --out OUT` with the code of `source` (its own `bywire` first on the path)."""
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(p for p in (str(source), os.environ.get("PYTHONPATH")) if p),
    }
    cmd = [sys.executable, "-m", "bywire.cli", "campaign", "run", str(spec), "--out", str(out)]
    cmd += ["--workers", str(workers), "--quiet"]
    done = subprocess.run(
        cmd, cwd=source, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    if done.returncode not in (0, 1):  # 1: a run failed its checks, which the compare judges
        sys.stderr.write(done.stderr)
    return done.returncode


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("base", help="the commit (or any git revision) the change is measured against")
    p.add_argument(
        "--campaign", action="append", help="a shipped campaign or a file (repeatable; default: all)"
    )
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    p.add_argument("--out", type=Path, help="where the campaigns' folders go (default: a temporary folder)")
    p.add_argument(
        "--keep", action="store_true", help="keep the base's worktree (the campaigns' folders are kept)"
    )
    args = p.parse_args(argv)
    try:
        base = _git("rev-parse", "--verify", f"{args.base}^{{commit}}")
    except subprocess.CalledProcessError:
        print(f"error: {args.base}: not a commit of {ROOT}", file=sys.stderr)
        return 2
    found = [_campaign_file(n) for n in (args.campaign or DEFAULT_CAMPAIGNS)]
    specs = [f for f in found if f is not None]
    if len(specs) < len(found):
        return 2
    out = args.out or Path(tempfile.mkdtemp(prefix="identical-"))
    worktree = out / "base-src"
    _git("worktree", "add", "--detach", "--force", str(worktree), base)
    status = 0
    try:
        for spec in specs:
            name = spec.stem
            for side, source in (("base", worktree), ("new", ROOT)):
                code = _run(source, spec, out / side / name, args.workers)
                if code not in (0, 1):
                    print(
                        f"error: campaign {name} did not run at {side} ({source}): exit status {code}",
                        file=sys.stderr,
                    )
                    return 2
            # 1: not identical; 2: the folders could not be compared (said on stderr)
            compared = bywire(
                ["campaign", "compare", str(out / "base" / name), str(out / "new" / name), "--identical"]
            )
            status = max(status, compared)
    finally:
        if not args.keep:
            _git("worktree", "remove", "--force", str(worktree))
    print(f"{'identical' if status == 0 else 'NOT identical'} to {base[:12]}; the campaigns' folders: {out}")
    return status


if __name__ == "__main__":
    sys.exit(main())
