"""`bywire bench urban` (host/behaviour/bench.py): a short run and its JSON contract; no timing asserts."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from bywire.cli import benchmark

bench = benchmark("urban")


def test_bench_runs_and_writes_json(tmp_path: Path, capsys) -> None:
    parser = argparse.ArgumentParser()
    bench.add_arguments(parser)
    out = tmp_path / "sub" / "urban.json"
    args = parser.parse_args(["--seconds", "0.2", "--json", str(out)])
    assert bench.main(args) == 0
    doc = json.loads(out.read_text(encoding="utf-8"))
    rows = doc["rows"]
    assert set(rows) == {
        "baseline",
        "mtc_1",
        "mtc_10",
        "precedence_update",
        "lateral_step",
        "lateral_step_hinted",
        "hsm_step",
    }
    for name, r in rows.items():
        assert r["n"] >= 400 and 0.0 < r["p50_us"] <= r["p99_us"] <= r["max_us"], name
        if name != "baseline":
            assert r["ratio_p50"] > 0.0
    printed = capsys.readouterr().out
    assert "mtc_10" in printed and "p50 / baseline" in printed


def test_bench_rejects_a_bad_duration() -> None:
    assert bench.main(argparse.Namespace(seconds=-1.0, json=None)) == 2
