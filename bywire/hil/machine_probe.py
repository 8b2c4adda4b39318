"""Did the machine itself stall? Probes at the top real-time priority, beside a three-process HIL run.

When the ECU's watchdog stops a car in HIL, the stall recorders of the host and the plant say which of
them fell behind and where (`stall_report`), but not whether any process could have run at all. On a
kernel without preemption (CONFIG_PREEMPT_NONE, as on the shared 2-core VMs this project is tested on) a
system call of any process holds its CPU to its end, and a virtual machine's CPUs can be withheld by its
host; then the processes on that CPU fall behind, the ECU at SCHED_FIFO 80 included, for reasons no
priority of ours controls. The probes tell the two apart: one process per CPU, pinned to it, at
SCHED_FIFO 99 (above every process of the run) with locked memory, doing nothing but wake on an absolute
2 ms grid (`WallClock.sleep_until`). A wake that comes `STALL_MS` or more late means that CPU could not
be given to the highest priority there is for that long: the kernel or the hypervisor held it, and any
process of ours the scheduler had placed there (an unpinned ECU wakes on the CPU where it last ran)
waited with it. Per CPU because that is how the stalls come: a probe free to move runs on whichever CPU
is free and sees only the stalls of the whole machine. Each stall is recorded with its instant
(CLOCK_MONOTONIC, the run's time base) and the CPU time the hypervisor reports stolen since the previous
one (/proc/stat `steal`).

What it cannot tell: whose system call held a CPU. A stall caused by a system call of one of our own
processes (a large allocation populated under mlockall, an fsync) looks the same; the stall's CPU and
instant are recorded so that a reader can look. It is evidence, never a verdict: the ECU's LOOP_STALL
stays a stop fault whatever the cause (a car's ECU that misses 20 ms is not to be trusted with the
brake), and the run fails as it should. A test rig may use the evidence to rerun a run the machine
spoiled (tests/hil_process_run.py does, and says so).

Not from the seed papers: AnnieWAY's ECU ran on dedicated hardware. Cost: one wake per 2 ms per CPU of
about 30 us, 1-2 % of each CPU.

Run as `python -m bywire.hil.machine_probe --cpu N --out FILE`: prints `ready`, probes until SIGINT or
SIGTERM, then writes FILE (JSON: `MachineProbe.summary`); `merge_summaries` joins the CPUs' files.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bywire.clock import WallClock
from bywire.process_util import StopFlag
from bywire.realtime import apply_realtime
from bywire.rhythm import GapHistogram

__all__ = ["PERIOD_S", "STALL_MS", "MachineProbe", "main", "merge_summaries", "steal_s"]

PERIOD_S = 0.002
# A stall worth recording: a quarter of the ECU's loop-stall bound (20 ms), ten of our periods; wakes a
# few ms late are common on a busy VM and explain nothing.
STALL_MS = 5.0
PRIORITY = 99
MAX_STALLS = 2000  # a run of hours on a bad machine keeps its first stalls and counts the rest


def steal_s(stat_text: str) -> float | None:
    """The machine's stolen CPU time in seconds from /proc/stat's aggregate `cpu` line (the eighth
    value, USER_HZ ticks), or None when the kernel does not report it."""
    for line in stat_text.splitlines():
        if line.startswith("cpu "):
            values = line.split()[1:]
            if len(values) < 8:
                return None
            ticks = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
            return int(values[7]) / float(ticks)
    return None


def _read_steal_s() -> float | None:
    try:
        return steal_s(Path("/proc/stat").read_text(encoding="ascii"))
    except OSError:
        return None


@dataclass
class MachineProbe:
    """The probe's bookkeeping, apart from its loop so that it is tested without a real-time process."""

    period_s: float = PERIOD_S
    stall_ms: float = STALL_MS
    wakes: int = 0
    stalls: list[dict[str, Any]] = field(default_factory=list)
    dropped: int = 0
    lateness: GapHistogram = field(default_factory=lambda: GapHistogram(bin_ms=0.05))
    _steal_at_last_s: float | None = None
    _steal_at_start_s: float | None = None

    def start(self, steal_now_s: float | None) -> None:
        self._steal_at_start_s = self._steal_at_last_s = steal_now_s

    def woke(
        self, due_s: float, now_s: float, read_steal: Callable[[], float | None] = _read_steal_s
    ) -> None:
        """Book one wake due at `due_s` that came at `now_s` (CLOCK_MONOTONIC seconds)."""
        late_ms = max(0.0, (now_s - due_s) * 1e3)
        self.wakes += 1
        self.lateness.add(late_ms / 1e3, due_s)
        if late_ms < self.stall_ms:
            return
        steal = read_steal()  # only after a stall: reading /proc/stat costs a few tens of us
        stolen_ms = None
        if steal is not None and self._steal_at_last_s is not None:
            stolen_ms = round((steal - self._steal_at_last_s) * 1e3, 1)
        self._steal_at_last_s = steal
        if len(self.stalls) < MAX_STALLS:
            stall = {"from_s": due_s, "late_ms": round(late_ms, 3), "steal_ms_since_last": stolen_ms}
            self.stalls.append(stall)
        else:
            self.dropped += 1

    def summary(
        self, realtime: str, steal_now_s: float | None, cpu: int | None = None, fifo: bool = True
    ) -> dict[str, Any]:
        """The JSON the probe writes: its set-up, its lateness (`GapHistogram` quantiles), and every stall
        of `stall_ms` or more (`from_s`: when the late wake was due, CLOCK_MONOTONIC)."""
        steal = None
        if steal_now_s is not None and self._steal_at_start_s is not None:
            steal = round((steal_now_s - self._steal_at_start_s) * 1e3, 1)
        return {
            "cpu": cpu,
            "fifo": fifo,
            "priority": PRIORITY,
            "period_ms": self.period_s * 1e3,
            "stall_threshold_ms": self.stall_ms,
            "realtime": realtime,
            "wakes": self.wakes,
            "late_ms": self.lateness.to_json(),
            "steal_ms": steal,
            "stalls": self.stalls,
            "dropped": self.dropped,
        }


def merge_summaries(docs: list[dict[str, Any]], t0: float) -> dict[str, Any]:
    """One summary of the CPUs' probes: the lateness over all wakes, each CPU's own (`cpus`), and every
    stall with its `cpu`, in run time (`from_s` seconds after `t0`), in time order. A probe the system
    refused SCHED_FIFO (no root, no CAP_SYS_NICE) waited behind ordinary processes, so its late wakes say
    nothing about the machine: its stalls are left out, and `cpus` says why."""
    lateness = GapHistogram(bin_ms=0.05)
    stalls: list[dict[str, Any]] = []
    cpus: dict[str, Any] = {}
    for doc in docs:
        lateness.merge(GapHistogram.from_json(doc["late_ms"]))
        if doc.get("fifo", True):
            stalls += [{**s, "from_s": round(s["from_s"] - t0, 3), "cpu": doc["cpu"]} for s in doc["stalls"]]
        late = {k: doc["late_ms"][k] for k in ("p50", "p99", "p999", "max")}
        cpus[str(doc["cpu"])] = {
            "realtime": doc["realtime"],
            "stalls_kept": bool(doc.get("fifo", True)),
            "wakes": doc["wakes"],
            "late_ms": late,
        }
    return {
        "priority": PRIORITY,
        "stall_threshold_ms": docs[0]["stall_threshold_ms"] if docs else STALL_MS,
        "wakes": lateness.count,
        "late_ms": lateness.summary(),
        "steal_ms": max((d["steal_ms"] for d in docs if d["steal_ms"] is not None), default=None),
        "cpus": cpus,
        "stalls": sorted(stalls, key=lambda s: s["from_s"]),
        "dropped": sum(d["dropped"] for d in docs),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bywire.hil.machine_probe", description=__doc__)
    parser.add_argument("--out", type=Path, required=True, help="where the summary JSON goes at the end")
    parser.add_argument("--cpu", type=int, default=None, help="the CPU to probe (default: any, free to move)")
    parser.add_argument("--period-ms", type=float, default=PERIOD_S * 1e3)
    args = parser.parse_args(argv)
    stop = StopFlag()
    report = apply_realtime(PRIORITY, cpu=args.cpu)
    probe = MachineProbe(period_s=args.period_ms / 1e3)
    clock = WallClock()
    print("ready", flush=True)
    probe.start(_read_steal_s())
    due = clock.now() + probe.period_s
    while not stop():
        clock.sleep_until(due)
        now = clock.now()
        if now < due:  # a signal woke us early
            continue
        probe.woke(due, now)
        # The next instant on the grid after now: a stall is one late wake, not a burst of catch-ups.
        due += probe.period_s * max(1, int((now - due) / probe.period_s) + 1)
    summary = probe.summary(report.summary(), _read_steal_s(), args.cpu, report.sched_fifo.applied)
    args.out.write_text(json.dumps(summary), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
