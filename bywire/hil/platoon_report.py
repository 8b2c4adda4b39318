"""Platoon report figures: seed 003 Fig. 6 and Fig. 7 for a simulated heat, and our string
stability beside the real strings'.

- `<name>_path_time.png`: position along the road over time of every vehicle, coloured by speed (seed 003
  Fig. 6, the heat's path-time diagram), our car drawn thicker; lanes in separate panels.
- `<name>_headway.png`: headway error (desired minus actual distance, seed 003 Fig. 7) of our car and of
  every follower with a desired distance, over time.
- `<name>_string_stability.png`: the string-stability estimate (peak H1 gain over the excited band) of
  each pair of our lane's string, and the same estimator on the shared OpenACC / CARMA strings.
matplotlib on its Agg backend.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import LineCollection

from bywire.hil.platoon_eval import SETTLE_S, by_vehicle, desired_distance, platoon_params
from bywire.hil.scenario import Scenario
from bywire.hil.world.traffic import EGO


def plot_platoon(
    out_dir: Path,
    scenario: Scenario,
    traffic: dict[str, np.ndarray],
    host: dict[str, np.ndarray] | None,
    document: dict[str, Any],
) -> list[Path]:
    """Write the three figures into `out_dir`; returns their paths."""
    spec = scenario.world
    assert spec is not None
    out_dir.mkdir(parents=True, exist_ok=True)
    names = ["ego"] + [v.name for v in spec.vehicles]
    tables = by_vehicle(traffic)
    paths = [
        _path_time(out_dir / f"{scenario.name}_path_time.png", scenario, tables, names),
        _headway(out_dir / f"{scenario.name}_headway.png", scenario, tables, names),
        _stability(out_dir / f"{scenario.name}_string_stability.png", scenario, document),
    ]
    del host
    return paths


def _path_time(
    path: Path, scenario: Scenario, tables: dict[int, dict[str, np.ndarray]], names: list[str]
) -> Path:
    spec = scenario.world
    assert spec is not None
    lanes = sorted({int(tab["lane"][0]) for tab in tables.values()})
    fig, axes = plt.subplots(1, len(lanes), figsize=(6.5 * len(lanes), 6), sharey=True, squeeze=False)
    vmax = max(float(np.max(tab["speed_mps"])) for tab in tables.values()) * 3.6
    vmin = min(float(np.min(tab["speed_mps"])) for tab in tables.values()) * 3.6
    norm = plt.Normalize(vmin, max(vmax, vmin + 1.0))
    for ax, lane in zip(axes[0], lanes, strict=True):
        for vid, tab in tables.items():
            if int(tab["lane"][0]) != lane:
                continue
            pts = np.column_stack((tab["t_s"], tab["s_m"]))
            segs = np.stack((pts[:-1], pts[1:]), axis=1)
            lc = LineCollection(list(segs), cmap="viridis", norm=norm, linewidths=3.5 if vid == EGO else 1.0)
            if vid == EGO:  # our car: outlined, so it stands out among the others
                ax.plot(tab["t_s"], tab["s_m"], color="k", lw=5.5, zorder=0)
            lc.set_array(tab["speed_mps"][:-1] * 3.6)
            ax.add_collection(lc)
            ax.annotate(names[vid], (tab["t_s"][-1], tab["s_m"][-1]), fontsize=7)
        ax.autoscale()
        ax.set_title(f"lane {lane}" + (" (ours)" if lane == spec.ego.lane else ""))
        ax.set_xlabel("time [s]")
    axes[0][0].set_ylabel("position along the road [m]")
    fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap="viridis"), ax=axes[0].tolist(), label="speed [km/h]")
    fig.suptitle(f"{scenario.name}: path-time diagram (cf. seed 003 Fig. 6)")
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _headway(
    path: Path, scenario: Scenario, tables: dict[int, dict[str, np.ndarray]], names: list[str]
) -> Path:
    spec = scenario.world
    assert spec is not None
    params = platoon_params(scenario)
    fig, ax = plt.subplots(figsize=(11, 4.5))
    t_from = scenario.engage_at_s + SETTLE_S
    for vid, tab in sorted(tables.items()):
        desired = desired_distance(spec, vid, tab["speed_mps"], params)
        if desired is None or int(tab["lane"][0]) != spec.ego.lane:
            continue
        sel = np.isfinite(tab["gap_m"]) & (tab["t_s"] >= t_from)
        if not np.any(sel):
            continue
        ax.plot(
            tab["t_s"][sel],
            desired[sel] - tab["gap_m"][sel],
            lw=2.0 if vid == EGO else 0.8,
            color="k" if vid == EGO else None,
            label=names[vid] + (" (ours)" if vid == EGO else ""),
        )
    ax.axhline(0.0, color="0.5", lw=0.8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("headway error: desired - actual [m]")
    ax.set_title(f"{scenario.name}: headway error (cf. seed 003 Fig. 7)")
    ax.legend(fontsize=7, ncol=4)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _stability(path: Path, scenario: Scenario, document: dict[str, Any]) -> Path:
    m = document.get("metrics", {})
    labels: list[str] = []
    values: list[float] = []
    colors: list[str] = []
    for p in m.get("string", {}).get("pairs", []):
        if p.get("ratio") is None:
            continue
        labels.append(f"{p['leader']}->{p['follower']}")
        values.append(float(p["ratio"]))
        colors.append("C3" if p["follower"] == "ego" else "C0")
    for name, res in (m.get("real_strings") or {}).items():
        if isinstance(res, dict) and res.get("string_stability") is not None:
            labels.append(Path(name).stem[:28])
            values.append(float(res["string_stability"]))
            colors.append("C7")
    fig, ax = plt.subplots(figsize=(max(6.0, 0.55 * len(labels) + 2), 4.5))
    ax.bar(range(len(values)), values, color=colors)
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_xticks(range(len(values)), labels, rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("peak |H1| over the excited band")
    ax.set_title(f"{scenario.name}: string stability (red: ours, blue: simulated pairs, grey: real strings)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


__all__ = ["plot_platoon"]
