"""Readers of the KITTI tracking benchmark's files, and its camera frame to the tracker's plane.

The files, read in place (KITTI is CC BY-NC-SA: never copied into this repository):
- `label_02/NNNN.txt`: ground truth, one object per line, space separated,
  `frame id type truncated occluded alpha x1 y1 x2 y2 h w l x y z ry` in the rectified frame of
  camera 2 (x right, y down, z forward; x, y, z is the bottom centre of the box; ry the rotation
  about y, 0 when the box's length lies along x). DontCare regions have id -1 and no 3-D box.
- detections as AB3DMOT distributes PointRCNN's, comma separated,
  `frame,type,x1,y1,x2,y2,score,h,w,l,x,y,z,ry,alpha` with type 1 pedestrian, 2 car, 3 cyclist.
- `calib/NNNN.txt`: `P0:` .. `P3:` (3x4 projections), `R_rect`, `Tr_velo_cam`, `Tr_imu_velo`; the
  projection of camera 2, P2, maps the rectified frame into the left colour image.

A malformed line raises `KittiFormatError` naming the file and the line.

The tracker's plane (seed 000 section 5 tracks on the ground): x forward = camera z, y left =
-camera x, yaw counter-clockwise from forward, so that yaw = -ry - pi/2. The shared folder has no
ego poses (KITTI's OXTS files for these sequences are not in it), so the plane is the moving car's
camera ground plane, not a world frame: everything the ego car does shows up as the objects' motion.
Driving straight at constant speed, a parked car moves at minus the ego speed, which the
constant-velocity model follows; when the ego car turns at yaw rate w, an object at range r swings
sideways at w * r (0.3 rad/s at 20 m: 6 m/s within a second), an acceleration the model only absorbs
through a larger process noise, and "moving" means moving relative to the ego car. AB3DMOT tracks in
the same camera frame, so the comparison with it is like for like.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from bywire.host.perception.tracker import Detection

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

# The benchmark's frame rate: the scans' own time stamps are not in the shared folder.
KITTI_FRAME_S = 0.1
DETECTION_TYPES = {1: "Pedestrian", 2: "Car", 3: "Cyclist"}
LABEL_FIELDS = 17
DETECTION_FIELDS = 15


class KittiFormatError(ValueError):
    """A KITTI file that is not what its reader expects; the message starts with `file:line:`."""


@dataclass(frozen=True)
class KittiBoxes:
    """The objects of one file (or of one frame of it), column by column.

    frame, track_id (-1: none, as DontCare and detections), type (KITTI's names), truncation and
    occlusion (KITTI's levels, -1 where not given), box2d_px (N, 4) x1 y1 x2 y2, hwl_m (N, 3) height
    width length, xyz_m (N, 3) bottom centre in camera 2's rectified frame, ry_rad (N,), score (N,)
    (NaN for ground truth).
    """

    frame: IntArray
    track_id: IntArray
    type: npt.NDArray[np.str_]
    truncation: IntArray
    occlusion: IntArray
    box2d_px: FloatArray
    hwl_m: FloatArray
    xyz_m: FloatArray
    ry_rad: FloatArray
    score: FloatArray

    def __len__(self) -> int:
        return int(self.frame.size)

    def select(self, mask: npt.NDArray[np.bool_] | IntArray) -> KittiBoxes:
        """The rows a boolean mask or an index array picks."""
        return KittiBoxes(
            self.frame[mask],
            self.track_id[mask],
            self.type[mask],
            self.truncation[mask],
            self.occlusion[mask],
            self.box2d_px[mask],
            self.hwl_m[mask],
            self.xyz_m[mask],
            self.ry_rad[mask],
            self.score[mask],
        )

    def frames(self) -> dict[int, KittiBoxes]:
        """The objects frame by frame (frames without objects are absent)."""
        if len(self) == 0:
            return {}
        ordered = self.select(np.argsort(self.frame, kind="stable"))
        starts = np.flatnonzero(np.r_[True, np.diff(ordered.frame) != 0])
        ends = np.r_[starts[1:], len(ordered)]
        return {
            int(ordered.frame[a]): ordered.select(np.arange(a, b)) for a, b in zip(starts, ends, strict=True)
        }

    @property
    def last_frame(self) -> int:
        return int(self.frame.max()) if len(self) else -1


def _floats(path: Path, line_no: int, words: list[str], what: str) -> list[float]:
    try:
        values = [float(w) for w in words]
    except ValueError as e:
        raise KittiFormatError(f"{path}:{line_no}: {what}: {e}") from None
    if not all(np.isfinite(values)):
        raise KittiFormatError(f"{path}:{line_no}: {what}: a value is not finite")
    return values


def _int(path: Path, line_no: int, word: str, what: str) -> int:
    try:
        value = float(word)
    except ValueError:
        raise KittiFormatError(f"{path}:{line_no}: {what} {word!r} is not a number") from None
    if value != int(value):
        raise KittiFormatError(f"{path}:{line_no}: {what} {word!r} is not an integer")
    return int(value)


def _lines(path: Path) -> list[tuple[int, str]]:
    try:
        text = Path(path).read_text()
    except OSError as e:
        raise KittiFormatError(f"{path}: cannot read: {e.strerror or e}") from e
    return [(i, line) for i, line in enumerate(text.splitlines(), 1) if line.strip()]


def _boxes(rows: list[tuple[int, int, str, int, int, list[float], float]]) -> KittiBoxes:
    # (frame, track_id, type, truncation, occlusion, [x1 y1 x2 y2 h w l x y z ry], score)
    n = len(rows)
    nums = np.array([r[5] for r in rows], float).reshape(n, 11)
    return KittiBoxes(
        frame=np.array([r[0] for r in rows], np.int64),
        track_id=np.array([r[1] for r in rows], np.int64),
        type=np.array([r[2] for r in rows], dtype=np.str_).reshape(n),
        truncation=np.array([r[3] for r in rows], np.int64),
        occlusion=np.array([r[4] for r in rows], np.int64),
        box2d_px=nums[:, 0:4],
        hwl_m=nums[:, 4:7],
        xyz_m=nums[:, 7:10],
        ry_rad=nums[:, 10],
        score=np.array([r[6] for r in rows], float),
    )


def read_labels(path: Path) -> KittiBoxes:
    """A `label_02` ground-truth file."""
    path = Path(path)
    rows = []
    for line_no, line in _lines(path):
        w = line.split()
        if len(w) != LABEL_FIELDS:
            raise KittiFormatError(
                f"{path}:{line_no}: {len(w)} fields, a label has {LABEL_FIELDS} "
                "(frame id type truncated occluded alpha x1 y1 x2 y2 h w l x y z ry)"
            )
        frame = _int(path, line_no, w[0], "frame")
        if frame < 0:
            raise KittiFormatError(f"{path}:{line_no}: frame {frame} is negative")
        track_id = _int(path, line_no, w[1], "track id")
        truncation = _int(path, line_no, w[3], "truncated")
        occlusion = _int(path, line_no, w[4], "occluded")
        nums = _floats(path, line_no, w[6:17], "box")
        rows.append((frame, track_id, w[2], truncation, occlusion, nums, float("nan")))
    return _boxes(rows)


def read_detections(path: Path) -> KittiBoxes:
    """A detection file in AB3DMOT's comma-separated format."""
    path = Path(path)
    rows = []
    for line_no, line in _lines(path):
        w = [s.strip() for s in line.split(",")]
        if len(w) != DETECTION_FIELDS:
            raise KittiFormatError(
                f"{path}:{line_no}: {len(w)} fields, a detection has {DETECTION_FIELDS} "
                "(frame,type,x1,y1,x2,y2,score,h,w,l,x,y,z,ry,alpha)"
            )
        frame = _int(path, line_no, w[0], "frame")
        if frame < 0:
            raise KittiFormatError(f"{path}:{line_no}: frame {frame} is negative")
        code = _int(path, line_no, w[1], "type")
        if code not in DETECTION_TYPES:
            raise KittiFormatError(f"{path}:{line_no}: type {code} is none of {sorted(DETECTION_TYPES)}")
        v = _floats(path, line_no, w[2:14], "box")
        if min(v[5:8]) <= 0.0:
            raise KittiFormatError(f"{path}:{line_no}: box dimensions h w l {v[5:8]} must be positive")
        rows.append((frame, -1, DETECTION_TYPES[code], -1, -1, v[0:4] + v[5:12], v[4]))
    return _boxes(rows)


def read_calib(path: Path) -> dict[str, FloatArray]:
    """A tracking calibration file: each key (`P2`, `R_rect`, ...) with its numbers, the projections
    as 3x4 matrices."""
    path = Path(path)
    out: dict[str, FloatArray] = {}
    for line_no, line in _lines(path):
        # `P2: 7.2e+02 ...`; some copies write `R_rect 9.9e-01 ...` without the colon.
        first, *words = line.replace(":", " ", 1).split() if ":" in line.split()[0] else line.split()
        key = first
        values = np.array(_floats(path, line_no, words, key), float)
        if key.startswith("P") and key[1:].isdigit():
            if values.size != 12:
                raise KittiFormatError(f"{path}:{line_no}: {key} has {values.size} numbers, a projection 12")
            values = values.reshape(3, 4)
        out[key] = values
    if "P2" not in out:
        raise KittiFormatError(f"{path}: no P2 (the projection of camera 2, the labels' camera)")
    return out


def to_plane(boxes: KittiBoxes) -> list[Detection]:
    """Camera-frame boxes as the tracker's detections on the ground plane (x forward, y left)."""
    yaw = _wrap(-boxes.ry_rad - np.pi / 2)
    score = np.where(np.isnan(boxes.score), 1.0, boxes.score)
    return [
        Detection(
            x_m=float(boxes.xyz_m[i, 2]),
            y_m=float(-boxes.xyz_m[i, 0]),
            length_m=float(boxes.hwl_m[i, 2]),
            width_m=float(boxes.hwl_m[i, 1]),
            yaw_rad=float(yaw[i]),
            score=float(score[i]),
        )
        for i in range(len(boxes))
    ]


def plane_to_camera(
    x_m: FloatArray, y_m: FloatArray, yaw_rad: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The inverse of `to_plane`'s mapping: camera x, camera z and ry."""
    return -y_m, x_m, _wrap(-yaw_rad - np.pi / 2)


def _wrap(a: FloatArray) -> FloatArray:
    return np.asarray((a + np.pi) % (2 * np.pi) - np.pi, float)


def box_corners(hwl_m: FloatArray, xyz_m: FloatArray, ry_rad: FloatArray) -> FloatArray:
    """The 8 corners (N, 8, 3) of camera-frame boxes (bottom face first)."""
    h, w, length = hwl_m[:, 0:1], hwl_m[:, 1:2], hwl_m[:, 2:3]
    sx = np.array([1, 1, -1, -1, 1, 1, -1, -1]) / 2.0
    sz = np.array([1, -1, -1, 1, 1, -1, -1, 1]) / 2.0
    sy = np.array([0, 0, 0, 0, -1, -1, -1, -1], float)
    local_x, local_y, local_z = length * sx, h * sy, w * sz
    c, s = np.cos(ry_rad)[:, None], np.sin(ry_rad)[:, None]
    # Rotation about camera y by ry: x' = c x + s z, z' = -s x + c z.
    cam_x = c * local_x + s * local_z + xyz_m[:, 0:1]
    cam_z = -s * local_x + c * local_z + xyz_m[:, 2:3]
    cam_y = local_y + xyz_m[:, 1:2]
    return np.stack([cam_x, cam_y, cam_z], axis=-1)


# KITTI's colour images are 1224-1242 x 370-376 px: boxes are clipped to the largest (pixel 1241, 374).
IMAGE_SIZE_PX = (1241.0, 374.0)
# Corners closer than this in front of the camera are pushed out to it before projecting.
MIN_DEPTH_M = 0.1


def project_boxes(p2: FloatArray, hwl_m: FloatArray, xyz_m: FloatArray, ry_rad: FloatArray) -> FloatArray:
    """The image boxes (N, 4: x1 y1 x2 y2, px) of camera-frame 3-D boxes under P2, clipped to the image."""
    corners = box_corners(hwl_m, xyz_m, ry_rad)
    corners[..., 2] = np.maximum(corners[..., 2], MIN_DEPTH_M)
    homo = np.concatenate([corners, np.ones((*corners.shape[:-1], 1))], axis=-1)
    uvw = homo @ p2.T
    uv = uvw[..., :2] / uvw[..., 2:3]
    lo = np.clip(uv.min(axis=1), 0.0, IMAGE_SIZE_PX)
    hi = np.clip(uv.max(axis=1), 0.0, IMAGE_SIZE_PX)
    return np.concatenate([lo, hi], axis=1)
