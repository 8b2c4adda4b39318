"""`bywire bench hil [--load]`: the three-process HIL as CI and users run it, with and without a
standard background load, and whether the ECU ever stops the car for the computer's sake.

Each run is `bywire hil run SCENARIO --mode hil` in a process of its own (bus servers, ECU, plant and
host as separate processes): the GCDC heat's first 60 s (seed 003, `hil_variants.gcdc_heat_hil`) and
the urban four-way stop with a car waiting (seed 000 section 8). With `--load` the benchmark starts
the standard background load beside every run — one CPU-bound process at normal priority and one
disk writer (4 MiB blocks, each flushed with fsync) — and measures the same scenarios without it as
the baseline of the same invocation (DESIGN section 5: numbers from one run, side by side, never
asserted).

Reported per scenario and load, from each process's own rhythm (`bywire.rhythm` histograms, merged
over the runs): the host's ECU-link period (its 20 ms heartbeat and request, on its own clock) and
its 1 ms scheduler tick, the plant's 1 kHz step, the ECU's loop lateness, the gaps between the host's
heartbeats as the ECU received them (what its watchdog judges), the ECU's faults, pass/fail, and the
spurious stops: a run whose ECU went to SAFE_STOP although the scenario provokes none (neither
scenario does). The target (DESIGN section 4): no spurious stop in 20 loaded runs of each, and the
host's heartbeat gap under 50 ms.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bywire.hil.hil_variants import four_way_stop_hil, gcdc_heat_hil
from bywire.host.trace import HOST_COLUMNS, read_trace
from bywire.protocol.ecu_types import EcuState, Fault
from bywire.rhythm import GapHistogram

SCENARIOS = ("gcdc_heat_hil", "four_way_stop_hil")
HEARTBEAT_TARGET_MS = 50.0
RUN_TIMEOUT_S = 400.0
DISK_BLOCK = 4 << 20
DISK_FILE_MAX = 256 << 20

_CPU_HOG = "while True: pass"
_DISK_WRITER = f"""
import os, sys
block = os.urandom({DISK_BLOCK})
path = sys.argv[1]
while True:
    with open(path, "wb") as f:
        for _ in range({DISK_FILE_MAX // DISK_BLOCK}):
            f.write(block)
            f.flush()
            os.fsync(f.fileno())
"""


# The machine's own floor: a bare SCHED_FIFO 1 kHz loop that does nothing, in a process of its own,
# under the same load. What it is late, every real-time process of the run is late too.
_BARE_LOOP = """
import json, os, sys, time
try:
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(90))
except (OSError, AttributeError):
    pass
late = []
nxt = time.monotonic()
end = nxt + float(sys.argv[1])
while nxt < end:
    nxt += 0.001
    d = nxt - time.monotonic()
    if d > 0:
        time.sleep(d)
    late.append(time.monotonic() - nxt)
late.sort()
q = lambda f: round(late[min(len(late) - 1, int(f * len(late)))] * 1e3, 3)
print(json.dumps({"p50": q(0.5), "p99": q(0.99), "p999": q(0.999), "max": round(late[-1] * 1e3, 3)}))
"""
BARE_LOOP_S = 10.0


def _pinned(cpus: set[int] | None) -> Any:
    """A `preexec_fn` that confines the child to `cpus` (None: leave it where the scheduler puts it)."""
    return None if cpus is None else (lambda: os.sched_setaffinity(0, cpus))


@dataclass(frozen=True)
class Partition:
    """Which CPU the ECU has to itself and where the rest of the machine's work goes: the layout a
    real-time engineer gives a 2-core box when the kernel cannot be made preemptible (`isolcpus` or a
    cpuset on a car). This kernel runs without preemption (CONFIG_PREEMPT_NONE): a normal process's
    write and fsync hold the CPU they run on for up to ~40 ms, SCHED_FIFO or not, and only the other
    CPU is free of it."""

    ecu_cpu: int
    housekeeping: frozenset[int]

    @classmethod
    def of_this_machine(cls) -> Partition:
        cpus = sorted(os.sched_getaffinity(0))
        if len(cpus) < 2:
            raise ValueError(f"--partition needs two CPUs or more; this process may use {cpus}")
        return cls(cpus[-1], frozenset(cpus[:-1]))


def bare_loop_lateness_ms(seconds: float = BARE_LOOP_S, cpu: int | None = None) -> dict[str, float]:
    out = subprocess.run(
        [sys.executable, "-c", _BARE_LOOP, str(seconds)],
        capture_output=True,
        text=True,
        timeout=seconds + 30,
        preexec_fn=_pinned(None if cpu is None else {cpu}),
    )
    doc: dict[str, float] = json.loads(out.stdout)
    return doc


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--load", action="store_true", help="add the standard background load (CPU hog + disk)")
    p.add_argument(
        "--no-disk", action="store_true", help="the load without its disk writer (the CPU hog alone)"
    )
    p.add_argument(
        "--partition",
        action="store_true",
        help="loaded runs also with the ECU pinned to the last CPU and the load confined to the others",
    )
    p.add_argument("--runs", type=int, default=20, help="loaded runs of each scenario (default 20)")
    p.add_argument(
        "--unloaded-runs",
        type=int,
        default=None,
        help="runs of each scenario without load (default: --runs without --load, else a quarter of it)",
    )
    p.add_argument("--scenario", choices=SCENARIOS, action="append", help="only this one (repeatable)")
    p.add_argument("--gcdc-seconds", type=float, default=60.0, help="GCDC heat run length (default 60)")
    p.add_argument("--json", type=Path, metavar="FILE", help="write the results as JSON")
    p.add_argument("--keep", type=Path, metavar="DIR", help="keep every run's report folder under DIR")


@contextlib.contextmanager
def background_load(
    folder: Path, disk: bool = True, cpus: frozenset[int] | None = None
) -> Iterator[list[subprocess.Popen[bytes]]]:
    """The standard load: a CPU-bound process and a disk writer, both at normal priority, on `cpus`
    (default: wherever the scheduler puts them)."""
    where = _pinned(None if cpus is None else set(cpus))
    procs = [subprocess.Popen([sys.executable, "-c", _CPU_HOG], preexec_fn=where)]
    if disk:
        writer = [sys.executable, "-c", _DISK_WRITER, str(folder / "disk_load.bin")]
        procs.append(subprocess.Popen(writer, preexec_fn=where))
    try:
        yield procs
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait()
        with contextlib.suppress(OSError):
            (folder / "disk_load.bin").unlink()


def scenario_doc(name: str, gcdc_seconds: float) -> dict[str, Any]:
    return gcdc_heat_hil(gcdc_seconds) if name == "gcdc_heat_hil" else four_way_stop_hil()


@dataclass
class Tally:
    """One scenario under one load, over its runs."""

    runs: int = 0
    passed: int = 0
    spurious_stops: int = 0
    errors: int = 0
    host_link: GapHistogram = field(default_factory=GapHistogram)
    host_tick: GapHistogram = field(default_factory=GapHistogram)
    plant: GapHistogram = field(default_factory=GapHistogram)
    ecu_heard: GapHistogram = field(default_factory=GapHistogram)
    ecu_lateness_ms: list[float] = field(default_factory=list)  # per run: max
    ecu_lateness_p99_ms: list[float] = field(default_factory=list)
    ecu_faults: dict[str, int] = field(default_factory=dict)
    stops: list[dict[str, Any]] = field(default_factory=list)
    machine_late_ms: list[float] = field(default_factory=list)  # per run: the CPU probes' worst wake

    def add(self, run: dict[str, Any]) -> None:
        self.runs += 1
        if run.get("error"):
            self.errors += 1
            return
        self.passed += int(run["passed"])
        if run["spurious_stop"] is not None:
            self.spurious_stops += 1
            self.stops.append(run["spurious_stop"])
        for name, hist in (
            ("host_link", self.host_link),
            ("host_tick", self.host_tick),
            ("plant", self.plant),
        ):
            if run["rhythm"].get(name) is not None:
                hist.merge(GapHistogram.from_json(run["rhythm"][name]))
        heard = run.get("ecu_heard_heartbeat")
        if heard is not None:
            self.ecu_heard.merge(GapHistogram.from_json(heard))
        if run.get("ecu_lateness_us"):
            self.ecu_lateness_ms.append(run["ecu_lateness_us"]["max"] / 1e3)
            self.ecu_lateness_p99_ms.append(run["ecu_lateness_us"]["p99"] / 1e3)
        for f in run["faults"]:
            self.ecu_faults[f] = self.ecu_faults.get(f, 0) + 1
        if run.get("machine_late_max_ms") is not None:
            self.machine_late_ms.append(run["machine_late_max_ms"])

    def doc(self) -> dict[str, Any]:
        def gaps(h: GapHistogram) -> dict[str, Any]:
            s = h.summary()
            return {k: s[k] for k in ("p50", "p99", "p999", "max", "count")}

        return {
            "runs": self.runs,
            "passed": self.passed,
            "errors": self.errors,
            "spurious_stops": self.spurious_stops,
            "host_gap_ms": gaps(self.host_link),
            "host_tick_gap_ms": gaps(self.host_tick),
            "heartbeat_gap_max_ms": round(self.ecu_heard.max_s * 1e3, 3),
            "heartbeat_gap_ms": gaps(self.ecu_heard),
            "plant_gap_ms": gaps(self.plant),
            "ecu_lateness_ms": {
                "p99_worst_run": round(max(self.ecu_lateness_p99_ms, default=0.0), 3),
                "max": round(max(self.ecu_lateness_ms, default=0.0), 3),
            },
            "ecu_faults": dict(sorted(self.ecu_faults.items())),
            # bywire.hil.machine_probe: how long a CPU was withheld from SCHED_FIFO 99, worst run
            "machine_late_max_ms": round(max(self.machine_late_ms, default=0.0), 3),
            "stops": self.stops,
        }


def _fault_names(bits: int) -> list[str]:
    return [str(f.name) for f in Fault if bits & int(f)]


def judge_run(result: dict[str, Any], report: Path, duration_s: float = float("inf")) -> dict[str, Any]:
    """What one run's result and host trace say: pass, the first SAFE_STOP before the scenario's end
    (after it the plant stops sending and the ECU rightly stops the car), faults seen, rhythms."""
    host = read_trace(report / "host.csv", HOST_COLUMNS) if (report / "host.csv").exists() else None
    stop = None
    faults: set[str] = set()
    if host is not None and len(host["t_s"]):
        state = host["ecu_state"].astype(int)
        bits = host["ecu_faults"].astype(int)
        engaged = np.flatnonzero(state == int(EcuState.ENGAGED))
        after = engaged[0] if len(engaged) else len(state)
        for b in np.unique(bits[after:]):
            faults.update(_fault_names(int(b)))
        during = host["t_s"] - host["t_s"][0] < duration_s
        stopped = np.flatnonzero((state == int(EcuState.SAFE_STOP)) & during)
        if len(stopped):
            i = int(stopped[0])
            stop = {
                "at_s": round(float(host["t_s"][i] - host["t_s"][0]), 3),
                "faults": _fault_names(int(bits[i])),
                "culprits": result.get("watchdog_culprits", []),
            }
    stalls = result.get("stalls", {})
    rhythm = {
        "host_link": stalls.get("host", {}).get("rhythm_ms", {}).get("ecu_link"),
        "host_tick": stalls.get("host", {}).get("rhythm_ms", {}).get("scheduler"),
        "plant": stalls.get("plant", {}).get("rhythm_ms", {}).get("step"),
    }
    loop = result.get("metrics", {}).get("ecu_loop", {})
    return {
        "passed": result.get("verdict") == "pass",
        "failed_checks": [c["name"] for c in result.get("checks", []) if not c.get("passed")],
        "spurious_stop": stop,
        "faults": sorted(faults),
        "rhythm": rhythm,
        "ecu_heard_heartbeat": _heard(loop),
        "ecu_lateness_us": loop.get("lateness_us"),
        "machine_late_max_ms": result.get("metrics", {}).get("machine_late_max_ms"),
    }


def _heard(loop: dict[str, Any]) -> dict[str, Any] | None:
    """The gaps between the host's heartbeats as the ECU received them (a histogram document)."""
    hb: dict[str, Any] | None = loop.get("host_link", {}).get("heartbeat_gap_ms")
    return hb if hb is not None and "bins" in hb else None


def run_once(doc: dict[str, Any], folder: Path, ecu_cpu: int | None = None) -> dict[str, Any]:
    folder.mkdir(parents=True, exist_ok=True)
    scenario = folder / f"{doc['name']}.yaml"
    scenario.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
    report = folder / "report"
    out = report / "result.json"
    argv = [sys.executable, "-m", "bywire", "hil", "run", str(scenario), "--mode", "hil", "--json", str(out),
            "--report", str(report), "--quiet"]  # fmt: skip
    if ecu_cpu is not None:
        argv += ["--ecu-cpu", str(ecu_cpu)]
    t = time.monotonic()
    try:
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=RUN_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return {"error": f"timed out after {RUN_TIMEOUT_S:.0f} s", "wall_s": RUN_TIMEOUT_S}
    if not out.exists():
        return {"error": (proc.stderr or proc.stdout)[-2000:], "wall_s": time.monotonic() - t}
    run = judge_run(json.loads(out.read_text(encoding="utf-8")), report, float(doc["duration_s"]))
    run["wall_s"] = round(time.monotonic() - t, 1)
    return run


def measure(
    names: tuple[str, ...],
    runs: int,
    loaded: bool,
    gcdc_seconds: float,
    keep: Path | None,
    disk: bool = True,
    partition: Partition | None = None,
) -> dict[str, Any]:
    per: dict[str, Tally] = {}
    log: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="bywire-bench-hil-") as tmp:
        base = keep if keep is not None else Path(tmp)
        cpus = None if partition is None else partition.housekeeping
        ecu_cpu = None if partition is None else partition.ecu_cpu
        load = background_load(Path(tmp), disk, cpus) if loaded else contextlib.nullcontext()
        with load:
            floor = bare_loop_lateness_ms(cpu=ecu_cpu)
            print(f"  machine floor (bare SCHED_FIFO 1 kHz loop, lateness ms): {floor}", flush=True)
            for k in range(runs):
                for name in names:
                    where = "-partitioned" if partition else ""
                    tag = f"{'loaded' if loaded else 'unloaded'}{where}-{name}-{k:02d}"
                    run = run_once(scenario_doc(name, gcdc_seconds), base / tag, ecu_cpu)
                    per.setdefault(name, Tally()).add(run)
                    log.append({"run": tag, **{key: run.get(key) for key in ("passed", "error", "wall_s")}})
                    stop = run.get("spurious_stop")
                    print(
                        f"  {tag}: {'error' if run.get('error') else 'pass' if run['passed'] else 'FAIL'}"
                        + (f", SAFE_STOP at {stop['at_s']} s {stop['faults']}" if stop else "")
                        + (f" ({run['error'][-200:]})" if run.get("error") else ""),
                        flush=True,
                    )
    scenarios = {name: t.doc() for name, t in per.items()}
    total = Tally()
    for t in per.values():
        total.runs += t.runs
        total.passed += t.passed
        total.errors += t.errors
        total.spurious_stops += t.spurious_stops
        total.stops += t.stops
        total.host_link.merge(t.host_link)
        total.host_tick.merge(t.host_tick)
        total.plant.merge(t.plant)
        total.ecu_heard.merge(t.ecu_heard)
        total.ecu_lateness_ms += t.ecu_lateness_ms
        total.ecu_lateness_p99_ms += t.ecu_lateness_p99_ms
        for f, n in t.ecu_faults.items():
            total.ecu_faults[f] = total.ecu_faults.get(f, 0) + n
    return {
        **total.doc(),
        "runs_per_scenario": runs,
        "machine_floor_lateness_ms": floor,
        "scenarios": scenarios,
        "log": log,
    }


def print_table(title: str, doc: dict[str, Any]) -> None:
    print(f"\n{title}")
    print(
        f"{'scenario':<20} {'runs':>4} {'pass':>4} {'stops':>5}  {'host link gap ms p50/p99/p99.9/max':>36}"
        f"  {'hb heard max':>12}  {'plant step p99/max':>18}  {'ECU late max':>12}  {'CPU stall max':>13}"
    )
    rows = [*doc["scenarios"].items(), ("all", doc)]
    for name, s in rows:
        h, p = s["host_gap_ms"], s["plant_gap_ms"]
        print(
            f"{name:<20} {s['runs']:>4} {s['passed']:>4} {s['spurious_stops']:>5}  "
            f"{h['p50']:>8.1f} {h['p99']:>8.1f} {h['p999']:>8.1f} {h['max']:>8.1f}  "
            f"{s['heartbeat_gap_max_ms']:>12.1f}  {p['p99']:>8.1f} {p['max']:>8.1f}  "
            f"{s['ecu_lateness_ms']['max']:>12.2f}  {s['machine_late_max_ms']:>13.2f}"
        )
    print(f"machine floor (bare SCHED_FIFO 1 kHz loop, lateness ms): {doc['machine_floor_lateness_ms']}")
    if doc["ecu_faults"]:
        print(f"ECU faults (runs that saw them after engaging): {doc['ecu_faults']}")


def _met(doc: dict[str, Any]) -> bool:
    return bool(doc["spurious_stops"] == 0 and doc["heartbeat_gap_max_ms"] < HEARTBEAT_TARGET_MS)


def main(args: argparse.Namespace) -> int:
    if args.runs < 1:
        print(f"bywire bench hil: --runs {args.runs} must be >= 1", file=sys.stderr)
        return 2
    partition = None
    if args.partition:
        if not args.load:
            print("bywire bench hil: --partition places the --load; give both", file=sys.stderr)
            return 2
        try:
            partition = Partition.of_this_machine()
        except ValueError as exc:
            print(f"bywire bench hil: {exc}", file=sys.stderr)
            return 2
    names = tuple(args.scenario or SCENARIOS)
    unloaded_runs = args.unloaded_runs
    if unloaded_runs is None:
        unloaded_runs = max(1, args.runs // 4) if args.load else args.runs
    cpus = os.cpu_count()
    print(
        f"bywire bench hil: {', '.join(names)}; {args.runs if args.load else 0} loaded and {unloaded_runs} "
        f"unloaded runs each, on {cpus} CPUs",
        flush=True,
    )
    unloaded = measure(names, unloaded_runs, False, args.gcdc_seconds, args.keep) if unloaded_runs else None
    doc: dict[str, Any]
    if args.load:
        doc = measure(names, args.runs, True, args.gcdc_seconds, args.keep, disk=not args.no_disk)
        doc["load"] = "one CPU-bound process at normal priority" + (
            "" if args.no_disk else " + a disk writer (4 MiB blocks, fsync)"
        )
        doc["unloaded"] = unloaded
        if partition is not None:
            doc["partitioned"] = measure(
                names, args.runs, True, args.gcdc_seconds, args.keep, not args.no_disk, partition
            )
            doc["partitioned"]["ecu_cpu"] = partition.ecu_cpu
            doc["partitioned"]["load_cpus"] = sorted(partition.housekeeping)
    else:
        assert unloaded is not None
        doc = {**unloaded, "load": None, "unloaded": unloaded}
    doc["targets"] = {
        "spurious_stops": 0,
        "heartbeat_gap_max_ms": HEARTBEAT_TARGET_MS,
        "met": _met(doc),
        **({"met_partitioned": _met(doc["partitioned"])} if "partitioned" in doc else {}),
    }
    if unloaded is not None:
        print_table("without load", unloaded)
    if args.load:
        print_table("with the standard load", doc)
    if partition is not None:
        print_table(
            f"with the standard load on CPU {sorted(partition.housekeeping)}, "
            f"the ECU alone on CPU {partition.ecu_cpu}",
            doc["partitioned"],
        )
    verdicts = [("", doc["targets"]["met"])]
    if "met_partitioned" in doc["targets"]:
        verdicts.append((" partitioned", doc["targets"]["met_partitioned"]))
    for label, met in verdicts:
        print(
            f"\ntarget{label} (no spurious stop, ECU-heard heartbeat gap < {HEARTBEAT_TARGET_MS:.0f} ms): "
            f"{'met' if met else 'NOT met'}"
        )
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    return 0
