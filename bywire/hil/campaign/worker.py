"""One run of a campaign, in whatever process runs it (a worker of the local pool, a Ray task).

It takes the run as plain data (`spec.Run.to_dict`) and gives back its row as plain data: the run's
parameters, its verdict, every metric flattened to a column (`m.stop_distance_m`,
`m.ecu_vehicle_rx.corrupt`), the campaign's own checks, a digest of the trajectory, the seed, the
duration and the code version. The scenario is run as `bywire hil run` runs it (`hil.run.run_scenario`,
SIL), so that the command a report prints for a run reproduces it alone. A run that raises is a row
with the verdict `error` and the exception, not a lost run.

What the wall clock decides (`WALL_CLOCK_COLUMNS`: the run's duration, its speed against real time,
the worker) differs from one execution to the next; every other column is the same wherever and
whenever the run executes, bit for bit (SIL is deterministic).
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import socket
import subprocess
import time
import traceback
from pathlib import Path
from typing import Any

# Columns that the wall clock decides: the only ones two executions of a campaign may disagree on.
WALL_CLOCK_COLUMNS = ("duration_s", "real_time_factor", "worker")
# What a row leaves out of the metrics: reference data that is the same for every run (the shared
# recordings' string stability), and what moved to its own column.
SKIPPED_METRICS = ("real_strings", "real_time_factor")
TRAJECTORY_PLANT = ("t_s", "speed_mps", "accel_mps2", "distance_m", "ecu_state")
TRAJECTORY_HOST = ("accel_request_mps2",)


@functools.cache
def code_version() -> str:
    """`git describe --always --dirty` of the checkout this `bywire` runs from, else the package's
    version (an installed wheel)."""
    import bywire

    root = Path(bywire.__file__).resolve().parent.parent
    if (root / ".git").exists():
        try:
            out = subprocess.run(
                ["git", "-C", str(root), "describe", "--always", "--dirty", "--tags"],
                capture_output=True,
                text=True,
                timeout=10,
                check=True,
            )
            return f"{out.stdout.strip()}"
        except (OSError, subprocess.SubprocessError):
            pass
    return f"bywire {bywire.__version__}"


def flatten(value: Any, prefix: str, into: dict[str, Any]) -> None:
    """Mappings flattened to `prefix.key` columns; lists as JSON text; numbers, text, truth as they are."""
    if isinstance(value, dict):
        for k, v in value.items():
            flatten(v, f"{prefix}.{k}", into)
    elif isinstance(value, list | tuple):
        into[prefix] = json.dumps(value, default=str, allow_nan=True)
    elif isinstance(value, float) and not math.isfinite(value):
        into[prefix] = value  # inf and NaN are values (a settle time never reached)
    elif value is None or isinstance(value, bool | int | float | str):
        into[prefix] = value
    else:
        item = getattr(value, "item", None)  # numpy scalars
        into[prefix] = item() if item is not None else str(value)


def trajectory_digest(plant: dict[str, Any], host: dict[str, Any] | None) -> str:
    """sha256 over what the car did and what the host asked (plant and host traces), for runs that must
    behave identically (a V2V flood against the same run without it)."""
    h = hashlib.sha256()
    for table, columns in ((plant, TRAJECTORY_PLANT), (host or {}, TRAJECTORY_HOST)):
        for c in columns:
            if c in table:
                h.update(c.encode())
                h.update(table[c].tobytes())
    return h.hexdigest()[:32]


def _inspect(scenario: Any, result: Any, document: dict[str, Any]) -> None:
    from bywire.hil.campaign.stop_bound import stop_bound_metrics
    from bywire.hil.run_calibration import load_run_calibration

    metrics = document["metrics"]
    metrics["trajectory_digest"] = trajectory_digest(result.plant, result.host)
    cal, _ = load_run_calibration(scenario, None)
    metrics.update(stop_bound_metrics(scenario, metrics, cal))
    document["seed"] = scenario.seed


def _leader_profile(value: str | None) -> Path | None:
    if value is None:
        return None
    from bywire.hil.world.urban_spec import SHARED_PREFIX, shared_data_root

    if value.startswith(SHARED_PREFIX):
        return shared_data_root() / value[len(SHARED_PREFIX) :]
    return Path(value)


def run_one(run: dict[str, Any]) -> dict[str, Any]:
    """Run one campaign run (`spec.Run.to_dict()`) and return its record: `row` (the flat columns) and
    `checks` (the scenario's and the campaign's, judged)."""
    t0 = time.perf_counter()
    row: dict[str, Any] = {
        "run_id": run["run_id"],
        "index": run["index"],
        "sweep": run["sweep"],
        "scenario": Path(run["scenario"]).stem,
    }
    for k, v in {**run["params"], **run["options"]}.items():
        flatten(v, f"p.{k}", row)
    checks: list[dict[str, Any]] = []
    try:
        from bywire.hil.evaluate import run_check
        from bywire.hil.run import run_scenario
        from bywire.hil.scenario import load_scenario, parse_check

        scenario = load_scenario(run["scenario"], run["overrides"])
        options = run["options"]
        document = run_scenario(
            scenario,
            leader_profile=_leader_profile(options.get("leader_profile")),
            perception=options.get("perception"),
            inspect=_inspect,
        )
        metrics = document["metrics"]
        checks = list(document["checks"])
        for i, raw in enumerate(run["checks"]):
            check = parse_check(raw, run["source"], f"sweeps[{run['sweep']}].checks[{i}]")
            checks.append({**run_check(check, metrics), "campaign": True})
        failed = [c["name"] for c in checks if not c["passed"]]
        verdict = "fail" if failed or document["verdict"] != "pass" else "pass"
        row.update(
            seed=int(document.get("seed", scenario.seed)),
            verdict=verdict,
            failed_checks=", ".join(failed),
            error=None,
        )
        row["real_time_factor"] = metrics.get("real_time_factor")
        for k, v in metrics.items():
            if k not in SKIPPED_METRICS:
                flatten(v, f"m.{k}", row)
    except Exception as exc:  # a run that raises is a result: the row says what and where
        frames = traceback.extract_tb(exc.__traceback__)[-3:]
        where = " <- ".join(f"{Path(f.filename).name}:{f.lineno}" for f in reversed(frames))
        row.update(
            seed=None, verdict="error", failed_checks="", error=f"{type(exc).__name__}: {exc} (at {where})"
        )
        row["real_time_factor"] = None
    row["code_version"] = code_version()
    row["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    row["duration_s"] = round(time.perf_counter() - t0, 3)
    return {"row": row, "checks": checks}


__all__ = ["WALL_CLOCK_COLUMNS", "code_version", "flatten", "run_one", "trajectory_digest"]
