"""Regenerate demo_10s.mcap, the replay reference of tests/host/test_replay.py (see its docstring).

A 10 s SIL run of the demo scenario, recorded, with the CAN frames left out (the replay does not
use them, and the reference stays small). Run from the repository root:

    .venv/bin/python tests/data/replay/make_reference.py
"""

from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path

from bywire.hil.scenario import load_scenario
from bywire.hil.sil import run_sil
from bywire.host.runtime.mcap_reader import read_objects
from bywire.host.runtime.mcap_recorder import McapRecorder

OUT = Path(__file__).with_name("demo_10s.mcap")


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        full = Path(tmp) / "full.mcap"
        run_sil(dataclasses.replace(load_scenario("demo"), duration_s=10.0), record=full)
        with McapRecorder(OUT) as rec:
            for entry in read_objects(full):
                if not entry.topic.startswith("/can/"):
                    rec.record(entry.topic, entry.obj)
    print(f"wrote {OUT} ({OUT.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
