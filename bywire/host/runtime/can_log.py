"""CAN frames in the field's log formats: one channel per bus, the vehicle bus apart from the host link.

Seed 000 section 3 (every bus frame of a run is logged, DESIGN.md section 1). python-can writes and
reads the formats the field's tools open (Vector ASC and BLF, PEAK TRC, ASAM MDF4, candump .log,
CSV); a frame's bus travels in `can.Message.channel`. ASC, BLF, TRC and MDF4 number their channels:
python-can counts from 0 in `channel` and writes channel + 1 into the file (CANalyzer's CAN 1,
CAN 2), so a bus must be given as a number there, or every frame lands on the writer's default
channel 1 and the two buses of a run become one. candump logs name their interface, so there the
bus keeps its name.

Numbering: the vehicle bus is channel 0 (CAN 1 in the file), the host link channel 1 (CAN 2); any
other bus takes the next numbers in the order first seen. `export_frames` turns an MCAP recording
(`--record X.mcap`) into one of these files; a run recorded straight into one
(`--record X.asc`) numbers its buses the same way.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import can

from bywire.host.runtime.mcap_reader import read_frames

# python-can's channel numbers (0-based; the file shows them + 1). Fixed so that a bus keeps its
# channel from one run to the next and between the recorder and the exporter.
BUS_CHANNELS: dict[str, int] = {"vehicle": 0, "host_link": 1}

# Suffixes of the python-can formats whose channels are numbers (python-can's `channel2int`).
NUMBERED_FORMATS = frozenset({".asc", ".blf", ".trc", ".mf4"})


class BusChannels:
    """The channel a bus's frames carry in one log file: a number in the numbered formats, else the
    bus's name."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.numbered = Path(path).suffix.lower() in NUMBERED_FORMATS
        self.numbers = dict(BUS_CHANNELS)

    def channel(self, bus: str) -> int | str:
        if not self.numbered:
            return bus
        number = self.numbers.get(bus)
        if number is None:
            number = self.numbers[bus] = max(self.numbers.values(), default=-1) + 1
        return number


def write_frames(frames: Iterable[can.Message], out: str | os.PathLike[str]) -> dict[str, int]:
    """Write frames whose `channel` is their bus's name into a python-can log file (format by the
    suffix), each bus on its own channel; the number of frames per bus."""
    channels = BusChannels(out)
    counts: dict[str, int] = {}
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    with can.Logger(os.fspath(out)) as logger:
        for msg in frames:
            bus = str(msg.channel)
            msg.channel = channels.channel(bus)
            logger.on_message_received(msg)
            counts[bus] = counts.get(bus, 0) + 1
    return counts


def export_frames(recording: str | os.PathLike[str], out: str | os.PathLike[str]) -> dict[str, int]:
    """The CAN frames of an MCAP recording into `out` (.asc, .blf, .trc, .mf4, .log, .csv), one channel
    per bus, on the run's clock; the number of frames per bus. LogError for an unreadable recording."""
    return write_frames(read_frames(recording), out)
