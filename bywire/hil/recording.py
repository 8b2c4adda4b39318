"""Recording a run: every bus frame, and with MCAP also every topic of the host runtime.

By the file's suffix: `.mcap` records into MCAP (`host.runtime.mcap_recorder`: Foxglove opens it, and
`bywire log info|plot|replay|export` read it); any other suffix uses python-can's loggers (.log,
.asc, .blf, .csv, .trc), frames only. One file for all buses of a run: each frame carries its bus
("vehicle", "host_link"), in MCAP as its topic `/can/<bus>`, in ASC, BLF and TRC as its own
channel (`host.runtime.can_log`: the vehicle bus CAN 1, the host link CAN 2).

In SIL the frames and the host's topics go into one recorder in one process. In HIL the host
process records its topics itself (it must: its store is in that process) and the runner records
the frames; `merge_recordings` then interleaves both by time into the file asked for. A host that
crashed leaves a readable prefix of its part (the recorder's crash bound), and the merge keeps it.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import can
from mcap.writer import CompressionType, Writer

from bywire.hil.sil_bus import received_copy
from bywire.host.runtime.can_log import BusChannels
from bywire.host.runtime.log_schema import LogError
from bywire.host.runtime.mcap_reader import McapLogReader, RawMessage
from bywire.host.runtime.mcap_recorder import McapRecorder
from bywire.protocol.timebase import rx_time_s


def is_mcap(path: Path) -> bool:
    return path.suffix.lower() == ".mcap"


class Recorder:
    """Drains listener buses into one file; call `pump()` regularly, `close()` at the end.

    `run_clock(msg)` gives a frame's time on the run's clock (SIL: the simulated timestamp as is;
    HIL: python-can's epoch timestamp mapped to CLOCK_MONOTONIC, the host's time base).
    """

    def __init__(
        self,
        path: Path,
        buses: dict[str, can.BusABC],
        run_clock: Callable[[can.Message], float] | None = None,
    ) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self.buses = buses
        self.run_clock = run_clock or (lambda msg: float(msg.timestamp))
        self.mcap: McapRecorder | None = McapRecorder(path) if is_mcap(path) else None
        self.logger = None if self.mcap is not None else can.Logger(str(path))
        self.channels = BusChannels(path)
        self.frames = 0

    def pump(self) -> int:
        n = 0
        for name, bus in self.buses.items():
            while True:
                msg = bus.recv(timeout=0)
                if msg is None:
                    break
                if self.mcap is not None:
                    self.mcap.record_frame(name, msg, t_s=self.run_clock(msg))
                else:
                    assert self.logger is not None
                    # A copy: in SIL receivers share one frame object, which must stay untouched.
                    self.logger(received_copy(msg, msg.timestamp, self.channels.channel(name)))
                n += 1
        self.frames += n
        return n

    def close(self) -> None:
        self.pump()
        if self.mcap is not None:
            self.mcap.close()
        if self.logger is not None:
            self.logger.stop()


def wall_run_clock(msg: can.Message) -> float:
    """A received frame's time on CLOCK_MONOTONIC (HIL: python-can stamps epoch time)."""
    return rx_time_s(msg, time.monotonic())


def _stream(path: Path, report: dict[str, str]) -> Iterator[RawMessage]:
    reader = McapLogReader(path)
    try:
        yield from reader.messages()
    except LogError as exc:
        report[path.name] = f"damaged, readable prefix kept: {exc}"
        return
    if not reader.complete:
        report[path.name] = f"not closed cleanly (a crash?): {reader.end_note}"


def merge_recordings(out: Path, parts: Sequence[Path]) -> dict[str, Any]:
    """Merge MCAP recordings into `out` in log-time order, schemas and channels as they were.

    A part that is missing or unreadable from the start is skipped and reported, so one crashed
    process does not cost the other parts of a run.
    """
    out.parent.mkdir(parents=True, exist_ok=True)
    report: dict[str, Any] = {"parts": {}, "messages": 0}
    streams = []
    for p in parts:
        if not p.exists():
            report["parts"][p.name] = "missing"
            continue
        report["parts"][p.name] = "ok"
        streams.append(_stream(p, report["parts"]))
    with out.open("wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD, enable_data_crcs=True)
        writer.start(profile="", library="bywire merge")
        schemas: dict[tuple[str, str, bytes], int] = {}
        channels: dict[tuple[str, str, int], int] = {}
        # Sorted in memory (a part is only roughly in time order: buses are drained one after the
        # other, topics come from several threads); a run's messages fit easily.
        for msg in sorted(itertools.chain(*streams), key=lambda m: m.log_time_ns):
            sch = msg.channel.schema
            schema_id = 0
            if sch is not None:
                key = (sch.name, sch.encoding, sch.data)
                if key not in schemas:
                    schemas[key] = writer.register_schema(sch.name, sch.encoding, sch.data)
                schema_id = schemas[key]
            ckey = (msg.channel.topic, msg.channel.message_encoding, schema_id)
            if ckey not in channels:
                channels[ckey] = writer.register_channel(
                    msg.channel.topic, msg.channel.message_encoding, schema_id
                )
            writer.add_message(
                channels[ckey],
                log_time=msg.log_time_ns,
                data=msg.data,
                publish_time=msg.publish_time_ns,
                sequence=msg.sequence,
            )
            report["messages"] += 1
        writer.finish()
    return report
