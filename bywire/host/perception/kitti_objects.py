"""Our segmented objects (seed 000 section 5) scored against KITTI object-benchmark labels.

A KITTI object frame has a Velodyne scan (`velodyne/*.bin`), boxes in the rectified camera frame
(`label_2/*.txt`: type, truncation, occlusion, alpha, image box, h w l, bottom-centre x y z, rotation
ry) and the calibration (`calib/*.txt`). A label's centre goes to the Velodyne frame as
x_velo = Tr_velo_to_cam^-1 (R0_rect^-1 x_rect), lifted by half its height (camera y points down).

The labels cover only the left camera's image, so the score is taken inside its horizontal field of
view (from P2's focal length and the image width) and within the grid's range. A labelled box of an
evaluated class (Car, Van, Truck, Pedestrian, Cyclist) and one of our objects match when their
centres are within `match_distance_m` (one-to-one, nearest first by Hungarian assignment); our
objects left unmatched are false positives unless they lie within that distance of a box of another
class (Misc, Tram, Person_sitting: objects, just not scored). `DontCare` regions have no 3-D place
and are ignored. KITTI data is non-commercial: read it in place, never copy it into the repository.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from bywire.host.perception.grid import GridLayout, OccupancyGrid
from bywire.host.perception.scan import ScanFormatError, read_kitti_bin
from bywire.host.perception.segmentation import (
    ParticipantShape,
    SegmentationParams,
    SegmentedObject,
    box_corners_m,
    segment,
)

F64 = npt.NDArray[np.float64]

EVALUATED_CLASSES = ("Car", "Van", "Truck", "Pedestrian", "Cyclist")
PARTICIPANTS = ParticipantShape()
KITTI_IMAGE_WIDTH_PX = 1242  # the left colour camera's rectified image (1224-1242 px across frames)


@dataclass(frozen=True)
class Calibration:
    velo_to_cam: F64  # 4x4, Tr_velo_to_cam
    rect: F64  # 4x4, R0_rect
    horizontal_fov_rad: float  # of camera 2 (P2)

    def camera_to_velodyne(self, xyz_rect: F64) -> F64:
        """(N, 3) points of the rectified camera frame in the Velodyne frame."""
        h = np.column_stack((xyz_rect, np.ones(len(xyz_rect))))
        return (np.linalg.inv(self.velo_to_cam) @ np.linalg.inv(self.rect) @ h.T).T[:, :3]


@dataclass(frozen=True)
class LabelledBox:
    """A labelled object in the Velodyne frame: box centre (m), size (m), yaw (rad, from x towards y)."""

    kind: str
    x_m: float
    y_m: float
    z_m: float
    length_m: float
    width_m: float
    height_m: float
    yaw_rad: float
    occluded: int
    truncated: float

    def corners_m(self) -> F64:
        """The box's four ground corners (4, 2), counter-clockwise."""
        return box_corners_m(self.x_m, self.y_m, self.length_m, self.width_m, self.yaw_rad)


@dataclass(frozen=True)
class FrameScore:
    """One frame: scored labels and objects, and which matched (label index, object index, distance)."""

    frame: str
    labels: list[LabelledBox]
    objects: list[SegmentedObject]
    matches: list[tuple[int, int, float]] = field(default_factory=list)
    false_positives: list[int] = field(default_factory=list)

    @property
    def true_positives(self) -> int:
        return len(self.matches)

    @property
    def misses(self) -> int:
        return len(self.labels) - len(self.matches)


def read_calibration(path: Path) -> Calibration:
    rows: dict[str, F64] = {}
    try:
        text = Path(path).read_text()
    except OSError as e:
        raise ScanFormatError(f"{path}: cannot read: {e.strerror or e}") from e
    for line in text.splitlines():
        key, _, values = line.partition(":")
        if values.strip():
            try:
                rows[key.strip()] = np.array([float(v) for v in values.split()])
            except ValueError as e:
                raise ScanFormatError(f"{path}: {key}: {e}") from e
    try:
        velo_to_cam = np.eye(4)
        velo_to_cam[:3, :4] = rows["Tr_velo_to_cam"].reshape(3, 4)
        rect = np.eye(4)
        rect[:3, :3] = rows["R0_rect"].reshape(3, 3)
        fx = float(rows["P2"].reshape(3, 4)[0, 0])
    except (KeyError, ValueError) as e:
        raise ScanFormatError(f"{path}: needs Tr_velo_to_cam (3x4), R0_rect (3x3) and P2 (3x4): {e}") from e
    return Calibration(velo_to_cam, rect, 2.0 * math.atan(KITTI_IMAGE_WIDTH_PX / 2.0 / fx))


def read_labels(path: Path, calib: Calibration) -> list[LabelledBox]:
    """The frame's boxes with a 3-D place (not DontCare), in the Velodyne frame."""
    boxes = []
    for n, line in enumerate(Path(path).read_text().splitlines(), 1):
        f = line.split()
        if not f or f[0] == "DontCare":
            continue
        if len(f) < 15:
            raise ScanFormatError(f"{path}:{n}: {len(f)} fields, a KITTI label has 15")
        h, w, length, x, y, z, ry = (float(v) for v in f[8:15])
        centre = calib.camera_to_velodyne(np.array([[x, y - h / 2.0, z]]))[0]
        yaw = (-ry - math.pi / 2.0 + math.pi) % (2.0 * math.pi) - math.pi
        cx, cy, cz = (float(c) for c in centre)
        boxes.append(LabelledBox(f[0], cx, cy, cz, length, w, h, yaw, int(f[2]), float(f[1])))
    return boxes


def in_view(x_m: float, y_m: float, calib: Calibration, max_range_m: float) -> bool:
    """Inside the labelled camera's horizontal field of view and within range of the sensor."""
    return (
        x_m > 0.0
        and abs(math.atan2(y_m, x_m)) <= calib.horizontal_fov_rad / 2
        and max(abs(x_m), abs(y_m)) < max_range_m
    )


def score_frame(
    frame: str,
    labels: Sequence[LabelledBox],
    objects: Sequence[SegmentedObject],
    calib: Calibration,
    max_range_m: float,
    match_distance_m: float = 2.0,
    classes: Sequence[str] = EVALUATED_CLASSES,
    match: str = "centre",
) -> FrameScore:
    """match "centre": centre to centre distance; "box": how far our centre is outside the labelled box
    (0 inside), which does not fault an object seen only from its near side for where its far half is."""
    if match not in ("centre", "box"):
        raise ValueError(f"match {match!r}: 'centre' or 'box'")
    scored = [b for b in labels if b.kind in classes and in_view(b.x_m, b.y_m, calib, max_range_m)]
    others = [b for b in labels if b.kind not in classes]
    ours = [o for o in objects if in_view(o.x_m, o.y_m, calib, max_range_m)]
    matches: list[tuple[int, int, float]] = []
    if scored and ours:
        if match == "centre":
            d = _distances([(b.x_m, b.y_m) for b in scored], [(o.x_m, o.y_m) for o in ours])
        else:
            d = np.array([[_outside_box_m(b, o.x_m, o.y_m) for o in ours] for b in scored])
        cost = np.where(d <= match_distance_m, d, 1e6)
        for i, j in zip(*linear_sum_assignment(cost), strict=True):
            if d[i, j] <= match_distance_m:
                matches.append((int(i), int(j), float(d[i, j])))
    matched = {j for _, j, _ in matches}
    unscored = _distances([(o.x_m, o.y_m) for o in ours], [(b.x_m, b.y_m) for b in others])
    near_other = (
        [bool((row <= match_distance_m).any()) for row in unscored] if others else [False] * len(ours)
    )
    fps = [j for j in range(len(ours)) if j not in matched and not near_other[j]]
    return FrameScore(frame, list(scored), ours, matches, fps)


def _outside_box_m(b: LabelledBox, x_m: float, y_m: float) -> float:
    c, s = math.cos(b.yaw_rad), math.sin(b.yaw_rad)
    dx, dy = x_m - b.x_m, y_m - b.y_m
    u = abs(c * dx + s * dy) - b.length_m / 2
    v = abs(-s * dx + c * dy) - b.width_m / 2
    return math.hypot(max(u, 0.0), max(v, 0.0))


def _distances(a: Sequence[tuple[float, float]], b: Sequence[tuple[float, float]]) -> F64:
    pa = np.asarray(a, float).reshape(-1, 2)
    pb = np.asarray(b, float).reshape(-1, 2)
    return np.asarray(np.hypot(pa[:, None, 0] - pb[None, :, 0], pa[:, None, 1] - pb[None, :, 1]))


def precision_recall(scores: Sequence[FrameScore]) -> tuple[float, float, int, int, int]:
    """(precision, recall, true positives, false positives, misses) over frames; NaN where undefined."""
    tp = sum(s.true_positives for s in scores)
    fp = sum(len(s.false_positives) for s in scores)
    fn = sum(s.misses for s in scores)
    precision = tp / (tp + fp) if tp + fp else math.nan
    recall = tp / (tp + fn) if tp + fn else math.nan
    return precision, recall, tp, fp, fn


def evaluate_object_frames(
    folder: Path,
    layout: GridLayout | None = None,
    params: SegmentationParams | None = None,
    shape: ParticipantShape | None = PARTICIPANTS,
    match_distance_m: float = 2.0,
    match: str = "centre",
    png_dir: Path | None = None,
) -> list[FrameScore]:
    """Every frame of a KITTI object folder (velodyne/, label_2/, calib/): one grid update from the
    scan, segmentation, the participant-shape filter (None: every object) and the score; with
    `png_dir`, a picture per frame (`plot_grid`) of the scan, our objects and the labelled boxes."""
    folder = Path(folder)
    layout = layout if layout is not None else GridLayout.graded()
    scores = []
    for scan_path in sorted((folder / "velodyne").glob("*.bin")):
        frame = scan_path.stem
        calib = read_calibration(folder / "calib" / f"{frame}.txt")
        labels = read_labels(folder / "label_2" / f"{frame}.txt", calib)
        scan = read_kitti_bin(scan_path)
        grid = OccupancyGrid(layout)
        grid.update(scan)
        snapshot = grid.snapshot()
        seg = segment(snapshot, params)
        objects = [o for o in seg.objects if shape is None or shape.accepts(o)]
        score = score_frame(
            frame, labels, objects, calib, layout.half_extent_m, match_distance_m, match=match
        )
        scores.append(score)
        if png_dir is not None:
            from bywire.host.perception.grid_plot import plot_grid

            plot_grid(
                Path(png_dir) / f"kitti_object_{frame}.png",
                snapshot,
                seg,
                f"KITTI object frame {frame}, {layout.name}: {score.true_positives} of "
                f"{len(score.labels)} labelled objects found within {match_distance_m} m, "
                f"{len(score.false_positives)} false positives in view",
                scan=scan,
                labelled_boxes=[b.corners_m() for b in labels],
            )
    return scores
