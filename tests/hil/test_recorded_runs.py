"""Recordings of real runs (SIL, in process) as the field's tools take them: every message strict JSON
valid against its channel's schema, the shipped Foxglove layouts naming only what a run of their
kind holds, and a recording cut by a crash read as far as the mcap library's stream reader gets."""

from __future__ import annotations

import dataclasses
import json
import struct
from pathlib import Path
from typing import Any

import jsonschema
import pytest
from mcap.exceptions import EndOfFile
from mcap.reader import make_reader
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader

from bywire.hil.foxglove import LAYOUTS, layout_path
from bywire.hil.scenario import load_scenario
from bywire.hil.sil import run_sil
from bywire.host.runtime.mcap_reader import McapLogReader

# The kind of run each layout is for, and a scenario of that kind (shortened: every topic appears
# within the first seconds).
RUNS = {"demo": ("demo", 20.0), "urban": ("four_way_stop_1", 20.0)}


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = {}
    for kind, (scenario, duration_s) in RUNS.items():
        path = tmp_path_factory.mktemp(kind) / f"{scenario}.mcap"
        run_sil(dataclasses.replace(load_scenario(scenario), duration_s=duration_s), record=path)
        out[kind] = path
    return out


def _not_json(name: str) -> None:
    raise AssertionError(f"{name} is not JSON (RFC 8259)")


@pytest.mark.parametrize("kind", sorted(RUNS))
def test_every_message_is_json_valid_against_its_channel_schema(
    recordings: dict[str, Path], kind: str
) -> None:
    validators: dict[int, jsonschema.Draft202012Validator] = {}
    invalid: dict[str, int] = {}
    checked = 0
    with open(recordings[kind], "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            assert schema is not None and schema.encoding == "jsonschema", channel.topic
            if schema.id not in validators:
                validators[schema.id] = jsonschema.Draft202012Validator(json.loads(schema.data))
            doc = json.loads(message.data, parse_constant=_not_json)
            if not validators[schema.id].is_valid(doc):
                invalid[channel.topic] = invalid.get(channel.topic, 0) + 1
            checked += 1
    assert checked > 10_000 and invalid == {}


def _schemas_by_topic(path: Path) -> dict[str, dict[str, Any]]:
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    counts = summary.statistics.channel_message_counts
    return {
        channel.topic: json.loads(summary.schemas[channel.schema_id].data)
        for channel_id, channel in summary.channels.items()
        if counts.get(channel_id, 0) > 0
    }


def _layout_paths(layout: dict[str, Any]) -> list[tuple[str, str]]:
    """(panel, message path) for every path the panels of a Foxglove layout show."""
    out = []
    for panel, config in layout["configById"].items():
        for entry in config.get("paths", []):
            out.append((panel, entry["value"]))
        if "xAxisPath" in config:
            out.append((panel, config["xAxisPath"]["value"]))
        if "topicPath" in config:
            out.append((panel, config["topicPath"]))
    return out


def _panel_ids(tree: Any) -> set[str]:
    if isinstance(tree, str):
        return {tree}
    return _panel_ids(tree["first"]) | _panel_ids(tree["second"])


def _missing(path: str, schemas: dict[str, dict[str, Any]]) -> str | None:
    """Why a Foxglove message path (`/topic.field.sub`) is not in the recording, or None."""
    topic = max((t for t in schemas if path == t or path.startswith(t + ".")), key=len, default=None)
    if topic is None:
        return "no such topic"
    node = schemas[topic]
    for name in path[len(topic) + 1 :].split(".") if path != topic else []:
        props = node.get("properties", {})
        if name not in props:
            return f"no field {name!r} (fields: {', '.join(props)})"
        node = props[name]
    return None


@pytest.mark.parametrize("kind", sorted(LAYOUTS))
def test_a_layout_shows_only_what_a_run_of_its_kind_records(recordings: dict[str, Path], kind: str) -> None:
    layout = json.loads(layout_path(kind).read_text(encoding="utf-8"))
    assert _panel_ids(layout["layout"]) == set(layout["configById"])  # every panel placed, none dangling
    schemas = _schemas_by_topic(recordings[kind])
    paths = _layout_paths(layout)
    assert len(paths) >= 10
    problems = {f"{panel}: {path}": why for panel, path in paths if (why := _missing(path, schemas))}
    assert problems == {}


def test_a_path_that_is_not_recorded_is_found(recordings: dict[str, Path]) -> None:
    schemas = _schemas_by_topic(recordings["demo"])
    assert _missing("/ego/odometry.speed_mps", schemas) is None
    assert _missing("/ego/odometry.velocity", schemas) is not None
    assert _missing("/urban/pose.x_m", schemas) == "no such topic"  # the urban layout's, not the demo's


def _library_prefix(path: Path) -> list[tuple[str, int, bytes]]:
    topics: dict[int, str] = {}
    out = []
    try:
        for record in StreamReader(str(path), validate_crcs=True).records:
            if isinstance(record, Channel):
                topics[record.id] = record.topic
            elif isinstance(record, Message):
                out.append((topics[record.channel_id], record.log_time, bytes(record.data)))
    except (EndOfFile, struct.error):  # how the library ends a file cut inside a record
        pass
    return out


def test_a_run_cut_at_60_percent_reads_as_far_as_the_mcap_stream_reader_gets(
    recordings: dict[str, Path], tmp_path: Path
) -> None:
    full_path = recordings["urban"]
    full = [(m.topic, m.log_time_ns, m.data) for m in McapLogReader(full_path).messages()]
    data = full_path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 6 // 10])
    reader = McapLogReader(cut)
    ours = [(m.topic, m.log_time_ns, m.data) for m in reader.messages()]
    library = _library_prefix(cut)
    assert ours == library == full[: len(ours)]
    assert len(full) // 3 < len(ours) < len(full) and not reader.complete
