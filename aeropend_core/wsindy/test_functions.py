"""Test functions of the weak form: φ(t) = (1 − ((t − c)/(m·Δt))²)^p, their power p, their half-width m from the
signal's spectrum (corner wavenumber of the cumulative Fourier magnitude), and the quadrature kernels of φ's
derivatives and of the zero-order-hold (interval-midpoint) rule. Times in s, half-widths in samples.
"""
from __future__ import annotations

import functools
import math

import numba
import numpy as np
from numpy.polynomial import polynomial as npoly



# --------------------------------------------------------------------------------------------- test functions
def test_function_power(half_width: int, decay_tolerance: float = 1e-10, minimum: int = 2) -> int:
    """Smallest p with (1 − ((m−1)/m)²)^p ≤ tolerance, i.e. φ negligible at the first interior sample."""
    m = int(half_width)
    edge = 1.0 - ((m - 1) / m) ** 2
    if edge <= 0.0 or edge >= 1.0:
        return minimum
    return max(minimum, math.ceil(math.log(decay_tolerance) / math.log(edge)))


def spectral_corner(signal: np.ndarray) -> int:
    """Corner wavenumber k* (in cycles per record) of a signal's spectrum.

    The cumulative Fourier magnitude, summed from the highest frequency down, rises slowly (linearly) through the
    noise floor and steeply through the signal band; k* is the split of the best two-piece linear fit (secant
    lines, least squares), i.e. where the signal band ends.
    """
    x = np.asarray(signal, float)
    x = x - x.mean()
    mag = np.abs(np.fft.rfft(x))
    cum = np.cumsum(mag[::-1])[::-1]         # cum[k] = Σ_{j>=k} |X_j|, decreasing in k
    n = len(cum)
    if n < 8:
        return max(1, n // 2)
    return _two_piece_split(cum)


@numba.njit(cache=True, nogil=True)
def _two_piece_split(cum):
    """Split index (2 .. n−3) of the best two-piece secant fit of ``cum`` (least squares over each piece).

    Error of the secant line through (i0, y0) and (i1, y1) over i0..i1 from prefix sums of 1, k, k², y, y², k·y.
    """
    n = cum.size
    s0 = np.zeros(n + 1)
    s1 = np.zeros(n + 1)
    s2 = np.zeros(n + 1)
    sy = np.zeros(n + 1)
    syy = np.zeros(n + 1)
    sky = np.zeros(n + 1)
    for i in range(n):
        k = float(i)
        s0[i + 1] = s0[i] + 1.0
        s1[i + 1] = s1[i] + k
        s2[i + 1] = s2[i] + k * k
        sy[i + 1] = sy[i] + cum[i]
        syy[i + 1] = syy[i] + cum[i] * cum[i]
        sky[i + 1] = sky[i] + k * cum[i]
    best = np.inf
    best_split = 2
    for split in range(2, n - 2):
        total = 0.0
        for i0, i1 in ((0, split), (split, n - 1)):
            slope = (cum[i1] - cum[i0]) / max(i1 - i0, 1)
            a = cum[i0] - slope * i0            # line y = a + slope·k
            n_ = s0[i1 + 1] - s0[i0]
            k1 = s1[i1 + 1] - s1[i0]
            k2 = s2[i1 + 1] - s2[i0]
            y1 = sy[i1 + 1] - sy[i0]
            y2 = syy[i1 + 1] - syy[i0]
            ky = sky[i1 + 1] - sky[i0]
            # Σ (a + slope k − y)²
            total += a * a * n_ + 2 * a * slope * k1 + slope * slope * k2 - 2 * a * y1 - 2 * slope * ky + y2
        if total < best:
            best = total
            best_split = split
    return best_split


def choose_support(signal: np.ndarray, order: int = 1, decay_tolerance: float = 1e-10,
                   spectral_width: float = 1.0, min_half_width: int = 8,
                   max_half_width: int = 1000) -> tuple[int, int]:
    """Half-width m (samples) and power p of the test functions for one signal, from its spectrum corner."""
    n = len(signal)
    k_star = max(spectral_corner(signal), 1)
    p = max(test_function_power(min_half_width, decay_tolerance), order + 2)
    m = min_half_width
    for _ in range(20):
        m_new = spectral_width * n * math.sqrt(2 * p + 3) / (2 * math.pi * k_star)
        m_new = int(min(max(round(m_new), min_half_width), max_half_width))
        p_new = max(test_function_power(m_new, decay_tolerance), order + 2)
        if (m_new, p_new) == (m, p):
            break
        m, p = m_new, p_new
    return m, p


def kernel_derivatives(half_width: int, power: int, dt: float, max_order: int) -> np.ndarray:
    """Quadrature weights ``Δt·φ^(k)(t_i)`` (trapezoid) on the 2m+1 support, shape (max_order+1, 2m+1).

    Row k is the k-th time derivative of φ (units 1/s^k) times the trapezoid weights, so that
    ``weights[k] @ x[c−m : c+m+1]`` approximates ``∫ φ^(k)(t) x(t) dt``. Depends on (m, p, Δt, k) only:
    cached (successive windows of a stream reuse it).
    """
    return _kernel_derivatives(int(half_width), int(power), float(dt), int(max_order)).copy()


@functools.lru_cache(maxsize=64)
def _kernel_derivatives(half_width: int, power: int, dt: float, max_order: int) -> np.ndarray:
    m = int(half_width)
    xs = np.arange(-m, m + 1) / m
    u = 1.0 - xs * xs
    # closed forms of d^k/dx^k (1 − x²)^p for k <= 2 (p >= 3 here), the polynomial expansion beyond
    closed = {0: lambda: u ** power,
              1: lambda: -2.0 * power * xs * u ** (power - 1),
              2: lambda: -2.0 * power * u ** (power - 1) + 4.0 * power * (power - 1) * xs * xs * u ** (power - 2)}
    coef = None
    rows = []
    for k in range(max_order + 1):
        if k in closed and power - k >= 0:
            values = closed[k]()
        else:
            coef = npoly.polypow([1.0, 0.0, -1.0], power) if coef is None else coef
            values = npoly.polyval(xs, npoly.polyder(coef, k))
        rows.append(values * (1.0 / (m * dt)) ** k)
    w = np.array(rows) * dt
    w[:, 0] *= 0.5
    w[:, -1] *= 0.5
    return w


def kernel_hold(half_width: int, power: int, dt: float) -> np.ndarray:
    """Weights for a zero-order-hold signal: sample i holds over [t_i, t_i+1), so its weight is Δt·φ at the
    interval midpoint (midpoint rule), shape (2m+1,); the last interval lies outside the support (cached)."""
    return _kernel_hold(int(half_width), int(power), float(dt)).copy()


@functools.lru_cache(maxsize=64)
def _kernel_hold(half_width: int, power: int, dt: float) -> np.ndarray:
    m = int(half_width)
    xs = (np.arange(-m, m + 1) + 0.5) / m
    w = np.where(np.abs(xs) < 1.0, np.clip(1.0 - xs * xs, 0.0, None) ** power, 0.0)
    return w * dt
