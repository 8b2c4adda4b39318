"""CLEAR-MOT evaluation of our tracker on the KITTI tracking benchmark's car class (seed 000 section 5).

The tracker (`tracker.Tracker`) runs on a sequence's detections projected to the ground plane
(`kitti_tracking.to_plane`); its published tracks are turned back into camera-frame 3-D boxes and
scored against `label_02` with `motmetrics` (MOTA, MOTP, ID switches, fragmentations).

The protocol follows AB3DMOT's KITTI evaluation (its `scripts/KITTI/evaluate.py`, itself KITTI's
devkit with 3-D boxes), which gives the published car MOTA 86.47 at 3-D IoU 0.25 with the same
PointRCNN detections:
- a ground-truth car and a track match when their 3-D IoU is at least 0.25 (bird's-eye polygon
  overlap times the vertical overlap); the distance handed to motmetrics is 1 - IoU;
- Van is the car's neighbouring class: a van, and a car truncated (level > 0) or occluded beyond
  level 2, is neither a miss when lost nor a false positive's cause when tracked: it is dropped, and
  so is the track matched to it (matching for this first pass: Hungarian on 1 - IoU, as KITTI's);
- an unmatched track whose image box is at most 25 px high, or lies more than half inside a
  DontCare region, is dropped (the track's image box is its 3-D box projected through P2).

Where we differ:
- motmetrics matches with CLEAR-MOT's rule (a pair matched in the previous frame is kept while
  it stays inside the threshold, the rest by Hungarian); KITTI's devkit re-runs Hungarian every
  frame. ID switches and fragmentations are motmetrics' (a switch whenever a ground truth's track
  changes, also across frames where it was missed; KITTI counts one only between consecutive
  tracked frames), so ours are counted a little more strictly.
- MOTP is reported as AB3DMOT does, the mean 3-D IoU of the matches (higher is better);
  motmetrics' own, the mean distance 1 - IoU, is `motp_distance`.
- AB3DMOT reports MOTA at the track-score threshold that maximises it on the evaluated sequences
  themselves. Ours runs with fixed parameters (`TrackEvalParams`, `TrackerParams`), chosen across
  all shared sequences (docs/perception.md).
- The shared folder holds 4 of AB3DMOT's 11 validation sequences (0001, 0006, 0008, 0010) and 9
  of the training ones. The overall score is over the sequences asked for; `val_overall` is over
  the validation ones among them, the like-for-like comparison (PointRCNN was trained on KITTI's
  object training split, whose frames may overlap the tracking training sequences, where its
  detections are then better than on unseen data).
- Time stamps are the frame index times 0.1 s (the scans' own stamps are not in the folder).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import motmetrics
import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from bywire.host.perception.kitti_tracking import (
    KITTI_FRAME_S,
    KittiBoxes,
    box_corners,
    plane_to_camera,
    project_boxes,
    read_calib,
    read_detections,
    read_labels,
    to_plane,
)
from bywire.host.perception.tracker import Tracker, TrackerParams

FloatArray = npt.NDArray[np.float64]

# Measured on the shared training sequences (docs/perception.md): a PointRCNN score of 2.5 starts a
# track (`TrackEvalParams.min_score`, 0.5, continues one); four times the world frame's process
# noise, for the ego car's turns that move everything in the camera frame.
KITTI_TRACKER = TrackerParams(accel_psd_m2_s3=4.0, birth_min_score=2.5)

AB3DMOT_VAL_SEQUENCES = (1, 6, 8, 10, 12, 13, 14, 15, 16, 18, 19)
# AB3DMOT with PointRCNN detections, KITTI validation, car, 3-D IoU 0.25 (the shared data's SOURCES).
AB3DMOT_CAR = {"mota": 0.8647, "samota": 0.9334}


@dataclass(frozen=True)
class TrackEvalParams:
    """The evaluation's protocol (AB3DMOT's values) and the detection and output gates before and
    after the tracker (ours, measured: docs/perception.md)."""

    min_score: float = 0.5  # PointRCNN's score; below it a detection is not fed to the tracker
    report_misses: int = 0  # published tracks missed for up to this many scans are reported
    iou_threshold: float = 0.25
    max_truncation: int = 0
    max_occlusion: int = 2
    min_height_px: float = 25.0
    dontcare_overlap: float = 0.5
    tracker: TrackerParams = field(default_factory=lambda: KITTI_TRACKER)


def _polygon_area(poly: FloatArray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def _clip(subject: FloatArray, clip: FloatArray) -> FloatArray:
    """Sutherland-Hodgman: the part of convex polygon `subject` inside convex polygon `clip`
    (both counter-clockwise or both clockwise)."""
    out = subject
    sign = np.sign(_signed_area(clip))
    for i in range(len(clip)):
        if len(out) == 0:
            break
        a, b = clip[i], clip[(i + 1) % len(clip)]
        edge = b - a
        side = sign * (edge[0] * (out[:, 1] - a[1]) - edge[1] * (out[:, 0] - a[0]))
        pts = []
        for j in range(len(out)):
            p, q = out[j], out[(j + 1) % len(out)]
            sp, sq = side[j], side[(j + 1) % len(out)]
            if sp >= 0:
                pts.append(p)
            if (sp >= 0) != (sq >= 0):
                pts.append(p + (q - p) * (sp / (sp - sq)))
        out = np.array(pts).reshape(-1, 2)
    return out


def _signed_area(poly: FloatArray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def iou_3d(a: KittiBoxes, b: KittiBoxes) -> FloatArray:
    """3-D IoU (len(a), len(b)) of camera-frame boxes: bird's-eye (x, z) overlap times y overlap."""
    out = np.zeros((len(a), len(b)))
    if len(a) == 0 or len(b) == 0:
        return out
    bev_a = box_corners(a.hwl_m, a.xyz_m, a.ry_rad)[:, :4][..., [0, 2]]
    bev_b = box_corners(b.hwl_m, b.xyz_m, b.ry_rad)[:, :4][..., [0, 2]]
    # Boxes whose circumscribed circles do not meet have no overlap: most pairs stop here.
    ra = 0.5 * np.hypot(a.hwl_m[:, 1], a.hwl_m[:, 2])
    rb = 0.5 * np.hypot(b.hwl_m[:, 1], b.hwl_m[:, 2])
    centre_d = np.hypot(a.xyz_m[:, None, 0] - b.xyz_m[None, :, 0], a.xyz_m[:, None, 2] - b.xyz_m[None, :, 2])
    # y points down and xyz is the bottom centre: a box spans [y - h, y].
    top = np.maximum(a.xyz_m[:, None, 1] - a.hwl_m[:, None, 0], b.xyz_m[None, :, 1] - b.hwl_m[None, :, 0])
    bottom = np.minimum(a.xyz_m[:, None, 1], b.xyz_m[None, :, 1])
    height = np.maximum(bottom - top, 0.0)
    vol_a = np.prod(a.hwl_m, axis=1)
    vol_b = np.prod(b.hwl_m, axis=1)
    for i, j in zip(*np.nonzero((centre_d < ra[:, None] + rb[None, :]) & (height > 0.0)), strict=True):
        inter = _polygon_area(_clip(bev_a[i], bev_b[j])) * height[i, j]
        out[i, j] = inter / (vol_a[i] + vol_b[j] - inter)
    return out


def _box_overlap_of_a(a: FloatArray, b: FloatArray) -> FloatArray:
    """Intersection of image boxes a (N, 4) and b (M, 4) as a share of a's area (N, M)."""
    w = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0])
    h = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1])
    inter = np.where((w > 0) & (h > 0), w * h, 0.0)
    area = np.maximum((a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1]), 1e-9)
    return np.asarray(inter / area[:, None], float)


def empty_boxes() -> KittiBoxes:
    return KittiBoxes(
        np.zeros(0, np.int64),
        np.zeros(0, np.int64),
        np.zeros(0, np.str_),
        np.zeros(0, np.int64),
        np.zeros(0, np.int64),
        np.zeros((0, 4)),
        np.zeros((0, 3)),
        np.zeros((0, 3)),
        np.zeros(0),
        np.zeros(0),
    )


def track_sequence(
    detections: KittiBoxes, p2: FloatArray, n_frames: int, params: TrackEvalParams
) -> KittiBoxes:
    """Our tracker over a sequence's car detections: its reported tracks as camera-frame boxes
    (track_id: the tracker's id; score: the track's confidence; image box: projected through P2)."""
    tracker = Tracker(params.tracker)
    by_frame = detections.frames()
    empty = empty_boxes()
    # The filter tracks the ground plane; a box's bottom (camera y) and height come from the
    # detection the track last took.
    vertical: dict[int, tuple[float, float]] = {}
    # Per reported track: frame, id, plane x, plane y, plane yaw, camera y, h, w, l, confidence.
    rows: list[tuple[float, ...]] = []
    for frame in range(n_frames):
        det = by_frame.get(frame, empty)
        det = det.select((det.type == "Car") & (det.score >= params.min_score))
        for t in tracker.update(to_plane(det), frame * KITTI_FRAME_S):
            if t.detection >= 0:
                vertical[t.id] = (float(det.xyz_m[t.detection, 1]), float(det.hwl_m[t.detection, 0]))
            if t.misses > params.report_misses or t.id not in vertical:
                continue
            y, h = vertical[t.id]
            rows.append((frame, t.id, t.x_m, t.y_m, t.yaw_rad, y, h, t.width_m, t.length_m, t.confidence))
    a = np.array(rows, float).reshape(-1, 10)
    cam_x, cam_z, ry = plane_to_camera(a[:, 2], a[:, 3], a[:, 4])
    hwl = a[:, 6:9]
    xyz = np.column_stack([cam_x, a[:, 5], cam_z])
    return KittiBoxes(
        frame=a[:, 0].astype(np.int64),
        track_id=a[:, 1].astype(np.int64),
        type=np.full(len(a), "Car"),
        truncation=np.full(len(a), -1, np.int64),
        occlusion=np.full(len(a), -1, np.int64),
        box2d_px=project_boxes(p2, hwl, xyz, ry),
        hwl_m=hwl,
        xyz_m=xyz,
        ry_rad=ry,
        score=a[:, 9],
    )


def _hungarian_matches(cost: FloatArray, allowed: npt.NDArray[np.bool_]) -> dict[int, int]:
    if cost.size == 0:
        return {}
    rows, cols = linear_sum_assignment(np.where(allowed, cost, 1e9))
    return {int(r): int(c) for r, c in zip(rows, cols, strict=True) if allowed[r, c]}


def frame_pairs(
    gt: KittiBoxes, tracks: KittiBoxes, params: TrackEvalParams
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64], FloatArray]:
    """One frame after KITTI's ignore rules: the ground-truth ids and track ids that count, and the
    distance matrix between them (1 - 3-D IoU; NaN where the IoU is below the threshold)."""
    is_dc = gt.type == "DontCare"
    dontcare = gt.select(is_dc)
    cars = gt.select(~is_dc & np.isin(gt.type, ["Car", "Van"]))
    iou = iou_3d(cars, tracks)
    allowed = iou >= params.iou_threshold
    matched = _hungarian_matches(1.0 - iou, allowed)
    ignorable = (
        (cars.type == "Van")
        | (cars.truncation > params.max_truncation)
        | (cars.occlusion > params.max_occlusion)
    )
    drop_track = np.zeros(len(tracks), bool)
    for g, t in matched.items():
        if ignorable[g]:
            drop_track[t] = True
    unmatched = np.ones(len(tracks), bool)
    unmatched[list(matched.values())] = False
    small = (tracks.box2d_px[:, 3] - tracks.box2d_px[:, 1]) <= params.min_height_px
    in_dontcare = np.zeros(len(tracks), bool)
    if len(dontcare) and len(tracks):
        overlap = _box_overlap_of_a(tracks.box2d_px, dontcare.box2d_px)
        in_dontcare = np.asarray((overlap > params.dontcare_overlap).any(axis=1), bool)
    drop_track |= unmatched & (small | in_dontcare)
    keep_gt = ~ignorable
    dist = np.where(allowed, 1.0 - iou, np.nan)[np.ix_(keep_gt, ~drop_track)]
    return cars.track_id[keep_gt], tracks.track_id[~drop_track], dist


class TrackEvalError(ValueError):
    """Missing or inconsistent inputs to the evaluation (a sequence without labels, say)."""


def sequence_names(folder: Path) -> list[str]:
    return sorted(p.stem for p in Path(folder).glob("*.txt"))


def score_tracks(
    labels: KittiBoxes, tracks: KittiBoxes, n_frames: int, params: TrackEvalParams
) -> motmetrics.MOTAccumulator:
    """The motmetrics accumulator of a sequence's tracks (camera-frame boxes with ids and image
    boxes, as `track_sequence` gives) against its labels."""
    gt_by_frame, tracks_by_frame = labels.frames(), tracks.frames()
    empty = empty_boxes()
    acc = motmetrics.MOTAccumulator(auto_id=False)
    for frame in range(n_frames):
        gt_ids, track_ids, dist = frame_pairs(
            gt_by_frame.get(frame, empty), tracks_by_frame.get(frame, empty), params
        )
        acc.update(gt_ids, track_ids, dist, frameid=frame)
    return acc


def evaluate_sequence(
    labels: KittiBoxes, detections: KittiBoxes, p2: FloatArray, params: TrackEvalParams
) -> motmetrics.MOTAccumulator:
    """The motmetrics accumulator of one sequence: our tracker on the detections against the labels."""
    n_frames = max(labels.last_frame, detections.last_frame) + 1
    return score_tracks(labels, track_sequence(detections, p2, n_frames, params), n_frames, params)


_METRICS = {
    "mota": "mota",
    "motp_distance": "motp",
    "id_switches": "num_switches",
    "fragmentations": "num_fragmentations",
    "false_positives": "num_false_positives",
    "misses": "num_misses",
    "objects": "num_objects",
    "matches": "num_matches",
    "recall": "recall",
    "precision": "precision",
    "idf1": "idf1",
    "mostly_tracked": "mostly_tracked",
    "mostly_lost": "mostly_lost",
    "trajectories": "num_unique_objects",
}


def scores(accs: dict[str, motmetrics.MOTAccumulator]) -> dict[str, dict[str, Any]]:
    """Each sequence's scores and the overall ones (key "OVERALL", motmetrics' name), in plain JSON types."""
    mh = motmetrics.metrics.create()
    table = mh.compute_many(
        list(accs.values()), names=list(accs), metrics=list(_METRICS.values()), generate_overall=True
    )
    out: dict[str, dict[str, Any]] = {}
    for name, row in table.iterrows():
        one: dict[str, Any] = {}
        for key, col in _METRICS.items():
            v = row[col]
            one[key] = int(v) if col.startswith("num_") or col.startswith("mostly") else _finite(v)
        one["motp"] = None if one["motp_distance"] is None else 1.0 - one["motp_distance"]
        out[str(name)] = one
    return out


def _finite(v: Any) -> float | None:
    f = float(v)
    return f if np.isfinite(f) else None


def evaluate(
    labels_dir: Path,
    detections_dir: Path,
    calib_dir: Path,
    sequences: Sequence[str] | None = None,
    params: TrackEvalParams | None = None,
) -> dict[str, Any]:
    """Our tracker's CLEAR-MOT scores on the sequences (default: every one with labels and
    detections): {"mota", "motp", "id_switches", "fragmentations", ..., "sequences": {name: {...}},
    "val_overall": over AB3DMOT's validation sequences among them, "ab3dmot": its published score}."""
    params = params or TrackEvalParams()
    labels_dir, detections_dir, calib_dir = Path(labels_dir), Path(detections_dir), Path(calib_dir)
    if sequences is None:
        sequences = sorted(set(sequence_names(labels_dir)) & set(sequence_names(detections_dir)))
    if not sequences:
        raise TrackEvalError(
            f"no sequence has both labels in {labels_dir} and detections in {detections_dir}"
        )
    accs: dict[str, motmetrics.MOTAccumulator] = {}
    for name in sequences:
        files = {
            "labels": labels_dir / f"{name}.txt",
            "detections": detections_dir / f"{name}.txt",
            "calibration": calib_dir / f"{name}.txt",
        }
        for what, path in files.items():
            if not path.is_file():
                raise TrackEvalError(f"sequence {name}: no {what} file {path}")
        p2 = read_calib(files["calibration"])["P2"]
        accs[name] = evaluate_sequence(
            read_labels(files["labels"]), read_detections(files["detections"]), p2, params
        )
    per = scores(accs)
    overall = per.pop("OVERALL")
    val = {k: v for k, v in accs.items() if k.isdigit() and int(k) in AB3DMOT_VAL_SEQUENCES}
    for name in per:
        per[name]["ab3dmot_val"] = name in val
    return {
        **{k: overall[k] for k in ("mota", "motp", "id_switches", "fragmentations")},
        **{k: v for k, v in overall.items() if k not in ("mota", "motp", "id_switches", "fragmentations")},
        "sequences": per,
        "val_overall": scores(val)["OVERALL"] if val else None,
        "ab3dmot": {
            **AB3DMOT_CAR,
            "sequences": [f"{s:04d}" for s in AB3DMOT_VAL_SEQUENCES],
            "protocol": "3-D IoU 0.25, car, MOTA at the best track-score threshold on those sequences",
        },
        "params": asdict(params),
    }
