"""The Radon transform's spectrum slices (radon.py; seed 000 section 6), compiled with numba.

Each ray sample's Lanczos-3 taps were twelve `np.sinc` calls per axis in numpy, 24 sines a sample and
two thirds of a slice's cost. Here a sample's tap distances are x0 - t (x0 its fraction of a bin,
t = -2 .. 3), so sin(pi (x0 - t)) = (-1)^t sin(pi x0) and sin(pi (x0 - t) / 3) follows from sin and cos
of pi x0 / 3 by the angle-difference formula: three sines and cosines per axis, and two more for the
nearest bin, whose weight (near 1) the formula would take as a difference of nearly equal numbers
when x0 is near a whole bin. The weights agree with
numpy's to within a few units in the last place of float64 (the sine's argument is rounded elsewhere)
and so, as float32, almost always exactly; the 36 taps are summed in float64 where numpy's einsum
summed them in complex64. A slice therefore differs from `radon.RadonSpectrum._slices_reference` at
float32 rounding (1e-7 of its largest sample), which tests/host/perception/test_radon.py holds it to.
Compiled once per machine (`cache=True`) and released from the GIL while it runs (`nogil`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# cos and sin of t pi / 3 for the taps t = -2 .. 3 (index t + 2)
_COS_T = np.array([math.cos(t * math.pi / 3.0) for t in range(-2, 4)])
_SIN_T = np.array([math.sin(t * math.pi / 3.0) for t in range(-2, 4)])


@njit(cache=True, nogil=True)
def _lanczos3_taps(k: float, cos_t: np.ndarray, sin_t: np.ndarray, out: np.ndarray) -> int:
    """The Lanczos-3 weights (float32) of the six bins floor(k) - 2 .. floor(k) + 3 around k; returns
    floor(k)."""
    f = math.floor(k)
    x0 = k - f
    s1 = math.sin(math.pi * x0)
    u = math.pi * x0 / 3.0
    su = math.sin(u)
    cu = math.cos(u)
    for i in range(6):
        t = i - 2
        d = x0 - t
        if d == 0.0:
            out[i] = np.float32(1.0)
        elif abs(d) <= 0.5:
            # The nearest bin, as numpy has it: its weight is near 1, and near a whole bin the formula's
            # sines of pi x0 and pi x0 / 3 - t pi / 3 are differences of nearly equal numbers (at
            # x0 = 1 - 1e-16 the sine of pi x0 is a few ulps of pi, half of them rounding).
            y = math.pi * d
            y3 = math.pi * (d / 3.0)
            out[i] = np.float32((math.sin(y) / y) * (math.sin(y3) / y3))
        elif abs(d) < 3.0:
            sign = 1.0 if t % 2 == 0 else -1.0
            s3 = su * cos_t[i] - cu * sin_t[i]  # sin(pi d / 3)
            out[i] = np.float32((sign * s1 / (math.pi * d)) * (s3 / (math.pi * d / 3.0)))
        else:
            out[i] = np.float32(0.0)
    return int(f)


@njit(cache=True, nogil=True)
def slices(
    ext: np.ndarray,
    cos_a: np.ndarray,
    sin_a: np.ndarray,
    rho: np.ndarray,
    margin: int,
    half: int,
    cos_t: np.ndarray,
    sin_t: np.ndarray,
    out: np.ndarray,
) -> None:
    """out[i, r] = the spectrum at (kx, ky) = rho[r] (cos_a[i], sin_a[i]) (bins), Lanczos-3 interpolated
    from `ext` (radon.py's half spectrum with a margin: ext[margin + half + ky, margin + kx])."""
    wx = np.empty(6, np.float32)
    wy = np.empty(6, np.float32)
    for i in range(cos_a.shape[0]):
        for r in range(rho.shape[0]):
            fx = _lanczos3_taps(cos_a[i] * rho[r], cos_t, sin_t, wx)
            fy = _lanczos3_taps(sin_a[i] * rho[r], cos_t, sin_t, wy)
            re = 0.0
            im = 0.0
            for a in range(6):
                row = fy - 2 + a + margin + half
                wa = np.float64(wy[a])
                for b in range(6):
                    v = ext[row, fx - 2 + b + margin]
                    w = wa * np.float64(wx[b])
                    re += w * np.float64(v.real)
                    im += w * np.float64(v.imag)
            out[i, r] = complex(re, im)
