"""What a campaign adds up to: pass rates, the worst runs with the command that reruns each alone, the
invariants across runs, and plots of every judged metric against every varied parameter.

The summary (`summarise`, the JSON of `bywire campaign report --json`) is a contract: `campaign`,
`runs`, `passed`, `failed` (a run that failed a check, raised, or broke an invariant), `errors`,
`by_scenario` (per scenario: `runs`, `passed`, `pass_rate`, and `by_parameter`: the same per value of
each parameter varied), `metrics` (per judged metric: `min`, `p50`, `p99`, `max`), `invariants`, and
`worst`: the runs that failed, worst first, then those closest to a limit; each with its `command`.
A run's margin to a check is (limit - value) / |limit| for a `max` check and (value - limit) / |limit|
for a `min` one (negative: failed; a limit of 0 divides by 1, in the metric's unit); the closest check
is the one of smallest margin.

The plots (`DIR/report/`, matplotlib): per sweep, each judged metric against each varied parameter
(passed and failed runs apart, the limit drawn), each judged metric's distribution with its limit and
maximum, and for a sweep of two or more numeric parameters the map of the first two, coloured by
whether the runs there passed (where a platoon is string stable, over frequency and headway).
"""

from __future__ import annotations

import json
import math
import shlex
from pathlib import Path
from typing import Any

from bywire.hil.campaign import store

VERDICT_ORDER = {verdict: rank for rank, verdict in enumerate(store.VERDICTS)}  # worst first
MAX_PARAMS_PLOTTED = 4
MAX_METRICS_PLOTTED = 6


def reproduce_command(run: dict[str, Any]) -> str:
    """`bywire hil run` with the run's scenario and every field the campaign set: the run alone."""
    from bywire.hil.scenario import builtin_scenarios
    from bywire.hil.scenario_overrides import format_assignment
    from bywire.hil.world.urban_spec import SHARED_PREFIX, shared_data_root

    scenario = run["scenario"]
    name = Path(scenario).stem
    words = [
        "bywire",
        "hil",
        "run",
        name if builtin_scenarios().get(name) and "/" not in scenario else scenario,
    ]
    for path, value in run["overrides"].items():
        words += ["--set", format_assignment(path, value)]
    profile = run["options"].get("leader_profile")
    if profile is not None:
        if profile.startswith(SHARED_PREFIX):
            profile = str(shared_data_root() / profile[len(SHARED_PREFIX) :])
        words += ["--leader-profile", profile]
    if run["options"].get("perception") is not None:
        words += ["--perception", str(run["options"]["perception"])]
    return shlex.join(words)


def _margin(check: dict[str, Any]) -> float | None:
    value, limit = check.get("value"), check.get("limit")
    if check.get("op") not in ("max", "min") or isinstance(value, bool) or isinstance(limit, bool):
        return None if check.get("passed") else -math.inf
    if not isinstance(value, int | float) or not isinstance(limit, int | float):
        return None if check.get("passed") else -math.inf
    if float(value) == float(limit) == 0.0:
        return None  # a count that must stay 0 and is 0: no margin to rank by
    scale = abs(float(limit)) or 1.0  # a limit of 0 (an excess over a bound): in the metric's unit
    m = (
        (float(limit) - float(value)) / scale
        if check["op"] == "max"
        else (float(value) - float(limit)) / scale
    )
    return m if math.isfinite(m) else -math.inf


def _closest(checks: list[dict[str, Any]]) -> tuple[str, float]:
    best = ("", math.inf)
    for c in checks:
        m = _margin(c)
        if m is not None and m < best[1]:
            best = (c["name"], m)
    return best


def _invariants(records: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], set[str]]:
    """Each sweep's invariant metrics: equal to the sweep's first run's value in every run."""
    out: list[dict[str, Any]] = []
    broken: set[str] = set()
    sweeps: dict[str, list[dict[str, Any]]] = {}
    for r in records:
        sweeps.setdefault(r["row"]["sweep"], []).append(r)
    for sweep, recs in sweeps.items():
        for metric in recs[0]["run"].get("invariants", []):
            ref = recs[0]["row"].get(f"m.{metric}")
            differing = [
                r["row"]["run_id"] for r in recs if r["row"].get(f"m.{metric}") != ref or ref is None
            ]
            broken.update(differing)
            out.append(
                {
                    "sweep": sweep,
                    "metric": metric,
                    "reference": ref,
                    "runs": len(recs),
                    "holds": not differing,
                    "differing": differing,
                }
            )
    return out, broken


def _rate(passed: int, runs: int) -> float:
    return round(passed / runs, 4) if runs else 0.0


def judged_metrics(record: dict[str, Any]) -> list[tuple[str, str, Any]]:
    """(metric, op, limit) of the numeric checks of a run: its scenario's and the campaign's."""
    from bywire.hil.scenario import load_scenario, parse_check

    run = record["run"]
    out: list[tuple[str, str, Any]] = []
    try:
        checks = list(load_scenario(run["scenario"], run["overrides"]).checks)
    except ValueError:
        checks = []
    checks += [parse_check(c, run["source"], "checks") for c in run["checks"]]
    for c in checks:
        if c.op in ("max", "min") and (c.metric, c.op, c.limit) not in out:
            out.append((c.metric, c.op, c.limit))
    return out


def _stats(values: list[float]) -> dict[str, float]:
    import numpy as np

    a = np.asarray(values, dtype=float)
    return {
        "n": int(a.size),
        "min": round(float(np.min(a)), 4),
        "p50": round(float(np.percentile(a, 50)), 4),
        "p99": round(float(np.percentile(a, 99)), 4),
        "max": round(float(np.max(a)), 4),
    }


def summarise(folder: Path, worst: int = 10) -> dict[str, Any]:
    """The campaign's summary (module docstring) from its folder's finished runs."""
    manifest = store.read_manifest(folder)
    records = store.load_records(folder)
    invariants, broken = _invariants(records)
    ok = [r["row"]["verdict"] == "pass" and r["row"]["run_id"] not in broken for r in records]
    by_scenario: dict[str, dict[str, Any]] = {}
    for r, passed in zip(records, ok, strict=True):
        s = by_scenario.setdefault(r["row"]["scenario"], {"runs": 0, "passed": 0, "by_parameter": {}})
        s["runs"] += 1
        s["passed"] += passed
        for k, v in {**r["run"]["params"], **r["run"]["options"]}.items():
            key = json.dumps(v) if not isinstance(v, str) else v
            cell = s["by_parameter"].setdefault(k, {}).setdefault(key, {"runs": 0, "passed": 0})
            cell["runs"] += 1
            cell["passed"] += passed
    for s in by_scenario.values():
        s["pass_rate"] = _rate(s["passed"], s["runs"])
        for values in s["by_parameter"].values():
            for cell in values.values():
                cell["pass_rate"] = _rate(cell["passed"], cell["runs"])
    metrics: dict[str, dict[str, Any]] = {}
    judged_by_sweep: dict[str, list[tuple[str, str, Any]]] = {}
    for r in records:
        if r["row"]["sweep"] not in judged_by_sweep:
            judged_by_sweep[r["row"]["sweep"]] = judged_metrics(r)
    for sweep, judged in judged_by_sweep.items():
        for metric, op, limit in judged:
            values = [
                float(r["row"][f"m.{metric}"])
                for r in records
                if r["row"]["sweep"] == sweep
                and isinstance(r["row"].get(f"m.{metric}"), int | float)
                and not isinstance(r["row"].get(f"m.{metric}"), bool)
                and math.isfinite(float(r["row"][f"m.{metric}"]))
            ]
            if values:
                metrics[f"{sweep}.{metric}"] = {**_stats(values), "op": op, "limit": limit}
    ranked = []
    for r, passed in zip(records, ok, strict=True):
        name, margin = _closest(r["checks"])
        verdict = r["row"]["verdict"]
        if verdict == "pass" and not passed:
            verdict = "fail"  # an invariant broken
        ranked.append((VERDICT_ORDER[verdict], margin, r["row"]["index"], r, name, verdict))
    ranked.sort(key=lambda x: (x[0], x[1], x[2]))
    worst_runs = [
        {
            "index": r["row"]["index"],
            "run_id": r["row"]["run_id"],
            "sweep": r["row"]["sweep"],
            "scenario": r["row"]["scenario"],
            "verdict": verdict,
            "failed_checks": r["row"]["failed_checks"]
            or ("invariant broken" if r["row"]["run_id"] in broken else ""),
            "error": r["row"].get("error"),
            "closest_check": name,
            "margin": None if not math.isfinite(margin) else round(margin, 4),
            "params": {**r["run"]["params"], **r["run"]["options"]},
            "command": reproduce_command(r["run"]),
        }
        for _, margin, _, r, name, verdict in ranked[:worst]
    ]
    return {
        "campaign": manifest["name"],
        "runs": len(records),
        "of": len(manifest["run_ids"]),
        "passed": sum(ok),
        "failed": len(records) - sum(ok),
        "errors": sum(r["row"]["verdict"] == "error" for r in records),
        "pass_rate": _rate(sum(ok), len(records)),
        "code_versions": sorted({str(r["row"].get("code_version")) for r in records}),
        "by_scenario": by_scenario,
        "metrics": metrics,
        "invariants": invariants,
        "worst": worst_runs,
    }


def write_report(folder: Path, summary: dict[str, Any]) -> list[Path]:
    """`DIR/report/summary.json` and the plots; the files written."""
    out = folder / "report"
    out.mkdir(parents=True, exist_ok=True)
    written = [out / "summary.json"]
    store.write_atomic(written[0], (json.dumps(summary, indent=2, default=str) + "\n").encode())
    written += _plots(folder, out)
    return written


def _numeric(values: list[Any]) -> bool:
    present = [v for v in values if v is not None]
    return bool(present) and all(isinstance(v, int | float) and not isinstance(v, bool) for v in present)


def _plots(folder: Path, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    records = store.load_records(folder)
    sweeps: dict[str, list[dict[str, Any]]] = {}
    for r in records:
        sweeps.setdefault(r["row"]["sweep"], []).append(r)
    written: list[Path] = []
    for sweep, recs in sweeps.items():
        judged = [
            j for j in judged_metrics(recs[0]) if any(_numeric([r["row"].get(f"m.{j[0]}")]) for r in recs)
        ][:MAX_METRICS_PLOTTED]
        params = [k for k in recs[0]["run"]["params"] if _numeric([r["run"]["params"].get(k) for r in recs])]
        params = [k for k in params if len({r["run"]["params"].get(k) for r in recs}) > 1][
            :MAX_PARAMS_PLOTTED
        ]
        passed = [r["row"]["verdict"] == "pass" for r in recs]
        if judged and params:
            fig, axes = plt.subplots(
                len(judged), len(params), figsize=(4 * len(params), 2.6 * len(judged)), squeeze=False
            )
            for i, (metric, op, limit) in enumerate(judged):
                for j, param in enumerate(params):
                    ax = axes[i][j]
                    for ok, colour, label in ((True, "tab:green", "pass"), (False, "tab:red", "fail")):
                        xs = [r["run"]["params"][param] for r, p in zip(recs, passed, strict=True) if p == ok]
                        ys = [
                            r["row"].get(f"m.{metric}") for r, p in zip(recs, passed, strict=True) if p == ok
                        ]
                        pts = [(x, y) for x, y in zip(xs, ys, strict=True) if _numeric([y]) and y is not None]
                        if pts:
                            ax.scatter(*zip(*pts, strict=True), s=12, c=colour, label=label, alpha=0.7)
                    if isinstance(limit, int | float):
                        ax.axhline(float(limit), color="k", lw=0.8, ls="--")
                    ax.set_xlabel(param, fontsize=8)
                    ax.set_ylabel(f"{metric} ({op})", fontsize=8)
                    ax.tick_params(labelsize=7)
            fig.suptitle(f"{sweep}: judged metrics against the parameters varied (dashed: limit)", fontsize=9)
            fig.tight_layout()
            path = out / f"{sweep}_vs_parameters.png"
            fig.savefig(path, dpi=90)
            plt.close(fig)
            written.append(path)
        if judged:
            fig, axes = plt.subplots(1, len(judged), figsize=(3.6 * len(judged), 2.8), squeeze=False)
            for i, (metric, op, limit) in enumerate(judged):
                ax = axes[0][i]
                ys = [float(r["row"][f"m.{metric}"]) for r in recs if _numeric([r["row"].get(f"m.{metric}")])]
                ys = [y for y in ys if math.isfinite(y)]
                if ys:
                    ax.hist(ys, bins=min(40, max(5, len(ys) // 3)), color="tab:blue", alpha=0.8)
                    ax.axvline(max(ys), color="tab:red", lw=0.8, label=f"max {max(ys):.3g}")
                if isinstance(limit, int | float):
                    ax.axvline(float(limit), color="k", lw=0.8, ls="--", label=f"{op} {limit}")
                ax.set_xlabel(metric, fontsize=8)
                ax.legend(fontsize=7)
                ax.tick_params(labelsize=7)
            fig.suptitle(f"{sweep}: distributions ({len(recs)} runs)", fontsize=9)
            fig.tight_layout()
            path = out / f"{sweep}_distributions.png"
            fig.savefig(path, dpi=90)
            plt.close(fig)
            written.append(path)
        if len(params) >= 2:
            fig, ax = plt.subplots(figsize=(5, 4))
            xs = [r["run"]["params"][params[0]] for r in recs]
            ys = [r["run"]["params"][params[1]] for r in recs]
            ax.scatter(xs, ys, c=["tab:green" if p else "tab:red" for p in passed], s=30, alpha=0.6)
            ax.set_xlabel(params[0])
            ax.set_ylabel(params[1])
            ax.set_title(f"{sweep}: where runs pass (green) and fail (red)", fontsize=9)
            fig.tight_layout()
            path = out / f"{sweep}_map.png"
            fig.savefig(path, dpi=90)
            plt.close(fig)
            written.append(path)
    return written


__all__ = ["judged_metrics", "reproduce_command", "summarise", "write_report"]
