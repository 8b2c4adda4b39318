"""The CAN frames of a run in the field's log formats: each bus on its own channel, as python-can's
readers (and the tools that open ASC and BLF) see them."""

from __future__ import annotations

import argparse
from pathlib import Path

import can
import pytest

from bywire.hil.recording import Recorder
from bywire.host import log_cli
from bywire.host.runtime.can_log import BusChannels, export_frames
from bywire.host.runtime.mcap_recorder import McapRecorder

# (bus, id, data): ids and data differ per bus, so a frame on the wrong channel shows.
FRAMES = [
    ("vehicle", 0x101, b"\x01"),
    ("host_link", 0x181, b"\x02\x03"),
    ("vehicle", 0x102, b"\x04"),
    ("host_link", 0x701, b"\x05"),
    ("radar", 0x500, b"\x06\x07\x08"),
    ("vehicle", 0x103, b""),
]


def _read_back(path: Path) -> list[tuple[object, int, bytes]]:
    return [(m.channel, m.arbitration_id, bytes(m.data)) for m in can.LogReader(str(path))]


def _expected(channels: dict[str, object]) -> list[tuple[object, int, bytes]]:
    return [(channels[bus], can_id, data) for bus, can_id, data in FRAMES]


@pytest.fixture
def recording(tmp_path: Path) -> Path:
    path = tmp_path / "run.mcap"
    with McapRecorder(path) as rec:
        for k, (bus, can_id, data) in enumerate(FRAMES):
            rec.record_frame(
                bus,
                can.Message(
                    timestamp=1.0 + 0.001 * k, arbitration_id=can_id, data=data, is_extended_id=False
                ),
            )
    return path


@pytest.mark.parametrize("suffix", [".asc", ".blf"])
def test_export_puts_each_bus_on_its_own_channel(recording: Path, tmp_path: Path, suffix: str) -> None:
    out = tmp_path / f"run{suffix}"
    assert export_frames(recording, out) == {"vehicle": 3, "host_link": 2, "radar": 1}
    # python-can counts channels from 0 and writes them + 1: CAN 1 the vehicle, CAN 2 the host link.
    assert _read_back(out) == _expected({"vehicle": 0, "host_link": 1, "radar": 2})


def test_asc_text_names_the_channels_as_canalyzer_counts(recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "run.asc"
    export_frames(recording, out)
    lines = [line.split() for line in out.read_text().splitlines() if " Rx " in line]
    assert [(cols[1], cols[2]) for cols in lines] == [
        ("1", "101"),
        ("2", "181"),
        ("1", "102"),
        ("2", "701"),
        ("3", "500"),
        ("1", "103"),
    ]


def test_candump_logs_keep_the_bus_names(recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "run.log"
    export_frames(recording, out)
    assert _read_back(out) == _expected({bus: bus for bus, _, _ in FRAMES})


def test_bywire_log_export(recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    log_cli.add_arguments(parser.add_subparsers(dest="log_command", required=True))
    out = tmp_path / "out" / "run.blf"
    assert log_cli.main(parser.parse_args(["export", str(recording), "-o", str(out)])) == 0
    assert "6 frames (vehicle 3, host_link 2, radar 1)" in capsys.readouterr().out
    assert _read_back(out) == _expected({"vehicle": 0, "host_link": 1, "radar": 2})
    assert log_cli.main(parser.parse_args(["export", str(recording), "-o", str(tmp_path / "run.xyz")])) == 2
    assert "run.xyz" in capsys.readouterr().err
    assert log_cli.main(parser.parse_args(["export", str(tmp_path / "none.mcap"), "-o", str(out)])) == 2
    assert "none.mcap: cannot open" in capsys.readouterr().err


@pytest.mark.parametrize("suffix", [".asc", ".blf"])
def test_a_run_recorded_straight_into_asc_or_blf_keeps_the_buses_apart(tmp_path: Path, suffix: str) -> None:
    names = {bus: f"rec-{bus}-{suffix[1:]}-{tmp_path.name}" for bus in ("vehicle", "host_link", "radar")}
    senders = {bus: can.Bus(interface="virtual", channel=ch) for bus, ch in names.items()}
    listeners = {bus: can.Bus(interface="virtual", channel=ch) for bus, ch in names.items()}
    out = tmp_path / f"run{suffix}"
    try:
        recorder = Recorder(out, listeners)
        for k, (bus, can_id, data) in enumerate(FRAMES):
            senders[bus].send(
                can.Message(timestamp=1.0 + 0.001 * k, arbitration_id=can_id, data=data, is_extended_id=False)
            )
            recorder.pump()  # frame by frame: the file's order is the order sent
        recorder.close()
    finally:
        for bus in (*senders.values(), *listeners.values()):
            bus.shutdown()
    assert recorder.frames == len(FRAMES)
    assert _read_back(out) == _expected({"vehicle": 0, "host_link": 1, "radar": 2})


def test_bus_channels_number_only_the_numbered_formats() -> None:
    blf, log = BusChannels("x.BLF"), BusChannels("x.log")
    assert [blf.channel(b) for b in ("host_link", "other", "vehicle", "more")] == [1, 2, 0, 3]
    assert log.channel("host_link") == "host_link"
