"""The digital filters a diagnosis uses, without importing :mod:`scipy.signal` (issue 41).

Importing scipy.signal imports scipy.stats, scipy.interpolate and scipy.spatial with it: about a seventh of a 60 s
record's ``aeropend diagnose`` (cProfile, bench/results/2026-12-07-s23-speed), for four routines. They are written
here, each following scipy's own steps in the same order so that the numbers are scipy's (tests/test_filters.py
compares them with scipy.signal on random and recorded signals: equal bit for bit, the Butterworth design within a
few units in the last place):

* :func:`savgol_filter` -- Savitzky-Golay smoothing or derivative, scipy's ``mode='interp'`` (polynomial fits at the
  two edges);
* :func:`first_order_lag` -- ``lfilter([1 - d], [1, -d], x, zi=[d x[0]])``, a first-order lag starting at rest on
  the first sample;
* :func:`butter_lowpass_sos` -- the second-order Butterworth low-pass of ``butter(2, wn, output='sos')``;
* :func:`sosfiltfilt` -- zero-phase filtering with odd extension at the ends (scipy's defaults);
* :func:`lfilter`, :func:`lfiltic`, :func:`lfilter_zi` and :func:`foh_transfer_function` (cont2discrete's first-order
  hold of a transfer function) -- the angle sensor's low-pass (:mod:`aeropend_core.model.sensor_filter`).
"""
from __future__ import annotations

import math

import numba
import numpy as np


def savgol_coefficients(window_length: int, polyorder: int, deriv: int = 0, delta: float = 1.0) -> np.ndarray:
    """Convolution coefficients [-] of a Savitzky-Golay filter (scipy.signal.savgol_coeffs, ``use='conv'``).

    Parameters
    ----------
    window_length : int [samples]
        Odd or even window length.
    polyorder : int [-]
        Order of the fitted polynomial, below `window_length`.
    deriv : int [-]
        Order of the derivative (0: smoothing).
    delta : float [s]
        Sample spacing, for a derivative in units per second to the `deriv`.
    """
    from scipy.linalg import lstsq
    if polyorder >= window_length:
        raise ValueError('polyorder must be less than window_length.')
    halflen, rem = divmod(window_length, 2)
    pos = halflen - 0.5 if rem == 0 else halflen
    if deriv > polyorder:
        return np.zeros(window_length)
    x = np.flip(np.arange(-pos, window_length - pos, dtype=np.float64))
    order = np.arange(polyorder + 1, dtype=np.float64).reshape(-1, 1)
    a = x ** order
    y = np.zeros(polyorder + 1)
    y[deriv] = float(math.factorial(deriv)) / (delta ** deriv)
    coefficients, _, _, _ = lstsq(a, y, cond=np.finfo(np.float64).eps * max(a.shape[-1], a.shape[-2]))
    return coefficients


def _polyfit(x: np.ndarray, y: np.ndarray, degree: int) -> np.ndarray:
    """scipy.signal._polyutils.polyfit for a 1-D `x` and 2-D `y` (columns scaled, least squares)."""
    from scipy.linalg import lstsq
    powers = np.flip(np.arange(degree + 1, dtype=x.dtype))
    lhs = x[:, None] ** powers[None, :]
    scale = np.sqrt(np.sum(lhs * lhs, axis=0))
    lhs /= scale
    c, _, _, _ = lstsq(lhs, y, cond=x.shape[0] * np.finfo(x.dtype).eps)
    return (c.T / scale).T


def _polyder(p: np.ndarray, m: int) -> np.ndarray:
    """scipy.signal._savitzky_golay._polyder: the `m`-th derivative of the polynomials in `p`'s columns."""
    if m == 0:
        return p
    n = p.shape[0]
    if n <= m:
        return np.zeros_like(p[:1, ...])
    dp = np.array(p[:-m, ...], copy=True)
    for k in range(m):
        dp *= np.arange(n - k - 1, m - k - 1, -1, dtype=p.dtype).reshape((n - m,) + (1,) * (p.ndim - 1))
    return dp


def _fit_edge(x, window_start, window_stop, interp_start, interp_stop, polyorder, deriv, delta, y) -> None:
    """scipy.signal._savitzky_golay._fit_edge for a 1-D signal, in place on `y`."""
    edge = x[window_start:window_stop].reshape(-1, 1)
    coefficients = _polyfit(np.arange(0, window_stop - window_start, dtype=x.dtype), edge, polyorder)
    if deriv > 0:
        coefficients = _polyder(coefficients, deriv)
    i = np.arange(interp_start - window_start, interp_stop - window_start, dtype=coefficients.dtype).reshape(-1, 1)
    values = np.zeros_like(i)
    for j in range(coefficients.shape[0]):
        values = values * i + coefficients[j, ...]
    y[interp_start:interp_stop] = (values / (delta ** deriv)).reshape(interp_stop - interp_start)


def savgol_filter(x, window_length: int, polyorder: int, deriv: int = 0, delta: float = 1.0) -> np.ndarray:
    """Savitzky-Golay filter of a 1-D signal (scipy.signal.savgol_filter with ``mode='interp'``).

    Parameters
    ----------
    x : array_like [any unit]
        The signal.
    window_length : int [samples]
        Window length, at most the signal's length.
    polyorder : int [-]
        Order of the fitted polynomial.
    deriv : int [-]
        Order of the derivative (0: smoothing).
    delta : float [s]
        Sample spacing.

    Returns
    -------
    numpy.ndarray
        The smoothed signal or its derivative [unit of `x` per second to the `deriv`].
    """
    from scipy.ndimage import convolve1d
    x = np.asarray(x)
    if x.dtype != np.float64 and x.dtype != np.float32:
        x = x.astype(np.float64)
    if x.ndim != 1:
        raise ValueError('savgol_filter here filters 1-D signals')
    if window_length > x.shape[0]:
        raise ValueError("If mode is 'interp', window_length must be less than or equal to the size of x.")
    coefficients = savgol_coefficients(window_length, polyorder, deriv, delta)
    y = convolve1d(x, coefficients, mode='constant')
    halflen = window_length // 2
    n = x.shape[0]
    _fit_edge(x, 0, window_length, 0, halflen, polyorder, deriv, delta, y)
    _fit_edge(x, n - window_length, n, n - halflen, n, polyorder, deriv, delta, y)
    return y


@numba.njit(cache=True, nogil=True)
def _lag_kernel(signal, gain, decay, state):                      # pragma: no cover - compiled
    out = np.empty_like(signal)
    for n in range(signal.size):
        out[n] = state + gain * signal[n]
        state = 0.0 * signal[n] - (-decay) * out[n]
    return out


def first_order_lag(signal, decay: float) -> np.ndarray:
    """``scipy.signal.lfilter([1 - decay], [1, -decay], signal, zi=[decay * signal[0]])[0]``: a first-order lag with
    pole `decay` [-] (exp(-sample time / time constant)) and unit gain, at rest on the first sample; same unit as
    `signal`."""
    signal = np.ascontiguousarray(signal, dtype=np.float64)
    if signal.size == 0:
        return signal.copy()
    return _lag_kernel(signal, 1.0 - decay, float(decay), decay * signal[0])


def butter_lowpass_sos(normalized_cutoff: float) -> np.ndarray:
    """``scipy.signal.butter(2, normalized_cutoff, output='sos')``: the second-order Butterworth low-pass as one
    second-order section (b0, b1, b2, 1, a1, a2) [-]; `normalized_cutoff` [-] is the cutoff over the Nyquist
    frequency, in (0, 1)."""
    if not 0.0 < normalized_cutoff < 1.0:
        raise ValueError('Digital filter critical frequencies must be 0 < Wn < 1')
    fs = 2.0
    warped = 2 * fs * np.tan(np.pi * np.float64(normalized_cutoff) / fs)
    poles = -np.exp(1j * np.pi * np.arange(-1.0, 2.0, 2.0) / 4.0) * float(warped)   # buttap(2), lp2lp_zpk
    gain = 1.0 * float(warped) ** 2
    fs2 = 2.0 * fs
    poles_z = (fs2 + poles) / (fs2 - poles)                                           # bilinear_zpk
    gain_z = gain * np.real(1.0 / np.prod(fs2 - poles))
    numerator = gain_z * np.poly(np.array([-1.0, -1.0]))
    denominator = np.real(np.poly(poles_z))
    return np.concatenate([numerator, denominator]).reshape(1, 6)


@numba.njit(cache=True, nogil=True)
def _sosfilt_kernel(sos, x, zi):                                   # pragma: no cover - compiled
    out = np.empty_like(x)
    for n in range(x.size):
        current = x[n]
        for s in range(sos.shape[0]):
            new = sos[s, 0] * current + zi[s, 0]
            zi[s, 0] = sos[s, 1] * current - sos[s, 4] * new + zi[s, 1]
            zi[s, 1] = sos[s, 2] * current - sos[s, 5] * new
            current = new
        out[n] = current
    return out


def _sosfilt_zi(sos: np.ndarray) -> np.ndarray:
    """scipy.signal.sosfilt_zi: each section's steady state for a unit step."""
    from scipy import linalg
    zi = np.empty((sos.shape[0], 2))
    scale = 1.0
    for section in range(sos.shape[0]):
        b, a = sos[section, :3], sos[section, 3:]
        if a[0] != 1.0:
            b, a = b / a[0], a / a[0]
        step = np.linalg.solve(np.eye(2) - linalg.companion(a).T, b[1:] - a[1:] * b[0])
        zi[section, ...] = scale * step
        scale *= np.sum(sos[section, :3]) / np.sum(sos[section, 3:])
    return zi


def sosfiltfilt(sos: np.ndarray, x) -> np.ndarray:
    """Zero-phase filtering of a 1-D signal by second-order sections (scipy.signal.sosfiltfilt with its defaults:
    odd extension by 3 (2 sections + 1) samples, forward and backward from the steady state); unit of `x`."""
    sos = np.ascontiguousarray(sos, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    n_taps = 2 * sos.shape[0] + 1 - min(int((sos[:, 2] == 0).sum()), int((sos[:, 5] == 0).sum()))
    edge = 3 * n_taps
    if x.shape[0] <= edge:
        raise ValueError(f'The length of the input vector x must be greater than padlen, which is {edge}.')
    ext = np.concatenate((2 * x[:1] - x[edge:0:-1], x, 2 * x[-1:] - x[-2:-(edge + 2):-1]))
    zi = _sosfilt_zi(sos)
    y = _sosfilt_kernel(sos, np.ascontiguousarray(ext), zi * ext[0])
    y = _sosfilt_kernel(sos, np.ascontiguousarray(y[::-1]), zi * y[-1])[::-1]
    return np.ascontiguousarray(y[edge:-edge]) if edge > 0 else y


@numba.njit(cache=True, nogil=True)
def _lfilter_kernel(b, a, x, zi):                                  # pragma: no cover - compiled
    # scipy's _linear_filter (direct form II transposed), its order of operations; b and a normalised by a[0]
    out = np.empty_like(x)
    taps = b.size
    for k in range(x.size):
        xn = x[k]
        yn = zi[0] + b[0] * xn
        for n in range(taps - 2):
            zi[n] = zi[n + 1] + xn * b[n + 1] - yn * a[n + 1]
        zi[taps - 2] = xn * b[taps - 1] - yn * a[taps - 1]
        out[k] = yn
    return out


def lfilter(b, a, x, zi) -> tuple[np.ndarray, np.ndarray]:
    """``scipy.signal.lfilter(b, a, x, zi=zi)`` for a 1-D float signal: (output, final state), unit of `x`; `b` and
    `a` [-] of equal length at least 2 and `a[0]` nonzero (the filters here: a lag, the angle sensor's ladder)."""
    b = np.asarray(b, dtype=np.float64)
    a = np.asarray(a, dtype=np.float64)
    if b.size != a.size or b.size < 2 or a[0] == 0:
        raise ValueError('lfilter here takes b and a of equal length >= 2 with a[0] != 0')
    if a[0] != 1.0:
        b, a = b / a[0], a / a[0]
    state = np.array(zi, dtype=np.float64).reshape(b.size - 1)
    out = _lfilter_kernel(b, a, np.ascontiguousarray(x, dtype=np.float64), state)
    return out, state


def lfiltic(b, a, y, x) -> np.ndarray:
    """``scipy.signal.lfiltic(b, a, y, x)``: the initial state [unit of the signal] of :func:`lfilter` that gives the
    past outputs `y` (most recent first) for the past inputs `x`."""
    b = np.atleast_1d(np.asarray(b, dtype=np.float64))
    a = np.atleast_1d(np.asarray(a, dtype=np.float64))
    n, m = a.shape[0] - 1, b.shape[0] - 1
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x.size < m:
        x = np.concatenate((x, np.zeros(m - x.size)))
    if y.size < n:
        y = np.concatenate((y, np.zeros(n - y.size)))
    zi = np.zeros(max(m, n))
    for k in range(m):
        zi[k] = np.sum(b[k + 1:] * x[:m - k], axis=0)
    for k in range(n):
        zi[k] -= np.sum(a[k + 1:] * y[:n - k], axis=0)
    if a[0] != 1.0:
        zi /= a[0]
    return zi


def lfilter_zi(b, a) -> np.ndarray:
    """``scipy.signal.lfilter_zi(b, a)``: :func:`lfilter`'s state [-] in the steady state of a unit step; `b` and `a`
    of equal length."""
    from scipy import linalg
    b = np.atleast_1d(np.asarray(b, dtype=np.float64))
    a = np.atleast_1d(np.asarray(a, dtype=np.float64))
    while a.shape[0] > 1 and a[0] == 0.0:
        a = a[1:]
    if a[0] != 1.0:
        b, a = b / a[0], a / a[0]
    if a.shape[0] != b.shape[0]:
        raise ValueError('lfilter_zi here takes b and a of equal length')
    return np.linalg.solve(np.eye(a.shape[0] - 1) - linalg.companion(a).T, b[1:] - a[1:] * b[0])


def foh_transfer_function(numerator, denominator, step: float) -> tuple[np.ndarray, np.ndarray]:
    """``scipy.signal.cont2discrete((numerator, denominator), step, method='foh')[:2]``: the continuous transfer
    function (coefficients [-] in powers of s, highest first) discretised with a first-order hold at `step` [s],
    as (b of shape (1, n), a) [-]; the denominator of degree at least 1 and not below the numerator's."""
    from scipy import linalg
    den = np.atleast_1d(np.asarray(denominator, dtype=np.float64))
    num = np.atleast_2d(np.asarray(numerator, dtype=np.float64))
    den = np.trim_zeros(den, 'f')
    num, den = num / den[0], den / den[0]                         # normalize (no leading zeros to strip here)
    if num.shape[0] == 1:
        num = num[0, :]
    num = np.asarray([num], num.dtype)                            # tf2ss
    m_, k_ = num.shape[1], len(den)
    if m_ > k_ or k_ < 2:
        raise ValueError('foh_transfer_function takes a proper transfer function of order >= 1')
    num = np.hstack((np.zeros((num.shape[0], k_ - m_), dtype=num.dtype), num))
    d = np.atleast_2d(num[:, 0])
    a = np.r_[-np.array([den[1:]]), np.eye(k_ - 2, k_ - 1)]
    b = np.eye(k_ - 1, 1)
    c = num[:, 1:] - np.outer(num[:, 0], den[1:])
    d = d.reshape((c.shape[0], b.shape[1]))
    n, m = a.shape[0], b.shape[1]                                 # cont2discrete, 'foh'
    em_upper = linalg.block_diag(np.block([a, b]) * step, np.eye(m))
    em = np.block([[em_upper], [np.zeros((m, n + 2 * m))]])
    ms = linalg.expm(em)
    ms11, ms12, ms13 = ms[:n, 0:n], ms[:n, n:n + m], ms[:n, n + m:]
    ad, bd, cd, dd = ms11, ms12 - ms13 + ms11 @ ms13, c, d + c @ ms13
    den_d = np.poly(ad)                                           # ss2tf
    type_test = ad[:, 0] + bd[:, 0] + cd[0, :] + dd + 0.0
    num_d = np.empty((dd.shape[0], n + 1), type_test.dtype)
    for k in range(dd.shape[0]):
        num_d[k] = np.poly(ad - np.dot(bd, np.atleast_2d(cd[k, :]))) + (dd[k] - 1) * den_d
    return num_d, den_d


def autocorrelation(x) -> np.ndarray:
    """``scipy.signal.correlate(x, x, mode='full', method='fft')`` of a 1-D real signal (its steps: real FFTs of a
    fast length, the product, the inverse, cut to 2 n - 1 lags); unit of `x` squared."""
    from scipy import fft
    x = np.asarray(x, dtype=np.float64)
    size = 2 * x.size - 1
    shape = fft.next_fast_len(size, True)
    product = fft.rfftn(x, [shape], axes=[0]) * fft.rfftn(np.conj(x[::-1]), [shape], axes=[0])
    return fft.irfftn(product, [shape], axes=[0])[:size].copy()


def welch_density(x, sample_rate: float, segment: int) -> tuple[np.ndarray, np.ndarray]:
    """Welch's power spectral density of a 1-D real signal as ``scipy.signal.welch(x, fs=sample_rate,
    nperseg=segment)`` gives it (periodic Hann window, half overlap, each segment's mean removed, one-sided,
    averaged): (frequencies [Hz], density [unit of `x` squared per Hz]). Equal to scipy's within ~1e-12 relative,
    not bit for bit (tests/test_filters.py)."""
    x = np.asarray(x, dtype=np.float64)
    segment = min(int(segment), x.size)
    window = 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(segment) / segment)
    hop = segment - segment // 2
    count = (x.size - segment // 2) // hop
    starts = np.arange(count) * hop
    pieces = np.stack([x[s:s + segment] for s in starts])
    pieces = (pieces - pieces.mean(axis=1, keepdims=True)) * window
    power = np.abs(np.fft.rfft(pieces, axis=1)) ** 2 / (sample_rate * float(np.sum(window * window)))
    power[:, 1:-1 if segment % 2 == 0 else None] *= 2.0
    return np.fft.rfftfreq(segment, 1.0 / sample_rate), power.mean(axis=0)


__all__ = ['autocorrelation', 'butter_lowpass_sos', 'first_order_lag', 'foh_transfer_function', 'lfilter', 'lfilter_zi',
           'lfiltic', 'savgol_coefficients', 'savgol_filter', 'sosfiltfilt', 'welch_density']
