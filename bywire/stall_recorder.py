"""Stall recorder: when a process misses its rhythm, what each of its threads was doing.

DESIGN section 4's timing budget holds only if every process keeps its period; the watchdogs tell the
ECU that one did not (seed 000 section 12: AnnieWAY lost the 2007 final to a process that stalled), but
not why. A process beats on named channels — the host at every scheduler tick and every heartbeat it
sends, the plant at every 1 kHz step — each with the silence that counts as a stall. A watchdog thread,
above the process's own work in real-time priority, looks every `poll_s`; when a channel has been
silent for longer than its gap it records, once per stall:

- the channel, when it last beat (process clock), and, once it beats again, how long the gap was;
- `watchdog_late_ms`: how late the watchdog itself woke. A late watchdog means the whole process was
  kept off the CPU (a higher-priority process, a stalled VM) or a thread held the GIL in native code;
- per thread: its name, its scheduler state (R runnable, S sleeping, D in the kernel), the CPU time it
  used since the watchdog's previous sample (from /proc/self/task/TID/schedstat), and the innermost
  frames of its Python stack (`sys._current_frames`): the thread that burned the CPU, and the call
  it was in, name the culprit;
- `process_cpu_ms`: CPU time of all threads since that sample; with the gap, the share of a CPU the
  process got while it was stalled.

Every channel also keeps the distribution of its gaps between beats (`rhythm.GapHistogram`): the
rhythm a run kept, not only the times it broke (`summary()["rhythm_ms"]`: p50, p99, p99.9, max).

The recorder costs one clock read and one histogram increment per beat and, every `sample_s`, one read
of /proc per thread. It never blocks a beating thread: beats are plain stores, the watchdog does
everything else.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from bywire.process_util import task_cpu_time_s, task_state
from bywire.rhythm import GapHistogram

KEEP_LONGEST = 60  # a run that stalls often keeps its longest stalls ...
KEEP_LATEST = 60  # ... and its latest ones (a watchdog that fired late in a run); the rest is counted
STACK_FRAMES = 4  # innermost frames kept per thread


def _innermost(frame: Any, depth: int = STACK_FRAMES) -> list[str]:
    """`file:line function` of the innermost frames, innermost last. Read from the frame objects only:
    `traceback` would fetch each source line (linecache reads the files), which stalled a 1 kHz loop
    for 200 ms the first time."""
    out: list[str] = []
    f = frame
    while f is not None and len(out) < depth:
        code = f.f_code
        out.append(f"{os.path.basename(code.co_filename)}:{f.f_lineno} {code.co_name}")
        f = f.f_back
    return out[::-1]


@dataclass
class _Channel:
    gap_s: float
    last_s: float | None = None
    open_record: dict[str, Any] | None = None  # the stall being recorded on this channel
    rhythm: GapHistogram = field(default_factory=GapHistogram)


@dataclass
class StallRecorder:
    """`beat(channel)` from the process's loops; `start()` the watchdog; `records` the evidence."""

    process: str
    gaps_s: dict[str, float]
    poll_s: float = 0.005
    sample_s: float = 0.05
    rt_priority: int = 0  # SCHED_FIFO priority of the watchdog (0: normal scheduling)
    records: list[dict[str, Any]] = field(default_factory=list)
    dropped: int = 0
    clock: Any = time.monotonic

    def __post_init__(self) -> None:
        self._channels = {name: _Channel(gap) for name, gap in self.gaps_s.items()}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._cpu_before: dict[int, float] = {}
        self._sampled_s = 0.0

    def beat(self, channel: str, now_s: float | None = None) -> None:
        """The channel's work happened now (cheap: a store; the watchdog does the rest)."""
        ch = self._channels[channel]
        t = self.clock() if now_s is None else now_s
        if ch.last_s is not None:
            ch.rhythm.add(t - ch.last_s, t)
        ch.last_s = t
        rec = ch.open_record
        if rec is not None:  # the stall is over: its length, as the watchdog reads it next
            rec["gap_ms"] = round((t - rec["_since_s"]) * 1e3, 3)
            ch.open_record = None

    def start(self) -> None:
        self._sample_cpu()
        self._thread = threading.Thread(
            target=self._watch, name=f"stall-recorder-{self.process}", daemon=True
        )
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(1.0)

    def summary(self) -> dict[str, Any]:
        """The records kept (the watchdog's private fields left out) and how many were dropped."""
        out = [{k: v for k, v in r.items() if not k.startswith("_")} for r in self.records]
        return {
            "process": self.process,
            "gaps_ms": {k: v * 1e3 for k, v in self.gaps_s.items()},
            "stalls": out,
            "dropped": self.dropped,
            "rhythm_ms": {name: ch.rhythm.to_json() for name, ch in self._channels.items()},
        }

    # -- the watchdog ------------------------------------------------------------------------------

    def _watch(self) -> None:
        if self.rt_priority:
            with contextlib.suppress(OSError, AttributeError, PermissionError):
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.rt_priority))
        next_s = self.clock() + self.poll_s
        while not self._stop.is_set():
            delay = next_s - self.clock()
            if delay > 0:
                time.sleep(delay)
            woke_s = self.clock()
            late_s = max(0.0, woke_s - next_s)
            next_s = max(next_s + self.poll_s, woke_s)
            for name, ch in self._channels.items():
                if ch.last_s is None or ch.open_record is not None:
                    continue
                if woke_s - ch.last_s > ch.gap_s:
                    self._record(name, ch, woke_s, late_s)
            if woke_s - self._sampled_s >= self.sample_s:
                self._sample_cpu()

    def _sample_cpu(self) -> None:
        cpu: dict[int, float] = {}
        with contextlib.suppress(OSError):
            for entry in os.listdir("/proc/self/task"):
                v = task_cpu_time_s("self", int(entry))
                if v is not None:
                    cpu[int(entry)] = v
        self._cpu_before = cpu
        self._sampled_s = self.clock()

    def _prune(self) -> None:
        """Keep the longest and the latest records (in time order); count the others as dropped."""
        if len(self.records) <= 2 * (KEEP_LONGEST + KEEP_LATEST):
            return
        closed = [r for r in self.records if r["gap_ms"] is not None]
        longest = sorted(closed, key=lambda r: r["gap_ms"], reverse=True)[:KEEP_LONGEST]
        keep = {id(r) for r in longest} | {id(r) for r in self.records[-KEEP_LATEST:]}
        kept = [r for r in self.records if id(r) in keep]
        self.dropped += len(self.records) - len(kept)
        self.records = kept

    def _record(self, name: str, ch: _Channel, now_s: float, late_s: float) -> None:
        self._prune()
        assert ch.last_s is not None
        alive = threading.enumerate()
        names = {t.native_id: t.name for t in alive if t.native_id is not None}
        idents = {t.ident: t.native_id for t in alive}
        frames = sys._current_frames()
        threads: dict[str, Any] = {}
        total_ms = 0.0
        since_sample_s = now_s - self._sampled_s
        for ident, frame in frames.items():
            tid = idents.get(ident)
            if tid is None or tid == threading.get_native_id():
                continue
            cpu = task_cpu_time_s("self", tid)
            used_ms = None
            if cpu is not None and tid in self._cpu_before:
                used_ms = round((cpu - self._cpu_before[tid]) * 1e3, 3)
                total_ms += used_ms
            threads[names.get(tid, str(tid))] = {
                "state": task_state("self", tid),
                "cpu_ms_since_sample": used_ms,
                "stack": _innermost(frame),
            }
        rec = {
            "_since_s": ch.last_s,
            "channel": name,
            "last_beat_s": round(ch.last_s, 6),
            "seen_after_ms": round((now_s - ch.last_s) * 1e3, 3),
            "gap_ms": None,  # set when the channel beats again
            "watchdog_late_ms": round(late_s * 1e3, 3),
            "sample_window_ms": round(since_sample_s * 1e3, 3),
            "process_cpu_ms": round(total_ms, 3),
            "threads": threads,
        }
        # Busiest first: the thread that burned the CPU during the gap is the first suspect.
        busiest = max(threads.items(), key=lambda kv: kv[1]["cpu_ms_since_sample"] or 0.0, default=None)
        rec["busiest_thread"] = busiest[0] if busiest is not None else None
        self.records.append(rec)
        ch.open_record = rec
