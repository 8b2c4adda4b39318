"""Run reports: PNG plots of a run and its JSON verdict.

One figure per run with the signals an engineer looks at first: speed, requested vs.
measured acceleration, throttle pedal and brake pressure, ECU state and faults over time, and the gap
to the lead car when there is one. matplotlib runs on its Agg backend: no display needed.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from bywire.hil.scenario import Scenario
from bywire.host.trace import CONTROLLERS
from bywire.protocol.ecu_types import EcuState


def write_json(path: Path, document: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(
        json.dumps(document, indent=2, sort_keys=False, default=_json_default) + "\n", encoding="utf-8"
    )


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def plot_run(
    path: Path,
    scenario: Scenario,
    plant: dict[str, np.ndarray],
    host: dict[str, np.ndarray] | None,
    result: dict[str, Any],
) -> Path:
    """Write the run's overview figure to `path` (PNG) and return it."""
    t = plant["t_s"]
    has_lead = bool(np.isfinite(plant["lead_gap_m"]).any())
    rows = 5 if has_lead else 4
    fig, axes = plt.subplots(rows, 1, figsize=(11, 2.3 * rows + 1), sharex=True)
    verdict = result.get("verdict", "?").upper()
    fig.suptitle(f"{scenario.name} ({result.get('mode', '?')}): {verdict}", fontweight="bold")

    ax = axes[0]
    ax.plot(t, plant["speed_mps"], label="speed (FMU)", color="C0")
    if host is not None and host["t_s"].size and scenario.host_mode == "drive":
        ax.plot(host["t_s"], host["v_des_mps"], "--", label="desired speed (host)", color="C7")
    if has_lead:
        ax.plot(t, plant["lead_speed_mps"], ":", label="lead car speed", color="C3")
    ax.set_ylabel("speed [m/s]")
    ax.legend(loc="best", fontsize=8)

    ax = axes[1]
    ax.plot(t, plant["accel_mps2"], label="measured (FMU)", color="C0", lw=1)
    if host is not None and host["t_s"].size:
        ax.step(host["t_s"], host["accel_request_mps2"], where="post", label="requested (host)", color="C1")
    ax.set_ylabel("accel [m/s²]")
    ax.legend(loc="best", fontsize=8)

    ax = axes[2]
    ax.plot(t, plant["throttle_applied_pct"], label="throttle applied [%]", color="C2")
    ax.plot(t, plant["brake_actual_bar"], label="brake pressure [bar]", color="C3")
    if np.any(plant["driver_brake_pct"] > 0):
        ax.plot(t, plant["driver_brake_pct"], ":", label="driver brake pedal [%]", color="k")
    if np.any(plant["grade_pct"] != 0):
        ax.plot(t, plant["grade_pct"], "--", label="grade [%]", color="C5")
    ax.set_ylabel("pedal / brake")
    ax.legend(loc="best", fontsize=8)

    ax = axes[3]
    ax.step(t, plant["ecu_state"], where="post", label="ECU state", color="C4")
    ax.set_yticks([int(s) for s in EcuState], [s.name for s in EcuState], fontsize=7)
    ax.set_ylim(-0.5, max(int(s) for s in EcuState) + 0.5)
    if host is not None and host["t_s"].size:
        ax2 = ax.twinx()
        ax2.step(host["t_s"], host["ecu_faults"], where="post", color="C3", alpha=0.6, label="fault bits")
        ax2.set_ylabel("fault bits", color="C3", fontsize=8)
    for fault in scenario.faults:
        for a in axes:
            a.axvline(fault.at_s, color="r", alpha=0.25, lw=1)
        ax.annotate(
            fault.kind if fault.kind != "estop" else f"E-stop {fault.mode.name}",
            (fault.at_s, 0.2),
            fontsize=7,
            color="r",
            rotation=90,
            va="bottom",
        )
    for event in result.get("host_runtime", {}).get("events", []):
        if event["cause"] in ("dependant", "recovered"):
            continue
        for a in axes:
            a.axvline(event["t_rel_s"], color="m", alpha=0.35, lw=1, ls="--")
        ax.annotate(
            f"supervisor: {event['module']} {event['cause']} -> {event['action']}",
            (event["t_rel_s"], max(int(s) for s in EcuState)),
            fontsize=7,
            color="m",
            rotation=90,
            va="top",
            ha="right",
        )
    ax.set_ylabel("ECU")

    if has_lead:
        ax = axes[4]
        ax.plot(t, plant["lead_gap_m"], label="gap to lead (truth)", color="C3")
        if host is not None and host["t_s"].size:
            ax.plot(host["t_s"], host["lead_gap_m"], ".", ms=2, label="radar gap (host)", color="C0")
            ctrl = host["controller"].astype(int)
            ax2 = ax.twinx()
            ax2.step(host["t_s"], ctrl, where="post", color="C7", alpha=0.5)
            ax2.set_yticks(range(len(CONTROLLERS)), CONTROLLERS, fontsize=7)
        ax.set_ylabel("gap [m]")
        ax.legend(loc="best", fontsize=8)
    axes[-1].set_xlabel("scenario time [s]")
    checks = result.get("checks", [])
    text = "\n".join(
        f"{'PASS' if c['passed'] else 'FAIL'} {c['name']}: {c['value']} ({c['op']} {c['limit']})"
        for c in checks
    )
    if text:
        fig.text(0.01, 0.005, text, fontsize=7, family="monospace", va="bottom")
    fig.tight_layout(rect=(0, 0.03 + 0.012 * len(checks), 1, 0.97))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
