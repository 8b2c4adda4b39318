"""tools/identical_campaigns.py: a campaign run at a base commit (a git worktree of it) and at this
checkout, compared run by run. Against this checkout's own commit it is identical (unless the package
has uncommitted changes, when only the comparison's taking place is judged); a base git does not know
is refused."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TOOL = ROOT / "tools" / "identical_campaigns.py"

# The tool compares commits of a git checkout; an exported tree (an sdist, a tarball) has none.
pytestmark = pytest.mark.skipif(
    not (ROOT / ".git").exists(), reason=f"{ROOT} is not a git checkout: the tool compares its commits"
)


def _tool(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, str(TOOL), *args], cwd=ROOT, capture_output=True, text=True, timeout=600
    )


def test_a_campaign_at_this_commit_is_identical_to_this_checkout(tmp_path: Path) -> None:
    spec = tmp_path / "short.yaml"
    spec.write_text(
        "name: short\nsweeps:\n  - scenario: accel_steps\n    set: {duration_s: 3.0}\n"
        "    grid:\n      seed: [1, 2]\n",
        encoding="utf-8",
    )
    done = _tool("HEAD", "--campaign", str(spec), "--workers", "2", "--out", str(tmp_path / "out"))
    assert "runs matched 2, 0 only in" in done.stdout, done.stdout + done.stderr
    clean = subprocess.run(["git", "diff", "--quiet", "HEAD", "--", "bywire"], cwd=ROOT).returncode == 0
    if clean:
        assert done.returncode == 0, done.stdout + done.stderr
        assert "identical but for the wall clock: 2 of 2" in done.stdout
    assert not (tmp_path / "out" / "base-src").exists()  # the worktree is removed
    assert (
        "base-src"
        not in subprocess.run(["git", "worktree", "list"], cwd=ROOT, capture_output=True, text=True).stdout
    )


def test_a_base_git_does_not_know_is_refused() -> None:
    done = _tool("no-such-commit-anywhere")
    assert done.returncode == 2
    assert "no-such-commit-anywhere: not a commit of" in done.stderr
