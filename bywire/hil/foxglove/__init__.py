"""Foxglove layouts for the recordings of the simulator's runs (`bywire hil run NAME --record X.mcap`).

A layout is Foxglove's own JSON (Layouts > Import from file): panels and the message paths they show,
`/topic.field` as the recordings name them (`host.runtime.log_schema`: one JSON Schema per topic).
`demo_layout.json` fits the longitudinal runs (demo, accel_steps, the stop and ACC scenarios): speed
and its setpoint, acceleration requested, sent and measured, pedals, the lead, the ECU's state and
the runtime's health. `urban_layout.json` fits the urban runs (four_way_stop_1, ...): the path
driven in plan view, speeds, steering, the behaviour's state and checkpoints, the objects seen.
Tests check that every path a layout names exists in a recorded run of its kind.
"""

from __future__ import annotations

from pathlib import Path

LAYOUTS = {"demo": "demo_layout.json", "urban": "urban_layout.json"}


def layout_path(kind: str) -> Path:
    """The shipped layout file of a kind of run ("demo" or "urban")."""
    try:
        return Path(__file__).with_name(LAYOUTS[kind])
    except KeyError:
        raise ValueError(f"no Foxglove layout for {kind!r} runs (there are: {', '.join(LAYOUTS)})") from None
