"""What a SIGKILL costs a recording: how much of the last moments a killed recorder loses.

The MCAP recorder flushes its chunk every `flush_interval_s` (host/runtime/mcap_recorder.py), so a
host killed mid-run should leave everything but about the last interval readable. A child process
records a tick every millisecond (its wall stamp inside); it is killed at a random moment, and the
loss is the kill instant minus the newest readable tick's stamp. The baseline is the flush interval
itself: the ratio says how many intervals a kill loses on this machine (1 is the design; more is the
scheduler's delay of the recorder's background thread). p50 / p99 / max over the runs (DESIGN.md
section 5: distributions and ratios from the same run, never a bound in a unit test).
"""

from __future__ import annotations

import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.run import distribution
from bywire.host.runtime.mcap_reader import read_objects

FLUSH_INTERVAL_S = 0.1

CHILD = """
import sys, time
from dataclasses import dataclass
from bywire.host.runtime.log_schema import register_type
from bywire.host.runtime.mcap_recorder import McapRecorder

@register_type(name="bench.Tick")
@dataclass(frozen=True)
class Tick:
    t_s: float
    seq: int
    wall_s: float

rec = McapRecorder(sys.argv[1], flush_interval_s=float(sys.argv[2]))
seq = 0
start = time.monotonic()
while True:
    now = time.monotonic()
    rec.record("/tick", Tick(now - start, seq, now))
    seq += 1
    if seq == 200:
        print("recording", flush=True)
    time.sleep(0.001)
"""


def _newest_wall_s(path: Path) -> float | None:
    newest = None
    for entry in read_objects(path):
        obj = entry.obj
        wall = obj.get("wall_s") if isinstance(obj, dict) else getattr(obj, "wall_s", None)
        if wall is not None:
            newest = wall
    return newest


def run(runs: int = 8, seed: int = 1) -> dict[str, Any]:
    rng = random.Random(seed)
    lost_s: list[float] = []
    with tempfile.TemporaryDirectory(prefix="bywire-bench-kill-") as tmp:
        for k in range(runs):
            path = Path(tmp) / f"kill{k}.mcap"
            child = subprocess.Popen(
                [sys.executable, "-c", CHILD, str(path), str(FLUSH_INTERVAL_S)],
                stdout=subprocess.PIPE,
                text=True,
            )
            try:
                if child.stdout is None or child.stdout.readline().strip() != "recording":
                    raise RuntimeError("the recording child did not start")
                time.sleep(0.3 + rng.random() * 0.3)
                killed_at = time.monotonic()
                child.send_signal(signal.SIGKILL)
                child.wait(timeout=10)
            finally:
                child.kill()
            newest = _newest_wall_s(path)
            if newest is not None:
                lost_s.append(killed_at - newest)
    if not lost_s:
        return {"runs": runs, "error": "no readable tick in any run"}
    d = distribution(lost_s)  # the same p99 as every other row of the benchmarks
    base_ms = FLUSH_INTERVAL_S * 1e3
    return {
        "runs": runs,
        "flush_interval_ms": base_ms,
        "lost_p50_ms": d["median_us"] / 1e3,
        "lost_p99_ms": d["p99_us"] / 1e3,
        "lost_max_ms": d["max_us"] / 1e3,
        "ratio_p50": d["median_us"] / 1e3 / base_ms,
        "ratio_max": d["max_us"] / 1e3 / base_ms,
    }


def print_row(row: dict[str, Any]) -> None:
    print("\nrecording killed with SIGKILL: the last moments lost (baseline: the flush interval)")
    if "error" in row:
        print(f"  {row['error']}")
        return
    print(
        f"  {row['runs']} runs, flush every {row['flush_interval_ms']:.0f} ms: lost p50 "
        f"{row['lost_p50_ms']:.0f} ms, p99 {row['lost_p99_ms']:.0f} ms, max {row['lost_max_ms']:.0f} ms "
        f"(x interval: p50 {row['ratio_p50']:.2f}, max {row['ratio_max']:.2f})"
    )
