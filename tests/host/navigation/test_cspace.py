"""Configuration-space obstacles by FFT (seed 000 Sec. 10.1): the table never calls a pose free where the
car's exact rectangle (grown by the margin) touches an obstacle cell or leaves the map, and it is not
needlessly cautious: poses clear of every obstacle by more than a cell and a bin's sweep are free."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bywire.host.navigation.cspace import PASSAT_FOOTPRINT, Footprint, build_cspace
from bywire.host.navigation.grid_map import GridMap


def _rect_touches_cells(
    fp: Footprint, margin: float, pose: tuple[float, float, float], grid: GridMap
) -> tuple[bool, float]:
    """Exact: (the grown rectangle at `pose` meets an occupied cell's square or the map's outside, the
    smallest gap to any occupied cell or the edge), by dense sampling of the rectangle's area."""
    corners = fp.corners(margin)
    c, s = math.cos(pose[2]), math.sin(pose[2])
    us = np.linspace(corners[:, 0].min(), corners[:, 0].max(), 80)
    vs = np.linspace(corners[:, 1].min(), corners[:, 1].max(), 30)
    uu, vv = np.meshgrid(us, vs)
    x = pose[0] + c * uu - s * vv
    y = pose[1] + s * uu + c * vv
    touches = bool(grid.occupied_at(x.ravel(), y.ravel()).any())
    # gap: from the rectangle's samples to the nearest occupied cell's centre, less half its diagonal
    occ_r, occ_c = np.nonzero(grid.occupied)
    ox, oy = grid.centre_of(occ_r, occ_c)
    pts = np.column_stack((x.ravel(), y.ravel()))
    d = (
        np.sqrt(((pts[:, None, 0] - ox[None]) ** 2 + (pts[:, None, 1] - oy[None]) ** 2).min())
        if ox.size
        else np.inf
    )
    w, h = grid.size_m
    edge = min((x - grid.origin_xy_m[0]).min(), (grid.origin_xy_m[0] + w - x).min(),
               (y - grid.origin_xy_m[1]).min(), (grid.origin_xy_m[1] + h - y).min())  # fmt: skip
    return touches, min(float(d) - 0.5 * grid.resolution_m * math.sqrt(2.0), float(edge))


@pytest.mark.parametrize("margin", [0.0, 0.3])
def test_a_free_pose_is_free_and_a_clear_pose_is_not_blocked(margin: float) -> None:
    rng = np.random.default_rng(7)
    boxes = [
        (float(rng.uniform(3, 17)), float(rng.uniform(3, 17)), float(rng.uniform(0, 3)), 2.0, 1.0)
        for _ in range(6)
    ]
    grid = GridMap.from_boxes((20.0, 20.0), 0.2, boxes)
    cs = build_cspace(grid, PASSAT_FOOTPRINT, margin_m=margin, n_headings=72)
    slack = 0.2 * math.sqrt(2.0) + PASSAT_FOOTPRINT.reach_m(margin) * 2 * math.pi / 72 + 0.05
    free_seen = clear_seen = 0
    for _ in range(400):
        pose = (float(rng.uniform(0, 20)), float(rng.uniform(0, 20)), float(rng.uniform(-math.pi, math.pi)))
        blocked = bool(cs.collides(np.array([pose[0]]), np.array([pose[1]]), np.array([pose[2]]))[0])
        touches, gap = _rect_touches_cells(PASSAT_FOOTPRINT, margin, pose, grid)
        if not blocked:
            free_seen += 1
            assert not touches, f"the table calls {pose} free, but the car touches an obstacle"
        if not touches and gap > slack:
            clear_seen += 1
            assert not blocked, f"{pose} is clear by {gap:.2f} m but the table blocks it"
    assert free_seen > 40 and clear_seen > 20


def test_the_map_outside_is_an_obstacle_and_inputs_are_checked() -> None:
    grid = GridMap(np.zeros((100, 100), dtype=bool), 0.2)
    cs = build_cspace(grid, PASSAT_FOOTPRINT, margin_m=0.0, n_headings=36)
    assert cs.collides(np.array([10.0, 1.0, -5.0]), np.array([10.0, 10.0, 10.0]), np.zeros(3)).tolist() == [
        False, True, True,
    ]  # fmt: skip
    assert cs.disk_free[50, 50] and not cs.disk_free[0, 50]
    with pytest.raises(ValueError, match="margin_m"):
        build_cspace(grid, margin_m=-1.0)
    with pytest.raises(ValueError, match="n_headings"):
        build_cspace(grid, n_headings=4)
    with pytest.raises(ValueError, match="2-D bool"):
        GridMap(np.zeros((10, 10)), 0.2)


def test_maps_load_from_npy_and_images_with_clear_errors(tmp_path) -> None:  # type: ignore[no-untyped-def]
    import matplotlib.image as mpimg

    from bywire.host.navigation.grid_map import load

    arr = np.zeros((20, 30), dtype=np.uint8)
    arr[5, 7] = 1
    np.save(tmp_path / "m.npy", arr)
    g = load(tmp_path / "m.npy", 0.5)
    assert g.shape == (20, 30) and g.occupied[5, 7] and g.occupied.sum() == 1
    img = np.ones((20, 30, 3))
    img[2, 4] = 0.0  # dark: occupied; row 2 from the top is row 17 from the bottom
    mpimg.imsave(tmp_path / "m.png", img)
    g = load(tmp_path / "m.png", 0.5)
    assert g.occupied[17, 4] and g.occupied.sum() == 1
    (tmp_path / "bad.npy").write_bytes(b"not numpy")
    with pytest.raises(ValueError, match=r"bad\.npy"):
        load(tmp_path / "bad.npy", 0.5)
    with pytest.raises(ValueError, match="no such map"):
        load(tmp_path / "missing.png", 0.5)
