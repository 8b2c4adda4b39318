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
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

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
    lost_ms: list[float] = []
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
                lost_ms.append((killed_at - newest) * 1e3)
    if not lost_ms:
        return {"runs": runs, "error": "no readable tick in any run"}
    ordered = sorted(lost_ms)
    p99 = ordered[min(len(ordered) - 1, round(0.99 * (len(ordered) - 1)))]
    base_ms = FLUSH_INTERVAL_S * 1e3
    return {
        "runs": runs,
        "flush_interval_ms": base_ms,
        "lost_p50_ms": statistics.median(lost_ms),
        "lost_p99_ms": p99,
        "lost_max_ms": ordered[-1],
        "ratio_p50": statistics.median(lost_ms) / base_ms,
        "ratio_max": ordered[-1] / base_ms,
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
