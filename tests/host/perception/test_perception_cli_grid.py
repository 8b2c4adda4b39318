"""`bywire perception grid SCAN.bin [--png OUT] [--json OUT]` through the one entry point: a synthetic
scan, a real KITTI one when the shared data is there, and files that are not scans."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from grid_scenes import Box, cast, write_kitti_bin
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from shared_data import shared_data_dir

from bywire.cli import main

KITTI_SCAN = shared_data_dir() / "lidar_kitti" / "odometry_seq00_frames0-5" / "000000.bin"


@pytest.fixture
def scene_bin(tmp_path: Path) -> Path:
    path = tmp_path / "scene.bin"
    write_kitti_bin(str(path), cast((Box(10.0, 0.0, 4.0, 1.8), Box(-6.0, 8.0, 1.0, 1.0))))
    return path


@pytest.mark.parametrize("layout", ["graded", "uniform"])
def test_grid_writes_the_picture_and_the_numbers(
    scene_bin: Path, tmp_path: Path, layout: str, capsys: pytest.CaptureFixture[str]
) -> None:
    png, out = tmp_path / "grid.png", tmp_path / "grid.json"
    argv = ["perception", "grid", str(scene_bin), "--png", str(png), "--json", str(out), "--layout", layout]
    assert main(argv) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    result = json.loads(out.read_text())
    assert result["layout"]["name"].startswith(layout)
    assert result["points"] > 10000 and result["cells"]["hit"] > 1000
    assert result["obstacle_cells"] > 0 and result["update_ms"] > 0
    centres = [(o["x_m"], o["y_m"]) for o in result["objects"]]
    assert len(centres) == 2
    assert any(math.dist(c, (9.5, 0.0)) < 1.5 for c in centres)
    assert any(math.dist(c, (-6.0, 8.0)) < 1.0 for c in centres)
    line = capsys.readouterr().out.strip()
    assert str(scene_bin) in line and "2 objects" in line


def test_grid_on_a_kitti_scan(tmp_path: Path) -> None:
    if not KITTI_SCAN.exists():
        pytest.skip(f"KITTI scan not found at {KITTI_SCAN} (shared data absent)")
    out = tmp_path / "grid.json"
    assert main(["perception", "grid", str(KITTI_SCAN), "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["points"] == 124668
    assert result["obstacle_cells"] > 1000 and len(result["objects"]) > 10


def run_bad(path: Path, capsys: pytest.CaptureFixture[str]) -> str:
    assert main(["perception", "grid", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(path) in err
    return err


def test_a_truncated_file_is_one_line_naming_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "cut.bin"
    path.write_bytes(np.zeros(4 * 100, np.float32).tobytes()[:-3])
    assert "16-byte points" in run_bad(path, capsys)


def test_a_nan_point_is_one_line_naming_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pts = np.ones((50, 4), np.float32)
    pts[17, 2] = np.nan
    path = tmp_path / "nan.bin"
    pts.tofile(path)
    assert "point 17" in run_bad(path, capsys)


def test_a_missing_file_is_one_line_naming_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert "cannot read" in run_bad(tmp_path / "absent.bin", capsys)


def test_an_output_that_cannot_be_written_is_bad_input(
    scene_bin: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "no such folder" / "grid.json"
    assert main(["perception", "grid", str(scene_bin), "--json", str(out)]) == 2
    assert capsys.readouterr().err == f"error: {out}: cannot write: No such file or directory\n"


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=4000))
def test_any_bytes_are_a_scan_or_a_clean_error(
    data: bytes, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "fuzz.bin"
    path.write_bytes(data)
    usable = len(data) % 16 == 0 and bool(np.isfinite(np.frombuffer(data, np.float32)).all())
    assert main(["perception", "grid", str(path)]) == (0 if usable else 2)
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    if not usable:
        assert len(captured.err.strip().splitlines()) == 1
