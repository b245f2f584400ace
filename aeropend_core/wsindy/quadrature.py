"""Weak-form assembly: splitting records into segments, test-function centres on a strided grid, the strided
correlation of library columns with a kernel (one row per test function), and the GLS whitener of the rows.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy import linalg

from aeropend_core.errors import AeropendError, InsufficientDataError


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


def _weak_rows(columns: np.ndarray, weights: np.ndarray, starts: np.ndarray, step: int | None = None) -> np.ndarray:
    """∫ φ_c · column for each start, shape (len(starts), n_columns); ``step`` [samples], when given, promises
    evenly spaced starts (``starts[i] = starts[0] + i·step``, as :func:`_centres` makes them)."""
    width = weights.shape[-1]
    k = len(starts)
    if step is None:
        step = int(starts[1] - starts[0]) if k > 1 else 1
        if k > 1 and np.any(np.diff(starts) != step):
            step = 0
    if k < 2 or step < 1:
        view = np.lib.stride_tricks.sliding_window_view(columns, width, axis=0)   # (n - width + 1, ncol, width)
        return view[starts] @ weights
    # Evenly spaced supports: cut the data into blocks of ``step`` samples and the kernel into q pieces of the
    # same length; row r is Σ_j (block r+j)·(piece j). One small matrix product, no (K, ncol, width) copy.
    q = -(-width // step)
    n_blocks = k - 1 + q
    first = int(starts[0])
    n_col = columns.shape[1]
    # by_phase[σ, b, c] = data[first + b·step + σ, c] (zero past the end): one copy, padding included
    by_phase = np.empty((step, n_blocks, n_col))      # every element written below: no zero fill of the whole
    full = min(n_blocks, (len(columns) - first) // step)
    by_phase[:, :full] = columns[first:first + full * step].reshape(full, step, n_col).transpose(1, 0, 2)
    by_phase[:, full:] = 0.0
    tail = columns[first + full * step:first + n_blocks * step]
    if len(tail):
        by_phase[:len(tail), full] = tail
    kernel = np.zeros(q * step)
    kernel[:width] = weights
    # (q, step) @ (step, n_blocks·n_col): parts[j, b, c] = Σ_σ kernel[j·step + σ]·data[b·step + σ, c]
    parts = (kernel.reshape(q, step) @ by_phase.reshape(step, -1)).reshape(q, n_blocks, n_col)
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


def _median(values: np.ndarray) -> float:
    """np.median of a 1-D float array (same value: mean of the two middle elements for even sizes), through
    one partition and without np.median's generic-axis machinery."""
    k = values.size // 2
    if values.size % 2:
        return float(np.partition(values, k)[k])
    part = np.partition(values, (k - 1, k))
    return float((part[k - 1] + part[k]) / 2)
