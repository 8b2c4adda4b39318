"""Multi-object tracking of dynamic obstacles (seed 000 section 5, eq. 7) on plain 2-D detections.

Model (section 5): one linear Kalman filter per object on the state [x, y, vx, vy] (metres, m/s) under
constant velocity, observing the position [x, y] with independent Gaussian noise R = diag(sigma_x^2,
sigma_y^2). The detections arrive in one plane frame (on the car: the world frame the host localises in;
on KITTI: the camera's ground plane, see `kitti_tracking`), each with a box (length, width, yaw) and a
score, and a time stamp per update.

Eq. 7 as printed is garbled. It shows "Q" as a 3x4 matrix of ones on the diagonal, which is neither
square nor a covariance, and the observation matrix O announced in the sentence before it is missing.
The printed matrix is best read as a corrupted O: with the measurement [x, y], O = [[1, 0, 0, 0],
[0, 1, 0, 0]] (2x4), and R is as printed. For Q we take the standard constant-velocity model:
white-noise acceleration of power spectral density q (m^2/s^3) per axis, integrated exactly over the
step dt (the continuous white-noise acceleration model, Bar-Shalom et al. 2001, section 6.2.2):

    Q_axis(dt) = q * [[dt^3/3, dt^2/2],
                      [dt^2/2, dt    ]]   (rows/columns: position, velocity of that axis).

The discrete ("piecewise constant") alternative, sigma_a^2 * [[dt^4/4, dt^3/2], [dt^3/2, dt^2]], has
rank 1 and is not consistent over a varying step (two steps of dt/2 do not give the Q of one step of
dt); the continuous model is, which matters here because a missed scan or a late one makes dt vary.
The two agree in the velocity variance when q = sigma_a^2 * dt.

Association (section 5: "a maximum-likelihood matching ... one-to-one function from filters to
observations"): the cost of track i taking detection j is the negative log-likelihood of the
innovation, 0.5 * (d2_ij + ln det(2 pi S_i)) with d2 the squared Mahalanobis distance; pairs with d2
over the chi-square gate (2 degrees of freedom) are forbidden. The one-to-one assignment is solved by
`scipy.optimize.linear_sum_assignment` on the matrix augmented with a "missed" column per track (cost:
the NLL at the gate) and a "new object" row per detection, so that leaving a track unmatched is a
priced hypothesis, not an artefact of a rectangular problem. Only the pairs the gate can pass are
costed (`gated_costs`), and a track and a detection that have only each other in the gate are decided
without the solver (`assign`): the same optimum, for the hundreds of tracks of a street.

Confidence (section 5): a track's confidence rises by `hit_gain` when it is observed and falls by
`miss_loss` when it is not, capped at `confidence_max`. A track is published while it has at least
`publish_hits` hits and a confidence of at least `publish_confidence`; it is deleted when the
confidence falls below `delete_confidence` or after `max_misses` consecutive misses. Tracks between
the thresholds are kept but not published, so a false detection seen for one scan is never published.
A standing track that has been seen `standing_hits` times loses `standing_miss_loss` per miss and may
miss `standing_max_misses` scans (both default to the moving ones'): a car waiting at a stop line that
another car hides for a second or two is hidden, not gone (section 9.3's queue depends on it).
Only detections scoring at least `birth_min_score` start a track ("only 'good' candidates are
augmented in the following tracking step"); any detection may continue one.

Moving vs static (section 8 gives vehicles on lanes to the behaviour and treats obstacles off them as
static; section 3: "traffic participants that are able to move but have zero velocity at the moment"):
a track turns moving when its speed exceeds `moving_speed_mps` and its velocity is nonzero with
chi-square confidence `moving_confidence` (Mahalanobis test of v against 0 under the velocity block of
P), after at least `moving_min_hits` hits; it turns static again when the speed falls below
`static_speed_mps` (hysteresis). The velocity covariance is published with every track; the lane
association is the behaviour's.

Deviations: one model (no multi-hypothesis tracking, which section 3 mentions); the box (length,
width, yaw) is smoothed outside the filter, and its yaw is an orientation modulo pi (the direction of
travel is the velocity's). `Track.detection` gives the index of the detection a track took in this
update, so the caller can carry attributes the filter does not model (a box's height, say).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment
from scipy.stats import chi2

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

# O of eq. 7: the filter observes the position of the state [x, y, vx, vy].
OBSERVATION = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])


@dataclass(frozen=True)
class Detection:
    """One detected object in the tracking plane: centre (m), box length along yaw and width (m),
    yaw (rad, counter-clockwise from the plane's x axis) and the detector's score (higher: surer).
    The box defaults to a passenger car's."""

    x_m: float
    y_m: float
    length_m: float = 4.0
    width_m: float = 1.8
    yaw_rad: float = 0.0
    score: float = 1.0


@dataclass(frozen=True)
class TrackerParams:
    """The tracker's parameters, for detections in a world frame at 10 Hz. KITTI's camera frame
    takes `track_eval.KITTI_TRACKER` (docs/perception.md "Tracking")."""

    # R of eq. 7: the detector's centre error, 1 sigma per axis.
    position_sigma_m: float = 0.3
    # Q: white-noise acceleration PSD in a world frame: the velocity's random walk grows by
    # sqrt(q * t), 1 m/s over a second, an urban car's unmodelled braking and turning. Camera-frame
    # tracking (KITTI) sees the ego car's turns as everything's acceleration and needs more.
    accel_psd_m2_s3: float = 1.0
    # Velocity of a newborn track is unknown: zero mean, this sigma (a car at urban speed).
    initial_speed_sigma_mps: float = 10.0
    # chi-square gate probability, 2 degrees of freedom (0.999: d2 <= 13.8).
    gate_probability: float = 0.999
    # Only detections this sure start a track ("only 'good' candidates", section 5); any detection
    # can update one.
    birth_min_score: float = -np.inf
    hit_gain: float = 1.0
    miss_loss: float = 1.0
    confidence_max: float = 5.0
    initial_confidence: float = 1.0
    publish_confidence: float = 2.0
    publish_hits: int = 2
    delete_confidence: float = 0.0
    # 0.5 s at 10 Hz: a car hidden behind another for a few scans keeps its id.
    max_misses: int = 5
    # A standing track seen this often coasts longer through misses (see the module docstring); None:
    # as a moving one.
    standing_hits: int = 10
    standing_miss_loss: float | None = None
    standing_max_misses: int | None = None
    # Box smoothing: weight of a new detection's length, width and yaw.
    box_gain: float = 0.5
    # 1.5 m/s (5.4 km/h): slower, a car is creeping or standing. A static track's velocity noise
    # (about 0.6 m/s, 1 sigma, at the default q and R) rarely passes it, and never together with the
    # chi-square test below.
    moving_speed_mps: float = 1.5
    # Half of it: a car braking to a stop stays moving until it nearly stands.
    static_speed_mps: float = 0.75
    moving_confidence: float = 0.99
    # Two scans give a velocity from one difference of two noisy positions; three from a fit.
    moving_min_hits: int = 3

    def __post_init__(self) -> None:
        if not 0.0 < self.gate_probability < 1.0:
            raise ValueError(f"gate_probability {self.gate_probability} must be in (0, 1)")
        if not 0.0 < self.moving_confidence < 1.0:
            raise ValueError(f"moving_confidence {self.moving_confidence} must be in (0, 1)")
        if self.static_speed_mps > self.moving_speed_mps:
            raise ValueError("static_speed_mps above moving_speed_mps leaves no hysteresis band")
        if self.delete_confidence >= self.publish_confidence:
            raise ValueError("delete_confidence must be below publish_confidence")
        if min(self.position_sigma_m, self.accel_psd_m2_s3, self.initial_speed_sigma_mps) <= 0.0:
            raise ValueError("sigmas and the acceleration PSD must be positive")
        if self.max_misses < 1 or self.publish_hits < 1:
            raise ValueError("max_misses and publish_hits count scans: at least 1")

    @property
    def gate_d2(self) -> float:
        return float(chi2.ppf(self.gate_probability, 2))

    @property
    def moving_d2(self) -> float:
        return float(chi2.ppf(self.moving_confidence, 2))


@dataclass(frozen=True)
class Track:
    """A published track. covariance: 4x4 over [x, y, vx, vy] (m, m/s); age_s since birth; hits:
    scans observed; misses: consecutive scans not observed (0: observed in this update); detection:
    index of the detection taken in this update, -1 if none."""

    id: int
    x_m: float
    y_m: float
    vx_mps: float
    vy_mps: float
    covariance: FloatArray = field(repr=False)
    length_m: float
    width_m: float
    yaw_rad: float
    moving: bool
    age_s: float
    hits: int
    misses: int
    confidence: float
    detection: int

    @property
    def speed_mps(self) -> float:
        return float(np.hypot(self.vx_mps, self.vy_mps))

    @property
    def velocity_covariance(self) -> FloatArray:
        return self.covariance[2:, 2:]


def transition(dt_s: float) -> FloatArray:
    """F of the constant-velocity model over dt_s."""
    f = np.eye(4)
    f[0, 2] = f[1, 3] = dt_s
    return f


def process_noise(dt_s: float, accel_psd_m2_s3: float) -> FloatArray:
    """Q over dt_s of continuous white-noise acceleration with PSD q per axis (the eq. 7 fix)."""
    q = accel_psd_m2_s3
    a, b, c = q * dt_s**3 / 3.0, q * dt_s**2 / 2.0, q * dt_s
    return np.array([[a, 0.0, b, 0.0], [0.0, a, 0.0, b], [b, 0.0, c, 0.0], [0.0, b, 0.0, c]])


def predict(
    x: FloatArray, p: FloatArray, dt_s: float, accel_psd_m2_s3: float
) -> tuple[FloatArray, FloatArray]:
    """All tracks' states (N, 4) and covariances (N, 4, 4) predicted dt_s ahead."""
    f = transition(dt_s)
    return x @ f.T, f @ p @ f.T + process_noise(dt_s, accel_psd_m2_s3)


def innovation_costs(
    x: FloatArray, p: FloatArray, z: FloatArray, r: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Squared Mahalanobis distances d2 (N, D) and negative log-likelihoods (N, D) of every track's
    predicted position against every detection z (D, 2), under S_i = O P_i O^T + R."""
    s = p[:, :2, :2] + r
    y = z[None, :, :] - x[:, None, :2]
    d2 = _mahalanobis2(y, np.linalg.inv(s)[:, None])
    log_det = np.log(np.linalg.det(2.0 * np.pi * s))
    return d2, 0.5 * (d2 + log_det[:, None])


def gated_costs(
    x: FloatArray, p: FloatArray, z: FloatArray, r: FloatArray, gate_d2: float
) -> tuple[FloatArray, FloatArray]:
    """`innovation_costs` where a pair can pass the gate d2 <= gate_d2, inf elsewhere: the same numbers
    on those pairs, computed only for them. d2 >= |y|^2 / lambda_max(S) >= |y|^2 / trace(S), so a pair
    with |y|^2 > gate_d2 trace(S) cannot pass (a track meets a handful of the detections around it)."""
    n, d = x.shape[0], z.shape[0]
    d2 = np.full((n, d), np.inf)
    nll = np.full((n, d), np.inf)
    if n == 0 or d == 0:
        return d2, nll
    s = p[:, :2, :2] + r
    reach2 = gate_d2 * (s[:, 0, 0] + s[:, 1, 1]) * (1.0 + 1e-9)  # the margin: rounding of |y|^2
    ex = z[None, :, 0] - x[:, None, 0]
    ey = z[None, :, 1] - x[:, None, 1]
    ti, dj = np.nonzero(ex * ex + ey * ey <= reach2[:, None])
    y = np.stack((ex[ti, dj], ey[ti, dj]), axis=-1)
    pair_d2 = _mahalanobis2(y, np.linalg.inv(s)[ti])
    log_det = np.log(np.linalg.det(2.0 * np.pi * s))
    d2[ti, dj] = pair_d2
    nll[ti, dj] = 0.5 * (pair_d2 + log_det[ti])
    return d2, nll


def _mahalanobis2(y: FloatArray, s_inv: npt.NDArray[np.floating[Any]]) -> FloatArray:
    """y^T S^-1 y over the last axis of y (..., 2), S^-1 (..., 2, 2) broadcast against it: the terms in
    one fixed order, so that a pair's value does not depend on which other pairs are computed with it."""
    y0, y1 = y[..., 0], y[..., 1]
    return (
        y0 * s_inv[..., 0, 0] * y0
        + y0 * s_inv[..., 0, 1] * y1
        + y1 * s_inv[..., 1, 0] * y0
        + y1 * s_inv[..., 1, 1] * y1
    )


def assign(
    nll: FloatArray, allowed: npt.NDArray[np.bool_], miss_cost: FloatArray
) -> tuple[IntArray, IntArray]:
    """The one-to-one assignment of minimal total cost: rows (tracks, ascending) and columns
    (detections) of the matched pairs. nll (N, D): the cost of each pair; allowed: the pairs inside the
    gate; miss_cost (N,): the price of leaving a track unmatched (a new object costs nothing: its price
    is folded into the miss cost).

    The total is a sum over the connected components of the allowed pairs' graph, whose optimum is
    each component's: a lone pair (a track and a detection that have only each other in the gate) is
    matched when it costs less than the miss, without a solver; `linear_sum_assignment` takes the
    tracks and detections of the other components. Most components of a scene are a car and its
    detection, and the solver's cost grows with the cube of what it is given."""
    n, d = nll.shape
    ti, dj = np.nonzero(allowed)
    if ti.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    track_pairs = np.bincount(ti, minlength=n)
    det_pairs = np.bincount(dj, minlength=d)
    lone = (track_pairs[ti] == 1) & (det_pairs[dj] == 1)
    take = lone & (nll[ti, dj] < miss_cost[ti])
    rows, cols = [ti[take]], [dj[take]]
    if not lone.all():
        tracks, dets = np.unique(ti[~lone]), np.unique(dj[~lone])
        r, k = _assign_dense(nll[np.ix_(tracks, dets)], allowed[np.ix_(tracks, dets)], miss_cost[tracks])
        rows.append(tracks[r])
        cols.append(dets[k])
    row, col = np.concatenate(rows).astype(np.int64), np.concatenate(cols).astype(np.int64)
    order = np.argsort(row)
    return row[order], col[order]


def _assign_dense(
    nll: FloatArray, allowed: npt.NDArray[np.bool_], miss_cost: FloatArray
) -> tuple[IntArray, IntArray]:
    """`assign` by one `linear_sum_assignment` on the matrix augmented with a "missed" column per track
    and a "new object" row per detection."""
    n, d = nll.shape
    big = np.full((n + d, d + n), np.inf)
    big[:n, :d] = np.where(allowed, nll, np.inf)
    big[np.arange(n), d + np.arange(n)] = miss_cost
    big[n + np.arange(d), np.arange(d)] = 0.0
    big[n:, d:] = 0.0
    # Forbidden pairs are inf; the augmented matrix always has a finite assignment (everyone unmatched).
    rows, cols = linear_sum_assignment(big)
    keep = (rows < n) & (cols < d)
    return rows[keep].astype(np.int64), cols[keep].astype(np.int64)


def kalman_update(
    x: FloatArray, p: FloatArray, z: FloatArray, r: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Posterior states (M, 4) and covariances (M, 4, 4) of M tracks each observing its z (M, 2).
    Joseph form, symmetrised, so that P stays symmetric positive definite in floating point."""
    s = p[:, :2, :2] + r
    k = p[:, :, :2] @ np.linalg.inv(s)
    y = z - x[:, :2]
    x_new = x + np.einsum("mij,mj->mi", k, y)
    i_kh = np.eye(4) - k @ OBSERVATION
    p_new = i_kh @ p @ np.swapaxes(i_kh, 1, 2) + k @ r @ np.swapaxes(k, 1, 2)
    return x_new, 0.5 * (p_new + np.swapaxes(p_new, 1, 2))


def classify_moving(
    v: FloatArray, p_vv: FloatArray, was_moving: npt.NDArray[np.bool_], hits: IntArray, params: TrackerParams
) -> npt.NDArray[np.bool_]:
    """Moving flags (N,) with hysteresis from velocities v (N, 2) and their covariances (N, 2, 2)."""
    speed = np.hypot(v[:, 0], v[:, 1])
    d2 = np.einsum("nk,nkl,nl->n", v, np.linalg.inv(p_vv), v)
    turn_on = (speed > params.moving_speed_mps) & (d2 > params.moving_d2) & (hits >= params.moving_min_hits)
    stay_on = was_moving & (speed >= params.static_speed_mps)
    return turn_on | stay_on


def _wrap_half_turn(a: FloatArray) -> FloatArray:
    """An orientation difference (rad) into [-pi/2, pi/2): a box turned by pi is the same box."""
    return (a + np.pi / 2) % np.pi - np.pi / 2


class Tracker:
    """The tracks of one sensor stream. Feed `update` the detections of each scan in time order."""

    def __init__(self, params: TrackerParams | None = None) -> None:
        self.params = params or TrackerParams()
        p = self.params
        self._r = np.diag([p.position_sigma_m**2, p.position_sigma_m**2])
        self._gate_d2 = p.gate_d2
        self._t_s: float | None = None
        self._next_id = 1
        self._x = np.zeros((0, 4))
        self._p = np.zeros((0, 4, 4))
        self._box = np.zeros((0, 3))  # length_m, width_m, yaw_rad
        self._ids = np.zeros(0, np.int64)
        self._hits = np.zeros(0, np.int64)
        self._misses = np.zeros(0, np.int64)
        self._confidence = np.zeros(0)
        self._born_s = np.zeros(0)
        self._moving = np.zeros(0, bool)

    def __len__(self) -> int:
        """Tracks held, published or not."""
        return int(self._ids.size)

    def update(self, detections: Sequence[Detection], t_s: float) -> list[Track]:
        """Predict to t_s, associate, update, count, classify; the published tracks after this scan."""
        p = self.params
        if self._t_s is not None:
            dt_s = t_s - self._t_s
            if not dt_s > 0.0:
                raise ValueError(f"time stamps must increase: {t_s} s after {self._t_s} s")
            self._x, self._p = predict(self._x, self._p, dt_s, p.accel_psd_m2_s3)
        self._t_s = t_s
        z = np.array([[d.x_m, d.y_m] for d in detections], float).reshape(-1, 2)
        boxes = np.array([[d.length_m, d.width_m, d.yaw_rad] for d in detections], float).reshape(-1, 3)
        if not np.isfinite(z).all() or not np.isfinite(boxes).all():
            raise ValueError("detections must be finite")

        gate = self._gate_d2
        d2, nll = gated_costs(self._x, self._p, z, self._r, gate)
        miss_cost = 0.5 * (gate + np.log(np.linalg.det(2.0 * np.pi * (self._p[:, :2, :2] + self._r))))
        rows, cols = assign(nll, d2 <= gate, miss_cost)

        taken = np.full(len(self), -1, np.int64)
        taken[rows] = cols
        if rows.size:
            self._x[rows], self._p[rows] = kalman_update(self._x[rows], self._p[rows], z[cols], self._r)
            old = self._box[rows]
            new = boxes[cols]
            size = old[:, :2] + p.box_gain * (new[:, :2] - old[:, :2])
            yaw = old[:, 2] + p.box_gain * _wrap_half_turn(new[:, 2] - old[:, 2])
            self._box[rows] = np.column_stack([size, np.arctan2(np.sin(yaw), np.cos(yaw))])
        hit = taken >= 0
        self._hits[hit] += 1
        self._misses[hit] = 0
        self._misses[~hit] += 1
        standing = ~self._moving & (self._hits >= p.standing_hits)
        loss = np.where(
            standing, p.miss_loss if p.standing_miss_loss is None else p.standing_miss_loss, p.miss_loss
        )
        self._confidence = np.where(
            hit, np.minimum(self._confidence + p.hit_gain, p.confidence_max), self._confidence - loss
        )
        max_misses = np.where(
            standing, p.max_misses if p.standing_max_misses is None else p.standing_max_misses, p.max_misses
        )
        keep = (self._confidence >= p.delete_confidence) & (self._misses < max_misses)
        self._select(keep)
        taken = taken[keep]

        unused = np.setdiff1d(np.arange(len(detections)), cols)
        scores = np.array([d.score for d in detections], float)
        unused = unused[scores[unused] >= p.birth_min_score]
        self._birth(z[unused], boxes[unused], t_s)
        taken = np.concatenate([taken, unused.astype(np.int64)])

        self._moving = classify_moving(self._x[:, 2:], self._p[:, 2:, 2:], self._moving, self._hits, p)
        published = (self._hits >= p.publish_hits) & (self._confidence >= p.publish_confidence)
        which = np.flatnonzero(published)
        return self._tracks(which, taken[which])

    def all_tracks(self) -> list[Track]:
        """Every track held, published or not (for inspection and tests)."""
        return self._tracks(np.arange(len(self)), np.full(len(self), -1, np.int64))

    def _select(self, keep: npt.NDArray[np.bool_]) -> None:
        for name in ("_x", "_p", "_box", "_ids", "_hits", "_misses", "_confidence", "_born_s", "_moving"):
            setattr(self, name, getattr(self, name)[keep])

    def _birth(self, z: FloatArray, boxes: FloatArray, t_s: float) -> None:
        n = len(z)
        if n == 0:
            return
        p = self.params
        p0 = np.diag([p.position_sigma_m**2] * 2 + [p.initial_speed_sigma_mps**2] * 2)
        self._x = np.concatenate([self._x, np.column_stack([z, np.zeros((n, 2))])])
        self._p = np.concatenate([self._p, np.broadcast_to(p0, (n, 4, 4)).copy()])
        self._box = np.concatenate([self._box, boxes])
        self._ids = np.concatenate([self._ids, np.arange(self._next_id, self._next_id + n)])
        self._next_id += n
        self._hits = np.concatenate([self._hits, np.ones(n, np.int64)])
        self._misses = np.concatenate([self._misses, np.zeros(n, np.int64)])
        self._confidence = np.concatenate([self._confidence, np.full(n, p.initial_confidence)])
        self._born_s = np.concatenate([self._born_s, np.full(n, t_s)])
        self._moving = np.concatenate([self._moving, np.zeros(n, bool)])

    def _tracks(self, which: IntArray, detection: IntArray) -> list[Track]:
        if which.size == 0:  # also before the first update, which has no time yet
            return []
        assert self._t_s is not None
        x, box = self._x[which], self._box[which]
        covariance = self._p[which]  # a copy: the tracks do not share the filter's state
        columns = zip(
            self._ids[which].tolist(),
            x[:, 0].tolist(),
            x[:, 1].tolist(),
            x[:, 2].tolist(),
            x[:, 3].tolist(),
            box[:, 0].tolist(),
            box[:, 1].tolist(),
            box[:, 2].tolist(),
            self._moving[which].tolist(),
            (self._t_s - self._born_s[which]).tolist(),
            self._hits[which].tolist(),
            self._misses[which].tolist(),
            self._confidence[which].tolist(),
            detection.tolist(),
            strict=True,
        )
        return [
            Track(
                id=c[0],
                x_m=c[1],
                y_m=c[2],
                vx_mps=c[3],
                vy_mps=c[4],
                covariance=covariance[k],
                length_m=c[5],
                width_m=c[6],
                yaw_rad=c[7],
                moving=c[8],
                age_s=c[9],
                hits=c[10],
                misses=c[11],
                confidence=c[12],
                detection=c[13],
            )
            for k, c in enumerate(columns)
        ]
