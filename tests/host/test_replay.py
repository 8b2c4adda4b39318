"""Record a run to MCAP and replay it through the host's modules (the host runtime's record and replay).

The committed reference (tests/data/replay/demo_10s.mcap, a 10 s SIL run of the demo, topics
only) is openpilot's process replay for us: CI replays it with the current code and the outputs
must match the recording. A change that alters what the controller or the perception computes
fails here on purpose; if the change is intended, regenerate the reference with
`python tests/data/replay/make_reference.py` and say so in the commit.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bywire.hil.scenario import load_scenario
from bywire.hil.sil import run_sil
from bywire.host.log_cli import log_info
from bywire.host.modules.messages import CONTROL, ControlRequest
from bywire.host.replay import ReplayError, replay
from bywire.host.runtime.mcap_reader import read_frames, read_objects
from bywire.host.runtime.mcap_recorder import McapRecorder

REFERENCE = Path(__file__).resolve().parents[1] / "data" / "replay" / "demo_10s.mcap"


def _bywire(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "bywire", *args], capture_output=True, text=True, timeout=120
    )


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "sx.mcap"
    scenario = dataclasses.replace(load_scenario("supervisor_exception"), duration_s=11.0)
    run_sil(scenario, record=path)
    return path


def test_a_sil_recording_holds_frames_and_topics(recording: Path) -> None:
    info = log_info(recording)
    assert info["complete"] is True
    topics = info["topics"]
    assert topics["/control/request"]["rate_hz"] == pytest.approx(50.0, rel=0.01)
    assert topics["/can/vehicle"]["count"] > 5000 and topics["/can/host_link"]["count"] > 1000
    assert topics["/run/info"]["count"] == 1
    events = [e.obj for e in read_objects(recording, topics=["/supervisor/events"])]
    assert [(e.module, e.cause) for e in events][:1] == [("longitudinal", "exception")]


def test_replay_matches_the_recording_and_is_deterministic(recording: Path) -> None:
    first, second = replay(recording), replay(recording)
    assert first.matches, json.dumps(first.to_json()["topics"], indent=1)
    assert first.modules == ["odometry", "lead_tracker", "longitudinal"]
    assert first.restarts == 1  # the supervisor's restart of the controller, re-enacted
    assert first.outputs == second.outputs
    assert first.topics[CONTROL].compared == first.topics[CONTROL].recorded > 500


def test_a_tampered_output_is_found(recording: Path, tmp_path: Path) -> None:
    tampered = tmp_path / "tampered.mcap"
    with McapRecorder(tampered) as rec:
        n = 0
        for entry in read_objects(recording):
            obj = entry.obj
            if entry.topic.startswith("/can/"):
                continue
            if isinstance(obj, ControlRequest):
                n += 1
                if n == 300:
                    obj = dataclasses.replace(obj, accel_mps2=obj.accel_mps2 + 0.01)
            rec.record(entry.topic, obj)
    proc = _bywire("log", "replay", str(tampered), "--check", "--json", str(tmp_path / "r.json"))
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "#299" in proc.stdout and "accel_mps2" in proc.stdout
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["matches"] is False and doc["topics"][CONTROL]["mismatched"] == 1
    assert doc["topics"][CONTROL]["max_abs_diff"]["accel_mps2"] == pytest.approx(0.01)


def test_a_recording_without_run_info_is_refused(tmp_path: Path) -> None:
    bare = tmp_path / "bare.mcap"
    with McapRecorder(bare) as rec:
        rec.record(CONTROL, ControlRequest(0.0, 0.0, 0.0, 0, "none", 0.0, float("nan")))
    with pytest.raises(ReplayError, match="no /run/info"):
        replay(bare)
    proc = _bywire("log", "replay", str(bare), "--check")
    assert proc.returncode == 2 and "no /run/info" in proc.stderr


def test_the_committed_reference_replays_with_todays_code() -> None:
    if not REFERENCE.exists():
        pytest.fail(f"{REFERENCE} is missing: run tests/data/replay/make_reference.py")
    proc = _bywire("log", "replay", str(REFERENCE), "--check")
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_merging_keeps_what_a_crashed_part_holds(recording: Path, tmp_path: Path) -> None:
    """HIL: the host's part of a recording may end in a crash; the merge keeps its readable prefix
    and says so, next to the runner's complete part."""
    from bywire.hil.recording import merge_recordings

    host_part, frames_part = tmp_path / "host.mcap", tmp_path / "frames.mcap"
    with McapRecorder(host_part, chunk_size=4096) as rec:
        for entry in read_objects(recording):
            if not entry.topic.startswith("/can/"):
                rec.record(entry.topic, entry.obj)
    with McapRecorder(frames_part) as rec:
        for frame in read_frames(recording, bus="vehicle"):
            rec.record_frame("vehicle", frame)
    cut = tmp_path / "host_cut.mcap"
    cut.write_bytes(host_part.read_bytes()[: host_part.stat().st_size // 2])  # killed half-way
    report = merge_recordings(tmp_path / "merged.mcap", [cut, frames_part, tmp_path / "absent.mcap"])
    assert report["parts"]["frames.mcap"] == "ok" and report["parts"]["absent.mcap"] == "missing"
    assert report["parts"]["host_cut.mcap"].startswith(("not closed cleanly", "damaged"))
    info = log_info(tmp_path / "merged.mcap")
    assert info["complete"] is True
    assert info["topics"]["/can/vehicle"]["count"] > 5000
    assert 0 < info["topics"]["/control/request"]["count"] < 550


def test_arrays_are_compared_elementwise_within_the_tolerance() -> None:
    """A perception frame's arrays: equal within the tolerance, or named with the first difference."""
    from bywire.host.replay import _equal

    diffs: dict[str, float] = {}
    a = np.array([[1.0, 2.0], [3.0, np.nan]], dtype=np.float32)
    assert _equal(a, a.copy(), "xy_m", diffs) == [] and diffs["xy_m"] == 0.0
    b = a.copy()
    b[1, 0] += 0.5
    (line,) = _equal(a, b, "xy_m", diffs)
    assert "1 elements differ" in line and "[2]" in line and diffs["xy_m"] == 0.5
    assert "shape" in _equal(a, a[:1], "xy_m", diffs)[0]
    assert _equal(np.zeros(0), np.zeros(0), "e", diffs) == []
