"""Our objects against KITTI object labels (bywire.host.perception.kitti_objects): the camera-to-Velodyne
transform of a label, the matching rules, and the three shared labelled frames (skipped when absent)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from shared_data import shared_data_dir

from bywire.host.perception.grid import GridLayout
from bywire.host.perception.kitti_objects import (
    LabelledBox,
    evaluate_object_frames,
    precision_recall,
    read_calibration,
    read_labels,
    score_frame,
)
from bywire.host.perception.scan import ScanFormatError
from bywire.host.perception.segmentation import SegmentedObject

OBJECT_FRAMES = shared_data_dir() / "lidar_kitti" / "object_frames"

# Velodyne (x forward, y left, z up) to camera (x right, y down, z forward), the sensor 0.3 m behind.
CALIB = """P0: 700 0 600 0 0 700 180 0 0 0 1 0
P2: 700 0 600 0 0 700 180 0 0 0 1 0
R0_rect: 1 0 0 0 1 0 0 0 1
Tr_velo_to_cam: 0 -1 0 0 0 0 -1 0 1 0 0 -0.3
"""


@pytest.fixture
def calib_path(tmp_path: Path) -> Path:
    path = tmp_path / "calib.txt"
    path.write_text(CALIB)
    return path


def test_a_label_goes_to_the_velodyne_frame_lifted_by_half_its_height(
    calib_path: Path, tmp_path: Path
) -> None:
    calib = read_calibration(calib_path)
    labels = tmp_path / "label.txt"
    labels.write_text(
        "Car 0.00 0 0.1 100 100 200 200 1.50 1.80 4.20 -2.00 1.60 20.00 0.0\n"
        "DontCare -1 -1 -10 1 1 2 2 -1 -1 -1 -1000 -1000 -1000 -10\n"
        "Pedestrian 0.00 1 0.1 100 100 200 200 1.80 0.60 0.80 1.00 1.70 8.00 1.5707963\n"
    )
    car, ped = read_labels(labels, calib)
    assert (car.kind, car.occluded) == ("Car", 0)
    # camera (x -2 right, y 1.6 down to the bottom, z 20 ahead) -> velodyne (20.3 ahead, 2 left, centre)
    assert (car.x_m, car.y_m, car.z_m) == pytest.approx((20.3, 2.0, -1.6 + 0.75))
    # ry = 0 faces the camera's x (the car's right): yaw -90 deg in the Velodyne frame
    assert car.yaw_rad == pytest.approx(-math.pi / 2)
    assert ped.yaw_rad == pytest.approx(-math.pi, abs=1e-6) or ped.yaw_rad == pytest.approx(math.pi, abs=1e-6)
    assert calib.horizontal_fov_rad == pytest.approx(2 * math.atan(621 / 700))


def test_a_bad_label_or_calibration_names_the_file(calib_path: Path, tmp_path: Path) -> None:
    bad = tmp_path / "label.txt"
    bad.write_text("Car 0 0 0.1 1 2 3\n")
    with pytest.raises(ScanFormatError, match=r"label.txt:1"):
        read_labels(bad, read_calibration(calib_path))
    no_rect = tmp_path / "calib_no_rect.txt"
    no_rect.write_text(CALIB.replace("R0_rect", "R9_rect"))
    with pytest.raises(ScanFormatError, match=r"calib_no_rect\.txt"):
        read_calibration(no_rect)
    with pytest.raises(ScanFormatError, match="cannot read"):
        read_calibration(tmp_path / "absent.txt")


def box(kind: str, x: float, y: float, length: float = 4.0, width: float = 1.8) -> LabelledBox:
    return LabelledBox(kind, x, y, -1.0, length, width, 1.5, 0.0, 0, 0.0)


def obj(x: float, y: float) -> SegmentedObject:
    return SegmentedObject(x, y, 1.0, 1.0, 0.0, 1.5, 10, 1.0)


def test_matching_is_one_to_one_within_the_distance_and_skips_other_classes_and_the_unseen(
    calib_path: Path,
) -> None:
    calib = read_calibration(calib_path)
    labels = [
        box("Car", 20.0, 0.0),
        box("Pedestrian", 10.0, 3.0),
        box("Misc", 30.0, -5.0),
        box("Car", -15.0, 0.0),
    ]
    objects = [
        obj(19.0, 0.5),
        obj(19.5, -0.4),
        obj(10.2, 3.1),
        obj(30.5, -5.0),
        obj(25.0, 8.0),
        obj(-14.0, 0.0),
    ]
    s = score_frame("f", labels, objects, calib, 76.8, 2.0)
    # the car behind the sensor is out of the camera's view, and so is our object there
    assert [b.kind for b in s.labels] == ["Car", "Pedestrian"] and len(s.objects) == 5
    assert s.true_positives == 2 and s.misses == 0
    # the second object at the car, and the one far from any box, are false; the one at Misc is not scored
    assert sorted(s.objects[j].x_m for j in s.false_positives) == [19.5, 25.0] or sorted(
        s.objects[j].x_m for j in s.false_positives
    ) == [19.0, 25.0]
    assert precision_recall([s])[:2] == pytest.approx((0.5, 1.0))


def test_box_matching_finds_a_long_vehicle_seen_from_behind(calib_path: Path) -> None:
    calib = read_calibration(calib_path)
    truck = [box("Truck", 40.0, 0.0, length=12.0, width=2.5)]
    rear = [obj(34.2, 0.3)]  # its rear face: 5.8 m from the box centre, inside the box
    assert score_frame("f", truck, rear, calib, 76.8, 2.0, match="centre").true_positives == 0
    assert score_frame("f", truck, rear, calib, 76.8, 1.0, match="box").true_positives == 1
    with pytest.raises(ValueError):
        score_frame("f", truck, rear, calib, 76.8, 1.0, match="iou")


def test_no_objects_and_no_labels_give_undefined_rates(calib_path: Path) -> None:
    s = score_frame("f", [], [], read_calibration(calib_path), 76.8)
    p, r, tp, fp, fn = precision_recall([s])
    assert math.isnan(p) and math.isnan(r) and (tp, fp, fn) == (0, 0, 0)


def need_frames() -> None:
    if not (OBJECT_FRAMES / "velodyne").exists():
        pytest.skip(f"KITTI object frames not found at {OBJECT_FRAMES} (shared data absent)")


def test_the_shared_labels_land_on_their_points() -> None:
    need_frames()
    calib = read_calibration(OBJECT_FRAMES / "calib" / "000000.txt")
    (ped,) = read_labels(OBJECT_FRAMES / "label_2" / "000000.txt", calib)
    assert ped.kind == "Pedestrian"
    assert (ped.x_m, ped.y_m) == pytest.approx((8.75, -1.86), abs=0.05)
    pts = np.fromfile(OBJECT_FRAMES / "velodyne" / "000000.bin", np.float32).reshape(-1, 4)
    near = np.hypot(pts[:, 0] - ped.x_m, pts[:, 1] - ped.y_m) < 0.5
    assert near.sum() > 50
    assert pts[near, 2].max() == pytest.approx(ped.z_m + ped.height_m / 2, abs=0.2)


@pytest.mark.parametrize("layout", [GridLayout.graded(), GridLayout.uniform()], ids=["graded", "uniform"])
def test_the_labelled_frames_are_found(layout: GridLayout, tmp_path: Path) -> None:
    need_frames()
    scores = evaluate_object_frames(
        OBJECT_FRAMES, layout, match="box", match_distance_m=1.0, png_dir=tmp_path
    )
    assert len(scores) == 3 and len(list(tmp_path.glob("kitti_object_*.png"))) == 3
    _, recall, tp, fp, _ = precision_recall(scores)
    # the pedestrian at 9 m, the car at 35 m, the cyclist at 46 m and the truck at 70 m (its rear)
    assert tp >= 4 and recall >= 0.8
    assert fp > 0  # poles, hedges and walls in view carry no labels: precision is not the point here
    ped = scores[0]
    assert ped.labels[ped.matches[0][0]].kind == "Pedestrian"
    o = ped.objects[ped.matches[0][1]]
    assert math.hypot(o.x_m - 8.75, o.y_m + 1.86) < 0.5 and 1.5 < o.height_m < 2.2
