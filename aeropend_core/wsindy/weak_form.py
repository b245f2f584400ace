"""Weak SINDy (WSINDy) for ordinary differential equations, written from the method (Messenger & Bortz).

For each equation ``d^k x/dt^k = Σ_j w_j θ_j(signals)`` and each test function φ supported on 2m+1 samples, the
weak form integrates by parts until no derivative of data is left::

    (-1)^k ∫ φ^(k) x dt  =  Σ_j w_j ∫ φ θ_j dt          (a term with its own derivative order d
                                                           contributes (-1)^d ∫ φ^(d) θ_j dt)

which gives a linear system ``G w = b`` (one row per test function). Steps:

1. Test functions φ(t) = (1 − ((t − c)/(m Δt))²)^p; p is the smallest power that makes φ decay below
   ``decay_tolerance`` at the first interior sample; the half-width m comes from the target signal's spectrum:
   the corner wavenumber k* of its cumulative Fourier magnitude (two-piece linear fit) and
   ``2π k* m = spectral_width · N · sqrt(2p + 3)`` (φ's spectrum then falls off where the data's noise floor
   starts). m and p are solved together, m clipped to [``min_half_width``, ``max_half_width``].
2. Gram matrix and right-hand side by trapezoid quadrature: all test functions are shifts of one kernel, so the
   integrals are a strided correlation of each library column with the kernel (vectorised, no dense V).
   Terms marked ``hold`` (zero-order-hold inputs, interval quantities) use the midpoint of each sample interval
   instead: the trapezoid rule would shift a held input by half a sample (~1 % bias in gains and damping).
3. Generalised least squares: white noise on the target makes the rows of b correlated with covariance
   ∝ V^(k) V^(k)ᵀ; both sides are whitened with its (banded) Cholesky factor. Then the covariance is rebuilt
   from the linearised response of the whole residual b − Gw to white noise on every signal (including noise
   entering the library terms, with the current w) and the fit is repeated (``irls_iterations``), as in the
   reference WSINDy; without this the whitening amplifies low-frequency regressor noise and biases every
   coefficient (4 % on the pendulum with a 10-bit angle). In the reweighted passes the normal equations are
   also bias-compensated (``bias_correction``): the expected contribution of the noise to G̃ᵀG̃ and G̃ᵀb̃,
   computed from the per-signal noise levels (robust third-difference estimate unless given), is subtracted.
   Noisy regressors otherwise attenuate coefficients (errors in variables; -10 to -25 % on Kq at 30 dB).
   The reweighted covariance also gets a 'process noise' term q·V Vᵀ (``process_noise``), q estimated from the
   previous residual: for a second-order equation the measurement-only whitening integrates the equation twice,
   so an unmodelled force (pivot friction) would otherwise swamp the fit.
4. Modified sequential thresholding (MSTLS) in scale-free coordinates: with columns and b normalised, a term is
   kept while its relative contribution ``|w_i|·‖G_i‖/‖b‖`` lies in [λ, 1/λ]; refit on the kept terms until the
   set is stable. λ is chosen on a log grid 10^[-4..0] (100 values) by minimising
   ``L(λ) = 2α ‖G(w_λ − w_LS)‖/‖G w_LS‖ + 2(1 − α) nnz(w_λ)/J`` (α = 0.8), smallest minimiser. A small ridge
   (relative to the normalised Gram matrix) keeps nearly collinear libraries (sin y vs y) solvable during the
   thresholding; the kept terms are refitted without it. Because thresholding can drop a true term of a nearly
   collinear group early, the supports of a greedy backward elimination, a greedy forward selection and every
   support of up to ``exhaustive_terms`` terms are scored with the same loss L too; the best is refined by
   single additions/removals while L drops; the overall minimiser wins (λ reported as NaN when it is not on
   the MSTLS path).
5. Standard errors of the kept coefficients from the whitened residual: σ̂² = ‖r‖²/(n_rows − n_kept),
   Cov(w) = σ̂² (G̃ᵀG̃ − C)⁻¹ (C the noise compensation, when used).

Test-function centres are ``stride`` = m/4 samples apart (overlapping supports; the GLS covariance accounts
for the overlap). Heavy loops (support selection, banded covariance, band of Σ⁻¹) are numba kernels cached on
disk, so the first call in a fresh environment compiles for a few seconds.

Several experiments or segments are fitted together by stacking their (separately whitened) weak equations.

The public entry point is :func:`fit_weak_sindy`; the candidate terms come from :mod:`aeropend_core.wsindy.library`.
"""
from __future__ import annotations

import functools
import math
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numba
import numpy as np
from numpy.polynomial import polynomial as npoly
from scipy import linalg, special
from scipy.linalg import lapack
from threadpoolctl import ThreadpoolController

from aeropend_core.errors import AeropendError, InsufficientDataError
from aeropend_core.wsindy.library import Term

#: λ grid of the automatic threshold search.
THRESHOLD_GRID = np.logspace(-4.0, 0.0, 100)


@dataclass(frozen=True)
class Equation:
    """One equation to identify: ``d^order target / dt^order = Σ w_j · term_j``.

    Parameters
    ----------
    target : str
        Name of the signal whose derivative is the left-hand side.
    terms : sequence of Term
        Candidate terms (:mod:`aeropend_core.wsindy.library`).
    order : int
        Derivative order of the left-hand side (1 for first-order systems, 2 for the pendulum from the angle).
    keep : sequence of str
        Names of terms never thresholded away (known structure); others are subject to MSTLS.
    """

    target: str
    terms: tuple[Term, ...]
    order: int = 1
    keep: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, 'terms', tuple(self.terms))
        object.__setattr__(self, 'keep', tuple(self.keep))
        if self.order < 1:
            raise AeropendError(f'equation for {self.target!r}: order must be >= 1, got {self.order}')
        names = [t.name for t in self.terms]
        if not names:
            raise AeropendError(f'equation for {self.target!r} has no candidate terms')
        if len(set(names)) != len(names):
            raise AeropendError(f'equation for {self.target!r} has duplicate term names: {names}')
        unknown = set(self.keep) - set(names)
        if unknown:
            raise AeropendError(f'equation for {self.target!r}: keep names {sorted(unknown)} are not terms')

    @property
    def name(self) -> str:
        """Left-hand side, e.g. ``'dangle/dt'`` or ``'d^2angle/dt^2'``."""
        return f'd{self.target}/dt' if self.order == 1 else f'd^{self.order}{self.target}/dt^{self.order}'


@dataclass(frozen=True, eq=False)
class EquationFit:
    """Result for one equation. Coefficients are in the units of (lhs unit) / (term unit).

    Attributes
    ----------
    name : str
        Left-hand side (:attr:`Equation.name`).
    candidates : tuple of str
        All candidate term names, in library order.
    coefficients : dict
        Selected term name -> coefficient (terms not selected are absent).
    standard_errors : dict
        Selected term name -> 1σ standard error of the coefficient.
    covariance : ndarray, shape (n_selected, n_selected)
        Coefficient covariance, in the order of ``coefficients``.
    threshold : float
        The λ used (0.0 when thresholding was off; NaN when a greedy (backward/forward) support won).
    residual : float
        Relative whitened residual ‖G̃w − b̃‖/‖b̃‖ (0 = perfect fit).
    half_width, power, n_test_functions : int
        Test-function half-width m (samples), power p, and number of weak equations (rows) used.
    """

    name: str
    candidates: tuple[str, ...]
    coefficients: dict[str, float]
    standard_errors: dict[str, float]
    covariance: np.ndarray = field(repr=False)
    threshold: float
    residual: float
    half_width: int
    power: int
    n_test_functions: int

    @property
    def selected(self) -> tuple[str, ...]:
        """Names of the terms kept."""
        return tuple(self.coefficients)

    def coefficient(self, term: str) -> float:
        """Coefficient of ``term`` (0.0 if the term was not selected; KeyError if it was no candidate)."""
        if term not in self.candidates:
            raise KeyError(f'{term!r} is not a candidate of {self.name}; candidates: {list(self.candidates)}')
        return self.coefficients.get(term, 0.0)

    def format(self) -> str:
        """``lhs = c1·term1 + c2·term2 ...`` with ±1σ."""
        if not self.coefficients:
            return f'{self.name} = 0'
        parts = [f'({c:+.6g} ± {self.standard_errors[k]:.2g})·{k}' for k, c in self.coefficients.items()]
        return f'{self.name} = ' + ' + '.join(parts)


@dataclass(frozen=True, eq=False)
class WeakSindyResult:
    """Identified equations, in the order requested. Index by left-hand side name or by target signal."""

    equations: tuple[EquationFit, ...]

    def __getitem__(self, key: str) -> EquationFit:
        for eq in self.equations:
            if key == eq.name or eq.name in (f'd{key}/dt',) or eq.name.endswith(f'{key}/dt^2'):
                return eq
        raise KeyError(f'no equation {key!r}; have {[e.name for e in self.equations]}')

    @property
    def coefficients(self) -> dict[str, dict[str, float]]:
        """lhs name -> {term: coefficient}."""
        return {eq.name: dict(eq.coefficients) for eq in self.equations}

    @property
    def standard_errors(self) -> dict[str, dict[str, float]]:
        """lhs name -> {term: 1σ standard error}."""
        return {eq.name: dict(eq.standard_errors) for eq in self.equations}

    def format(self) -> str:
        return '\n'.join(eq.format() for eq in self.equations)


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


# ----------------------------------------------------------------------------------------------- validation
def _as_segments(time, signals) -> list[tuple[np.ndarray, dict[str, np.ndarray]]]:
    if isinstance(signals, Mapping):
        times, sigs = [time], [signals]
    else:
        times, sigs = list(time), list(signals)
        if len(times) != len(sigs):
            raise AeropendError(f'{len(times)} time arrays but {len(sigs)} signal sets: give one per segment')
    out = []
    for i, (t, s) in enumerate(zip(times, sigs)):
        label = f'segment {i}: ' if len(times) > 1 else ''
        t = np.asarray(t, float)
        if t.ndim != 1:
            raise AeropendError(f'{label}time must be 1-D, got shape {t.shape}')
        arrays = {}
        for name, x in s.items():
            x = np.asarray(x, float)
            if x.shape != t.shape:
                raise AeropendError(f'{label}signal {name!r} has shape {x.shape}, time has {t.shape}')
            arrays[name] = x
        for name, x in [('time', t), *arrays.items()]:
            bad = ~np.isfinite(x)
            if bad.any():
                i0 = int(np.argmax(bad))
                raise InsufficientDataError(
                    f'{label}{name!r} has {int(bad.sum())} NaN/inf value(s), first at sample {i0}'
                    f'{"" if name == "time" else f" (t = {t[i0]:.4g} s)"}; remove or interpolate them, '
                    'or split the record into clean segments')
        if len(t) < 3:
            raise InsufficientDataError(f'{label}only {len(t)} samples; a weak-form fit needs a window of data')
        dt = np.diff(t)
        step = _median(dt)
        if step <= 0 or np.max(np.abs(dt - step)) > 1e-3 * step:
            raise AeropendError(f'{label}time is not uniformly sampled (median step {step:.6g} s, largest '
                                f'deviation {np.max(np.abs(dt - step)):.3g} s); resample or split at the gaps')
        out.append((t, arrays))
    return out


# -------------------------------------------------------------------------------------------- weak assembly
def _centres(n: int, m: int, stride: int) -> np.ndarray:
    count = (n - 2 * m - 1) // stride + 1
    span = (count - 1) * stride
    first = m + (n - 2 * m - 1 - span) // 2      # centre the set of supports in the window
    return first + stride * np.arange(count)


def _weak_rows(columns: np.ndarray, weights: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """∫ φ_c · column for each start, shape (len(starts), n_columns)."""
    width = weights.shape[-1]
    k = len(starts)
    step = int(starts[1] - starts[0]) if k > 1 else 1
    if k < 2 or step < 1 or np.any(np.diff(starts) != step):
        view = np.lib.stride_tricks.sliding_window_view(columns, width, axis=0)   # (n - width + 1, ncol, width)
        return view[starts] @ weights
    # Evenly spaced supports: cut the data into blocks of ``step`` samples and the kernel into q pieces of the
    # same length; row r is Σ_j (block r+j)·(piece j). One small matrix product, no (K, ncol, width) copy.
    q = -(-width // step)
    n_blocks = k - 1 + q
    first = int(starts[0])
    stop = first + n_blocks * step
    block = columns[first:min(stop, len(columns))]
    if stop > len(columns):
        block = np.concatenate([block, np.zeros((stop - len(columns), columns.shape[1]))])
    kernel = np.zeros(q * step)
    kernel[:width] = weights
    n_col = columns.shape[1]
    # (q, step) @ (step, n_blocks·n_col): parts[j, b, c] = Σ_σ kernel[j·step + σ]·data[b·step + σ, c]
    by_phase = np.ascontiguousarray(block.reshape(n_blocks, step, n_col).transpose(1, 0, 2)).reshape(step, -1)
    parts = (kernel.reshape(q, step) @ by_phase).reshape(q, n_blocks, n_col)
    out = parts[0, :k].copy()
    for j in range(1, q):
        out += parts[j, j:j + k]
    return out


def _whitener(weights: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of Σ_ij = Σ_l w_l w_{l + c_j − c_i} (covariance of b under unit white noise)."""
    width = len(weights)
    auto = np.correlate(weights, weights, mode='full')           # lag −(width−1) .. (width−1)
    lags = centres[None, :] - centres[:, None]
    sigma = np.where(np.abs(lags) < width, auto[np.clip(lags + width - 1, 0, 2 * width - 2)], 0.0)
    sigma[np.diag_indices_from(sigma)] *= 1.0 + 1e-10
    return linalg.cholesky(sigma, lower=True, check_finite=False)


# ----------------------------------------------------------------------------------------------- regression
def _regress(a: np.ndarray, b: np.ndarray, keep: np.ndarray, threshold, ridge: float, alpha: float,
             noise_gram=None, noise_rhs=None, exhaustive: int = 4, greedy: bool = True):
    """Return (w in normalised coordinates, λ used, column scales, b scale, AᵀA, Aᵀb).

    Thresholding runs on the ridge-regularised solutions (the ridge damps cancelling pairs of nearly collinear
    terms, which would otherwise both look large); the selected terms are then refitted without ridge
    (only a 1e-12 safeguard), so the ridge does not bias the reported coefficients.
    """
    ata = a.T @ a
    atb = a.T @ b
    col = np.sqrt(np.diag(ata))
    usable = col > 0
    col = np.where(usable, col, 1.0)
    bnorm = float(np.sqrt(b @ b)) or 1.0
    gram = ata / np.outer(col, col)
    rhs = atb / (col * bnorm)
    if noise_gram is not None:
        gram = gram - noise_gram / np.outer(col, col)
        rhs = rhs - noise_rhs / (col * bnorm)
    keep = keep & usable
    if threshold is None:
        grid, backward = np.zeros(0), False
    elif isinstance(threshold, str):
        if threshold != 'auto':
            raise AeropendError(f'threshold must be in (0, 1], "auto" or None, got {threshold!r}')
        grid, backward = THRESHOLD_GRID, greedy
    else:
        lam = float(threshold)
        if not 0 < lam <= 1:
            raise AeropendError(f'threshold must be in (0, 1], "auto" or None, got {threshold!r}')
        grid, backward = np.array([lam]), False
    w, lam = _select(np.ascontiguousarray(gram), np.ascontiguousarray(rhs), keep, usable, float(ridge),
                     float(alpha), np.asarray(grid, float), backward, int(exhaustive if backward else 0))
    return w, (0.0 if threshold is None else float(lam)), col, bnorm, ata, atb


@numba.njit(cache=True, nogil=True)
def _solve_subset(gram, rhs, support, ridge):
    """Least squares restricted to the support (normal equations with a relative ridge), zeros elsewhere.

    Small dense systems (at most a few tens of terms), written out to avoid per-call LAPACK overhead: Cholesky
    when every pivot exceeds 1e-8 of the largest diagonal entry, otherwise Gaussian elimination with partial
    pivoting, where a numerically zero pivot drops that direction (minimum-norm-like).
    """
    n = support.size
    idx = np.empty(n, np.int64)
    k = 0
    for i in range(n):
        if support[i]:
            idx[k] = i
            k += 1
    w = np.zeros(n)
    if k == 0:
        return w
    a = np.empty((k, k + 1))
    scale = 0.0
    for i in range(k):
        for j in range(k):
            a[i, j] = gram[idx[i], idx[j]]
        a[i, i] += ridge
        a[i, k] = rhs[idx[i]]
        scale = max(scale, abs(a[i, i]))
    tiny = 1e-14 * max(scale, 1e-300)
    # Cholesky first (half the work); any pivot below 1e-8·scale (nearly singular or indefinite) falls back to
    # Gaussian elimination with partial pivoting below.
    low = np.zeros((k, k))
    y = np.zeros(k)
    ok = True
    for c in range(k):
        acc = a[c, c]
        for e in range(c):
            acc -= low[c, e] * low[c, e]
        if acc <= 1e-8 * scale:
            ok = False
            break
        d = np.sqrt(acc)
        low[c, c] = d
        for r in range(c + 1, k):
            v = a[r, c]
            for e in range(c):
                v -= low[r, e] * low[c, e]
            low[r, c] = v / d
        v = a[c, k]
        for e in range(c):
            v -= low[c, e] * y[e]
        y[c] = v / d
    if ok:
        for c in range(k - 1, -1, -1):
            v = y[c]
            for e in range(c + 1, k):
                v -= low[e, c] * y[e]
            y[c] = v / low[c, c]
        for i in range(k):
            w[idx[i]] = y[i]
        return w
    for c in range(k):
        p = c
        for r in range(c + 1, k):
            if abs(a[r, c]) > abs(a[p, c]):
                p = r
        if p != c:
            for j in range(c, k + 1):
                a[c, j], a[p, j] = a[p, j], a[c, j]
        if abs(a[c, c]) <= tiny:
            a[c, c] = 0.0
            continue
        for r in range(c + 1, k):
            f = a[r, c] / a[c, c]
            if f != 0.0:
                for j in range(c, k + 1):
                    a[r, j] -= f * a[c, j]
    sol = np.zeros(k)
    for c in range(k - 1, -1, -1):
        if a[c, c] == 0.0:
            continue
        acc = a[c, k]
        for j in range(c + 1, k):
            acc -= a[c, j] * sol[j]
        sol[c] = acc / a[c, c]
    for i in range(k):
        w[idx[i]] = sol[i]
    return w


@numba.njit(cache=True, nogil=True)
def _best_single_change(gram, rhs, support, candidates, state, ridge, gwls, c0, denom, alpha, n_terms):
    """Set each candidate term of `support` to `state` in turn (the rest unchanged), refit, score with
    :func:`_loss`; returns (loss, index, weights) of the best change, index -1 without candidates.
    `support` is restored before returning."""
    best_loss = np.inf
    best_j = -1
    best_w = np.zeros(support.size)
    for j in range(support.size):
        if not candidates[j]:
            continue
        support[j] = state
        w = _solve_subset(gram, rhs, support, ridge)
        support[j] = not state
        value = _loss(gram, w, gwls, c0, denom, alpha, n_terms)
        if value < best_loss:
            best_loss, best_j, best_w = value, j, w
    return best_loss, best_j, best_w


@numba.njit(cache=True, nogil=True)
def _loss(gram, w, gwls, c0, denom, alpha, n_terms):
    """L = 2α‖G(w − w_LS)‖/‖G w_LS‖ + 2(1 − α)·nnz(w)/J with the normalised Gram matrix, in O(nnz²):
    ‖G(w − w_LS)‖² = wᵀGw − 2 wᵀ(G w_LS) + w_LSᵀ G w_LS, with gwls = G w_LS and c0 = w_LSᵀ G w_LS."""
    n = w.size
    nz = np.empty(n, np.int64)
    k = 0
    for i in range(n):
        if w[i] != 0.0:
            nz[k] = i
            k += 1
    acc2 = c0
    for a in range(k):
        i = nz[a]
        row = 0.0
        for b in range(k):
            row += gram[i, nz[b]] * w[nz[b]]
        acc2 += w[i] * (row - 2.0 * gwls[i])
    return 2.0 * alpha * np.sqrt(max(acc2, 0.0)) / denom + 2.0 * (1.0 - alpha) * k / n_terms


@numba.njit(cache=True, nogil=True)
def _exhaustive(gram, rhs, gwls, c0, denom, alpha, n_terms, base, free, max_size, best_loss, ridge):
    """Best support (by the loss) among ``base`` plus every set of 1..max_size terms of ``free``.

    Depth-first over the combinations in lexicographic order with a Cholesky factor of the support's normal
    matrix extended by one row per added term, so each support costs O(k²) instead of a fresh O(k³) solve:
    with z = L⁻¹rhs_S and y = L⁻¹(Gw_LS)_S the loss numerator is c0 + ‖z‖² − 2 zᵀy (same value as
    :func:`_loss` on the subset solution). Supports whose factor breaks down (numerically collinear terms) are
    scored with :func:`_solve_subset`, as before. A size is not entered once its sparsity penalty alone
    reaches the best loss. Returns the best support (bool mask), or an empty array when none beats best_loss.
    """
    n = gram.shape[0]
    nb = 0
    for i in range(n):
        if base[i]:
            nb += 1
    kmax = nb + max_size
    idx = np.empty(kmax, np.int64)
    lmat = np.zeros((kmax, kmax))
    z = np.zeros(kmax)
    y = np.zeros(kmax)
    scale = 0.0
    for i in range(n):
        scale = max(scale, abs(gram[i, i]))
    tiny = 1e-13 * max(scale, 1e-300)
    penalty = 2.0 * (1.0 - alpha) / n_terms
    best = best_loss
    best_combo = np.empty(0, np.int64)
    # factor of the base (kept terms); a singular base falls back to full solves everywhere
    k = 0
    broken = False
    for i in range(n):
        if base[i]:
            idx[k] = i
            k += 1
    for a in range(nb):
        acc = gram[idx[a], idx[a]] + ridge
        for c in range(a):
            acc -= lmat[a, c] * lmat[a, c]
        if acc <= tiny:
            broken = True
            break
        lmat[a, a] = np.sqrt(acc)
        for r in range(a + 1, nb):
            v = gram[idx[r], idx[a]]
            for c in range(a):
                v -= lmat[r, c] * lmat[a, c]
            lmat[r, a] = v / lmat[a, a]
    if not broken:
        for a in range(nb):
            zr = rhs[idx[a]]
            yr = gwls[idx[a]]
            for c in range(a):
                zr -= lmat[a, c] * z[c]
                yr -= lmat[a, c] * y[c]
            z[a] = zr / lmat[a, a]
            y[a] = yr / lmat[a, a]
    nf = free.size
    combo = np.zeros(max_size, np.int64)
    # ok[d]: the factor of base + combo[:d] is valid (rows 0..nb+d-1)
    ok = np.zeros(max_size + 1, np.bool_)
    ok[0] = not broken
    sz = np.zeros(max_size + 1)   # running ‖z‖² − 2 zᵀy
    for a in range(nb):
        sz[0] += z[a] * z[a] - 2.0 * z[a] * y[a]
    placed = np.zeros(max_size, np.bool_)
    depth = 0            # position being varied: base + combo[:depth] is fixed
    combo[0] = -1
    support = base.copy()
    while True:
        if placed[depth]:
            support[free[combo[depth]]] = False
            placed[depth] = False
        nxt = combo[depth] + 1
        if nxt >= nf or penalty * (nb + depth + 1) >= best - 1e-12:
            if depth == 0:
                break
            depth -= 1
            continue
        combo[depth] = nxt
        j = free[nxt]
        support[j] = True
        placed[depth] = True
        row = nb + depth
        idx[row] = j
        value = np.inf
        ok[depth + 1] = False
        if ok[depth]:
            for c in range(row):
                v = gram[idx[c], j]
                for e in range(c):
                    v -= lmat[row, e] * lmat[c, e]
                lmat[row, c] = v / lmat[c, c]
            acc = gram[j, j] + ridge
            for c in range(row):
                acc -= lmat[row, c] * lmat[row, c]
            if acc > tiny:
                d = np.sqrt(acc)
                lmat[row, row] = d
                zr = rhs[j]
                yr = gwls[j]
                for c in range(row):
                    zr -= lmat[row, c] * z[c]
                    yr -= lmat[row, c] * y[c]
                z[row] = zr / d
                y[row] = yr / d
                sz[depth + 1] = sz[depth] + z[row] * z[row] - 2.0 * z[row] * y[row]
                ok[depth + 1] = True
                value = 2.0 * alpha * np.sqrt(max(c0 + sz[depth + 1], 0.0)) / denom + penalty * (row + 1)
        if not ok[depth + 1]:
            w = _solve_subset(gram, rhs, support, ridge)
            value = _loss(gram, w, gwls, c0, denom, alpha, n_terms)
        if value < best - 1e-12:
            best = value
            best_combo = combo[:depth + 1].copy()
        if depth + 1 < max_size and nxt + 1 < nf:
            depth += 1
            combo[depth] = nxt
    if best_combo.size == 0:
        return np.zeros(0, np.bool_)
    out = base.copy()
    for i in range(best_combo.size):
        out[free[best_combo[i]]] = True
    return out


@numba.njit(cache=True, nogil=True)
def _memo_solve(keys, vals, counts, slot, gram, rhs, support, ridge):
    """:func:`_solve_subset` through a small ring buffer of recent (support, solution) pairs."""
    for i in range(counts[slot]):
        if np.array_equal(keys[i], support):
            return vals[i].copy()
    w = _solve_subset(gram, rhs, support, ridge)
    i = counts[slot + 1]
    keys[i] = support
    vals[i] = w
    counts[slot + 1] = (i + 1) % keys.shape[0]
    counts[slot] = min(counts[slot] + 1, keys.shape[0])
    return w


@numba.njit(cache=True, nogil=True)
def _select(gram, rhs, keep, usable, ridge, alpha, grid, backward, exhaustive):
    """MSTLS over the λ grid (+ optional backward elimination), scored by the loss; returns (w, λ).

    Normalised coordinates: |w_i| is the relative contribution of term i. λ = NaN when the backward path won;
    with an empty grid and no backward path, the plain (near ridge-free) least squares on all usable terms.
    """
    final_ridge = 1e-12
    w_ls = _solve_subset(gram, rhs, usable, final_ridge)
    if grid.size == 0 and not backward:
        return w_ls, 0.0
    gwls = gram @ w_ls
    c0 = w_ls @ gwls
    denom = np.sqrt(max(c0, 0.0))
    if denom == 0.0:
        denom = 1.0
    n_terms = max(np.count_nonzero(usable), 1)
    best_loss = np.inf
    best_w = w_ls
    best_lam = 0.0
    w_full = _solve_subset(gram, rhs, usable, ridge)
    # Neighbouring λ mostly visit the same supports: remember recent solves (ridge ones and final ones).
    cap = 64
    n = usable.size
    ridge_keys = np.zeros((cap, n), np.bool_)
    ridge_vals = np.zeros((cap, n))
    final_keys = np.zeros((cap, n), np.bool_)
    final_vals = np.zeros((cap, n))
    counts = np.zeros(4, np.int64)          # ridge count, ridge next slot, final count, final next slot
    support = np.empty(n, np.bool_)
    new = np.empty(n, np.bool_)
    nonzero = np.empty(n, np.bool_)
    for lam in grid:
        upper = 1.0 / lam
        support[:] = usable
        w = w_full
        for _ in range(n + 1):
            # new = support & ((λ <= |w| <= 1/λ) | keep), without temporaries
            changed = False
            for i in range(n):
                size = abs(w[i])
                inside = support[i] and ((size >= lam and size <= upper) or keep[i])
                new[i] = inside
                if inside != support[i]:
                    changed = True
            if not changed:
                break
            support[:] = new
            w = _memo_solve(ridge_keys, ridge_vals, counts, 0, gram, rhs, support, ridge)
        for i in range(n):
            nonzero[i] = w[i] != 0.0
        # a support scored before cannot beat the best loss (which only decreases): skip it
        seen = False
        for i in range(counts[2]):
            if np.array_equal(final_keys[i], nonzero):
                seen = True
                break
        if seen:
            continue
        w = _memo_solve(final_keys, final_vals, counts, 2, gram, rhs, nonzero, final_ridge)
        value = _loss(gram, w, gwls, c0, denom, alpha, n_terms)
        if value < best_loss - 1e-12:
            best_loss, best_w, best_lam = value, w, lam
    if backward:
        # Greedy backward elimination scored by the same loss: with nearly collinear candidates (sin y, y, y²,
        # cos y, 1) the thresholding path can drop a true term early and never visit the true support; removing
        # one term at a time (the one whose removal changes the fit least) does visit it.
        support = usable.copy()
        while np.count_nonzero(support) > np.count_nonzero(keep):
            trial_loss, trial_j, trial_w = _best_single_change(gram, rhs, support, support & ~keep, False, final_ridge,
                                                               gwls, c0, denom, alpha, n_terms)
            if trial_j < 0:
                break
            support[trial_j] = False
            if trial_loss < best_loss - 1e-12:
                best_loss, best_w, best_lam = trial_loss, trial_w, np.nan
        # Greedy forward selection, same loss: adds the strongest single explanations first (sin y before its
        # polynomial look-alikes), which the backward path can miss when a whole look-alike group is present.
        support = keep & usable
        while np.count_nonzero(support) < np.count_nonzero(usable):
            # the sparsity penalty only grows along this path: once it alone reaches the best loss, stop
            if 2.0 * (1.0 - alpha) * (np.count_nonzero(support) + 1) / n_terms >= best_loss - 1e-12:
                break
            trial_loss, trial_j, trial_w = _best_single_change(gram, rhs, support, usable & ~support, True, final_ridge,
                                                               gwls, c0, denom, alpha, n_terms)
            if trial_j < 0:
                break
            support[trial_j] = True
            if trial_loss < best_loss - 1e-12:
                best_loss, best_w, best_lam = trial_loss, trial_w, np.nan
        # Exhaustive search over small supports (keep + up to ``exhaustive`` free terms): greedy paths fail when
        # the true terms only explain the data together (thrust and gravity nearly cancel at equilibrium) while a
        # polynomial look-alike group of sin y explains part of it.
        free = np.flatnonzero(usable & ~keep)
        if exhaustive > 0 and free.size:
            support = _exhaustive(gram, rhs, gwls, c0, denom, alpha, n_terms, keep & usable, free,
                                  min(exhaustive, free.size), best_loss, final_ridge)
            if support.size:
                w = _solve_subset(gram, rhs, support, final_ridge)
                value = _loss(gram, w, gwls, c0, denom, alpha, n_terms)
                if value < best_loss - 1e-12:
                    best_loss, best_w, best_lam = value, w, np.nan
        # Local search from the best support: single additions or removals while they lower the loss.
        support = best_w != 0.0
        for _ in range(2 * usable.size):
            trial_loss = best_loss
            trial_j = -1
            trial_w = best_w
            for j in range(support.size):
                if not usable[j] or (keep[j] and support[j]):
                    continue
                support[j] = not support[j]
                w = _solve_subset(gram, rhs, support, final_ridge)
                support[j] = not support[j]
                value = _loss(gram, w, gwls, c0, denom, alpha, n_terms)
                if value < trial_loss - 1e-12:
                    trial_loss, trial_j, trial_w = value, j, w
            if trial_j < 0:
                break
            support[trial_j] = not support[trial_j]
            best_loss, best_w, best_lam = trial_loss, trial_w, np.nan
    return best_w, best_lam


# ------------------------------------------------------------------------------------------------- main API
_BLAS: list = []


def _single_threaded_blas(func):
    """Run ``func`` with BLAS limited to one thread: the products here are small (tens of terms × a few hundred
    rows), and on a 2-core machine a multithreaded BLAS spends more time synchronising than computing (44 ms vs
    65-130 ms per 4-equation window). The controller is created on first use (after NumPy/SciPy loaded BLAS)."""
    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        if not _BLAS:
            _BLAS.append(ThreadpoolController())
        with _BLAS[0].limit(limits=1, user_api='blas'):
            return func(*args, **kwargs)
    return wrapper


@_single_threaded_blas
def fit_weak_sindy(time, signals, equations: Sequence[Equation], *,
                   half_width: int | Mapping[str, int] | None = None,
                   stride: int | None = None,
                   threshold: float | str | None = 'auto',
                   ridge: float = 1e-6,
                   alpha: float = 0.8,
                   decay_tolerance: float = 1e-10,
                   spectral_width: float = 1.0,
                   min_half_width: int = 8,
                   max_half_width: int = 1000,
                   exclude=None,
                   noise_std: Mapping[str, float] | None = None,
                   irls_iterations: int = 1,
                   bias_correction: bool = True,
                   exhaustive_terms: int = 4,
                   process_noise: bool = True,
                   significance: float | None = None) -> WeakSindyResult:
    """Identify sparse ODEs from uniformly sampled data with weak SINDy.

    Parameters
    ----------
    time : ndarray, shape (n_samples,), s — or a sequence of such arrays, one per segment/experiment.
    signals : mapping name -> ndarray, shape (n_samples,) — or a sequence of mappings, one per segment.
        SI units; every name a term or target uses must be present. Segments are fitted together.
    equations : sequence of Equation
        What to identify (targets, derivative orders, candidate terms).
    half_width : int or mapping target -> int, optional
        Test-function half-width m in samples (support 2m+1). Default (or targets missing from the mapping):
        chosen per equation from the target signal's spectrum (:func:`choose_support`, median over segments).
    stride : int, optional
        Samples between test-function centres; default max(1, m // 4).
    threshold : 'auto', float in (0, 1] or None
        MSTLS λ: 'auto' searches the grid 10^[-4..0]; a number fixes it; None gives the plain (ridge) GLS fit
        of all candidates (no sparsification).
    ridge : float
        Tikhonov term added to the normalised (unit-diagonal) Gram matrix.
    alpha : float
        Weight of accuracy vs sparsity in the λ loss.
    decay_tolerance, spectral_width, min_half_width, max_half_width
        Test-function selection (see :func:`choose_support`).
    exclude : ndarray of bool, shape (n_samples,), or one per segment, optional
        Samples no test-function support may cover (e.g. transients the model does not describe).
    noise_std : mapping signal -> float, optional
        Measurement-noise standard deviation per signal (signal units), for the residual covariance. Signals not
        given are estimated from the data (:func:`estimate_noise_std`); give 0 for an exactly known signal.
    irls_iterations : int
        Reweighting passes: after a first fit with Σ ∝ V^(k)V^(k)ᵀ (noise on the target only), Σ is rebuilt from
        the linearised response of the whole residual to the noise on every signal (target, derivative terms,
        nonlinear terms) and the fit repeated. This removes most of the errors-in-variables bias that a
        target-only whitening causes (it amplifies low-frequency noise in the regressors). One pass (default)
        is enough: a second one changed no support and no error by more than noise (full state: Kq rms error
        0.14 % at 50 dB, 1.48 % -> 1.37 % at 30 dB; live rig at 40 dB: worst parameter 2.1 % -> 1.5 %, with one
        pass; 4 to 8 records each) and costs a third more time.
    bias_correction : bool
        Subtract the expected noise contributions from the normal equations (bias-compensated least squares,
        :func:`_noise_gram`), using the per-signal noise levels; removes the errors-in-variables attenuation.
        Applied in the reweighted passes (so it needs ``irls_iterations >= 1``).
    process_noise : bool
        In the reweighted passes, add q·V Vᵀ to the residual covariance, q ≥ 0 estimated from the previous
        pass's residual (method of moments): unmodelled forces act like noise in the equation itself. With
        q = 0 (an exact model) nothing changes; with a missing effect (e.g. 3 rad/s² of pivot friction) the
        measurement-only whitening would otherwise wipe out the fit (all coefficients -99 %).
    exhaustive_terms : int
        With ``threshold='auto'``, every support of up to this many free terms (besides ``keep``) is scored with
        the loss as well, in the last pass (sum of C(J, k), k <= 4: 3,214 supports for J = 17, depth-first with
        one Cholesky row per added term).
    significance : float, optional
        With thresholding on, drop selected free terms whose |w|/σ_w is below the two-sided normal critical value
        at family-wise level ``significance`` over the J free candidates (Bonferroni: z = Φ⁻¹(1 − s/(2J)),
        2.99 for s = 0.05, J = 18), weakest first, refitting after each removal. None (default) skips the test.

    Returns
    -------
    WeakSindyResult

    Raises
    ------
    InsufficientDataError
        NaN/inf in the data, a segment shorter than the test-function support, a constant target, or fewer
        usable test functions than candidate terms.
    AeropendError
        Missing signals, non-uniform sampling, bad options.
    """
    equations = list(equations)
    if not equations:
        raise AeropendError('no equations to identify')
    segments = _as_segments(time, signals)
    if exclude is None:
        excludes = [None] * len(segments)
    elif isinstance(exclude, np.ndarray) and exclude.ndim == 1 and len(segments) == 1:
        excludes = [exclude]
    else:
        excludes = list(exclude)
    dt = _median(np.diff(segments[0][0]))
    for t, _ in segments[1:]:
        if abs(_median(np.diff(t)) - dt) > 1e-3 * dt:
            raise AeropendError('segments have different sample times; resample them to one rate first')
    for eq in equations:
        needed = {eq.target, *(v for t in eq.terms for v in t.variables)}
        for i, (_, s) in enumerate(segments):
            missing = needed - set(s)
            if missing:
                raise AeropendError(f'equation {eq.name} needs signal(s) {sorted(missing)}, not in the data '
                                    f'(have {sorted(s)})')

    fits = []
    cache: dict = {}   # library columns, Jacobians and noise levels shared by the equations (terms keyed by name)
    for eq in equations:
        targets = [s[eq.target] for _, s in segments]
        scale = max(float(np.max(np.abs(x))) for x in targets) or 1.0
        if all(np.ptp(x) <= 1e-12 * scale for x in targets):
            raise InsufficientDataError(f'{eq.target!r} is constant: nothing to identify for {eq.name} '
                                        '(no excitation)')
        # --- test functions
        if half_width is None or (isinstance(half_width, Mapping) and eq.target not in half_width):
            choices = [choose_support(x, eq.order, decay_tolerance, spectral_width, min_half_width,
                                      max_half_width) for x in targets]
            m = int(statistics.median([c[0] for c in choices]))
        else:
            m = int(half_width[eq.target] if isinstance(half_width, Mapping) else half_width)
            if m < 2:
                raise AeropendError(f'half_width must be >= 2 samples, got {m}')
        p = max(test_function_power(m, decay_tolerance), eq.order + 2)
        s_ = int(stride or max(1, m // 4))
        max_order = max([eq.order] + [t.derivative_order for t in eq.terms])
        weights = kernel_derivatives(m, p, dt, max_order)
        hold_weights = kernel_hold(m, p, dt)
        # kernel types of the noise model: 0 = lhs (-1)^k φ^(k), then one per term kernel ((-1)^d φ^(d) or hold)
        kernel_ids = [('lhs',)]
        kernel_list = [(-1) ** eq.order * weights[eq.order]]
        type_of = []
        for t_ in eq.terms:
            kid = ('hold',) if t_.hold else ('d', t_.derivative_order)
            if kid not in kernel_ids:
                kernel_ids.append(kid)
                order_ = t_.derivative_order
                kernel_list.append(hold_weights if t_.hold else (-1) ** order_ * weights[order_])
            type_of.append(kernel_ids.index(kid))
        width = 2 * m + 1
        short = [i for i, (t, _) in enumerate(segments) if len(t) < width]
        if short:
            i = short[0]
            raise InsufficientDataError(
                f'{f"segment {i}: " if len(segments) > 1 else ""}window of {len(segments[i][0])} samples '
                f'({len(segments[i][0]) * dt:.3g} s) is shorter than the test-function support for {eq.name}: '
                f'2m+1 = {width} samples ({width * dt:.3g} s); record longer windows')
        systems = []
        for si, ((t, s), excl) in enumerate(zip(segments, excludes)):
            centres = _centres(len(t), m, s_)
            if excl is not None:
                excl = np.asarray(excl, bool)
                hits = np.concatenate([[0], np.cumsum(excl)])
                covered = hits[centres + m + 1] - hits[centres - m]
                centres = centres[covered == 0]
                if centres.size == 0:
                    continue
            starts = centres - m
            gb = np.empty((len(starts), len(eq.terms) + 1), order='F')   # [G b], Fortran order for LAPACK
            g = gb[:, :-1]
            for d in sorted({t_.derivative_order for t_ in eq.terms}):
                for held in (False, True):
                    idx = [j for j, t_ in enumerate(eq.terms) if t_.derivative_order == d and t_.hold == held]
                    if idx:
                        group = tuple((eq.terms[j].name, eq.terms[j].variables) for j in idx)
                        members = [eq.terms[j] for j in idx]
                        theta = _cached(cache, ('thetas', si, group), lambda members=members, s=s, si=si:
                                        np.column_stack([_cached(cache, ('theta', si, term.name, term.variables),
                                                                 lambda term=term, s=s: term.evaluate(s))
                                                         for term in members]))
                        kern = hold_weights if held else weights[d]
                        g[:, idx] = (-1) ** d * _weak_rows(theta, kern, starts)
            gb[:, -1] = (-1) ** eq.order * _weak_rows(s[eq.target][:, None], weights[eq.order], starts)[:, 0]
            b = gb[:, -1]
            model = _noise_model(eq, s, starts, kernel_list, type_of, noise_std, cache, si, width, weights[0])
            systems.append((g, b, model, gb))
        n_rows = sum(len(sys_[1]) for sys_ in systems)
        if n_rows <= len(eq.terms):
            raise InsufficientDataError(
                f'{eq.name}: only {n_rows} usable test functions (support {width} samples) for {len(eq.terms)} '
                'candidate terms; record longer windows or use fewer terms')
        keep = np.array([t_.name in eq.keep for t_ in eq.terms])
        w = None
        for pass_ in range(irls_iterations + 1):
            rows_a, rows_b = [], []
            # The first pass (target-only whitening) is not corrected: that whitening amplifies regressor noise
            # so much that the correction itself becomes unstable; it only supplies w for the full covariance.
            correct = bias_correction and w is not None
            noise_gram = np.zeros((len(eq.terms), len(eq.terms))) if correct else None
            noise_rhs = np.zeros(len(eq.terms)) if correct else None
            bands = [_measurement_band(model, w) for _, _, model, _ in systems]
            process = 0.0
            if process_noise and w is not None:
                # Method of moments: E‖b − Gw‖² = tr Σ_meas + q·tr(V Vᵀ); q > 0 when the model misses forces
                # (friction, cable...). Without it the whitening integrates the equation twice (second order)
                # and any unmodelled low-frequency force swamps the fit.
                resid = sum(float(np.sum((b - g @ w) ** 2)) for g, b, _, _ in systems)
                trace_meas = sum(float(ab[0].sum()) for ab, _ in bands)
                trace_v = sum(len(b) for _, b, _, _ in systems) * float(weights[0] @ weights[0])
                process = max(0.0, (resid - trace_meas) / trace_v)
            for (g, b, model, gb), (ab, band) in zip(systems, bands):
                if process > 0.0:
                    ab = ab + _process_band(model, band, process)
                chol = _cholesky_band(ab)
                both, info = lapack.dtbtrs(chol, gb, uplo='L')   # L⁻¹[G b], L banded (gb is not overwritten)
                if info != 0:
                    raise InsufficientDataError(f'{eq.name}: the weak-form covariance is singular (LAPACK info '
                                                f'{info}); the data cannot support this fit')
                rows_a.append(both[:, :-1])
                rows_b.append(both[:, -1])
                if correct:
                    cg, cr = _noise_gram(model, chol, len(eq.terms))
                    noise_gram += cg
                    noise_rhs += cr
            a = rows_a[0] if len(rows_a) == 1 else np.vstack(rows_a)
            bw = rows_b[0] if len(rows_b) == 1 else np.concatenate(rows_b)
            # Earlier passes only supply w for the covariance: the greedy paths and the exhaustive search run in
            # the last one (with them in the first pass too, no support and no Kq error changed beyond noise).
            last = pass_ == irls_iterations
            w_n, lam, col, bnorm, ata, atb = _regress(a, bw, keep, threshold, ridge, alpha, noise_gram, noise_rhs,
                                                      exhaustive_terms if last else 0, greedy=last)
            w = w_n * bnorm / col
        sel = np.flatnonzero(w_n)
        cov, resid_vec = _coefficient_covariance(a, bw, w, sel, col, noise_gram, ata)
        if significance is not None and threshold is not None and sel.size:
            # Significance guard (backward elimination by t-statistic): a selected free term must differ from 0
            # at the family-wise level ``significance`` over the J free candidates (Bonferroni, two-sided normal
            # critical value). The loss-based selection cannot tell a real small term from the best of J noise
            # look-alikes (|t| ~ 2.5 at 40 dB); this test can, with a level chosen before seeing any data.
            free = int(np.count_nonzero(~keep & (col > 0)))
            critical = float(special.ndtri(1.0 - significance / (2.0 * max(free, 1))))
            gram_c = ata - (noise_gram if noise_gram is not None else 0.0)
            rhs_c = atb - (noise_rhs if noise_rhs is not None else 0.0)
            while sel.size:
                tstat = np.abs(w[sel]) / np.sqrt(np.maximum(np.diag(cov), 1e-300))
                tstat[keep[sel]] = np.inf
                worst = int(np.argmin(tstat))
                if tstat[worst] >= critical:
                    break
                sel = np.delete(sel, worst)
                w = np.zeros_like(w)
                if sel.size:
                    cs = col[sel]   # column-normalised, as in the selection
                    w[sel] = linalg.solve(gram_c[np.ix_(sel, sel)] / np.outer(cs, cs), rhs_c[sel] / cs,
                                          assume_a='sym', check_finite=False) / cs
                cov, resid_vec = _coefficient_covariance(a, bw, w, sel, col, noise_gram, ata)
        names = [eq.terms[j].name for j in sel]
        fits.append(EquationFit(
            name=eq.name,
            candidates=tuple(t_.name for t_ in eq.terms),
            coefficients={nm: float(w[j]) for nm, j in zip(names, sel)},
            standard_errors={nm: float(math.sqrt(max(cov[i, i], 0.0))) for i, nm in enumerate(names)},
            covariance=cov,
            threshold=lam,
            residual=float(np.linalg.norm(resid_vec) / (np.linalg.norm(bw) or 1.0)),
            half_width=m, power=p, n_test_functions=n_rows))
    return WeakSindyResult(tuple(fits))


@numba.njit(cache=True, nogil=True)
def _pinvh(matrix):
    """Pseudo-inverse of a small symmetric matrix (eigenvalues below n·eps·max|λ| dropped, as scipy's pinvh)."""
    values, vectors = np.linalg.eigh(matrix)
    n = values.size
    largest = 0.0
    for i in range(n):
        largest = max(largest, abs(values[i]))
    cutoff = n * np.finfo(np.float64).eps * largest
    out = np.zeros((n, n))
    for k in range(n):
        if abs(values[k]) > cutoff:
            for i in range(n):
                f = vectors[i, k] / values[k]
                for j in range(n):
                    out[i, j] += f * vectors[j, k]
    return out


def _coefficient_covariance(a, bw, w, sel, col, noise_gram, ata):
    """Covariance of the selected coefficients and the whitened residual vector.

    σ̂² = ‖r‖²/(n_rows − n_kept); Cov(w) = σ̂² (G̃ᵀG̃ − C)⁻¹ (C the noise compensation when used), computed in
    column-normalised coordinates.
    """
    resid_vec = bw - a[:, sel] @ w[sel]
    dof = max(a.shape[0] - sel.size, 1)
    sigma2 = float(resid_vec @ resid_vec) / dof
    if not sel.size:
        return np.zeros((0, 0)), resid_vec
    gram_sel = ata[np.ix_(sel, sel)]
    if noise_gram is not None:
        gram_sel = gram_sel - noise_gram[np.ix_(sel, sel)]
    scale_sel = np.outer(col[sel], col[sel])
    return sigma2 * _pinvh(gram_sel / scale_sel) / scale_sel, resid_vec


def _median(values: np.ndarray) -> float:
    """np.median of a 1-D float array (same value: mean of the two middle elements for even sizes), through
    one partition and without np.median's generic-axis machinery."""
    k = values.size // 2
    if values.size % 2:
        return float(np.partition(values, k)[k])
    part = np.partition(values, (k - 1, k))
    return float((part[k - 1] + part[k]) / 2)


@numba.njit(cache=True, nogil=True)
def _third_difference_mad(x):
    """(median absolute deviation of the third difference, the third difference), as np.diff(x, 3) and
    np.median give them."""
    d1 = x[1:] - x[:-1]
    d2 = d1[1:] - d1[:-1]
    third = d2[1:] - d2[:-1]
    return np.median(np.abs(third - np.median(third))), third


def estimate_noise_std(signal: np.ndarray) -> float:
    """Robust white-noise standard deviation of a smoothly varying, densely sampled signal (signal's units).

    The third difference cancels anything smooth over four samples (variance 20σ² for white noise); the median
    absolute deviation ignores the few samples around steps. When the MAD is 0 (quantised or held signals), the
    standard deviation of the third difference is used if at least 10 % of it is non-zero (quantisation of a
    moving signal); otherwise the signal is piecewise constant (a held input) and counts as noiseless.
    """
    x = np.asarray(signal, float)
    if x.size < 8:
        return 0.0
    mad, third = _third_difference_mad(np.ascontiguousarray(x))
    if mad > 0:
        return 1.4826 * mad / math.sqrt(20.0)
    if np.count_nonzero(third) < 0.1 * third.size:
        return 0.0
    return float(np.std(third) / math.sqrt(20.0))


def _cached(cache: dict, key, make):
    value = cache.get(key)
    if value is None:
        value = cache[key] = make()
    return value


# ------------------------------------------------------------------------------------ residual covariance
# The residual b − G·w of the weak equations responds to white noise ε_v on signal v through
#     R_v = (-1)^k V^(k) [v is target] − Σ_j w_j (-1)^{d_j} V^{(d_j)} diag(∂θ_j/∂v)      (linearised about the data).
# Grouping the terms by quadrature kernel ("kernel types": the lhs kernel, (-1)^d φ^(d), the hold kernel), row r
# of R_v is Σ_a k_a(t − start_r)·c_av(t) with c_av(t) = −Σ_{j of type a} w_j ∂θ_j/∂v(t) (c = 1 for the lhs of
# the target). All test functions sit on one grid of evenly spaced starts (``stride`` apart; rows dropped by
# ``exclude`` are holes in it), so every product of two shifted kernels depends only on the row offset u:
# H_ab[u, τ] = k_a(τ)·k_b(τ − u·stride). The band of Σ = Σ_v σ_v² R_v R_vᵀ and the diagonals needed by the
# noise compensation are then windowed dot products / overlap-adds with these few kernels (small matrix
# products), never a loop over terms × rows × support.

@dataclass(frozen=True, eq=False)
class _NoiseModel:
    """Noise response of one equation on one segment (see the section comment)."""

    kernels: np.ndarray            # (T, width) signed kernels; type 0 is the lhs
    signals: tuple                 # per noisy signal: (σ, is_target, term indices (n_v,), type per column (n_v,),
                                   #                    Jacobian columns ∂θ_j/∂v, shape (n, n_v))
    first: int                     # first start of the grid (sample index)
    step: int                      # grid spacing (samples)
    rows: np.ndarray               # grid index of each used test function, shape (K,)
    n: int                         # samples in the segment
    pairs: np.ndarray              # H[a, b, u, τ] (:func:`_pair_kernels`), u = 0..grid band
    plain_pair: np.ndarray         # H[u, τ] of the plain φ (process noise)

    @property
    def contiguous(self) -> bool:
        """No holes in the grid (no excluded rows): the used rows are the grid."""
        return int(self.rows[-1]) + 1 == len(self.rows)


def _term_partial(cache, segment, term, signals, name) -> np.ndarray:
    """∂term/∂signal, cached per segment (shared by the equations that offer the term)."""
    return _cached(cache, ('jac', segment, term.name, term.variables, name),
                   lambda: term.derivative_wrt(signals, name))


def _grid(starts: np.ndarray, width: int) -> tuple[int, int, np.ndarray]:
    """(first, step, grid index) with starts = first + step·index."""
    first = int(starts[0])
    offsets = np.asarray(starts, np.int64) - first
    step = int(np.gcd.reduce(offsets[1:])) if len(starts) > 1 else width
    return first, max(step, 1), offsets // max(step, 1)


def _noise_model(eq, signals, starts, kernel_list, type_of, noise_std, cache, segment, width,
                 plain_kernel) -> _NoiseModel:
    names = {eq.target, *(v for t in eq.terms for v in t.variables)}
    out = []
    for v in sorted(names):
        x = signals[v]
        if noise_std is not None and v in noise_std:
            sigma = float(noise_std[v])
        else:
            sigma = _cached(cache, ('sigma', segment, v), lambda x=x: estimate_noise_std(x))
        if not sigma > 0:
            continue
        # columns ordered by kernel type, so each type is a contiguous slice
        members = sorted((type_of[j], j) for j, term in enumerate(eq.terms) if v in term.variables)
        idx = np.array([j for _, j in members], np.int64)
        types = np.array([a for a, _ in members], np.int64)

        def stacked(v=v, x=x, idx=idx):
            cols = [_term_partial(cache, segment, eq.terms[j], signals, v) for j in idx]
            return np.column_stack(cols) if cols else np.zeros((len(x), 0))
        key = ('jacs', segment, v, tuple((eq.terms[j].name, eq.terms[j].variables) for j in idx))
        out.append((sigma, v == eq.target, idx, types, _cached(cache, key, stacked)))
    first, step, rows = _grid(starts, width)
    grid_band = max(-(-width // step) - 1, 0)
    kernels = np.array(kernel_list)
    pairs = _cached_pair_kernels(kernels, step, grid_band)
    plain = _cached_pair_kernels(plain_kernel[None, :], step, grid_band)[0, 0]
    return _NoiseModel(kernels, tuple(out), first, step, rows, len(signals[eq.target]), pairs, plain)


def clear_caches() -> None:
    """Forget the cached quadrature and pair kernels (they depend on (m, p, Δt, stride) only; benchmarks clear
    them to time a window whose support differs from the previous one)."""
    _kernel_derivatives.cache_clear()
    _kernel_hold.cache_clear()
    _pair_kernels_by_value.cache_clear()


def _cached_pair_kernels(kernels: np.ndarray, step: int, band: int) -> np.ndarray:
    """:func:`_pair_kernels`, cached on the kernels' values (read-only result; windows of a stream share it)."""
    kernels = np.ascontiguousarray(kernels, float)
    return _pair_kernels_by_value(kernels.tobytes(), kernels.shape, int(step), int(band))


@functools.lru_cache(maxsize=32)
def _pair_kernels_by_value(data: bytes, shape: tuple, step: int, band: int) -> np.ndarray:
    out = _pair_kernels(np.frombuffer(data).reshape(shape), step, band)
    out.setflags(write=False)
    return out


def _pair_kernels(kernels: np.ndarray, step: int, band: int) -> np.ndarray:
    """H[a, b, u, τ] = k_a(τ)·k_b(τ − u·step), u = 0..band (zero where τ − u·step is off the support)."""
    t, width = kernels.shape
    out = np.zeros((t, t, band + 1, width))
    for u in range(band + 1):
        shift = u * step
        if shift < width:
            out[:, :, u, shift:] = kernels[:, None, shift:] * kernels[None, :, :width - shift]
    return out


def _window_dots(columns: np.ndarray, kernels: np.ndarray, first: int, step: int, count: int) -> np.ndarray:
    """out[r, k] = Σ_c Σ_τ kernels[c, k, τ]·columns[c, first + r·step + τ], shape (count, nk).

    Blocked like :func:`_weak_rows`: with the data in blocks of ``step`` samples and each kernel cut into q
    pieces, one product (blocks × channel·phase) @ (channel·phase × piece·k), then q shifted sums.
    """
    c, nk, width = kernels.shape
    q = -(-width // step)
    n_blocks = count - 1 + q
    stop = first + n_blocks * step
    data = columns[:, first:min(stop, columns.shape[1])]
    if stop > columns.shape[1]:
        data = np.concatenate([data, np.zeros((c, stop - columns.shape[1]))], axis=1)
    blocks = np.ascontiguousarray(data.reshape(c, n_blocks, step).transpose(1, 0, 2)).reshape(n_blocks, c * step)
    padded = np.zeros((c, nk, q * step))
    padded[:, :, :width] = kernels
    pieces = padded.reshape(c, nk, q, step).transpose(0, 3, 2, 1).reshape(c * step, q * nk)
    parts = (blocks @ pieces).reshape(n_blocks, q, nk)
    out = parts[:count, 0].copy()
    for j in range(1, q):
        out += parts[j:j + count, j]
    return out


def _banded_overlap(zgrid: np.ndarray, kernels: np.ndarray, first: int, step: int, n: int) -> np.ndarray:
    """q_p(t) = Σ_r Σ_u zgrid[r, u]·kernels[p, u, t − first − r·step], shape (P, n).

    In blocks of ``step`` samples (t = first + b·step + σ, r = b − j): q_p[b, σ] = Σ_j Σ_u zgrid[b − j, u]·
    kernels[p, u, j·step + σ], one matrix product of the shifted copies of zgrid with the kernel pieces.
    """
    full, n_offsets = zgrid.shape
    n_pairs, _, width = kernels.shape
    q = -(-width // step)
    n_blocks = full - 1 + q
    shifted = np.zeros((n_blocks, q, n_offsets))
    for j in range(q):
        shifted[j:j + full, j] = zgrid
    padded = np.zeros((n_pairs, n_offsets, q * step))
    padded[:, :, :width] = kernels
    pieces = padded.reshape(n_pairs, n_offsets, q, step).transpose(2, 1, 0, 3).reshape(q * n_offsets, n_pairs * step)
    blocks = (shifted.reshape(n_blocks, q * n_offsets) @ pieces).reshape(n_blocks, n_pairs, step)
    flat = blocks.transpose(1, 0, 2).reshape(n_pairs, n_blocks * step)
    out = np.zeros((n_pairs, n))
    m = min(flat.shape[1], n - first)
    out[:, first:first + m] = flat[:, :m]
    return out


def _to_used_rows(model: _NoiseModel, grid_ab: np.ndarray):
    """Band on the grid (grid_ab[u, g] = Σ[g, g+u]) -> band on the used rows (LAPACK lower storage), bandwidth."""
    rows = model.rows
    if model.contiguous:
        return grid_ab, grid_ab.shape[0] - 1
    grid_band = grid_ab.shape[0] - 1
    k = len(rows)
    reach = np.searchsorted(rows, rows + grid_band, side='right') - np.arange(k) - 1
    band = int(max(int(reach.max()), 0))
    ab = np.zeros((band + 1, k))
    for u in range(band + 1):
        i = np.arange(k - u)
        offset = rows[i + u] - rows[i]
        ok = offset <= grid_band
        ab[u, i[ok]] = grid_ab[offset[ok], rows[i[ok]]]
    return ab, band


def _coefficient_functions(model: _NoiseModel, w) -> list[tuple[float, dict]]:
    """Per noisy signal: (σ², {type a: c_a(t)}) with the non-zero kernel-type coefficient functions (section
    comment); the lhs type 0 is the constant 1.0 for the target."""
    out = []
    for sigma, is_target, idx, types, jac in model.signals:
        c = {0: 1.0} if is_target else {}
        if w is not None and idx.size:
            wv = w[idx]
            for a in set(types[wv != 0.0].tolist()):
                lo, hi = np.searchsorted(types, a), np.searchsorted(types, a, side='right')   # columns by type
                c[a] = -(jac[:, lo:hi] @ wv[lo:hi])
        if c:
            out.append((sigma * sigma, c))
    return out


def _measurement_band(model: _NoiseModel, w):
    """Band (LAPACK lower storage, shape (band+1, K)) of the residual covariance Σ = Σ_v σ_v² R_v R_vᵀ over the
    used rows, and its bandwidth.

    Before any coefficient is known (``w is None``) only the target's noise counts: Σ ∝ V^(k) V^(k)ᵀ (unit
    variance when the target is estimated noiseless).
    """
    pairs = model.pairs
    full = int(model.rows[-1]) + 1
    funcs = _coefficient_functions(model, w)
    if not funcs:
        funcs = [(1.0, {0: 1.0})]
    # C_ab(t) = Σ_v σ_v² c_av(t)·c_bv(t) (= C_ba), with kernel H_ab + H_ba for a < b
    products: dict = {}
    for var, c in funcs:
        keys = sorted(c)
        for i, a in enumerate(keys):
            for b in keys[i:]:
                products[(a, b)] = products.get((a, b), 0.0) + var * c[a] * c[b]
    constant = sum(float(v) * (pairs[a, b] + (pairs[b, a] if a != b else 0.0)).sum(axis=1)
                   for (a, b), v in products.items() if np.ndim(v) == 0)
    varying = [(ab, v) for ab, v in products.items() if np.ndim(v)]
    grid_ab = np.zeros((pairs.shape[2], full)) + (constant[:, None] if np.ndim(constant) else 0.0)
    if varying:
        cols = np.array([v for _, v in varying])
        kerns = np.array([pairs[a, b] + (pairs[b, a] if a != b else 0.0) for (a, b), _ in varying])
        grid_ab += _window_dots(cols, kerns, model.first, model.step, full).T
    return _to_used_rows(model, grid_ab)


def _process_band(model: _NoiseModel, band: int, variance: float) -> np.ndarray:
    """Band of variance·V Vᵀ (white 'process noise' in the equation, V the plain φ quadrature) on the used rows."""
    per_offset = variance * model.plain_pair.sum(axis=1)   # Σ_τ φ(τ) φ(τ − u·step), u = 0..grid band
    full = int(model.rows[-1]) + 1
    ab, _ = _to_used_rows(model, np.repeat(per_offset[:, None], full, axis=1))
    return ab


def _noise_gram(model: _NoiseModel, chol, n_terms):
    """Expected noise contributions (C, c) to the whitened normal equations G̃ᵀG̃ and G̃ᵀb̃.

    With noise on the signals, G̃ = G̃₀ + Ñ and b̃ = b̃₀ + ñ, so E[G̃ᵀG̃] = G̃₀ᵀG̃₀ + C and E[G̃ᵀb̃] = G̃₀ᵀb̃₀ + c:
    least squares on noisy regressors is biased (errors in variables; collinear libraries make it large, e.g.
    −10 % on Kq at 30 dB). ``C_jk = Σ_v σ_v² Σ_t J_jv(t) J_kv(t) q_ab(t)`` with
    ``q_ab(t) = Σ_{r,s} (Σ⁻¹)[r,s] k_a(t − start_r) k_b(t − start_s)`` (a, b the kernel types of j, k). Only
    the band of Σ⁻¹ is needed (two test functions covering the same sample are within the band): the Takahashi
    recurrence on the banded Cholesky factor, then one product of (band of Σ⁻¹) with the pair kernels
    (:func:`_banded_overlap`).
    Subtracting C and c gives the bias-compensated least squares.
    """
    if not any(idx.size for _, _, idx, _, _ in model.signals):
        return np.zeros((n_terms, n_terms)), np.zeros(n_terms)
    zb = _band_of_inverse(np.ascontiguousarray(chol))          # zb[u, i] = Σ⁻¹[i, i+u] on the used rows
    pairs = model.pairs
    rows = model.rows
    full = int(rows[-1]) + 1
    grid_band = pairs.shape[2] - 1
    if model.contiguous:
        zgrid = np.ascontiguousarray(zb.T)
    else:
        zgrid = np.zeros((full, grid_band + 1))
        for u in range(zb.shape[0]):
            i = np.arange(len(rows) - u)
            offset = rows[i + u] - rows[i]
            ok = offset <= grid_band
            zgrid[rows[i[ok]], offset[ok]] = zb[u, i[ok]]
    # kernel types needed: (a, b) for two columns of one signal, (a, 0) for the target's own noise
    needed = set()
    for _, is_target, idx, types, _ in model.signals:
        present = sorted(set(types.tolist()))
        needed.update((a, b) for i, a in enumerate(present) for b in present[i:])
        if is_target:
            needed.update((0, a) for a in present)
    needed = sorted(needed)
    # s = r + u uses H_ab[u], s = r − u uses H_ba[u]
    kern = np.array([pairs[a, b] + np.concatenate([np.zeros_like(pairs[b, a][:1]), pairs[b, a][1:]])
                     for a, b in needed])                                  # (pairs, band+1, width)
    q_all = _banded_overlap(zgrid, kern, model.first, model.step, model.n)
    q = {ab: q_all[i] for i, ab in enumerate(needed)}
    gram = np.zeros((n_terms, n_terms))
    rhs = np.zeros(n_terms)
    for sigma, is_target, idx, types, jac in model.signals:
        if not idx.size:
            continue
        var = sigma * sigma
        present = sorted(set(types.tolist()))
        bounds = {a: (int(np.searchsorted(types, a)), int(np.searchsorted(types, a, side='right'))) for a in present}
        if len(present) == 1:
            (a,) = present
            block = (jac * q[(a, a)][:, None]).T @ jac
        else:
            block = np.empty((idx.size, idx.size))
            for a in present:
                lo, hi = bounds[a]
                # columns k of type b weighted by q_ab: one product per kernel type a
                weighted = np.empty_like(jac)
                for b in present:
                    lo_b, hi_b = bounds[b]
                    weighted[:, lo_b:hi_b] = jac[:, lo_b:hi_b] * q[(min(a, b), max(a, b))][:, None]
                block[lo:hi] = jac[:, lo:hi].T @ weighted
        if is_target:
            for a in present:
                lo, hi = bounds[a]
                rhs[idx[lo:hi]] += var * (jac[:, lo:hi].T @ q[(0, a)])
        gram[np.ix_(idx, idx)] += var * block
    return gram, rhs


@numba.njit(cache=True, nogil=True)
def _band_of_inverse(ab):
    """Band of Σ⁻¹ from the lower banded Cholesky factor (LAPACK storage ab[l, j] = L[j+l, j]).

    Returns zb with zb[d, r] = (Σ⁻¹)[r, r+d], d = 0..band (Takahashi recurrence on U = Lᵀ: U·Z = U⁻ᵀ).
    """
    p1, k = ab.shape
    p = p1 - 1
    z = np.zeros((p1, k))
    for i in range(k - 1, -1, -1):
        uii = ab[0, i]
        lmax = min(p, k - 1 - i)
        for e in range(lmax, -1, -1):
            acc = 0.0
            for m in range(1, lmax + 1):
                v = z[m - e, i + e] if m >= e else z[e - m, i + m]
                acc += ab[m, i] * v
            z[e, i] = ((1.0 / uii if e == 0 else 0.0) - acc) / uii
    return z


def _cholesky_band(ab):
    """Lower banded Cholesky factor (LAPACK storage) of the covariance band, with a 1e-10 relative jitter."""
    ab = np.array(ab, order='F')
    ab[0] *= 1.0 + 1e-10
    ab[0] += 1e-300
    chol, info = lapack.dpbtrf(ab, lower=1, overwrite_ab=1)
    if info != 0:
        raise InsufficientDataError(f'the weak-form covariance is not positive definite (LAPACK info {info}); '
                                    'the data cannot support this fit')
    return chol
