"""Pictures of the occupancy grid (seed 000 Figure 4's colours: dark = obstacle evidence, white =
drivable, grey = unknown), its obstacle cells with the segmented objects outlined, and optionally the
scan and labelled boxes under them. matplotlib with the Agg backend: files only, never a window."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bywire.host.perception.grid import GridSnapshot
from bywire.host.perception.scan import Scan
from bywire.host.perception.segmentation import Segmentation


def plot_grid(
    path: Path,
    snapshot: GridSnapshot,
    segmentation: Segmentation,
    title: str = "",
    scan: Scan | None = None,
    labelled_boxes: Sequence[np.ndarray] = (),
    view_half_m: float | None = None,
) -> None:
    """Two panels: occupancy (eq. 3) and obstacles with objects (red boxes; labelled boxes in green,
    the scan's points in light blue under them). `view_half_m` crops both around the grid centre."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    layout = snapshot.layout
    cx, cy = snapshot.centre_m
    half = layout.half_extent_m
    extent = (cx - half, cx + half, cy - half, cy + half)
    occupancy = np.asarray(layout.compose(np.where(layout.active_mask(), snapshot.occupancy, np.nan)), float)
    obstacles = layout.compose(snapshot.obstacle_mask())
    fig, (ax_p, ax_o) = plt.subplots(1, 2, figsize=(16, 8.4))
    # One revolution moves p by a few tenths from 0.5: a narrow grey scale shows free and occupied.
    ax_p.imshow(1.0 - occupancy, cmap="gray", vmin=0.3, vmax=0.7, origin="lower", extent=extent)
    ax_p.set_title("occupancy p (eq. 3), 0.3 white .. 0.7 black: grey = unknown", fontsize=9)
    if scan is not None and len(scan):
        step = max(1, len(scan) // 40000)
        ax_o.scatter(
            scan.xyz_m[::step, 0] + cx, scan.xyz_m[::step, 1] + cy, s=0.05, c="#9ecae1", rasterized=True
        )
    ax_o.imshow(
        np.where(obstacles, 1.0, np.nan), cmap="gray_r", vmin=0.0, vmax=1.0, origin="lower", extent=extent
    )
    for corners in labelled_boxes:
        ring = np.vstack((corners, corners[:1]))
        ax_o.plot(ring[:, 0], ring[:, 1], color="tab:green", lw=1.2)
    for o in segmentation.objects:
        ring = np.vstack((o.corners_m(), o.corners_m()[:1]))
        ax_o.plot(ring[:, 0], ring[:, 1], color="tab:red", lw=0.8)
    ax_o.set_title(
        f"{len(segmentation.cells)} obstacle cells, {len(segmentation.objects)} objects (red)"
        + (", labelled boxes (green)" if len(labelled_boxes) else ""),
        fontsize=9,
    )
    view = view_half_m if view_half_m is not None else half
    for ax in (ax_p, ax_o):
        ax.set_xlim(cx - view, cx + view)
        ax.set_ylim(cy - view, cy + view)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    fig.suptitle(title or layout.name, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
