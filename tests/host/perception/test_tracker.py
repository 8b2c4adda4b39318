"""The tracker of seed 000 section 5 on synthetic scenes: association, confidence, moving/static, gating,
and the filter's and the assignment's invariants as properties."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.host.perception.tracker import (
    Detection,
    Tracker,
    TrackerParams,
    assign,
    gated_costs,
    innovation_costs,
    kalman_update,
    predict,
    process_noise,
    transition,
)

DT_S = 0.1


def run(tracker: Tracker, scans: list[list[Detection]], t0_s: float = 0.0) -> list[list]:
    return [tracker.update(scan, t0_s + k * DT_S) for k, scan in enumerate(scans)]


def straight(x0: float, y0: float, vx: float, vy: float, n: int, sigma_m: float = 0.05, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT_S
    noise = rng.normal(0.0, sigma_m, (n, 2))
    return np.column_stack([x0 + vx * t, y0 + vy * t]) + noise


def nearest_track(tracks, x: float, y: float, within_m: float = 1.5):
    best = min(tracks, key=lambda t: np.hypot(t.x_m - x, t.y_m - y), default=None)
    if best is None or np.hypot(best.x_m - x, best.y_m - y) > within_m:
        return None
    return best


def test_crossing_targets_keep_their_ids():
    # Two cars on an X: they pass 0.2 s apart through the same point at 10 m/s, closer than a car's
    # length; constant velocity carries each through on its own track.
    n = 60
    a = straight(0.0, -15.0, 0.0, 10.0, n, seed=1)
    b = straight(-14.0, -14.0, 10.0, 10.0, n, seed=2)
    out = run(Tracker(), [[Detection(*a[k]), Detection(*b[k])] for k in range(n)])
    ids_a, ids_b = set(), set()
    for k, tracks in enumerate(out):
        for truth, ids in ((a[k], ids_a), (b[k], ids_b)):
            t = nearest_track(tracks, *truth)
            if t is not None:
                ids.add(t.id)
    assert len(ids_a) == 1 and len(ids_b) == 1 and ids_a != ids_b
    assert all(len(tracks) == 2 for tracks in out[2:])


def test_a_target_that_disappears_is_deleted_after_max_misses():
    p = TrackerParams(max_misses=4)
    tracker = Tracker(p)
    xy = straight(10.0, 0.0, 5.0, 0.0, 20)
    run(tracker, [[Detection(*q)] for q in xy])
    t_s = 19 * DT_S
    for miss in range(1, p.max_misses):
        t_s += DT_S
        tracker.update([], t_s)
        assert len(tracker) == 1 and tracker.all_tracks()[0].misses == miss
    tracker.update([], t_s + DT_S)
    assert len(tracker) == 0


def test_a_coasting_track_keeps_its_id_through_a_short_occlusion():
    tracker = Tracker()
    xy = straight(10.0, 0.0, 8.0, 1.0, 30)
    ids = set()
    for k in range(30):
        seen = [] if 12 <= k < 15 else [Detection(*xy[k])]
        ids |= {t.id for t in tracker.update(seen, k * DT_S) if t.misses == 0}
    assert len(ids) == 1


def test_a_false_detection_for_one_scan_is_never_published():
    tracker = Tracker()
    real = straight(5.0, 5.0, 0.0, 0.0, 12)
    clutter_at = np.array([30.0, -20.0])
    for k in range(12):
        scan = [Detection(*real[k])] + ([Detection(*clutter_at)] if k == 5 else [])
        published = tracker.update(scan, k * DT_S)
        assert nearest_track(published, *clutter_at, within_m=5.0) is None
        if k >= 1:
            assert len(published) == 1


def test_publication_waits_for_publish_hits():
    tracker = Tracker(TrackerParams(publish_hits=3, publish_confidence=3.0))
    xy = straight(5.0, 0.0, 1.0, 0.0, 4)
    counts = [len(tracks) for tracks in run(tracker, [[Detection(*q)] for q in xy])]
    assert counts == [0, 0, 1, 1]


def test_constant_velocity_converges_and_is_moving():
    v = np.array([8.0, -3.0])
    xy = straight(0.0, 10.0, *v, 50, sigma_m=0.1, seed=3)
    out = run(Tracker(), [[Detection(*q)] for q in xy])
    first = out[2][0]
    last = out[-1][0]
    assert np.hypot(last.vx_mps - v[0], last.vy_mps - v[1]) < 0.4
    assert last.moving and last.speed_mps == pytest.approx(np.hypot(*v), abs=0.4)
    # The velocity's covariance shrinks as the filter learns it, and is published with the track.
    assert np.trace(last.velocity_covariance) < 0.1 * np.trace(first.velocity_covariance)


def test_a_static_target_is_never_moving():
    xy = straight(12.0, 3.0, 0.0, 0.0, 60, sigma_m=0.15, seed=4)
    out = run(Tracker(), [[Detection(*q)] for q in xy])
    assert all(not t.moving for tracks in out for t in tracks)
    last = out[-1][0]
    v = np.array([last.vx_mps, last.vy_mps])
    # Zero velocity is well inside its own uncertainty (99.9 %).
    assert v @ np.linalg.solve(last.velocity_covariance, v) < 13.8


def test_moving_has_hysteresis():
    p = TrackerParams()
    tracker = Tracker(p)
    x, t_s, flags = 0.0, 0.0, []
    # 6 m/s, then 1.0 m/s (between the static and the moving thresholds), then standing.
    for speed, n in ((6.0, 40), (0.5 * (p.static_speed_mps + p.moving_speed_mps), 60), (0.0, 60)):
        for _ in range(n):
            x += speed * DT_S
            t_s += DT_S
            flags.extend(t.moving for t in tracker.update([Detection(x, 0.0)], t_s))
    # Published from the second scan on: flags[k] is scan k + 1.
    assert len(flags) == 159
    assert flags[38] and all(flags[39:99])
    assert not flags[-1]
    # The same middle speed from standing never turns a track moving.
    xy = straight(0.0, 0.0, 0.5 * (p.static_speed_mps + p.moving_speed_mps), 0.0, 60, sigma_m=0.0)
    assert not any(t.moving for tracks in run(Tracker(p), [[Detection(*q)] for q in xy]) for t in tracks)


def test_gating_rejects_a_far_detection():
    tracker = Tracker()
    xy = straight(10.0, 0.0, 5.0, 0.0, 10)
    run(tracker, [[Detection(*q)] for q in xy])
    (before,) = tracker.all_tracks()
    far = Detection(xy[-1, 0] + 0.5 + 10.0, 0.0)
    tracker.update([far], 10 * DT_S)
    kept = next(t for t in tracker.all_tracks() if t.id == before.id)
    assert kept.misses == 1 and kept.hits == before.hits
    assert len(tracker) == 2  # the far detection starts a track of its own


def test_assign_forbids_pairs_outside_the_gate():
    nll = np.array([[0.0, 1.0], [1.0, 0.0]])
    allowed = np.array([[False, True], [False, False]])
    rows, cols = assign(nll, allowed, miss_cost=np.array([5.0, 5.0]))
    assert list(zip(rows, cols, strict=True)) == [(0, 1)]


def test_a_new_tracker_holds_no_tracks():
    tracker = Tracker()
    assert len(tracker) == 0 and tracker.all_tracks() == []
    assert tracker.update([], 0.0) == [] and tracker.all_tracks() == []


def test_time_must_increase():
    tracker = Tracker()
    tracker.update([Detection(1.0, 1.0)], 1.0)
    with pytest.raises(ValueError, match="increase"):
        tracker.update([Detection(1.0, 1.0)], 1.0)


def test_params_refuse_an_empty_hysteresis_band():
    with pytest.raises(ValueError, match="hysteresis"):
        TrackerParams(moving_speed_mps=1.0, static_speed_mps=2.0)


def test_process_noise_is_consistent_over_split_steps():
    # The continuous model: predicting over dt1 then dt2 adds exactly the Q of dt1 + dt2, which
    # the piecewise-constant model of a varying step does not.
    q, dt1, dt2 = 3.0, 0.1, 0.25
    f2 = transition(dt2)
    two_steps = f2 @ process_noise(dt1, q) @ f2.T + process_noise(dt2, q)
    assert np.allclose(two_steps, process_noise(dt1 + dt2, q))
    assert np.all(np.linalg.eigvalsh(process_noise(dt1, q)) > 0.0)


def test_innovation_costs_match_the_gaussian_density():
    x = np.array([[1.0, 2.0, 0.0, 0.0]])
    p = np.diag([0.5, 0.2, 1.0, 1.0])[None]
    r = np.diag([0.1, 0.1])
    z = np.array([[1.3, 1.8]])
    d2, nll = innovation_costs(x, p, z, r)
    s = np.diag([0.6, 0.3])
    y = z[0] - x[0, :2]
    pdf = np.exp(-0.5 * y @ np.linalg.inv(s) @ y) / np.sqrt(np.linalg.det(2 * np.pi * s))
    assert d2[0, 0] == pytest.approx(y @ np.linalg.inv(s) @ y)
    assert nll[0, 0] == pytest.approx(-np.log(pdf))


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    n=st.integers(0, 40),
    d=st.integers(0, 40),
    spread_m=st.floats(0.5, 60.0),
    gate_d2=st.floats(0.5, 30.0),
)
def test_gated_costs_are_the_full_costs_wherever_the_gate_can_pass(
    seed: int, n: int, d: int, spread_m: float, gate_d2: float
) -> None:
    rng = np.random.default_rng(seed)
    x = rng.normal(0.0, spread_m, (n, 4))
    a = rng.normal(0.0, 1.0, (n, 4, 4))
    p = a @ np.swapaxes(a, 1, 2) + np.eye(4) * rng.uniform(0.01, 2.0, (n, 1, 1))
    z = rng.normal(0.0, spread_m, (d, 2))
    r = np.diag([0.09, 0.09])
    d2, nll = innovation_costs(x, p, z, r)
    g2, gnll = gated_costs(x, p, z, r, gate_d2)
    computed = np.isfinite(g2)
    assert np.array_equal(g2[computed], d2[computed]) and np.array_equal(gnll[computed], nll[computed])
    assert np.all(d2[~computed] > gate_d2) and np.all(np.isinf(gnll[~computed]))


costs = st.floats(-5.0, 5.0, allow_nan=False)


@st.composite
def assignment_problems(draw):
    n = draw(st.integers(0, 5))
    d = draw(st.integers(0, 5))
    nll = np.array(draw(st.lists(costs, min_size=n * d, max_size=n * d))).reshape(n, d)
    allowed = np.array(draw(st.lists(st.booleans(), min_size=n * d, max_size=n * d)), bool).reshape(n, d)
    miss = np.array(draw(st.lists(st.floats(-2.0, 6.0), min_size=n, max_size=n)))
    return nll, allowed, miss


@given(assignment_problems())
@settings(max_examples=300, deadline=None)
def test_assignment_is_one_to_one_gated_and_optimal(problem):
    nll, allowed, miss = problem
    rows, cols = assign(nll, allowed, miss)
    assert len(set(rows.tolist())) == len(rows) and len(set(cols.tolist())) == len(cols)
    assert all(allowed[r, c] for r, c in zip(rows, cols, strict=True))
    n, d = nll.shape

    def total(pairs):
        matched = {r for r, _ in pairs}
        return sum(nll[r, c] for r, c in pairs) + sum(miss[i] for i in range(n) if i not in matched)

    # Brute force over every partial one-to-one matching of allowed pairs.
    best = np.inf
    for k in range(min(n, d) + 1):
        for rs in itertools.combinations(range(n), k):
            for cs in itertools.permutations(range(d), k):
                pairs = list(zip(rs, cs, strict=True))
                if all(allowed[r, c] for r, c in pairs):
                    best = min(best, total(pairs))
    assert total(list(zip(rows, cols, strict=True))) == pytest.approx(best, abs=1e-9)


@given(
    st.lists(
        st.tuples(st.floats(0.01, 2.0), st.floats(-50.0, 50.0), st.floats(-50.0, 50.0), st.booleans()),
        min_size=1,
        max_size=60,
    ),
    st.floats(0.01, 3.0),
    st.floats(0.01, 50.0),
)
@settings(max_examples=150, deadline=None)
def test_covariance_stays_symmetric_positive_definite(steps, sigma_m, psd):
    x = np.zeros((1, 4))
    p = np.diag([sigma_m**2, sigma_m**2, 100.0, 100.0])[None]
    r = np.diag([sigma_m**2, sigma_m**2])
    for dt_s, zx, zy, observed in steps:
        x, p = predict(x, p, dt_s, psd)
        if observed:
            x, p = kalman_update(x, p, np.array([[zx, zy]]), r)
        assert np.allclose(p[0], p[0].T, rtol=0.0, atol=1e-12 * np.abs(p[0]).max())
        assert np.linalg.eigvalsh(p[0]).min() > 0.0
    assert np.isfinite(x).all()


@given(st.lists(st.lists(st.tuples(st.floats(-40, 40), st.floats(-40, 40)), max_size=6), max_size=25))
@settings(max_examples=60, deadline=None)
def test_tracks_are_unique_and_take_distinct_detections(scans):
    tracker = Tracker()
    for k, scan in enumerate(scans):
        published = tracker.update([Detection(x, y) for x, y in scan], k * DT_S)
        ids = [t.id for t in published]
        taken = [t.detection for t in published if t.detection >= 0]
        assert len(set(ids)) == len(ids)
        assert len(set(taken)) == len(taken) and all(0 <= i < len(scan) for i in taken)


def test_a_standing_car_hidden_for_two_seconds_keeps_its_track_when_told_to():
    """A car waiting at a stop line, hidden while another crosses between us: with the standing
    parameters it stays published (and keeps its id); with the defaults it is deleted after max_misses."""

    def hide(params: TrackerParams) -> tuple[list, set[int]]:
        tracker = Tracker(params)
        ids: set[int] = set()
        published = []
        for k in range(60):
            seen = [] if 20 <= k < 40 else [Detection(5.0, 2.0)]
            published = tracker.update(seen, k * DT_S)
            ids |= {t.id for t in published}
            if k == 39:
                hidden = published
        return hidden, ids

    hidden, ids = hide(TrackerParams(standing_miss_loss=0.1, standing_max_misses=30))
    assert len(hidden) == 1 and hidden[0].misses == 20 and not hidden[0].moving
    assert len(ids) == 1
    hidden, ids = hide(TrackerParams())
    assert hidden == [] and len(ids) == 2


def test_a_moving_car_does_not_coast_like_a_standing_one():
    tracker = Tracker(TrackerParams(standing_miss_loss=0.1, standing_max_misses=30, max_misses=4))
    xy = straight(10.0, 0.0, 8.0, 0.0, 30)
    run(tracker, [[Detection(*q)] for q in xy])
    for k in range(4):
        tracker.update([], (30 + k) * DT_S)
    assert len(tracker) == 0
