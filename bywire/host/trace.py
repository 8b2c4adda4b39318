"""CSV time-series traces: the host's record of every request it sent the ECU (`HOST_COLUMNS`), and
the append-only writer and the reader any process uses for its own trace (the simulator's plant too).

Each process appends rows to its own CSV file and flushes it about once a second, so a run that is
killed (or a host frozen with SIGSTOP and then killed) still leaves everything up to the last flush.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

HOST_COLUMNS = (
    "t_s",
    "accel_request_mps2",
    "steer_request_rad",
    "flags",
    "ecu_state",
    "ecu_faults",
    "status_speed_mps",
    "v_des_mps",
    "odometer_m",
    "controller",
    "lead_gap_m",
)
CONTROLLERS = ("none", "script", "velocity", "following", "stopping", "position", "platoon", "emergency")


class TraceWriter:
    """Append-only CSV trace with periodic flushes; usable in memory only (path None) for SIL."""

    def __init__(self, path: Path | None, columns: tuple[str, ...], flush_every: int = 100) -> None:
        self.columns = columns
        self.rows: list[tuple[float, ...]] = []
        self._file: io.TextIOWrapper | None = None
        self._flush_every = flush_every
        self._unflushed = 0
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open(path, "w", encoding="utf-8", newline="")  # noqa: SIM115 - closed in close()
            self._file.write(",".join(columns) + "\n")

    def append(self, row: tuple[float, ...]) -> None:
        self.rows.append(row)
        if self._file is not None:
            self._file.write(",".join(f"{v:.6g}" for v in row) + "\n")
            self._unflushed += 1
            if self._unflushed >= self._flush_every:
                self._file.flush()
                self._unflushed = 0

    def close(self) -> None:
        if self._file is not None:
            self._file.flush()
            self._file.close()
            self._file = None

    def array(self) -> dict[str, np.ndarray]:
        data = np.asarray(self.rows, dtype=float).reshape(-1, len(self.columns))
        return {name: data[:, i] for i, name in enumerate(self.columns)}


def read_trace(path: Path, columns: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Read a trace CSV; a torn last line (the writer was killed mid-write) is dropped."""
    rows: list[list[float]] = []
    with open(path, encoding="utf-8", newline="") as f:
        reader = csv.reader(f)
        header = next(reader, None)
        if header is None or tuple(header) != columns:
            raise ValueError(f"{path}: unexpected trace header {header}")
        for line in reader:
            if len(line) != len(columns):
                continue
            try:
                rows.append([float(v) for v in line])
            except ValueError:
                continue
    data = np.asarray(rows, dtype=float).reshape(-1, len(columns))
    return {name: data[:, i] for i, name in enumerate(columns)}
