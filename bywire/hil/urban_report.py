"""Plots of an urban run: the trajectory over the road network, and the behaviour's state history.

`NAME_urban.png`: every lane and exit of the RNDF (grey), stop lines (red bars), the MDF's checkpoints
(blue, numbered in mission order; green once reached), our car's track coloured by time, every traffic
car's track (thin), and the collisions (black crosses). `NAME_states.png`: the HSM state path over time.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from bywire.hil.scenario import Scenario
from bywire.hil.world.urban import cluster_stops, load_network
from bywire.host.roadnet.graph import EdgeKind


def plot_network_track(
    path: Path, scenario: Scenario, urban: dict[str, Any], document: dict[str, Any]
) -> None:
    spec = scenario.urban
    assert spec is not None
    graph, mission = load_network(spec.rndf, spec.mdf)
    fig, ax = plt.subplots(figsize=(10, 9))
    for e in graph.edges((EdgeKind.LANE, EdgeKind.EXIT)):
        p = e.path
        ax.plot(p.x_m, p.y_m, color="0.75" if e.kind == EdgeKind.LANE else "0.85", lw=0.8, zorder=1)
    lines, _ = cluster_stops(graph)
    for ln in lines:
        c, s = math.cos(ln.heading_rad), math.sin(ln.heading_rad)
        ax.plot(
            [ln.x_m - 1.8 * s, ln.x_m + 1.8 * s],
            [ln.y_m + 1.8 * c, ln.y_m - 1.8 * c],
            color="red",
            lw=2,
            zorder=2,
        )
    reached = len(urban.get("checkpoints_reached", []))
    for k, number in enumerate(mission.checkpoint_numbers):
        x, y = graph.vertex_xy(graph.checkpoint_vertex(number))
        colour = "green" if k < reached else "blue"
        ax.plot(x, y, "o", color=colour, ms=6, zorder=4)
        ax.annotate(str(number), (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7, color=colour)
    tracks = urban.get("tracks", {})
    for name, rows in tracks.items():
        if name == "ego" or not rows:
            continue
        ax.plot([r[1] for r in rows], [r[2] for r in rows], lw=0.8, alpha=0.7, zorder=3, label=name)
    ego = tracks.get("ego", [])
    if ego:
        sc = ax.scatter(
            [r[1] for r in ego], [r[2] for r in ego], c=[r[0] for r in ego], s=4, cmap="viridis", zorder=5
        )
        fig.colorbar(sc, ax=ax, label="t (s), our car")
    for c in urban.get("collisions", []):
        for name in (c["a"], c["b"]):
            rows = tracks.get(name, [])
            near = min(rows, key=lambda r: abs(r[0] - c["t_s"]), default=None)
            if near is not None:
                ax.plot(near[1], near[2], "kx", ms=10, mew=2, zorder=6)
    m = document.get("metrics", {})
    ax.set_title(
        f"{scenario.name} ({document.get('mode', 'sil')}): {document.get('verdict', '?')} - checkpoints "
        f"{m.get('checkpoints_reached')}/{m.get('checkpoints_total')}, "
        f"lateral RMS {m.get('lateral_error_rms_m')} m"
    )
    ax.set_xlabel("x (m, east)")
    ax.set_ylabel("y (m, north)")
    ax.set_aspect("equal", adjustable="datalim")
    if len(tracks) > 1 and len(tracks) < 15:
        ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_states(path: Path, scenario: Scenario, document: dict[str, Any]) -> None:
    history = document.get("state_history", [])
    fig, ax = plt.subplots(figsize=(10, 4))
    if history:
        names: list[str] = []
        for _, s in history:
            if s not in names:
                names.append(s)
        end = float(scenario.duration_s)
        for k, (t0, s) in enumerate(history):
            t1 = history[k + 1][0] if k + 1 < len(history) else end
            y = names.index(s)
            ax.plot([t0, t1], [y, y], lw=6, solid_capstyle="butt", color="tab:blue")
        ax.set_yticks(range(len(names)))
        ax.set_yticklabels(names, fontsize=7)
    ax.set_xlabel("t (s)")
    ax.set_title(f"{scenario.name}: behaviour state history")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_urban(
    report_dir: Path, scenario: Scenario, urban: dict[str, Any] | None, document: dict[str, Any]
) -> None:
    """Both plots into `report_dir` (the trajectory only with the world's bookkeeping)."""
    if urban:
        plot_network_track(report_dir / f"{scenario.name}_urban.png", scenario, urban, document)
    plot_states(report_dir / f"{scenario.name}_states.png", scenario, document)


__all__ = ["plot_network_track", "plot_states", "plot_urban"]
