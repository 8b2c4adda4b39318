"""`bywire rndf check`, `bywire mission plan` and `bywire bench roadnet` through their main functions, with
argparse namespaces built by their add_* functions: exit codes, the one-line error format, the JSON
contract and the plot."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest
from roadnet_helpers import SYNTHETIC_RNDF, need_data, synthetic_mission_text

from bywire.cli import benchmark
from bywire.host.roadnet import roadnet_cli

bench = benchmark("roadnet")


def check_args(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    roadnet_cli.add_rndf_check_arguments(p)
    return p.parse_args(list(argv))


def plan_args(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    roadnet_cli.add_mission_plan_arguments(p)
    return p.parse_args(list(argv))


def test_check_accepts_every_shared_file(capsys: pytest.CaptureFixture[str]) -> None:
    root = need_data()
    files = sorted(str(p) for p in root.glob("*/*") if p.parent.name != "spec" and p.is_file())
    assert roadnet_cli.main_rndf_check(check_args(*files)) == 0
    out, err = capsys.readouterr()
    assert err == "" and out.count(": ok, ") == len(files)
    assert "warning: header declares 1 zones, the body has 0" in out  # prc_small's quirk, reported


def test_check_reports_one_line_per_bad_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = tmp_path / "good.rndf"
    good.write_text(SYNTHETIC_RNDF)
    cut = tmp_path / "cut.rndf"
    cut.write_text(SYNTHETIC_RNDF[: SYNTHETIC_RNDF.index("end_segment\nsegment\t3")])
    neither = tmp_path / "notes.txt"
    neither.write_text("/* just a comment */\nhello world\n")
    mdf = tmp_path / "bad.mdf"
    mdf.write_text(synthetic_mission_text([1, 2], {1: (0, 30)}).replace("1\t0\t30", "1\t40\t30"))
    code = roadnet_cli.main_rndf_check(
        check_args(str(good), str(cut), str(neither), str(mdf), str(tmp_path / "nope"))
    )
    assert code == 1
    out, err = capsys.readouterr()
    lines = err.splitlines()
    n_cut = SYNTHETIC_RNDF[: SYNTHETIC_RNDF.index("end_segment\nsegment\t3")].count("\n")
    assert lines == [
        f"{cut}:{n_cut}: expected end_segment of segment 2, found the end of the file",
        f"{neither}:2: expected RNDF_name or MDF_name, found 'hello'",
        f"{mdf}:10: expected minimum speed <= maximum speed, found 40 > 30 mph",
        f"{tmp_path / 'nope'}:0: expected a readable file (No such file or directory)",
    ]
    assert f"{good}: ok, RNDF 'synthetic'" in out


def test_check_resolves_mdfs_against_an_rndf(capsys: pytest.CaptureFixture[str]) -> None:
    root = need_data()
    ok = check_args(
        str(root / "darpa_sample/Sample_MDF.txt"), "--rndf", str(root / "darpa_sample/Sample_RNDF.txt")
    )
    assert roadnet_cli.main_rndf_check(ok) == 0
    assert "all in RNDF 'Sample_RNDF.txt'" in capsys.readouterr().out
    bad = check_args(
        str(root / "stanford/shortloop_mdf.txt"), "--rndf", str(root / "stanford/shortloop_rndf.txt")
    )
    assert roadnet_cli.main_rndf_check(bad) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"{root / 'stanford/shortloop_mdf.txt'}:8: expected a checkpoint of RNDF")
    strict = check_args("--strict", "-q", str(root / "utexas/prc_small.rndf"))
    assert roadnet_cli.main_rndf_check(strict) == 1
    assert capsys.readouterr().err.strip().endswith("header declares 1 zones, the body has 0")


def test_mission_plan_json_and_plot(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = need_data()
    out_json, out_png = tmp_path / "r" / "route.json", tmp_path / "r" / "route.png"
    args = plan_args(
        str(root / "darpa_nqe/nqe_rndf.rdf"),
        str(root / "darpa_nqe/nqe_c_mdf.mdf"),
        "--json",
        str(out_json),
        "--plot",
        str(out_png),
    )
    assert roadnet_cli.main_mission_plan(args) == 0
    doc = json.loads(out_json.read_text())
    assert doc["checkpoints"] == [32, 30, 32, 30, 32, 30, 32, 30, 31]
    assert doc["reached_all"] is True
    assert isinstance(doc["route_length_m"], float) and isinstance(doc["route_time_s"], float)
    assert doc["route_length_m"] == pytest.approx(sum(leg["length_m"] for leg in doc["legs"]))
    assert 1000.0 < doc["route_length_m"] < 5000.0 and doc["start"] == doc["legs"][0]["waypoint"]
    assert out_png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    printed = capsys.readouterr().out
    assert "total " in printed and "checkpoint" in printed and printed.count("\n") >= 12


def test_mission_plan_start_and_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rndf = tmp_path / "s.rndf"
    rndf.write_text(SYNTHETIC_RNDF)
    mdf = tmp_path / "s.mdf"
    mdf.write_text(synthetic_mission_text([4, 5], {4: (0, 30), 5: (0, 10)}))
    out_json = tmp_path / "s.json"
    assert (
        roadnet_cli.main_mission_plan(
            plan_args(str(rndf), str(mdf), "--start", "4.1.1", "--json", str(out_json))
        )
        == 0
    )
    doc = json.loads(out_json.read_text())
    assert (
        doc["start"] == "4.1.1"
        and doc["legs"][0]["length_m"] > 190.0
        and "lane_change" in doc["legs"][0]["kinds"]
    )
    capsys.readouterr()
    assert roadnet_cli.main_mission_plan(plan_args(str(rndf), str(mdf), "--start", "4.1")) == 2
    assert capsys.readouterr().err.strip() == "error: --start:0: expected a waypoint id M.N.P, found '4.1'"
    assert roadnet_cli.main_mission_plan(plan_args(str(rndf), str(mdf), "--start", "4.1.9")) == 2
    assert "4.1.9 is not defined" in capsys.readouterr().err
    # a checkpoint that cannot be reached: exit 1, reported in the table and the JSON
    dead = tmp_path / "dead.mdf"
    dead.write_text(synthetic_mission_text([2, 3], {1: (0, 30)}))
    assert roadnet_cli.main_mission_plan(plan_args(str(rndf), str(dead), "--json", str(out_json))) == 1
    assert json.loads(out_json.read_text())["reached_all"] is False
    assert "UNREACHABLE" in capsys.readouterr().out
    # an MDF asking for a checkpoint the RNDF lacks: exit 2, the MDF line on stderr
    wrong = tmp_path / "wrong.mdf"
    wrong.write_text(synthetic_mission_text([1, 9], {1: (0, 30)}))
    assert roadnet_cli.main_mission_plan(plan_args(str(rndf), str(wrong))) == 2
    assert capsys.readouterr().err.startswith(f"error: {wrong}:6: expected a checkpoint of RNDF 'synthetic'")


def test_bench_rows_on_a_small_network(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    root = need_data()
    doc = bench.bench_network(root, "utexas/prc_large_obstacle.rndf", ("utexas/prc_large_obstacle.mdf",), 2)
    for row in bench.ROWS:
        r = doc[row]
        assert 0.0 < r["median_ms"] <= r["p99_ms"] <= r["max_ms"]
    assert (
        doc["parse_over_read"] > 1.0 and doc["replan_over_dijkstra"] > 0.0 and doc["route_length_m"] > 1000.0
    )
    # the full benchmark refuses to run without its data, with a message
    monkeypatch.setenv("BYWIRE_SHARED_DATA", str(tmp_path))
    p = argparse.ArgumentParser()
    bench.add_arguments(p)
    assert bench.main(p.parse_args(["--repeats", "1"])) == 2
    assert "road network data not found" in capsys.readouterr().out
    assert bench.main(p.parse_args(["--repeats", "0"])) == 2
