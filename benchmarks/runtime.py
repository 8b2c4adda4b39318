"""`bywire bench runtime`: publish-to-receive latency and throughput of the object store, in one
process and across processes, each next to a plain-queue baseline measured in the same run.

Rows (each for a small object, ten floats in a frozen dataclass, and a scan-sized one, a
(130000, 4) float32 LIDAR scan of 2.08 MB):

- in process: `ObjectStore.publish` -> `Subscription.wait` in another thread; baseline
  `queue.Queue.put` -> `get` in another thread.
- across processes: the runtime's transport (`transport.py`: pyzmq PUSH/PULL over ipc://), measured
  end to end, from `ObjectStore.publish` in this process (the `TopicPublisher` tap sends it) to
  `Subscription.wait` in a thread of the receiving process (its `TopicSubscriber` publishes into
  that process's store); baseline `multiprocessing.Queue` (pickle in band over a pipe, what a user
  of the standard library would write). The candidates the transport was chosen from are measured
  in the same run, raw (no store on either side: from the send call to their receive thread or
  callback), all with the transport's pickle-5 encoding with out-of-band buffers: pyzmq with the
  transport's sockets (PUSH/PULL over ipc://), iceoryx2 publish-subscribe on shared memory with its
  event service to wake the reader (one sample per object, frames at 64-byte aligned offsets), and
  eclipse-zenoh peer to peer over a unix socket (its shared-memory provider works from Python but
  copies every payload into and out of it, so it is off). iceoryx2 and zenoh are optional (the
  `bench` extra): a row says so when one is missing. The candidates run side by side and take turns
  in short rounds, so that load on the (shared) machine hits all alike.

Setup (`setup` in the JSON): what it costs to set up and tear down one endpoint pair (a sender and
a receiver with its receive thread, both in this process, as the host makes one per direction for
each process-isolated module), per candidate, interleaved like the rest, after one uncounted
warm-up each (imports, a process-wide context): `create_*_ms` (making the endpoint, sender and
receiver), `first_*_ms` (from then until the first object, sent every millisecond, arrives: a
transport may connect in the background) and `close_*_ms` (closing both and dropping them), each
as p50 / p99 / max; `stall_max_ms` and `stall_p50_ms`: how late a 1 ms `time.sleep` loop in
another thread of this process woke up during the create and close operations (the largest, and
the median over operations), i.e. how long an operation kept other Python threads (the host's
scheduler) from running, mostly by holding the GIL. The `idle` row is that loop while this thread
only sleeps, in 10 ms windows between the others: the machine's own noise.

Recorder kill (`recorder_kill` in the JSON): how much a recording loses when its process is killed,
against the flush interval (benchmarks/recorder_kill.py).

Latency: the sender stamps `time.perf_counter_ns()` (CLOCK_MONOTONIC, shared by all processes of the
machine) into the object just before publishing; the receiver subtracts it from its own clock on
receipt. Objects are paced (small at 1 kHz, scans at 50 Hz) so the numbers are latency, not queueing.
Throughput: a burst sent as fast as the sender can, objects delivered per second from the first send
to the last receipt; transports that drop rather than block report how many arrived.

Each ratio is the row's value over its baseline's (latency: > 1 is slower than the baseline;
throughput: > 1 is faster). In one process nothing is copied (both rows pass a reference), so the
scan rows' MB/s only say how many references per second. The machine matters more than anything
here: on a shared 2-core VM a thread wake-up alone costs tens to hundreds of microseconds, and
p99/max are set by the hypervisor; compare rows of one run, not runs.

The objects and the candidates are in `runtime_transports`, the phases that measure them in
`runtime_phases` (seed 000 section 3: the object store relays objects between processes; DESIGN.md
section 5: distributions and ratios from the same run).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks import recorder_kill
from benchmarks.runtime_phases import bench_cross_process, bench_in_process, bench_setup, with_baseline
from benchmarks.runtime_transports import CANDIDATES, KINDS, object_bytes
from bywire.host.runtime import transport

DEFAULT_SECONDS = 30.0


# -- the command ---------------------------------------------------------------------------------------


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", type=Path, help="write the results as JSON")
    p.add_argument(
        "--seconds",
        type=float,
        default=DEFAULT_SECONDS,
        help=f"roughly how long the whole run takes (default {DEFAULT_SECONDS:.0f}); scales every phase",
    )


def _fmt(value: Any, digits: int = 0) -> str:
    return "-" if value is None else f"{value:,.{digits}f}"


def _print_table(doc: dict[str, Any]) -> None:
    head = (
        f"{'':29} {'p50 us':>9} {'p99 us':>9} {'max us':>9} {'obj/s':>10} {'MB/s':>8}"
        f"   {'x base p50':>10} {'x base p99':>10} {'x base obj/s':>12}"
    )
    for kind in KINDS:
        print(f"\n{kind} objects ({object_bytes(kind):,} bytes encoded)")
        print(head)

        def line(label: str, row: dict[str, Any]) -> None:
            if "error" in row:
                print(f"  {label:27} failed: {row['error']}")
                return
            lost = "" if row.get("delivered") == row.get("sent") else f"  ({row['delivered']}/{row['sent']})"
            ratios = ""
            if "ratio_p50" in row:
                ratios = (
                    f"   {_fmt(row['ratio_p50'], 2):>10} {_fmt(row['ratio_p99'], 2):>10} "
                    f"{_fmt(row['ratio_throughput_per_s'], 2):>12}"
                )
            print(
                f"  {label:27} {_fmt(row['p50_us']):>9} {_fmt(row['p99_us']):>9} {_fmt(row['max_us']):>9} "
                f"{_fmt(row['throughput_per_s']):>10} {_fmt(row['mb_per_s'], 1):>8}{ratios}{lost}"
            )

        ip = doc["in_process"][kind]
        line("in process: store", ip)
        line(
            "in process: queue.Queue", {k.removeprefix("baseline_"): v for k, v in ip.items() if "base" in k}
        )
        for name, row in doc["candidates"][kind].items():
            label = {"transport": "x-proc: transport, store-store", "mp_queue": "x-proc: mp.Queue"}.get(
                name, f"x-proc: {name} (raw)"
            )
            line(label, row)
    _print_setup(doc["setup"])


def _print_setup(setup: dict[str, dict[str, Any]]) -> None:
    print(
        "\nsetting up and tearing down a pair (ms; stall: how late a 1 ms sleep loop in another thread woke)"
    )
    print(
        f"  {'':12} {'create p50':>10} {'p99':>7} {'max':>7}   {'first p50':>9} {'max':>7}   "
        f"{'close p50':>9} {'p99':>7} {'max':>7}   {'stall p50':>9} {'max':>7}"
    )
    for name, row in setup.items():
        if "error" in row:
            print(f"  {name:12} failed: {row['error']}")
        elif name == "idle":
            print(
                f"  {name:12} {'':>79}   {_fmt(row['stall_p50_ms'], 2):>9} {_fmt(row['stall_max_ms'], 2):>7}"
            )
        else:
            print(
                f"  {name:12} {_fmt(row['create_p50_ms'], 2):>10} {_fmt(row['create_p99_ms'], 2):>7} "
                f"{_fmt(row['create_max_ms'], 2):>7}   {_fmt(row['first_p50_ms'], 2):>9} "
                f"{_fmt(row['first_max_ms'], 2):>7}   {_fmt(row['close_p50_ms'], 2):>9} "
                f"{_fmt(row['close_p99_ms'], 2):>7} {_fmt(row['close_max_ms'], 2):>7}   "
                f"{_fmt(row['stall_p50_ms'], 2):>9} {_fmt(row['stall_max_ms'], 2):>7}"
            )


def run(seconds: float = DEFAULT_SECONDS, candidates: Sequence[str] = CANDIDATES) -> dict[str, Any]:
    scale = max(0.01, seconds / DEFAULT_SECONDS)
    doc: dict[str, Any] = {
        "seconds": seconds,
        "choice": transport.CHOICE,
        "machine": {
            "cpus": os.cpu_count(),
            "platform": platform.platform(),
            "python": platform.python_version(),
        },
        "object_bytes": {kind: object_bytes(kind) for kind in KINDS},
        "measured_to": {
            "in_process": "Subscription.wait in another thread",
            "cross_process": "Subscription.wait on the receiving process's store (transport row); "
            "the receive thread or callback (raw candidates)",
        },
        "in_process": {},
        "cross_process": {},
        "candidates": {kind: {} for kind in KINDS},
        "setup": {},
    }
    for kind in KINDS:
        print(f"in process, {kind} objects ...", flush=True)
        doc["in_process"][kind] = bench_in_process(kind, scale)
    print(f"setting up and tearing down pairs, interleaved: {', '.join(candidates)} ...", flush=True)
    doc["setup"] = bench_setup(candidates, scale)
    print(f"across processes, interleaved: {', '.join(candidates)} ...", flush=True)
    doc["candidates"] = bench_cross_process(candidates, scale)
    for kind in KINDS:
        base = doc["candidates"][kind].get("mp_queue", {})
        for name, row in doc["candidates"][kind].items():
            if name != "mp_queue" and "error" not in row and "error" not in base:
                doc["candidates"][kind][name] = with_baseline(row, base)
        chosen = doc["candidates"][kind].get("transport")
        if chosen is not None:
            doc["cross_process"][kind] = chosen
    print("killing recorders ...", flush=True)
    doc["recorder_kill"] = recorder_kill.run(runs=max(3, round(8 * scale)))
    return doc


def main(args: argparse.Namespace) -> int:
    doc = run(DEFAULT_SECONDS if args.seconds is None else args.seconds)  # the CLI's default is None
    _print_table(doc)
    recorder_kill.print_row(doc["recorder_kill"])
    print(f"\ncross-process transport: {doc['choice']}")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    failed = [k for k in KINDS if "error" in doc["cross_process"].get(k, {"error": 1})]
    return 1 if failed else 0
