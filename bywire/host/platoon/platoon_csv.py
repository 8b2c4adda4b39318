"""Reader of recorded platoon CSVs (OpenACC, CARMA) onto one uniform time grid, leader first.

The layout is told apart by the header against the table of published spellings in
`host.platoon.platoon_layouts` (what each dataset calls its time, speed and acceleration columns, units,
where the spelling comes from); a header none of them fits is refused naming the expected layouts.
Guide: docs/platoon_files.md.

After the columns are found, every layout is treated alike: rows are parsed (an empty cell is a missing
sample; a non-number is an error naming file, line and column), rows stored out of time order are sorted
back (CARMA holds a few) and said in `Platoon.notes`, a repeated time stamp is an error. Gaps of missing
samples up to MAX_GAP_S are interpolated linearly onto the median sample period; a longer gap cuts the
record, keeping the longest stretch where every vehicle has data (noted). A vehicle without any data is
dropped (noted); in OpenACC the platoon order is the vehicle index, so a pair may then span a missing
car, which the pair names show. Where a layout has no acceleration (OpenACC) it is differentiated from
the speed after a zero-phase 2nd-order Butterworth low-pass at ACCEL_LOWPASS_HZ (the string-stability band
ends at 1 Hz; the same linear filter on both cars of a pair cancels in their transfer function anyway).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy import signal as sps

from bywire.host.platoon.platoon_layouts import (
    LAYOUTS_BY_NAME,
    OPENACC_METADATA_KEYS,
    Layout,
    expected_layouts,
    header_layout,
    normalise_run,
)

FloatArray = npt.NDArray[np.float64]

# Longest run of missing samples bridged by linear interpolation: 1 s is ~ one period of the fastest
# motion in the string-stability band (1 Hz); longer holes would invent the dynamics we want to measure.
MAX_GAP_S = 1.0
# Shortest record worth a spectral estimate: four 50 s segments would be ideal, but the AstaZero cut is
# 30 s long; below 20 s the lowest resolvable frequency (1/T) climbs above most of the excited band.
MIN_DURATION_S = 20.0
ACCEL_LOWPASS_HZ = 2.0
# OpenACC's metadata lines before the table header: five in every campaign; a few more are tolerated.
MAX_METADATA_LINES = 10
# Uniform grid points per data row at most: a real recording has about one (gaps cut later); far more
# means stray time stamps (a 1e-9 s step beside 0.1 s ones) that would build a grid of billions.
MAX_GRID_POINTS_PER_ROW = 20

NumberedRow = tuple[int, list[str]]  # (line number in the file, fields)


class PlatoonCsvError(ValueError):
    """A platoon CSV that cannot be read; the message names file, line and column."""


@dataclass(frozen=True)
class Vehicle:
    name: str
    speed_mps: FloatArray
    accel_mps2: FloatArray
    accel_from_file: bool


@dataclass(frozen=True)
class Platoon:
    """Vehicles leader first, all sampled on the common uniform grid time_s."""

    source: str
    layout: str  # a name of platoon_layouts.LAYOUTS
    time_s: FloatArray
    vehicles: tuple[Vehicle, ...]
    notes: tuple[str, ...] = ()

    @property
    def sample_period_s(self) -> float:
        return float(self.time_s[1] - self.time_s[0])


# ---------------------------------------------------------------------------------------------- reading


def _read_rows(path: Path) -> list[NumberedRow]:
    rows: list[NumberedRow] = []
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            reader = csv.reader(fh)
            try:
                for row in reader:
                    rows.append((reader.line_num, row))
            except csv.Error as exc:
                raise PlatoonCsvError(f"{path}:{reader.line_num}: not CSV: {exc}") from None
    except UnicodeDecodeError as exc:
        raise PlatoonCsvError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    return rows


def _parse_float(text: str, path: Path, line: int, column: str) -> float:
    """A sample; empty (or NaN, as some writers spell it) is missing. Infinity is no measurement."""
    text = text.strip()
    if text == "":
        return math.nan
    try:
        value = float(text)
    except ValueError:
        raise PlatoonCsvError(f"{path}:{line}: column {column!r}: not a number: {text!r}") from None
    if math.isinf(value):
        raise PlatoonCsvError(f"{path}:{line}: column {column!r}: not a finite number: {text!r}")
    return value


def _column_index(path: Path, header_line: int, header: list[str], column: str) -> int:
    where = [j for j, name in enumerate(header) if name == column]
    if not where:
        raise PlatoonCsvError(f"{path}:{header_line}: header lacks column {column!r}")
    if len(where) > 1:
        raise PlatoonCsvError(
            f"{path}:{header_line}: header names column {column!r} {len(where)} times "
            f"(fields {', '.join(str(j + 1) for j in where)})"
        )
    return where[0]


def _check_length(path: Path, line: int, row: list[str], header: list[str]) -> None:
    if len(row) < len(header):
        raise PlatoonCsvError(
            f"{path}:{line}: {len(row)} fields, header has {len(header)} (truncated row; "
            f"first missing column {header[len(row)]!r})"
        )


def _data_rows(rows: list[NumberedRow]) -> list[NumberedRow]:
    """Without blank lines (e.g. at the end of the file)."""
    return [(line, row) for line, row in rows if row and any(f.strip() for f in row)]


def _read_table(
    path: Path,
    rows: list[NumberedRow],
    header: list[str],
    header_line: int,
    time_column: str,
    wanted: dict[str, str],
    notes: list[str],
) -> tuple[FloatArray, dict[str, FloatArray]]:
    """Parse the columns named in `wanted` (column -> key); return time and key -> values (NaN = missing).
    Appends what it repaired to `notes`."""
    j_time = _column_index(path, header_line, header, time_column)
    index = {col: _column_index(path, header_line, header, col) for col in wanted}
    times: list[float] = []
    lines: list[int] = []
    values: dict[str, list[float]] = {key: [] for key in wanted.values()}
    for line, row in rows:
        _check_length(path, line, row, header)
        t = _parse_float(row[j_time], path, line, time_column)
        if math.isnan(t):
            text = row[j_time].strip()
            why = f"not a number: {text!r}" if text else "empty"
            raise PlatoonCsvError(f"{path}:{line}: column {time_column!r}: {why}")
        times.append(t)
        lines.append(line)
        for col, key in wanted.items():
            values[key].append(_parse_float(row[index[col]], path, line, col))
    if len(times) < 2:
        raise PlatoonCsvError(f"{path}: fewer than two data rows")
    t_s = np.asarray(times)
    # The CARMA table holds a few rows stored out of time order (e.g. the row for 45.0 s between 42.5 and
    # 42.6 s) whose values fit their time stamp: sort them back into place and say so. Two rows with the
    # same time stamp cannot be ordered and are an error.
    order = np.argsort(t_s, kind="stable")
    n_moved = int((np.diff(t_s) < 0).sum())
    if n_moved:
        first_bad = lines[int(np.argmax(np.diff(t_s) <= 0)) + 1]
        notes.append(f"{n_moved} breaks in time order, rows sorted back (first at line {first_bad})")
    t_sorted = t_s[order]
    dup = np.flatnonzero(np.diff(t_sorted) <= 0)
    if dup.size:
        k = int(order[dup[0] + 1])
        raise PlatoonCsvError(
            f"{path}:{lines[k]}: column {time_column!r}: {t_s[k]} repeats an earlier time stamp"
        )
    return t_sorted, {key: np.asarray(v)[order] for key, v in values.items()}


# ---------------------------------------------------------------------------------------------- layouts


@dataclass(frozen=True)
class _Table:
    """Where the table of a detected layout is: its header, the header's line, the data rows after it."""

    layout: Layout
    header: list[str]
    header_line: int
    rows: list[NumberedRow]
    vehicle_order_names: tuple[str, ...] = ()  # OpenACC `Vehicle_order`, vehicle 1 first


def _openacc_table(path: Path, rows: list[NumberedRow]) -> _Table:
    """Metadata lines, then the header `Time,Speed1,...` (JRC OpenACC release)."""
    layout = LAYOUTS_BY_NAME["openacc_jrc"]
    names: tuple[str, ...] = ()
    for k, (line, row) in enumerate(rows[: MAX_METADATA_LINES + 1]):
        cells = [f.strip() for f in row]
        if cells and cells[0] == layout.time_column:
            if not layout.speed_columns(cells):
                raise PlatoonCsvError(f"{path}:{line}: OpenACC header has no 'Speed<i>' column")
            return _Table(layout, cells, line, _data_rows(rows[k + 1 :]), names)
        if cells and cells[0] == "Vehicle_order":
            names = tuple(f for f in cells[1:] if f)
    line = rows[min(len(rows), MAX_METADATA_LINES + 1) - 1][0]
    raise PlatoonCsvError(
        f"{path}:{line}: expected the OpenACC header 'Time,Speed1,...' within "
        f"{MAX_METADATA_LINES} metadata lines ('Date,...', 'Vehicle_order,...', ...)"
    )


def _find_table(path: Path, rows: list[NumberedRow]) -> _Table:
    if not rows:
        raise PlatoonCsvError(f"{path}:1: empty file")
    line, first_row = rows[0]
    first = [f.strip() for f in first_row]
    if first and first[0] in OPENACC_METADATA_KEYS and "Time" not in first:
        return _openacc_table(path, rows)
    layout = header_layout(first)
    if layout is None:
        raise PlatoonCsvError(
            f"{path}:{line}: unknown platoon CSV layout (expected one of: {expected_layouts()}); "
            f"got {','.join(first[:4])!r}"
        )
    return _Table(layout, first, line, _data_rows(rows[1:]))


def _select_run(path: Path, table: _Table, run: str | None) -> tuple[str | None, list[NumberedRow]]:
    """The rows of one run of a many-run file (CARMA as published): `run`, or the only one there is."""
    column = table.layout.run_column
    if column is None:
        if run is not None:
            raise PlatoonCsvError(
                f"{path}: {table.layout.name} files hold one run each; run={run!r} does not apply"
            )
        return None, table.rows
    j = _column_index(path, table.header_line, table.header, column)
    by_run: dict[str, list[NumberedRow]] = {}
    for line, row in table.rows:
        _check_length(path, line, row, table.header)
        by_run.setdefault(normalise_run(row[j]), []).append((line, row))
    if run is None:
        if len(by_run) != 1:
            raise PlatoonCsvError(
                f"{path}: column {column!r} holds {len(by_run)} runs ({', '.join(list(by_run)[:12])}): "
                f"give the run to read (load_platoon_csv(..., run=...)) or cut its rows into a file"
            )
        run = next(iter(by_run))
    chosen = normalise_run(run)
    if chosen not in by_run:
        raise PlatoonCsvError(f"{path}: column {column!r} has no run {run!r} (runs {', '.join(by_run)})")
    return chosen, by_run[chosen]


def _vehicle_keys(path: Path, table: _Table, speed_columns: dict[str, str], run: str | None) -> list[str]:
    layout = table.layout
    if layout.order_by_run:
        order = layout.order_by_run.get(run or "")
        if order is None:
            raise PlatoonCsvError(
                f"{path}: run {run}: its platoon order is not in the file and not known "
                f"(known for runs {', '.join(layout.order_by_run)})"
            )
        return [key for key in order if key in speed_columns]
    if layout.vehicle_order:
        return [key for key in layout.vehicle_order if key in speed_columns]
    # OpenACC's vehicle index, compared as a number without int() (no limit on a hostile digit string).
    return sorted(speed_columns, key=lambda k: (len(k.lstrip("0")), k.lstrip("0")))


def _vehicle_name(key: str, table: _Table) -> str:
    index = key.lstrip("0") or "0"
    if not index.isdigit():
        return key
    names = table.vehicle_order_names
    # OpenACC: vehicle i is the i-th of Vehicle_order (leader first); an index past the list stays bare.
    if len(index) <= 3 and 1 <= int(index) <= len(names):
        return f"{index}:{names[int(index) - 1]}"
    return index


def load_platoon_csv(path: str | Path, run: str | None = None) -> Platoon:
    """Load a recorded platoon (any layout of platoon_layouts.LAYOUTS, detected from the header).

    `run` picks one run of a file that holds several (CARMA as published by USDOT); a file of one run
    needs none."""
    path = Path(path)
    notes: list[str] = []
    table = _find_table(path, _read_rows(path))
    layout = table.layout
    run_id, rows = _select_run(path, table, run)
    speed_columns = layout.speed_columns(table.header)
    keys = _vehicle_keys(path, table, speed_columns, run_id)
    if run_id is not None:
        notes.append(f"run {run_id}")
    if layout.order_by_run:
        notes.append(f"platoon order {', '.join(keys)} (from the run's field notes; the file has none)")
    accel_columns: dict[str, str] = {}
    if layout.accel_template is not None:
        accel_columns = {k: layout.accel_template.format(k) for k in keys}
        missing = [c for c in accel_columns.values() if c not in table.header]
        if missing:
            notes.append(f"no {', '.join(missing)}: acceleration differentiated from speed")
            accel_columns = {}
    wanted: dict[str, str] = {}
    for k in keys:
        wanted[speed_columns[k]] = f"{k}_v"
        if k in accel_columns:
            wanted[accel_columns[k]] = f"{k}_a"
    t, cols = _read_table(path, rows, table.header, table.header_line, layout.time_column, wanted, notes)
    speeds = [_scaled(cols[f"{k}_v"], layout.speed_to_mps) for k in keys]
    accels = [_scaled(cols[f"{k}_a"], layout.accel_to_mps2) if k in accel_columns else None for k in keys]
    names = [_vehicle_name(k, table) for k in keys]
    return _build_platoon(path, layout.name, _scaled(t, layout.time_to_s), names, speeds, accels, notes)


def _scaled(x: FloatArray, factor: float) -> FloatArray:
    return x if factor == 1.0 else x * factor


# ---------------------------------------------------------------------------------------------- grid


def _resample(
    t_raw_s: FloatArray, x_raw: FloatArray, grid_s: FloatArray, max_gap_s: float
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """Linear interpolation onto grid_s; a grid point is invalid where the bracketing valid raw samples are
    further apart than max_gap_s (a long hole) or outside the valid span."""
    ok = np.isfinite(x_raw)
    t_ok, x_ok = t_raw_s[ok], x_raw[ok]
    if t_ok.size < 2:
        return np.full(grid_s.shape, math.nan), np.zeros(grid_s.shape, dtype=bool)
    x = np.interp(grid_s, t_ok, x_ok)
    j = np.clip(np.searchsorted(t_ok, grid_s), 1, t_ok.size - 1)
    # A tolerance of a thousandth of a step keeps regular samples (gap == one step) valid despite rounding.
    valid = (
        (t_ok[j] - t_ok[j - 1] <= max_gap_s + 1e-9) & (grid_s >= t_ok[0] - 1e-9) & (grid_s <= t_ok[-1] + 1e-9)
    )
    return x, valid


def _longest_true_run(mask: npt.NDArray[np.bool_]) -> tuple[int, int]:
    """[start, stop) of the longest run of True."""
    best = (0, 0)
    start = -1
    for k, m in enumerate([*mask.tolist(), False]):
        if m and start < 0:
            start = k
        elif not m and start >= 0:
            if k - start > best[1] - best[0]:
                best = (start, k)
            start = -1
    return best


def differentiate_speed(speed_mps: FloatArray, dt_s: float) -> FloatArray:
    """Acceleration from a speed record: zero-phase low-pass (ACCEL_LOWPASS_HZ) then central differences."""
    nyquist_hz = 0.5 / dt_s
    if nyquist_hz > ACCEL_LOWPASS_HZ and speed_mps.size > 15:
        b, a = sps.butter(2, ACCEL_LOWPASS_HZ / nyquist_hz)
        speed_mps = sps.filtfilt(b, a, speed_mps)
    return np.asarray(np.gradient(speed_mps, dt_s), dtype=np.float64)


def _build_platoon(
    path: Path,
    layout: str,
    t_raw_s: FloatArray,
    names: list[str],
    speeds: list[FloatArray],
    accels: list[FloatArray | None],
    notes: list[str],
) -> Platoon:
    dt_s = float(np.median(np.diff(t_raw_s)))
    steps = (t_raw_s[-1] - t_raw_s[0]) / dt_s
    if not math.isfinite(steps) or steps + 1 > MAX_GRID_POINTS_PER_ROW * t_raw_s.size:
        raise PlatoonCsvError(
            f"{path}: irregular time column: {t_raw_s[-1] - t_raw_s[0]:.6g} s spanned at a median step "
            f"of {dt_s:.6g} s by {t_raw_s.size} rows"
        )
    grid_s = t_raw_s[0] + dt_s * np.arange(math.floor(steps + 1e-6) + 1)
    kept: list[tuple[str, FloatArray, FloatArray | None]] = []
    valid_all = np.ones(grid_s.shape, dtype=bool)
    for name, v_raw, a_raw in zip(names, speeds, accels, strict=True):
        if not np.isfinite(v_raw).any():
            notes.append(f"vehicle {name}: no speed samples, dropped")
            continue
        v, ok = _resample(t_raw_s, v_raw, grid_s, MAX_GAP_S)
        a: FloatArray | None = None
        if a_raw is not None:
            a, ok_a = _resample(t_raw_s, a_raw, grid_s, MAX_GAP_S)
            ok &= ok_a
        if not ok.all():
            notes.append(f"vehicle {name}: {int((~ok).sum())} samples in gaps > {MAX_GAP_S} s")
        valid_all &= ok
        kept.append((name, v, a))
    if len(kept) < 2:
        raise PlatoonCsvError(f"{path}: fewer than two vehicles with data")
    start, stop = _longest_true_run(valid_all)
    if stop - start < grid_s.size:
        notes.append(
            f"record cut to {grid_s[start] - grid_s[0]:.1f}-{grid_s[stop - 1] - grid_s[0]:.1f} s "
            f"(longest stretch without a gap > {MAX_GAP_S} s in any vehicle)"
        )
    if (stop - start - 1) * dt_s < MIN_DURATION_S:
        raise PlatoonCsvError(
            f"{path}: only {(stop - start - 1) * dt_s:.1f} s without gaps > {MAX_GAP_S} s, "
            f"need {MIN_DURATION_S} s"
        )
    vehicles = []
    for name, v, a in kept:
        v = v[start:stop]
        from_file = a is not None
        acc = a[start:stop] if a is not None else differentiate_speed(v, dt_s)
        vehicles.append(Vehicle(name, v, acc, from_file))
    # Re-derive the time axis from the index: subtracting large absolute stamps (12643 s) leaves float dust.
    time_s = dt_s * np.arange(stop - start, dtype=np.float64)
    return Platoon(str(path), layout, time_s, tuple(vehicles), tuple(notes))


__all__ = [
    "ACCEL_LOWPASS_HZ",
    "MAX_GAP_S",
    "MIN_DURATION_S",
    "Platoon",
    "PlatoonCsvError",
    "Vehicle",
    "differentiate_speed",
    "load_platoon_csv",
]
