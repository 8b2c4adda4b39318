"""`bywire bus serve` and `bywire protocol table`: a python-can virtual bus served to the processes of
this machine, and the protocol table generated from the DBC and the EDS (docs/protocol.md).

DESIGN.md section 3: buses are named by URL, and between processes on one machine a `virtual` bus
is served on 127.0.0.1 (section 5: these machines have no SocketCAN); the DBC and the EDS are the
protocol's single source of truth, so its table is generated, never written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_serve_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", type=int, default=54701)
    p.add_argument("--channel", default="bywire", help="virtual channel name")
    p.add_argument("--host", default="127.0.0.1", help="listen address (keep it on loopback)")
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="SCHED_FIFO priority for the server (0: normal scheduling); the HIL runner uses 75",
    )


def main_serve(args: argparse.Namespace) -> int:
    from bywire.protocol.bus_url import run_bus_server

    if args.rt_priority:
        from bywire.realtime import apply_realtime

        print(f"bus: real-time: {apply_realtime(priority=args.rt_priority, freeze_gc=False).summary()}")
    run_bus_server(args.port, args.channel, args.host)
    return 0


def add_table_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--output", type=Path, help="write to this file instead of stdout")
    p.add_argument(
        "--profile",
        choices=("bywire", "pq"),
        default="bywire",
        help="vehicle profile: bywire (our gateway's messages, docs/protocol.md) or pq (a VW PQ "
        "Passat's own messages and ours beside them, docs/protocol_pq.md)",
    )


def main_table(args: argparse.Namespace) -> int:
    from bywire.protocol.table import render_protocol_table

    text = render_protocol_table(profile=args.profile)
    if args.output:
        args.output.write_text(text, encoding="utf-8")
    else:
        sys.stdout.write(text)
    return 0
