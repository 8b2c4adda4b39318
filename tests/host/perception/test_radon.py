"""The Radon transform by the central slice theorem (seed 000 Sec. 6): against a direct summation and
scikit-image where it is installed, exact on synthetic lines, and rotating with its image."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.host.perception.radon import (
    RadonSpectrum,
    dominant_normal,
    find_lines,
    profile_peaks,
    radon,
    radon_direct,
)

CELL_M = 0.15625


def blobs(n: int, spec: list[tuple[float, float, float, float]]) -> np.ndarray:
    """Gaussian blobs (dx, dy, sigma, amplitude) in pixels around the centre pixel (n // 2, n // 2)."""
    yy, xx = np.mgrid[0:n, 0:n]
    c = n // 2
    img = np.zeros((n, n))
    for dx, dy, sigma, amp in spec:
        img += amp * np.exp(-((xx - c - dx) ** 2 + (yy - c - dy) ** 2) / (2.0 * sigma * sigma))
    return img


def line_image(n: int, lines: list[tuple[float, float, float]], cell_m: float = CELL_M) -> np.ndarray:
    """Lines (normal rad, offset m, amplitude), one cell wide with linear edges, on an n x n grid."""
    yy, xx = np.mgrid[0:n, 0:n]
    x, y = (xx - n // 2) * cell_m, (yy - n // 2) * cell_m
    img = np.zeros((n, n))
    for normal, offset, amp in lines:
        d = x * math.cos(normal) + y * math.sin(normal) - offset
        img += amp * np.clip(1.0 - np.abs(d) / cell_m, 0.0, None)
    return img


def canonical(normal: float, offset: float) -> tuple[float, float]:
    """The same line with its normal in [-pi/2, pi/2)."""
    a = math.remainder(normal, 2.0 * math.pi)
    if a >= math.pi / 2.0:
        return a - math.pi, -offset
    if a < -math.pi / 2.0:
        return a + math.pi, -offset
    return a, offset


@pytest.mark.parametrize(
    ("where", "spec", "n"),
    [
        ("near", [(3, -4, 4.0, 1.0), (-5, 2, 3.5, 0.6), (4, 6, 4.0, 0.8)], 64),
        ("edge", [(20, -12, 4.0, 1.0), (-24, 6, 3.5, 0.6)], 64),  # out to the inscribed circle's edge
        ("edge", [(80, -48, 4.0, 1.0), (-96, 24, 3.5, 0.6)], 256),
    ],
)
def test_matches_a_direct_summation(
    where: str, spec: list[tuple[float, float, float, float]], n: int
) -> None:
    # Wide blobs: the reference blurs by a fraction of a pixel (square pixels, offset bins: 0.25 px^2),
    # 3 % of the peak of a 2 px blob and under 1 % of a 4 px one.
    img = blobs(n, spec)
    angles = np.radians(np.arange(-90.0, 270.0, 7.0))  # both halves: the folded angles too
    fast, off_fast = radon(img, angles)
    ref, off_ref = radon_direct(img, angles)
    np.testing.assert_array_equal(off_fast, off_ref)
    # Measured 0.6-1.2 % of the peak, near the centre and at the edge alike (Lanczos-3 slices of the
    # 2x padded spectrum; bilinear ones were 1.5 % near the centre and 10-13 % at the edge).
    assert np.abs(fast - ref).max() <= 0.02 * ref.max(), where
    # each projection holds the image's mass (the slice's rho = 0 sample is the spectrum's own)
    np.testing.assert_allclose(fast.sum(axis=1), img.sum(), rtol=1e-5)


def test_a_single_pixel_projects_to_its_offset() -> None:
    img = np.zeros((33, 33))
    img[16 + 5, 16 + 3] = 1.0  # x = 3, y = 5 pixels from the centre
    angles = np.radians([0.0, 30.0, 90.0, 135.0, 180.0, -60.0])
    proj, off = radon(img, angles)
    for theta, row in zip(angles, proj, strict=True):
        assert off[int(np.argmax(row))] == round(3.0 * math.cos(theta) + 5.0 * math.sin(theta))


def test_offsets_scale_with_the_cell() -> None:
    img = blobs(32, [(4, 0, 1.5, 1.0)])
    unit, off1 = radon(img, [0.0])
    scaled, off2 = radon(img, [0.0], cell_m=0.2)
    np.testing.assert_allclose(off2, 0.2 * off1)
    np.testing.assert_allclose(scaled, 0.2 * unit, atol=1e-9)  # a line integral in metres


def test_matches_scikit_image() -> None:
    skimage_transform = pytest.importorskip("skimage.transform")
    n = 65
    img = blobs(n, [(5, -7, 2.5, 1.0), (-10, 4, 3.0, 0.6), (8, 12, 2.0, 0.8)])
    yy, xx = np.mgrid[0:n, 0:n]
    img[(xx - n // 2) ** 2 + (yy - n // 2) ** 2 > (n // 2) ** 2] = 0.0  # what circle=True asks
    theta_deg = np.arange(0.0, 180.0, 5.0)
    sk = skimage_transform.radon(img, theta=theta_deg, circle=True)  # (offset, angle)
    # skimage sums along image rows after rotating: its p is x cos t - row sin t with rows downwards
    # from our point of view, i.e. our normal -t; its offset 0 is at index n // 2, as ours.
    ours, _ = radon(img, np.radians(-theta_deg))
    p = ours.shape[1]
    ours = ours[:, p // 2 - n // 2 : p // 2 - n // 2 + n].T
    # skimage rotates with bilinear interpolation and sums; measured 1.0 % of the peak (0.26.0).
    assert np.abs(sk - ours).max() <= 0.03 * sk.max()


@pytest.mark.parametrize(
    ("normal_deg", "offset_m"),
    [(90.0, 1.75), (4.26, 7.2), (-49.95, -6.84), (135.0, 2.5), (-115.3, 3.45), (0.0, -5.0)],
)
def test_finds_a_lines_angle_and_offset(normal_deg: float, offset_m: float) -> None:
    normal = math.radians(normal_deg)
    img = line_image(256, [(normal, offset_m, 1.0), (normal, offset_m + 3.5, 0.7)])
    img += 0.3 * np.random.default_rng(1).random(img.shape)
    found = find_lines(img, CELL_M)
    want_normal, want_offset = canonical(normal, offset_m)
    _, want_second = canonical(normal, offset_m + 3.5)
    # 0.05 deg turns the end of a 20 m half line by 1.7 cm; offsets measured within 1.5 cm (a tenth of a
    # cell), asserted within a third of one.
    assert abs(math.degrees(math.remainder(found.normal_rad - want_normal, math.pi))) <= 0.05
    assert len(found.lines) == 2
    assert abs(found.lines[0].offset_m - want_offset) <= CELL_M / 3.0
    assert abs(found.lines[1].offset_m - want_second) <= CELL_M / 3.0
    assert found.lines[0].strength > found.lines[1].strength


@settings(max_examples=25, deadline=None)
@given(
    normal=st.floats(-math.pi, math.pi),
    offset=st.floats(-8.0, 8.0),
    turn=st.floats(-math.pi, math.pi),
)
def test_lines_turn_with_the_image(normal: float, offset: float, turn: float) -> None:
    """Rotating the scene about the image's centre turns the found normal by the same angle and keeps
    the offset (the Radon transform's rotation property)."""
    before = find_lines(line_image(128, [(normal, offset, 1.0)]), CELL_M)
    after = find_lines(line_image(128, [(normal + turn, offset, 1.0)]), CELL_M)
    n0, p0 = before.normal_rad, before.lines[0].offset_m
    n1, p1 = after.normal_rad, after.lines[0].offset_m
    # the same line may come back with its normal reversed (and its offset negated)
    turned = math.remainder(n1 - n0 - turn, 2.0 * math.pi)
    if abs(turned) > math.pi / 2.0:
        turned, p1 = math.remainder(turned + math.pi, 2.0 * math.pi), -p1
    # A line within a degree of the grid's axes is drawn as a staircase whose energy peaks up to
    # 0.13 deg nearer the axis (a direct summation of the same image says the same: the image's doing,
    # not the transform's), so two such lines may differ by 0.26 deg; elsewhere the error is below
    # 0.01 deg. 0.3 deg is 5 cm at the 10 m edge of this image.
    assert abs(math.degrees(turned)) <= 0.3
    assert abs(p1 - p0) <= 0.3 * CELL_M


@settings(max_examples=20, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    quarter_turns=st.integers(1, 3),
    theta=st.floats(-math.pi, math.pi),
)
def test_a_quarter_turned_image_has_the_turned_projections(
    seed: int, quarter_turns: int, theta: float
) -> None:
    """np.rot90 moves pixels exactly (an odd size keeps the centre pixel), so the projection of the
    turned image at theta - k 90 deg is the projection of the image at theta (rot90 turns a y-up image
    clockwise)."""
    rng = np.random.default_rng(seed)
    img = blobs(
        33, [(*rng.uniform(-9, 9, 2), rng.uniform(1.0, 3.0), rng.uniform(0.2, 1.0)) for _ in range(3)]
    )
    turned = np.rot90(img, quarter_turns)
    a, _ = radon(img, [theta])
    b, _ = radon(turned, [theta - quarter_turns * math.pi / 2.0])
    # both are interpolated in the spectrum, at different points: measured below 1 % of the peak
    assert np.abs(a - b).max() <= 0.02 * a.max()


def test_dominant_direction_is_that_of_the_parallel_lines() -> None:
    normal = math.radians(20.0)
    lines = [(normal, p, 1.0) for p in (-5.25, -1.75, 1.75, 5.25)] + [(math.radians(-60.0), 0.0, 1.5)]
    spec = RadonSpectrum(line_image(256, lines), CELL_M, disc=True)
    # four parallel lines outweigh one stronger line across them
    assert abs(math.degrees(dominant_normal(spec) - normal)) <= 0.05
    # looking near the crossing line finds it instead
    near = dominant_normal(spec, math.radians(-58.0), math.radians(4.0))
    assert abs(math.degrees(near - math.radians(-60.0))) <= 0.05


@settings(max_examples=30, deadline=None)
@given(
    centre=st.floats(-4.0, 4.0),
    half_width=st.sampled_from([0.0, 0.01, 0.07, 0.3, 0.8]),
    count=st.integers(1, 12),
    seed=st.integers(0, 2**31 - 1),
)
def test_a_coarse_window_reads_the_same_energy_as_the_whole_power_spectrum(
    centre: float, half_width: float, count: int, seed: int
) -> None:
    # A narrow window squares only the part of the spectrum its rays touch; the energies must be
    # those read from the whole power spectrum, near the spectrum's edges and axes too.
    image = (np.random.default_rng(seed).random((64, 64)) < 0.05).astype(np.float32)
    angles = centre + np.linspace(-half_width, half_width, count)
    whole = RadonSpectrum(image, CELL_M, disc=True)
    whole.coarse_energy(np.linspace(-math.pi / 2, math.pi / 2, 180, endpoint=False))  # the whole
    want = whole.coarse_energy(angles)
    got = RadonSpectrum(image, CELL_M, disc=True).coarse_energy(angles)
    assert np.array_equal(got, want)


def test_profile_peaks_keep_the_stronger_of_close_peaks() -> None:
    offsets = np.arange(-100, 100) * 0.1
    profile = (
        np.exp(-((offsets - 1.0) ** 2) / 0.02)
        + 0.8 * np.exp(-((offsets - 1.5) ** 2) / 0.02)  # 0.5 m away: one marking (a double line)
        + 0.5 * np.exp(-((offsets + 3.0) ** 2) / 0.02)
        + 0.1 * np.exp(-((offsets - 6.0) ** 2) / 0.02)  # below 20 % of the highest
    )
    peaks, _ = profile_peaks(profile, offsets)
    assert [round(p, 2) for p, _ in peaks] == [1.0, -3.0]


def test_rejects_what_is_not_an_image() -> None:
    with pytest.raises(ValueError, match="2-D"):
        RadonSpectrum(np.zeros(5))
    with pytest.raises(ValueError, match="cell_m"):
        RadonSpectrum(np.zeros((4, 4)), cell_m=0.0)


@settings(max_examples=40, deadline=None)
@given(
    rows=st.integers(4, 80),
    cols=st.integers(4, 80),
    seed=st.integers(0, 2**31 - 1),
    disc=st.booleans(),
)
def test_the_compiled_slices_equal_the_numpy_ones_to_float32_rounding(
    rows: int, cols: int, seed: int, disc: bool
) -> None:
    """The compiled Lanczos taps (sines by the angle-difference formula, sums in float64) against numpy's
    sinc weights and complex64 einsum: within a millionth of the slice's largest sample."""
    rng = np.random.default_rng(seed)
    image = rng.random((rows, cols)).astype(np.float32) * (rng.random((rows, cols)) < 0.3)
    spec = RadonSpectrum(image, 0.2, disc=disc)
    # the axes and the angles whose rays pass a hair off whole bins (cos 60 deg = 0.5000000000000001)
    exact = np.radians([-90.0, -60.0, -45.0, -30.0, 0.0, 30.0, 45.0, 60.0])
    angles = np.concatenate((exact, rng.uniform(-math.pi / 2.0, math.pi / 2.0, 8)))
    got, want = spec._slices(angles), spec._slices_reference(angles)
    scale = max(float(np.abs(want).max()), 1e-30)
    np.testing.assert_allclose(got, want, rtol=0.0, atol=1e-6 * scale)
