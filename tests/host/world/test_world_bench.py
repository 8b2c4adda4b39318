"""`bywire bench world` (cooperative driving): the JSON contract on a short run, and the cross-checks it
carries (the kd-tree and brute-force matches agree; the closed-form CYRA agrees with the Euler baseline). No
timing is asserted: the figures are for the report, not for pass/fail."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from bywire.cli import benchmark

bench = benchmark("world")


def test_bench_contract(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = argparse.ArgumentParser()
    bench.add_arguments(p)
    out = tmp_path / "sub" / "world.json"
    args = p.parse_args(["--seconds", "0.5", "--json", str(out)])
    assert bench.main(args) == 0
    doc = json.loads(out.read_text())
    for key in (
        "match_us",
        "match_bruteforce_us",
        "predict10_us",
        "predict10_euler_us",
        "pose_odometry_us",
        "pose_fix_us",
        "pose_query_us",
    ):
        row = doc[key]
        assert row["n"] >= 5 and 0.0 < row["p50"] <= row["p99"] <= row["max"]
    assert doc["map_vertices"] > 40000
    assert doc["match_disagreements"] == 0
    # The Euler baseline integrates the same clipped model: it must agree to its own step error.
    assert doc["max_predict_diff_m"] < 0.01
    assert set(doc["ratios"]) == {"match_bruteforce_over_kdtree", "predict_euler_over_closed_form"}
    printed = capsys.readouterr().out
    assert "lane match, kd-tree" in printed and "Euler / closed-form" in printed
