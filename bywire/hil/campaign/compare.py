"""Two executions of a campaign side by side: what a change of code (or of machine) did to each run.

A run's id is a hash of its sweep, scenario, fields and options, the same on every machine and at every
code version, so the runs of two campaign folders are matched by id. SIL is deterministic and every
column of a row but the wall clock's (`worker.WALL_CLOCK_COLUMNS`) is the same wherever the run
executes, so for a matched pair any difference at all is the code's (or the data's) doing: the compare
says which runs changed, and how.

The summary (`compare`, the JSON of `bywire campaign compare --json`) is a contract: `base` and `new`
(each: `folder`, `campaign`, `runs`, `code_versions`), `matched`, `only_in_base` and `only_in_new` (run
ids), `identical` (matched runs whose every column but the wall clock's and `code_version` is equal,
bit for bit),
`regressions` (a run that passed in BASE and fails or raises in NEW) and `fixes` (the reverse), each
with the run's `run_id`, `index`, `sweep`, `scenario`, `params`, both verdicts, the checks that newly
fail (or pass), and the `command` that reruns it alone; `trajectories` (`compared`, `same`, `changed`:
run ids whose `trajectory_digest` differs); and `metrics`: per metric that differs in any matched run
(`m.` columns), the runs it changed in, the largest absolute change and the run where it happened; for
the metrics a run's checks judge, also how many runs moved towards the limit (`worse`) or away from it
(`better`), and the run that moved furthest towards it.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from bywire.hil.campaign import store
from bywire.hil.campaign.report import judged_metrics, reproduce_command
from bywire.hil.campaign.worker import WALL_CLOCK_COLUMNS

PASSING = "pass"


def _side(folder: Path, records: list[dict[str, Any]]) -> dict[str, Any]:
    return {
        "folder": str(folder),
        "campaign": store.read_manifest(folder)["name"],
        "runs": len(records),
        "code_versions": sorted({str(r["row"].get("code_version")) for r in records}),
    }


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value)


def _same(a: Any, b: Any) -> bool:
    """Equal as a row holds them: NaN equals NaN (a settle time never reached in both)."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b) and type(a) is type(b)


def _directions(record: dict[str, Any]) -> dict[str, str]:
    """metric -> 'max' or 'min', for the numeric checks of the run's sweep (a metric bounded both ways
    has no worse direction and is left out)."""
    ops: dict[str, set[str]] = {}
    for metric, op, _ in judged_metrics(record):
        ops.setdefault(metric, set()).add(op)
    return {metric: next(iter(o)) for metric, o in ops.items() if len(o) == 1}


def _verdict_change(base: dict[str, Any], new: dict[str, Any]) -> dict[str, Any]:
    failed_before = {c["name"] for c in base.get("checks", []) if not c.get("passed")}
    failed_now = {c["name"] for c in new.get("checks", []) if not c.get("passed")}
    row = new["row"]
    return {
        "run_id": row["run_id"],
        "index": row["index"],
        "sweep": row["sweep"],
        "scenario": row["scenario"],
        "params": {**new["run"]["params"], **new["run"]["options"]},
        "base_verdict": base["row"]["verdict"],
        "new_verdict": row["verdict"],
        "newly_failed_checks": sorted(failed_now - failed_before),
        "newly_passed_checks": sorted(failed_before - failed_now),
        "base_error": base["row"].get("error"),
        "new_error": row.get("error"),
        "command": reproduce_command(new["run"]),
    }


def compare(base_folder: Path, new_folder: Path) -> dict[str, Any]:
    """The comparison of the finished runs of two campaign folders (module docstring)."""
    base_records = store.load_records(base_folder)
    new_records = store.load_records(new_folder)
    base = {r["row"]["run_id"]: r for r in base_records}
    new = {r["row"]["run_id"]: r for r in new_records}
    matched = [rid for rid in new if rid in base]  # in the campaign's order: regressions and fixes too
    if (base_records or new_records) and not matched:
        raise store.StoreError(
            f"{base_folder} ({_side(base_folder, base_records)['campaign']}) and {new_folder} "
            f"({_side(new_folder, new_records)['campaign']}): no run in common; a run is matched by its id, "
            "the hash of its sweep, scenario, fields and options"
        )
    regressions: list[dict[str, Any]] = []
    fixes: list[dict[str, Any]] = []
    identical = 0
    same_trajectory = 0
    changed_trajectory: list[str] = []
    metrics: dict[str, dict[str, Any]] = {}
    directions: dict[str, dict[str, str]] = {}  # per sweep: its checks are the sweep's
    for rid in matched:
        b, n = base[rid], new[rid]
        brow, nrow = b["row"], n["row"]
        if brow["verdict"] == PASSING and nrow["verdict"] != PASSING:
            regressions.append(_verdict_change(b, n))
        elif brow["verdict"] != PASSING and nrow["verdict"] == PASSING:
            fixes.append(_verdict_change(b, n))
        columns = (set(brow) | set(nrow)) - set(WALL_CLOCK_COLUMNS) - {"code_version"}
        differing = sorted(c for c in columns if not _same(brow.get(c), nrow.get(c)))
        identical += not differing
        if "m.trajectory_digest" in brow and "m.trajectory_digest" in nrow:
            if brow["m.trajectory_digest"] == nrow["m.trajectory_digest"]:
                same_trajectory += 1
            else:
                changed_trajectory.append(rid)
        for column in differing:
            if not column.startswith("m.") or column == "m.trajectory_digest":
                continue
            metric = column[2:]
            entry = metrics.setdefault(metric, {"runs_changed": 0, "max_abs_change": None, "at": None})
            entry["runs_changed"] += 1
            x, y = _number(brow.get(column)), _number(nrow.get(column))
            if x is None or y is None or not (math.isfinite(x) and math.isfinite(y)):
                continue  # text, a metric that appeared or went, or a non-finite value: counted, not sized
            change = abs(y - x)
            if entry["max_abs_change"] is None or change > entry["max_abs_change"]:
                entry["max_abs_change"] = round(change, 9)
                entry["at"] = {"run_id": rid, "index": nrow["index"], "base": x, "new": y}
            sweep = nrow["sweep"]
            if sweep not in directions:  # the sweep's scenario is read only where a metric changed
                directions[sweep] = _directions(n)
            op = directions[sweep].get(metric)
            if op is not None and y != x:
                towards = (y > x) if op == "max" else (y < x)
                entry.setdefault("worse", 0)
                entry.setdefault("better", 0)
                entry["worse" if towards else "better"] += 1
                if towards and change > entry.get("max_worsening", {}).get("by", -1.0):
                    entry["max_worsening"] = {
                        "run_id": rid,
                        "index": nrow["index"],
                        "base": x,
                        "new": y,
                        "by": round(change, 9),
                        "command": reproduce_command(n["run"]),
                    }
    return {
        "base": _side(base_folder, base_records),
        "new": _side(new_folder, new_records),
        "matched": len(matched),
        "only_in_base": [rid for rid in base if rid not in new],
        "only_in_new": [rid for rid in new if rid not in base],
        "identical": identical,
        "regressions": regressions,
        "fixes": fixes,
        "trajectories": {
            "compared": same_trajectory + len(changed_trajectory),
            "same": same_trajectory,
            "changed": changed_trajectory,
        },
        "metrics": dict(sorted(metrics.items())),
    }


__all__ = ["compare"]
