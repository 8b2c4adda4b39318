"""The calibration a scenario runs its ECU with (`ecu.calibration` in a scenario file)."""

from __future__ import annotations

import tempfile
from pathlib import Path

from bywire.ecu.app import load_calibration_file
from bywire.ecu.calibration import Calibration, default_calibration, dumps_calibration
from bywire.hil.scenario import Scenario


def run_calibration_file(scenario: Scenario, run_dir: Path) -> Path | None:
    """The calibration file a scenario asks for; `corrupt_calibration` writes one with a bad CRC
    into `run_dir` (the run's own folder: never the user's working directory)."""
    if scenario.calibration is not None:
        return Path(scenario.calibration)
    if not scenario.corrupt_calibration:
        return None
    data = bytearray(dumps_calibration(default_calibration()))
    # Flip one digit of a map value: the JSON stays valid, only the CRC can tell.
    idx = data.find(b'"bar"')
    idx = next(i for i in range(idx, len(data)) if chr(data[i]).isdigit() and data[i] != ord("0"))
    data[idx] = ord("7") if data[idx] != ord("7") else ord("3")
    target = run_dir / "corrupt_calibration.json"
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_bytes(bytes(data))
    return target


def load_run_calibration(scenario: Scenario, run_dir: Path | None) -> tuple[Calibration | None, str | None]:
    """The calibration (or the reason it was refused); a run without a folder of its own writes a
    corrupt calibration to a temporary folder that is gone once it is loaded."""
    if run_dir is not None:
        return load_calibration_file(run_calibration_file(scenario, run_dir))
    with tempfile.TemporaryDirectory(prefix="bywire-cal-") as tmp:
        return load_calibration_file(run_calibration_file(scenario, Path(tmp)))
