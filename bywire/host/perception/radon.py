"""The Radon transform of a marker image through the central slice theorem, and its lines (seed 000 Sec. 6).

"Lane segments are detected by applying the Radon transform to the accumulated feature map ... For a
real-time calculation in the car, an implementation exploiting the central-slice theorem was used
(Bracewell, 1990). The position and direction of lane boundaries can be calculated by locating their
corresponding maxima in the Radon plane."

Conventions. An image is `image[row, col]` with rows along y (north, up) and columns along x (east), cells
`cell_m` wide; its origin is the centre of pixel (rows // 2, cols // 2). A line is given by its normal
angle theta (rad, counter-clockwise from +x) and its signed offset p (m): the points with
x cos(theta) + y sin(theta) = p. The projection is

    R(theta, p) = integral of f over that line  (image value x metres of line),

sampled at offsets k * cell_m, k = -P/2 .. P/2 - 1.

Method. The image is zero-padded to P x P (P the next power of two of twice its size, so that no
projection of it wraps around) with its origin at index 0, transformed once with a real 2-D FFT, and
for each angle the spectrum is sampled along the ray (rho cos theta, rho sin theta), rho = 0 .. P/2;
a 1-D inverse real FFT of that slice is the projection. Angles with cos(theta) < 0 lie outside the
half spectrum: they are the projection at theta + pi reversed. The samples between the spectrum's grid
points are interpolated with a Lanczos-3 kernel (6 x 6 taps): the padding makes the spectrum
band-limited at twice its sampling rate, and the kernel then holds the projections to about 1 % of
their peak against a direct summation (`radon_direct`; the tests measure it) and scikit-image. Bilinear
interpolation (`scipy.ndimage.map_coordinates`) was tried first: 10-13 % off in amplitude near the
image's edge, and a bias of up to 0.4 deg towards the grid's axes in the dominant direction (a ray
along an axis meets the grid points, one off it reads a blurred ridge between them), which the
rotation property test found. It still serves the coarse direction search (`coarse_energy`), an
eighth of the cost, whose best is refined with Lanczos slices. A cubic spline needs a prefilter of
the whole spectrum (13 ms here); padding 4x, 4x the FFT.
The slices are compiled (`radon_kernels`: three sines per axis and sample where numpy's sinc took
twelve), equal to the numpy `_slices_reference` to float32 rounding.

Lines. The dominant direction is the angle whose projection has the most energy after a high-pass (the
projection minus its Gaussian blur of `highpass_m`, so that a broad patch of clutter does not count as a
line): parallel lane markings add up at their common angle. The lines are then the peaks of the
high-passed projection at that angle. Deviations from the paper (which gives no detail): the image is
cut to its inscribed disc before the transform, so that every direction sees the same chord length
(a square's diagonal is 41 % longer and would favour 45 deg); the energy of a direction is summed over
its spectrum slice (Parseval), so the direction search needs no inverse FFT.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import scipy.fft
from scipy import ndimage

from . import radon_kernels

__all__ = [
    "Line",
    "LineSet",
    "RadonSpectrum",
    "dominant_normal",
    "find_lines",
    "lines_at",
    "profile_peaks",
    "radon",
    "radon_direct",
]

FloatArray = npt.NDArray[np.float64]

# Coarse then fine search for the dominant direction: the high-passed energy of a line falls to half
# over about 0.5-1 deg either side of it, so 1 deg steps find its lobe (and the coarse search's axis
# bias, up to 0.4 deg, stays inside the fine search's +-1 deg); 0.25 deg steps and a parabola through
# the best three put the peak within 0.02 deg (0.7 cm at the end of a 20 m half line).
COARSE_STEP_RAD = math.radians(1.0)
FINE_STEP_RAD = math.radians(0.25)
# High-pass of a projection: minus its Gaussian blur of this sigma. A painted line (0.1-0.3 m) or a
# curb passes; the broad hump of a road full of features (metres wide) does not.
HIGHPASS_M = 1.0
# Peaks: at least this far apart (two lines of a double centre line are 0.3-0.5 m apart and count as
# one marking), at least this fraction of the highest, and this many noise sigmas above zero.
MIN_SEPARATION_M = 0.8
MIN_PEAK_RATIO = 0.2
MIN_PEAK_SNR = 4.0
# Lanczos kernel half-width (in frequency bins) for slicing the spectrum: 3 taps either side. The 2x
# zero padding makes the spectrum band-limited at twice its sampling rate, which a Lanczos-3 kernel
# interpolates to about 1 % (bilinear: 10-15 % off-centre, and a bias towards the grid's axes).
LANCZOS_A = 3
# Ray samples interpolated per chunk: 4096 x 36 complex taps, 2.4 MB.
_SLICE_CHUNK = 4096


def _next_pow2(n: int) -> int:
    return 1 << max(int(n) - 1, 1).bit_length()


def _canonical(angles_rad: FloatArray) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """Angles folded into [-pi/2, pi/2) and whether each was turned by pi (its offsets then reverse)."""
    wrapped = (angles_rad + math.pi) % (2.0 * math.pi) - math.pi  # [-pi, pi)
    flip = (wrapped >= math.pi / 2.0) | (wrapped < -math.pi / 2.0)
    folded = np.where(flip, wrapped - np.copysign(math.pi, wrapped), wrapped)
    folded = np.where(folded >= math.pi / 2.0, folded - math.pi, folded)
    return folded, flip


@functools.lru_cache(maxsize=8)
def _disc(rows: int, cols: int) -> npt.NDArray[np.float32]:
    """1 inside the image's inscribed disc, 0 outside."""
    yy = (np.arange(rows) - rows // 2).astype(np.float64)
    xx = (np.arange(cols) - cols // 2).astype(np.float64)
    radius = min(rows, cols) / 2.0
    out = (yy[:, None] ** 2 + xx[None, :] ** 2 <= radius * radius).astype(np.float32)
    out.setflags(write=False)
    return out


def _lanczos(x: FloatArray) -> FloatArray:
    return np.where(np.abs(x) < LANCZOS_A, np.sinc(x) * np.sinc(x / LANCZOS_A), 0.0)


class RadonSpectrum:
    """An image's zero-padded 2-D spectrum, ready to be sliced into projections at any angle.

    Build it once per image; `projections` and `energy` are then cheap per angle (one interpolation
    of P/2 + 1 spectrum samples, plus one inverse FFT of length P for a projection).
    """

    def __init__(self, image: npt.ArrayLike, cell_m: float = 1.0, *, disc: bool = False, pad: int = 2):
        img = np.asarray(image, dtype=np.float32)
        if img.ndim != 2 or min(img.shape) < 1:
            raise ValueError(f"a Radon transform needs a 2-D image, got shape {img.shape}")
        if not (math.isfinite(cell_m) and cell_m > 0.0):
            raise ValueError(f"cell_m = {cell_m}: must be finite and > 0")
        rows, cols = img.shape
        p = _next_pow2(pad * max(rows, cols))
        cr, cc = rows // 2, cols // 2
        if disc:
            img = img * _disc(rows, cols)
        # Origin at index 0 (wrapped), so that the slices carry no phase ramp: the image's quadrants
        # go to the corners of the padded array.
        buf = np.zeros((p, p), dtype=np.float32)
        buf[: rows - cr, : cols - cc] = img[cr:, cc:]
        buf[: rows - cr, p - cc :] = img[cr:, :cc]
        buf[p - cr :, : cols - cc] = img[:cr, cc:]
        buf[p - cr :, p - cc :] = img[:cr, :cc]
        spec = scipy.fft.rfft2(buf)  # (P, P/2 + 1): ky wraps along axis 0, kx = 0 .. P/2 along axis 1
        # The half spectrum with a margin of A samples all round, so that an interpolation kernel of
        # half-width A never leaves it: rows ky = -P/2 - A .. P/2 + A (periodic), columns kx = -A ..
        # P/2 + A (F(-kx, ky) = conj F(kx, -ky), real image). ext[A + P/2 + ky, A + kx] = F(kx, ky).
        a, half = LANCZOS_A, p // 2
        ext = np.empty((p + 2 * a + 1, half + 2 * a + 1), dtype=np.complex64)
        ext[: half + a, a : a + half + 1] = spec[half - a :]  # ky = -P/2 - A .. -1
        ext[half + a :, a : a + half + 1] = spec[: half + a + 1]  # ky = 0 .. P/2 + A
        flipped = ext[::-1]  # row of -ky
        ext[:, :a] = np.conj(flipped[:, 2 * a : a : -1])  # kx = -A .. -1
        ext[:, a + half + 1 :] = np.conj(flipped[:, a + half - 1 : half - 1 : -1])  # kx = P/2 + 1 ..
        self._ext: npt.NDArray[np.complex64] = ext
        self._power: npt.NDArray[np.float32] | None = None
        self.size = p
        self.cell_m = float(cell_m)
        self.support_m = math.hypot(rows, cols) / 2.0 * self.cell_m
        self._rho = np.arange(half + 1, dtype=np.float64)

    @property
    def offsets_m(self) -> FloatArray:
        """Offset p of each projection sample (m), from -P/2 cells up."""
        return np.asarray((np.arange(self.size) - self.size // 2) * self.cell_m, dtype=np.float64)

    def _rays(self, folded: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(kx, ky) of each ray's samples, in frequency bins."""
        return np.outer(np.cos(folded), self._rho), np.outer(np.sin(folded), self._rho)

    def _slices(self, folded: FloatArray) -> npt.NDArray[np.complex64]:
        """The spectrum along each ray, Lanczos-interpolated (see the module docstring), in
        `radon_kernels.slices`: `_slices_reference`'s to float32 rounding."""
        out = np.empty((folded.size, self._rho.size), dtype=np.complex64)
        radon_kernels.slices(
            self._ext, np.cos(folded), np.sin(folded), self._rho, LANCZOS_A, self.size // 2,
            radon_kernels._COS_T, radon_kernels._SIN_T, out,
        )  # fmt: skip
        return out

    def _slices_reference(self, folded: FloatArray) -> npt.NDArray[np.complex64]:
        """`_slices` in numpy: Lanczos weights from `np.sinc`, the taps summed by einsum."""
        kx, ky = (v.ravel() for v in self._rays(folded))
        a, half = LANCZOS_A, self.size // 2
        taps = np.arange(-a + 1, a + 1)
        cx = np.floor(kx).astype(np.intp)[:, None] + taps[None, :]
        cy = np.floor(ky).astype(np.intp)[:, None] + taps[None, :]
        wx = _lanczos(kx[:, None] - cx).astype(np.float32)
        wy = _lanczos(ky[:, None] - cy).astype(np.float32)
        out = np.empty(kx.size, dtype=np.complex64)
        flat, width = self._ext.reshape(-1), self._ext.shape[1]
        for lo in range(0, kx.size, _SLICE_CHUNK):  # bounded memory: chunk x (2A)^2 samples
            sl = slice(lo, lo + _SLICE_CHUNK)
            # ext[row, col] as one take from the flat array (a third cheaper than 2-D fancy indexing)
            vals = flat.take((cy[sl] + a + half)[:, :, None] * width + (cx[sl] + a)[:, None, :])
            out[sl] = np.einsum("mij,mi,mj->m", vals, wy[sl], wx[sl])
        return out.reshape(folded.size, self._rho.size)

    def _highpass(self, highpass_m: float | None) -> FloatArray | None:
        if highpass_m is None:
            return None
        # Fourier pair of "minus a Gaussian blur of sigma": 1 - exp(-2 pi^2 sigma^2 f^2), f in cycles/m.
        f = self._rho / (self.size * self.cell_m)
        return -np.expm1(-2.0 * (math.pi * highpass_m * f) ** 2)

    def _parseval_weight(self, highpass_m: float | None) -> FloatArray:
        # The half spectrum holds rho = 1 .. P/2 - 1 twice (its negative frequencies).
        weight = np.full(self._rho.size, 2.0)
        weight[0] = weight[-1] = 1.0
        h = self._highpass(highpass_m)
        return weight if h is None else weight * h**2

    def projections(self, angles_rad: npt.ArrayLike, highpass_m: float | None = None) -> FloatArray:
        """R(theta, p) for each angle (rows) at `offsets_m` (columns); optionally high-passed."""
        angles = np.atleast_1d(np.asarray(angles_rad, dtype=np.float64))
        folded, flip = _canonical(angles)
        slices = self._slices(folded)
        h = self._highpass(highpass_m)
        if h is not None:
            slices = slices * h
        proj = scipy.fft.irfft(slices, n=self.size, axis=-1)  # p = 0 at index 0, wrapped
        if flip.any():  # R(theta + pi, p) = R(theta, -p): index k -> (P - k) mod P
            proj[flip] = np.roll(proj[flip][:, ::-1], 1, axis=-1)
        return np.fft.fftshift(proj, axes=-1).astype(np.float64) * self.cell_m

    def energy(self, angles_rad: npt.ArrayLike, highpass_m: float | None = HIGHPASS_M) -> FloatArray:
        """Sum over p of the (high-passed) projection squared at each angle, by Parseval on the slice
        (Lanczos-interpolated, as `projections`)."""
        angles = np.atleast_1d(np.asarray(angles_rad, dtype=np.float64))
        folded, _ = _canonical(angles)  # a reversed projection has the same energy
        s = self._slices(folded)
        power = s.real**2 + s.imag**2
        return np.einsum("ij,j->i", power, self._parseval_weight(highpass_m)).astype(np.float64)

    def coarse_energy(self, angles_rad: npt.ArrayLike, highpass_m: float | None = HIGHPASS_M) -> FloatArray:
        """`energy` from the power spectrum interpolated bilinearly: an eighth of the cost, for a coarse
        search; biased towards the grid's axes by up to 0.4 deg (a ray along an axis meets the samples,
        one off it falls between them and reads a blurred ridge), which a fine `energy` search undoes."""
        angles = np.atleast_1d(np.asarray(angles_rad, dtype=np.float64))
        folded, _ = _canonical(angles)
        kx, ky = self._rays(folded)
        a, half = LANCZOS_A, self.size // 2
        coords = np.stack(((ky + a + half).ravel(), (kx + a).ravel()))
        # The power only over the box the rays' bilinear samples touch (a window of a few degrees is a
        # thin wedge of the spectrum). Shifting a coordinate by a whole number is exact, and the box
        # keeps the spectrum's own edges where it reaches them, so the samples are the same.
        lo = np.maximum(np.floor(coords.min(axis=1)).astype(np.intp) - 1, 0)
        hi = np.minimum(np.floor(coords.max(axis=1)).astype(np.intp) + 3, self._ext.shape)
        if self._power is not None or np.prod(hi - lo) >= self._ext.size // 2:
            if self._power is None:  # most of it: the whole power, kept for the next search
                self._power = (self._ext.real**2 + self._ext.imag**2).astype(np.float32)
            box, lo = self._power, np.zeros(2, np.intp)
        else:
            part = self._ext[lo[0] : hi[0], lo[1] : hi[1]]
            box = (part.real**2 + part.imag**2).astype(np.float32)
        power = ndimage.map_coordinates(box, coords - lo[:, None], order=1, mode="nearest", prefilter=False)
        power = power.reshape(angles.size, self._rho.size)
        weight = self._parseval_weight(highpass_m).astype(np.float32)
        return np.einsum("ij,j->i", power, weight).astype(np.float64)  # einsum: no BLAS threads


def radon(
    image: npt.ArrayLike, angles_rad: npt.ArrayLike, cell_m: float = 1.0
) -> tuple[FloatArray, FloatArray]:
    """Projections R(theta, p) of `image` at each angle, and their offsets p (m); see the module docstring."""
    spec = RadonSpectrum(image, cell_m)
    return spec.projections(angles_rad), spec.offsets_m


def radon_direct(
    image: npt.ArrayLike, angles_rad: npt.ArrayLike, cell_m: float = 1.0, oversample: int = 4
) -> tuple[FloatArray, FloatArray]:
    """The reference: each pixel taken as a square of `oversample` x `oversample` points sharing its value,
    each point's value split linearly between the two offset bins either side of its p, on the same
    offsets as `radon`. (Whole pixels at 45 deg land on a lattice 0.71 bins apart and beat against the
    bins by 10 %; a 4 x 4 split, 0.18 bins apart, by well under 1 %.) O(pixels x oversample^2 x angles):
    for tests and small images."""
    img = np.asarray(image, dtype=np.float64)
    rows, cols = img.shape
    p_size = _next_pow2(2 * max(rows, cols))
    sub = (np.arange(oversample) + 0.5) / oversample - 0.5
    yy = (np.arange(rows) - rows // 2)[:, None, None, None] + sub[None, None, :, None]
    xx = (np.arange(cols) - cols // 2)[None, :, None, None] + sub[None, None, None, :]
    yy, xx = np.broadcast_arrays(yy, xx)
    values = np.broadcast_to(img[:, :, None, None] / oversample**2, yy.shape).ravel()
    angles = np.atleast_1d(np.asarray(angles_rad, dtype=np.float64))
    out = np.zeros((angles.size, p_size))
    for i, theta in enumerate(angles):
        p = (xx * math.cos(theta) + yy * math.sin(theta)).ravel() + p_size // 2
        k = np.floor(p).astype(np.int64)
        frac = p - k
        out[i] = np.bincount(k, values * (1.0 - frac), minlength=p_size)[:p_size]
        out[i] += np.bincount(k + 1, values * frac, minlength=p_size + 1)[:p_size]
    offsets = np.asarray((np.arange(p_size) - p_size // 2) * cell_m, dtype=np.float64)
    return out * cell_m, offsets


@dataclass(frozen=True)
class Line:
    """A line x cos(normal) + y sin(normal) = offset (m, from the image origin), and its strength (the
    high-passed projection's peak: image value x metres of line)."""

    normal_rad: float
    offset_m: float
    strength: float


@dataclass(frozen=True, eq=False)
class LineSet:
    """The lines found at one normal angle, strongest first, and the high-passed projection they came from."""

    normal_rad: float
    lines: tuple[Line, ...]
    profile: FloatArray
    offsets_m: FloatArray
    noise: float  # robust sigma of `profile` inside the image's support


def dominant_normal(
    spec: RadonSpectrum,
    around_rad: float | None = None,
    window_rad: float = math.pi / 2.0,
    *,
    coarse_step_rad: float = COARSE_STEP_RAD,
    fine_step_rad: float = FINE_STEP_RAD,
    highpass_m: float | None = HIGHPASS_M,
) -> float:
    """The normal angle with the most high-passed projection energy: over all directions, or within
    +-`window_rad` of `around_rad` (e.g. the map's lane direction). A coarse grid (`coarse_energy`),
    then a fine one around its best (`energy`); a parabola through the fine maximum and its neighbours
    gives the last fraction of a step."""
    if around_rad is None:
        coarse = -math.pi / 2.0 + np.arange(round(math.pi / coarse_step_rad)) * coarse_step_rad
    else:
        n = max(math.ceil(window_rad / coarse_step_rad), 1)
        coarse = around_rad + np.linspace(-window_rad, window_rad, 2 * n + 1)
    e = spec.coarse_energy(coarse, highpass_m)
    best = float(coarse[int(np.argmax(e))])
    n_fine = math.ceil(coarse_step_rad / fine_step_rad)
    fine = best + np.arange(-n_fine, n_fine + 1) * fine_step_rad
    if around_rad is not None:
        fine = fine[np.abs(fine - around_rad) <= window_rad + 1e-12]
    ef = spec.energy(fine, highpass_m)
    j = int(np.argmax(ef))
    angle = float(fine[j])
    if 0 < j < fine.size - 1:
        angle += _parabola_vertex(ef[j - 1], ef[j], ef[j + 1]) * fine_step_rad
    return angle


def _parabola_vertex(left: float, mid: float, right: float) -> float:
    """Offset in steps (-0.5 .. 0.5) of the vertex of the parabola through three equally spaced values."""
    denom = left - 2.0 * mid + right
    if denom >= 0.0:  # not a maximum
        return 0.0
    return float(np.clip(0.5 * (left - right) / denom, -0.5, 0.5))


def profile_peaks(
    profile: FloatArray,
    offsets_m: FloatArray,
    *,
    support_m: float | None = None,
    min_separation_m: float = MIN_SEPARATION_M,
    min_ratio: float = MIN_PEAK_RATIO,
    min_snr: float = MIN_PEAK_SNR,
) -> tuple[list[tuple[float, float]], float]:
    """Peaks of a projection: (offset m, strength), strongest first, and the noise sigma they were judged by.

    A peak is a local maximum at least `min_ratio` of the highest and `min_snr` robust sigmas (1.4826
    MAD of the profile inside +-`support_m`) above zero; weaker maxima within `min_separation_m` of a
    stronger one are dropped. The offset is refined by a parabola through the peak and its neighbours.
    """
    g = np.asarray(profile, dtype=np.float64)
    inside = np.ones(g.size, bool) if support_m is None else np.abs(offsets_m) <= support_m
    vals = g[inside]
    noise = float(1.4826 * np.median(np.abs(vals - np.median(vals)))) if vals.size else 0.0
    if g.size < 3:
        return [], noise
    is_max = np.zeros(g.size, bool)
    is_max[1:-1] = (g[1:-1] >= g[:-2]) & (g[1:-1] > g[2:]) & inside[1:-1]
    cand = np.flatnonzero(is_max)
    if cand.size == 0:
        return [], noise
    top = float(g[cand].max())
    floor = max(min_ratio * top, min_snr * noise, 0.0)
    cand = cand[g[cand] > floor]
    cand = cand[np.argsort(-g[cand], kind="stable")]
    step = float(offsets_m[1] - offsets_m[0])
    kept: list[tuple[float, float]] = []
    for i in cand:
        off = float(offsets_m[i]) + _parabola_vertex(g[i - 1], g[i], g[i + 1]) * step
        if all(abs(off - o) >= min_separation_m for o, _ in kept):
            kept.append((off, float(g[i])))
    return kept, noise


def find_lines(
    image: npt.ArrayLike | RadonSpectrum,
    cell_m: float = 1.0,
    *,
    around_rad: float | None = None,
    window_rad: float = math.pi / 2.0,
    highpass_m: float = HIGHPASS_M,
    min_separation_m: float = MIN_SEPARATION_M,
    min_ratio: float = MIN_PEAK_RATIO,
    min_snr: float = MIN_PEAK_SNR,
) -> LineSet:
    """The dominant direction of `image` (optionally near `around_rad`) and the parallel lines along it."""
    spec = image if isinstance(image, RadonSpectrum) else RadonSpectrum(image, cell_m, disc=True)
    normal = dominant_normal(spec, around_rad, window_rad, highpass_m=highpass_m)
    return lines_at(
        spec,
        normal,
        highpass_m=highpass_m,
        min_separation_m=min_separation_m,
        min_ratio=min_ratio,
        min_snr=min_snr,
    )


def lines_at(
    spec: RadonSpectrum,
    normal_rad: float,
    *,
    highpass_m: float = HIGHPASS_M,
    min_separation_m: float = MIN_SEPARATION_M,
    min_ratio: float = MIN_PEAK_RATIO,
    min_snr: float = MIN_PEAK_SNR,
) -> LineSet:
    """The lines with normal `normal_rad`: the peaks of the high-passed projection at that angle."""
    profile = spec.projections([normal_rad], highpass_m)[0]
    offsets = spec.offsets_m
    peaks, noise = profile_peaks(
        profile,
        offsets,
        support_m=spec.support_m,
        min_separation_m=min_separation_m,
        min_ratio=min_ratio,
        min_snr=min_snr,
    )
    lines = tuple(Line(normal_rad, off, strength) for off, strength in peaks)
    return LineSet(normal_rad, lines, profile, offsets, noise)
