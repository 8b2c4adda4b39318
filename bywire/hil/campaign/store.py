"""A campaign's folder: what it is, what it has done, and its results as one Parquet table.

    DIR/campaign.yaml      the campaign file as it was run
    DIR/manifest.json      its name, its runs' ids in order (what a resumed campaign must match)
    DIR/runs/ID.json       one per finished run: its row and its checks, written whole or not at all
    DIR/results.parquet    one row per finished run, in the campaign's order, built from runs/

A run's file is written to a temporary name and renamed (POSIX rename is atomic), so a campaign killed
at any instant, SIGKILL included, leaves every run either done, with its whole row, or not done, never
half; resuming runs exactly those not done. The table is rebuilt from the run files whenever the
campaign stops, so it too is never half written.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

MANIFEST = "manifest.json"
SPEC_COPY = "campaign.yaml"
RUNS = "runs"
RESULTS = "results.parquet"
FORMAT = "bywire.campaign/1"


class StoreError(ValueError):
    """A campaign folder that cannot be used as asked (said with the folder)."""


def write_atomic(path: Path, data: bytes) -> None:
    """`data` at `path`, whole or not at all (temporary file in the same folder, fsync, rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def create(folder: Path, name: str, spec_text: str, run_ids: list[str], code_version: str) -> None:
    """Start a campaign in `folder` (new or empty; one holding a campaign is refused: resume it)."""
    if (folder / MANIFEST).exists():
        raise StoreError(
            f"{folder}: holds a campaign already; continue it with --resume {folder}, or give another --out"
        )
    if folder.exists() and any(folder.iterdir()):
        raise StoreError(f"{folder}: not empty; a campaign starts in a new or empty folder")
    folder.mkdir(parents=True, exist_ok=True)
    write_atomic(folder / SPEC_COPY, spec_text.encode())
    manifest = {"format": FORMAT, "name": name, "code_version": code_version, "run_ids": run_ids}
    write_atomic(folder / MANIFEST, json.dumps(manifest, indent=1).encode())
    (folder / RUNS).mkdir(exist_ok=True)


def read_manifest(folder: Path) -> dict[str, Any]:
    path = folder / MANIFEST
    if not path.is_file():
        raise StoreError(f"{folder}: no campaign here (no {MANIFEST})")
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise StoreError(f"{path}: unreadable: {exc}") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise StoreError(f"{path}: not a {FORMAT} manifest")
    if not isinstance(manifest.get("name"), str):
        raise StoreError(f"{path}: name: expected the campaign's name")
    ids = manifest.get("run_ids")
    if not isinstance(ids, list) or not all(isinstance(i, str) for i in ids):
        raise StoreError(f"{path}: run_ids: expected a list of run ids")
    return manifest


def check_resume(folder: Path, name: str, run_ids: list[str]) -> None:
    """Refuse to resume `folder` with a campaign that is not the one it holds (other runs)."""
    manifest = read_manifest(folder)
    if manifest["name"] != name or manifest["run_ids"] != run_ids:
        theirs, ours = set(manifest["run_ids"]), set(run_ids)
        raise StoreError(
            f"{folder}: holds campaign {manifest['name']!r} of {len(theirs)} runs, and this one "
            f"({name!r}, {len(ours)} runs) differs in {len(theirs ^ ours)} of them: resume it with "
            f"the campaign file it was started with ({folder / SPEC_COPY})"
        )


def done_ids(folder: Path) -> set[str]:
    """The runs with a finished row in `folder`."""
    return {p.stem for p in (folder / RUNS).glob("*.json")}


def set_aside_unreadable(folder: Path) -> list[Path]:
    """Each run file of `folder` that is not a run's record as a worker writes it (one edited by hand or
    damaged on disk: an interrupted write never leaves one) renamed to `ID.json.unreadable[-N]`, so that
    a resumed campaign runs that run again without losing the file; the new names."""
    moved: list[Path] = []
    for path in sorted((folder / RUNS).glob("*.json")):
        if _read_record(path)[1] is None:
            continue
        target = path.with_name(f"{path.name}.unreadable")
        n = 1
        while target.exists():
            n += 1
            target = path.with_name(f"{path.name}.unreadable-{n}")
        os.replace(path, target)
        moved.append(target)
    return moved


def save_record(folder: Path, record: dict[str, Any]) -> None:
    """A finished run's record (`worker.run_one`'s), atomically."""
    run_id = record["row"]["run_id"]
    text = json.dumps(record, default=str, allow_nan=True, sort_keys=True)
    write_atomic(folder / RUNS / f"{run_id}.json", text.encode())


# What the readers of a run's record (report, compare, the table) take from it, and its type: a file
# edited by hand, merged from another machine or cut short is refused by name, not met as a KeyError.
_RECORD_PARTS: dict[str, type] = {"row": dict, "run": dict, "checks": list}
_ROW_FIELDS: dict[str, type] = {
    "run_id": str,
    "index": int,
    "sweep": str,
    "scenario": str,
    "verdict": str,
    "failed_checks": str,
}
_RUN_FIELDS: dict[str, type] = {
    "scenario": str,
    "source": str,
    "params": dict,
    "options": dict,
    "overrides": dict,
    "checks": list,
    "invariants": list,
}
VERDICTS = ("error", "fail", "pass")  # a run's verdicts, worst first


def record_problem(record: Any, run_id: str) -> str | None:
    """What is wrong with `record` as the record of run `run_id` (its file's name), None if nothing."""
    if not isinstance(record, dict):
        return f"expected an object, got {type(record).__name__}"
    for part, kind in _RECORD_PARTS.items():
        if not isinstance(record.get(part), kind):
            return f"{part}: expected {kind.__name__}, got {type(record.get(part)).__name__}"
    for fields, part in ((_ROW_FIELDS, "row"), (_RUN_FIELDS, "run")):
        for name, kind in fields.items():
            value = record[part].get(name)
            if not isinstance(value, kind) or (isinstance(value, bool) and kind is int):
                return f"{part}.{name}: expected {kind.__name__}, got {value!r:.60}"
    if record["row"]["run_id"] != run_id:
        return f"row.run_id: {record['row']['run_id']!r} in the file of run {run_id!r}"
    if record["row"]["verdict"] not in VERDICTS:
        return f"row.verdict: expected one of {', '.join(VERDICTS)}, got {record['row']['verdict']!r:.60}"
    for i, check in enumerate(record["checks"]):
        if not isinstance(check, dict) or not isinstance(check.get("name"), str):
            return f"checks[{i}]: expected an object with a name"
    return None


def _read_record(path: Path) -> tuple[Any, str | None]:
    """A run file's record, and what is wrong with it (None: nothing)."""
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        return None, f"unreadable: {exc}"
    problem = record_problem(record, path.stem)
    return record, None if problem is None else f"not a run's record as a worker writes it: {problem}"


def load_records(folder: Path) -> list[dict[str, Any]]:
    """Every finished run's record of the campaign in `folder`, in the campaign's order."""
    order = {rid: i for i, rid in enumerate(read_manifest(folder)["run_ids"])}
    records = []
    for path in (folder / RUNS).glob("*.json"):
        if path.stem in order:
            record, problem = _read_record(path)
            if problem is not None:
                raise StoreError(f"{path}: {problem}")
            records.append(record)
    records.sort(key=lambda r: order[r["row"]["run_id"]])
    return records


def _column_type(values: list[Any]) -> Any:
    import pyarrow as pa

    present = [v for v in values if v is not None]
    if present and all(isinstance(v, bool) for v in present):
        return pa.bool_()
    if present and all(isinstance(v, int) and not isinstance(v, bool) for v in present):
        return pa.int64()
    if all(isinstance(v, int | float) and not isinstance(v, bool) for v in present):
        return pa.float64()
    return pa.string()


def _as_type(values: list[Any], kind: Any) -> list[Any]:
    import pyarrow as pa

    if kind == pa.string():
        return [v if v is None or isinstance(v, str) else json.dumps(v) for v in values]
    if kind == pa.float64():
        return [None if v is None else float(v) for v in values]
    return values


# The row's columns in this order: who the run is, what it varied, how it went, what it measured, and
# what the machine that ran it says.
_LEADING = ("run_id", "index", "sweep", "scenario", "seed")
_VERDICT = ("verdict", "failed_checks", "error")


def _column_rank(name: str) -> tuple[int, str]:
    if name in _LEADING:
        return 0, f"{_LEADING.index(name):02d}"
    if name.startswith("p."):
        return 1, name
    if name in _VERDICT:
        return 2, f"{_VERDICT.index(name):02d}"
    if name.startswith("m."):
        return 3, name
    return 4, name


def build_table(records: list[dict[str, Any]]) -> Any:
    """The results table: one row per record, a column per key any row has (a row without it holds
    null), each column of the one type its values share (integers, numbers, truth, text)."""
    import pyarrow as pa

    seen: dict[str, None] = {}
    for r in records:
        seen.update(dict.fromkeys(r["row"]))
    columns = {}
    for name in sorted(seen, key=_column_rank):
        values = [r["row"].get(name) for r in records]
        kind = _column_type(values)
        columns[name] = pa.array(_as_type(values, kind), type=kind)
    return pa.table(columns)


def write_results(folder: Path) -> int:
    """Rebuild `results.parquet` from the run files; the number of rows."""
    import pyarrow.parquet as pq

    records = load_records(folder)
    table = build_table(records)
    tmp = folder / f".{RESULTS}.tmp"
    pq.write_table(table, tmp)
    os.replace(tmp, folder / RESULTS)
    return len(records)


def read_results(folder: Path) -> Any:
    """The results table of `folder` (pyarrow.Table)."""
    import pyarrow.parquet as pq

    path = folder / RESULTS
    if not path.is_file():
        raise StoreError(f"{folder}: no {RESULTS} (not a campaign's folder, or none of its runs finished)")
    return pq.read_table(path)


__all__ = [
    "StoreError",
    "build_table",
    "check_resume",
    "create",
    "done_ids",
    "load_records",
    "read_manifest",
    "read_results",
    "save_record",
    "set_aside_unreadable",
    "write_results",
]
