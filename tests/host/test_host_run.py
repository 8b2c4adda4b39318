"""`bywire host run CONFIG` as a user starts it: the modules run on the wall clock, bad files are refused."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from bywire.hil.runner import free_udp_port
from bywire.host.config import load_host_config


def _bywire(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "bywire", *args], capture_output=True, text=True, timeout=120
    )


def test_host_runs_a_configuration_on_the_wall_clock(tmp_path: Path) -> None:
    mine, peer = free_udp_port(), free_udp_port()  # no ECU listens: the link sends into the void
    summary = tmp_path / "summary.json"
    record = tmp_path / "host.mcap"
    proc = _bywire(
        "host",
        "run",
        "default",
        "--host-link",
        f"udp://127.0.0.1:{mine}?peer=127.0.0.1:{peer}",
        "--seconds",
        "1.5",
        "--summary",
        str(summary),
        "--record",
        str(record),
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    doc = json.loads(summary.read_text())
    modules = doc["modules"]
    assert list(modules) == [m.spec.name for m in load_host_config("default").modules]
    for name, m in modules.items():
        # 1.5 s at 50 Hz: every period of the grid is either released or, on a loaded machine that
        # fell behind, counted as skipped; each release completed.
        assert 70 <= m["releases"] + m["skipped"] <= 80, (name, m)
        assert m["completed"] == m["releases"] >= 30, (name, m)
        assert m["restarts"] == 0 and m["state"] == "running"
    info = _bywire("log", "info", str(record), "--json", "-")
    assert info.returncode == 0, info.stderr
    topics = json.loads(info.stdout[info.stdout.index("{") :])["topics"]
    # Every completed release of the controller published one request, and the recording holds each.
    assert topics["/control/request"]["count"] == modules["longitudinal"]["completed"]
    assert topics["/run/info"]["count"] == 1


def test_a_bad_configuration_is_refused_with_its_field(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("modules:\n  - {name: lon, kind: longitudinal, deadline_ms: fast}\n")
    proc = _bywire("host", "run", str(bad), "--seconds", "0.1")
    assert proc.returncode == 2
    assert "bad.yaml: modules[0].deadline_ms: expected a number, got 'fast'" in proc.stderr
