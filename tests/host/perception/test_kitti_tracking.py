"""KITTI tracking readers, the camera-to-plane mapping, the 3-D IoU, the CLEAR-MOT evaluation and
`bywire perception track-eval` on the shared KITTI sequences (skipped where they are absent)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from shared_data import shared_data_dir

from bywire.cli import main as bywire_main
from bywire.host.perception.kitti_tracking import (
    KittiBoxes,
    KittiFormatError,
    plane_to_camera,
    project_boxes,
    read_calib,
    read_detections,
    read_labels,
    to_plane,
)
from bywire.host.perception.track_eval import (
    AB3DMOT_VAL_SEQUENCES,
    TrackEvalParams,
    evaluate,
    iou_3d,
    score_tracks,
    scores,
)

TRACKING = shared_data_dir() / "lidar_kitti" / "tracking"
LABELS, DETECTIONS, CALIB = TRACKING / "label_02", TRACKING / "pointrcnn_det_Car_val", TRACKING / "calib"
VAL_PRESENT = [f"{s:04d}" for s in AB3DMOT_VAL_SEQUENCES if (LABELS / f"{s:04d}.txt").is_file()]
needs_kitti = pytest.mark.skipif(
    not (LABELS.is_dir() and DETECTIONS.is_dir() and CALIB.is_dir()),
    reason=f"the shared KITTI tracking data is not at {TRACKING} (set BYWIRE_SHARED_DATA)",
)

LABEL_LINE = "3 7 Car 0 1 -1.5 100.0 150.0 300.0 250.0 1.5 1.6 3.9 2.0 1.7 15.0 -1.57"
DETECTION_LINE = "3,2,100.0,150.0,300.0,250.0,7.5,1.5,1.6,3.9,2.0,1.7,15.0,-1.57,-1.7"


def boxes(xyz, hwl=(1.5, 1.6, 4.0), ry=0.0, track_id=None, frame=0, types="Car") -> KittiBoxes:
    xyz = np.atleast_2d(np.asarray(xyz, float))
    n = len(xyz)
    return KittiBoxes(
        frame=np.full(n, frame, np.int64),
        track_id=np.arange(n, dtype=np.int64) if track_id is None else np.asarray(track_id, np.int64),
        type=np.full(n, types),
        truncation=np.zeros(n, np.int64),
        occlusion=np.zeros(n, np.int64),
        box2d_px=np.tile([500.0, 150.0, 600.0, 250.0], (n, 1)),
        hwl_m=np.tile(np.asarray(hwl, float), (n, 1)),
        xyz_m=xyz,
        ry_rad=np.broadcast_to(np.asarray(ry, float), (n,)).copy(),
        score=np.full(n, np.nan),
    )


# -- readers -----------------------------------------------------------------------------------------


def test_read_labels_and_detections(tmp_path: Path):
    (tmp_path / "l.txt").write_text(LABEL_LINE + "\n\n" + LABEL_LINE.replace("Car", "DontCare", 1) + "\n")
    (tmp_path / "d.txt").write_text(DETECTION_LINE + "\n")
    labels = read_labels(tmp_path / "l.txt")
    dets = read_detections(tmp_path / "d.txt")
    assert len(labels) == 2 and list(labels.type) == ["Car", "DontCare"]
    assert labels.track_id[0] == 7 and labels.occlusion[0] == 1 and np.isnan(labels.score[0])
    assert dets.type[0] == "Car" and dets.score[0] == 7.5 and dets.track_id[0] == -1
    for b in (labels, dets):
        assert b.frame[0] == 3
        assert np.allclose(b.hwl_m[0], [1.5, 1.6, 3.9]) and np.allclose(b.xyz_m[0], [2.0, 1.7, 15.0])
        assert np.allclose(b.box2d_px[0], [100, 150, 300, 250]) and b.ry_rad[0] == pytest.approx(-1.57)
    assert set(labels.frames()) == {3} and labels.frames()[3].type[1] == "DontCare"


@pytest.mark.parametrize(
    ("reader", "good", "bad", "message"),
    [
        (read_labels, LABEL_LINE, LABEL_LINE.rsplit(" ", 1)[0], "16 fields"),
        (read_labels, LABEL_LINE, LABEL_LINE.replace(" 1.6 ", " wide "), "box"),
        (read_labels, LABEL_LINE, "x" + LABEL_LINE[1:], "frame 'x'"),
        (read_labels, LABEL_LINE, LABEL_LINE.replace(" 1.6 ", " nan "), "not finite"),
        (read_detections, DETECTION_LINE, DETECTION_LINE.replace("3,2,", "3,9,", 1), "type 9"),
        (read_detections, DETECTION_LINE, DETECTION_LINE + ",0", "16 fields"),
        (read_detections, DETECTION_LINE, DETECTION_LINE.replace(",1.6,", ",0.0,"), "positive"),
        (read_detections, DETECTION_LINE, "-2" + DETECTION_LINE[1:], "negative"),
    ],
)
def test_a_malformed_line_names_file_and_line(tmp_path: Path, reader, good, bad, message):
    path = tmp_path / "0042.txt"
    path.write_text(f"{good}\n{good}\n{bad}\n")
    with pytest.raises(KittiFormatError, match=message) as e:
        reader(path)
    assert str(e.value).startswith(f"{path}:3: ")


def test_read_calib(tmp_path: Path):
    p2 = " ".join(str(float(v)) for v in range(12))
    (tmp_path / "c.txt").write_text(f"P2: {p2}\nR_rect 1 0 0 0 1 0 0 0 1\n")
    calib = read_calib(tmp_path / "c.txt")
    assert calib["P2"].shape == (3, 4) and calib["P2"][2, 3] == 11.0 and calib["R_rect"].size == 9
    (tmp_path / "bad.txt").write_text("P0: 1 2 3\n")
    with pytest.raises(KittiFormatError, match=r"bad\.txt:1: P0 has 3 numbers"):
        read_calib(tmp_path / "bad.txt")
    (tmp_path / "none.txt").write_text("P0: " + p2 + "\n")
    with pytest.raises(KittiFormatError, match="no P2"):
        read_calib(tmp_path / "none.txt")


def test_a_missing_file_is_a_format_error(tmp_path: Path):
    with pytest.raises(KittiFormatError, match="cannot read"):
        read_labels(tmp_path / "absent.txt")


# -- frames and geometry ------------------------------------------------------------------------------


def test_camera_to_plane():
    # A car 15 m ahead, 2 m to the right, heading forward (ry = -pi/2: its length along camera z).
    (d,) = to_plane(boxes([2.0, 1.7, 15.0], ry=-np.pi / 2))
    assert (d.x_m, d.y_m) == (15.0, -2.0) and d.yaw_rad == pytest.approx(0.0)
    # Heading to the camera's right (ry = 0) is yaw -pi/2 in the plane (x forward, y left).
    (d,) = to_plane(boxes([0.0, 1.7, 10.0], ry=0.0))
    assert d.yaw_rad == pytest.approx(-np.pi / 2) and d.length_m == 4.0 and d.width_m == 1.6
    rng = np.random.default_rng(0)
    x, y, yaw = rng.uniform(-30, 30, 50), rng.uniform(-30, 30, 50), rng.uniform(-np.pi, np.pi, 50)
    cam_x, cam_z, ry = plane_to_camera(x, y, yaw)
    back = to_plane(boxes(np.column_stack([cam_x, np.zeros(50), cam_z]), ry=ry))
    assert np.allclose([b.x_m for b in back], x) and np.allclose([b.y_m for b in back], y)
    assert np.allclose(np.cos([b.yaw_rad for b in back]), np.cos(yaw))


def test_iou_3d():
    a = boxes([0.0, 1.0, 10.0])
    assert iou_3d(a, a)[0, 0] == pytest.approx(1.0)
    # Shifted by half its length along its length (ry = 0: length along camera x): 1/3.
    assert iou_3d(a, boxes([2.0, 1.0, 10.0]))[0, 0] == pytest.approx(1.0 / 3.0)
    # Half its height down: 1/3 again.
    assert iou_3d(a, boxes([0.0, 1.75, 10.0]))[0, 0] == pytest.approx(1.0 / 3.0)
    # A box turned by pi is the same box.
    assert iou_3d(a, boxes([0.0, 1.0, 10.0], ry=np.pi))[0, 0] == pytest.approx(1.0)
    assert iou_3d(a, boxes([0.0, 1.0, 20.0]))[0, 0] == 0.0


def test_iou_3d_agrees_with_sampling():
    rng = np.random.default_rng(7)
    a = boxes([0.0, 1.0, 10.0], hwl=(1.5, 1.8, 4.2), ry=0.3)
    b = boxes([0.8, 1.2, 10.5], hwl=(1.4, 1.6, 3.8), ry=-0.5)
    pts = rng.uniform([-4, -1.5, 6], [5, 1.5, 15], (400_000, 3))

    def inside(box, p):
        c, s = np.cos(box.ry_rad[0]), np.sin(box.ry_rad[0])
        dx, dz = p[:, 0] - box.xyz_m[0, 0], p[:, 2] - box.xyz_m[0, 2]
        along, across = c * dx - s * dz, s * dx + c * dz
        h, w, length = box.hwl_m[0]
        y = p[:, 1]
        return (
            (np.abs(along) <= length / 2)
            & (np.abs(across) <= w / 2)
            & (y <= box.xyz_m[0, 1])
            & (y >= box.xyz_m[0, 1] - h)
        )

    ia, ib = inside(a, pts), inside(b, pts)
    sampled = (ia & ib).sum() / (ia | ib).sum()
    assert iou_3d(a, b)[0, 0] == pytest.approx(sampled, abs=0.01)
    assert iou_3d(b, a)[0, 0] == pytest.approx(iou_3d(a, b)[0, 0])


@needs_kitti
def test_projection_reproduces_the_detections_image_boxes():
    p2 = read_calib(CALIB / "0001.txt")["P2"]
    dets = read_detections(DETECTIONS / "0001.txt")
    projected = project_boxes(p2, dets.hwl_m, dets.xyz_m, dets.ry_rad)
    # PointRCNN's image boxes are its 3-D boxes through P2: the same to a pixel.
    assert np.percentile(np.abs(projected - dets.box2d_px), 99) < 1.0


# -- the evaluation -----------------------------------------------------------------------------------


def test_ground_truth_as_tracks_scores_perfectly():
    frames = []
    for f in range(20):
        b = boxes([[2.0 + 0.5 * f, 1.7, 15.0], [-3.0, 1.7, 25.0 - 0.3 * f]], track_id=[1, 2], frame=f)
        frames.append(b)
    labels = concat(frames)
    acc = score_tracks(labels, labels, 20, TrackEvalParams())
    s = scores({"x": acc})["x"]
    assert s["mota"] == 1.0 and s["motp"] == pytest.approx(1.0) and s["id_switches"] == 0


def test_swapped_ids_count_as_switches_and_vans_are_ignored():
    frames, tracks = [], []
    for f in range(10):
        frames.append(boxes([[2.0, 1.7, 15.0], [-3.0, 1.7, 25.0]], track_id=[1, 2], frame=f))
        ids = [10, 20] if f < 5 else [20, 10]
        tracks.append(boxes([[2.0, 1.7, 15.0], [-3.0, 1.7, 25.0]], track_id=ids, frame=f))
    van = boxes([[8.0, 1.7, 12.0]], track_id=[3], frame=0, types="Van")
    labels, tracked = (
        concat([*frames, van]),
        concat([*tracks, boxes([[8.0, 1.7, 12.0]], track_id=[99], frame=0)]),
    )
    s = scores({"x": score_tracks(labels, tracked, 10, TrackEvalParams())})["x"]
    # The van is neither a miss nor, tracked, a false positive.
    assert s["false_positives"] == 0 and s["misses"] == 0 and s["objects"] == 20
    assert s["id_switches"] == 2 and s["mota"] == pytest.approx(1.0 - 2 / 20)


def concat(parts: list[KittiBoxes]) -> KittiBoxes:
    return KittiBoxes(
        *(np.concatenate([getattr(p, f) for p in parts]) for f in KittiBoxes.__dataclass_fields__)
    )


@needs_kitti
def test_kitti_validation_sequences_score_within_the_measured_band():
    if not VAL_PRESENT:
        pytest.skip("none of AB3DMOT's validation sequences is in the shared folder")
    result = evaluate(LABELS, DETECTIONS, CALIB, VAL_PRESENT)
    # Measured: MOTA 0.802, MOTP (mean 3-D IoU) 0.792, 7 ID switches on 0001/0006/0008/0010 (AB3DMOT
    # publishes 0.8647 on its 11 validation sequences). A floor 5 points under the measurement
    # catches a broken filter (measured: boxes lagging behind with R = 2 m score 0.65, a filter
    # without velocity 0.21 with over 1 000 switches) and leaves room for numerics.
    assert 0.75 <= result["mota"] <= 1.0
    assert result["motp"] > 0.72
    assert result["id_switches"] <= 20
    assert set(result["sequences"]) == set(VAL_PRESENT) and result["val_overall"]["mota"] == result["mota"]


@needs_kitti
def test_track_eval_command(tmp_path: Path, capsys):
    out = tmp_path / "scores.json"
    rc = bywire_main(
        ["perception", "track-eval", str(LABELS), str(DETECTIONS), "--sequences", "6", "--json", str(out)]
    )
    assert rc == 0
    result = json.loads(out.read_text())
    assert list(result)[:5] == ["mota", "motp", "id_switches", "fragmentations", "motp_distance"]
    assert {"mota", "motp", "id_switches", "fragmentations", "sequences"} <= set(result)
    assert list(result["sequences"]) == ["0006"] and result["sequences"]["0006"]["mota"] > 0.85
    printed = capsys.readouterr().out
    assert "0006*" in printed and "AB3DMOT" in printed and "86.47" in printed


def test_track_eval_command_names_a_bad_line(tmp_path: Path, capsys):
    for sub in ("label_02", "dets", "calib"):
        (tmp_path / sub).mkdir()
    (tmp_path / "label_02" / "0000.txt").write_text(LABEL_LINE + "\n")
    (tmp_path / "dets" / "0000.txt").write_text(DETECTION_LINE + "\n" + DETECTION_LINE[:-5] + "\n")
    (tmp_path / "calib" / "0000.txt").write_text("P2: " + " ".join(["1.0"] * 12) + "\n")
    args = ["perception", "track-eval", str(tmp_path / "label_02"), str(tmp_path / "dets")]
    assert bywire_main([*args, "--json", str(tmp_path / "o.json")]) == 2
    assert f"{tmp_path / 'dets' / '0000.txt'}:2:" in capsys.readouterr().err
    assert bywire_main([*args, "--sequences", "0001", "--json", str(tmp_path / "o.json")]) == 2
    assert "sequence 0001: no labels file" in capsys.readouterr().err
