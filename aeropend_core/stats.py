"""Statistics of correlated series: the evidence for a model change that stays valid when residuals are correlated.

A leaf module (numpy and scipy only), at the bottom of the import order so every layer that judges a fit uses the
same estimators: the motor observer (:mod:`aeropend_core.signals.motor`), the output-error fit and the diagnosis
(:mod:`aeropend_core.diagnosis.evidence` builds the evidence of a discovered term on them).

Output-error residuals of the angle are not independent: measurement noise is white, but whatever the model
misses is a smooth signal lasting seconds. Counting every residual as independent evidence would turn any small
misfit into "overwhelming" significance. Three tools here account for it:

* :func:`long_run_variance` -- the HAC (heteroskedasticity and autocorrelation consistent) variance of a mean:
  Bartlett-kernel (Newey--West) weights with the bandwidth of Andrews' AR(1) plug-in rule, computed by
  overlapping batch means (equivalent to the Bartlett estimator, and linear in the number of samples);
* :func:`hac_covariance` -- the sandwich covariance of least-squares parameters, ``B M B`` with ``B = (J'J)^-1``
  and ``M`` the long-run covariance of the scores ``J_t r_t`` (block sums within segments), so that a parameter's
  t-statistic is honest under correlated residuals;
* :func:`remainder_covariance` -- the same sandwich where the residual carries a slow remainder beside white noise
  (autocorrelation ``share * phi**k``, :func:`slow_remainder`): its meat modelled as ``J' S J``;
* :func:`input_covariance` -- the parameters' covariance caused by an estimated input (the motor observer's
  back-EMF), from an ensemble of input changes as large as its estimation error, added to the sandwich;
* :func:`held_bias_covariance` -- the same for a measurement bias held over input intervals (an angle ADC that
  does not dither at high PSNR);
* :func:`diebold_mariano` -- the held-out predictive test on the squared-error difference of two models,
  ``d_t = e0_t^2 - e1_t^2``, with the HAC variance of its mean (Diebold & Mariano 1995).

:func:`effective_samples` is the number of effectively independent residuals implied by the same long-run
variance (n var(x) / LRV), used in the information criterion.
"""
from __future__ import annotations

import math

import numpy as np


def bandwidth(x: np.ndarray) -> int:
    """Bartlett-kernel bandwidth [samples] by Andrews' AR(1) plug-in rule, between 1 and n/8."""
    x = np.asarray(x, dtype=float)
    n = x.size
    if n < 16:
        return 1
    centred = x - x.mean()
    # rho is scale-free: scaled to at most 1, a series of huge values (a diverging model's errors) cannot overflow
    scale = float(np.max(np.abs(centred)))
    if not (scale > 0 and math.isfinite(scale)):
        return 1
    centred = centred / scale
    denominator = float(np.dot(centred, centred))
    rho = float(np.dot(centred[1:], centred[:-1]) / denominator)
    rho = min(max(rho, 0.0), 0.999)
    alpha = 4.0 * rho ** 2 / ((1.0 - rho) ** 2 * (1.0 + rho) ** 2)
    width = 1.1447 * (alpha * n) ** (1.0 / 3.0)
    return int(min(max(round(width), 1), max(n // 8, 1)))


def long_run_variance(x: np.ndarray, width: int | None = None) -> float:
    """Long-run variance of the series `x` (the variance of sqrt(n) mean(x)): Bartlett/Newey--West estimate.

    Computed as the overlapping-batch-means estimator with batches of `width` samples (default:
    :func:`bandwidth`), which equals the Bartlett-kernel estimator up to edge terms.
    """
    x = np.asarray(x, dtype=float)
    n = x.size
    if n < 2:
        return float('nan')
    width = bandwidth(x) if width is None else int(max(1, min(width, n)))
    centred = x - x.mean()
    if width == 1:
        return float(np.mean(centred ** 2))
    cumulative = np.concatenate(([0.0], np.cumsum(centred)))
    sums = cumulative[width:] - cumulative[:-width]
    return float(np.mean(sums ** 2) / width * n / (n - width + 1))


def effective_samples(x: np.ndarray) -> float:
    """Number of effectively independent samples in `x`: n var(x) / long-run variance (at most n)."""
    x = np.asarray(x, dtype=float)
    n = x.size
    variance = float(np.var(x))
    lrv = long_run_variance(x)
    if not (variance > 0 and lrv > 0):
        return float(n)
    return float(min(n, n * variance / lrv))


def _jacobian_and_bread(jacobian) -> tuple:
    """(the Jacobian as a float csr_array or ndarray, whether it is sparse, ``B = pinv(J'J)``)."""
    from scipy import sparse
    is_sparse = sparse.issparse(jacobian)
    jacobian = sparse.csr_array(jacobian, dtype=float) if is_sparse else np.asarray(jacobian, dtype=float)
    gram = (jacobian.T @ jacobian).toarray() if is_sparse else jacobian.T @ jacobian
    return jacobian, is_sparse, np.linalg.pinv(gram)


def _block_indicator(labels: np.ndarray, count: int):
    """Sparse (count, n) matrix with a 1 at (labels[t], t): its product with per-residual rows sums them by block."""
    from scipy import sparse
    n = len(labels)
    return sparse.csr_array((np.ones(n), (labels, np.arange(n))), shape=(count, n))


def hac_covariance(jacobian: np.ndarray, residuals: np.ndarray, groups: np.ndarray | None = None,
                   width: int | None = None) -> np.ndarray:
    """Sandwich covariance of least-squares parameters under autocorrelated residuals.

    Parameters
    ----------
    jacobian : ndarray or scipy.sparse matrix, shape (n, p)
        d residual / d parameter at the solution (sparse for long multiple-shooting fits: each segment's initial
        state moves only that segment's residuals).
    residuals : ndarray, shape (n,)
    groups : ndarray of int, shape (n,), optional
        Independent groups (multiple-shooting segments); block sums never cross a group boundary.
    width : int, optional
        Block length [samples] (default: :func:`bandwidth` of the residuals).

    Returns
    -------
    ndarray, shape (p, p)
        ``B M B`` with ``B = pinv(J'J)`` and ``M`` the sum over blocks of (sum of scores)(sum of scores)'.
    """
    residuals = np.asarray(residuals, dtype=float)
    jacobian, is_sparse, bread = _jacobian_and_bread(jacobian)
    n, p = jacobian.shape
    width = bandwidth(residuals) if width is None else int(max(1, width))
    groups = np.zeros(n, dtype=int) if groups is None else np.asarray(groups)
    scores = jacobian.multiply(residuals[:, None]).tocsr() if is_sparse else jacobian * residuals[:, None]
    # Blocks of `width` consecutive residuals within each group (half-overlapping: two offsets averaged).
    meat = np.zeros((p, p))
    for shift in (0, width // 2) if width > 1 else (0,):
        block = np.empty(n, dtype=np.int64)
        start = 0
        label = 0
        boundaries = np.flatnonzero(np.diff(groups)) + 1
        for stop in list(boundaries) + [n]:
            index = np.arange(stop - start)
            block[start:stop] = label + (index + shift) // width
            label = int(block[stop - 1]) + 1
            start = stop
        if is_sparse:      # block sums as one sparse product (rows = blocks): linear in n
            sums = _block_indicator(block, label) @ scores
            meat += (sums.T @ sums).toarray()
        else:
            sums = np.zeros((label, p))
            np.add.at(sums, block, scores)
            meat += sums.T @ sums
    meat /= 2 if width > 1 else 1
    return bread @ meat @ bread


def input_covariance(jacobian: np.ndarray, changes: np.ndarray) -> np.ndarray:
    """Covariance of least-squares parameters caused by an uncertain input (a generated regressor).

    A fit that takes an estimated signal as its input (the motor observer's back-EMF) treats it as exact; its
    estimation error moves the parameters without showing in the residuals when they absorb it. Given an ensemble
    of input changes as large as that error, each member moves the parameters by one Gauss-Newton step,
    ``dz = -(J'J)^-1 J' dr`` with ``dr`` the change of the residuals at the solution; the covariance is the mean
    of ``dz dz'`` over the members (their spread, the ensemble being centred on the fitted input by construction).

    Parameters
    ----------
    jacobian : ndarray or scipy.sparse matrix, shape (n, p)
        d residual / d parameter at the solution.
    changes : ndarray, shape (members, n)
        Change of the residuals [residual unit] when each member replaces the input, parameters held.

    Returns
    -------
    ndarray, shape (p, p)
    """
    jacobian, _, bread = _jacobian_and_bread(jacobian)
    projected = np.asarray(jacobian.T @ np.asarray(changes, dtype=float).T)     # (p, members)
    steps = -bread @ projected
    return steps @ steps.T / steps.shape[1]


def held_bias_covariance(jacobian: np.ndarray, blocks: np.ndarray, bias_rms: float) -> np.ndarray:
    """Covariance of least-squares parameters caused by a measurement bias held constant over blocks of residuals.

    An ADC that does not dither (little noise before it) reads a held value off by a bias that stays while the
    value stays: constant within each block (an input interval), independent between blocks, RMS `bias_rms`.
    The parameters move by ``dz = -(J'J)^-1 J' b``; its covariance is ``B (sum_k s_k s_k') B bias_rms^2`` with
    ``s_k`` the sum of the Jacobian's rows in block k and ``B = (J'J)^-1``.

    Parameters
    ----------
    jacobian : ndarray or scipy.sparse matrix, shape (n, p)
        d residual / d parameter at the solution.
    blocks : ndarray of int, shape (n,)
        Block label of each residual.
    bias_rms : float
        RMS of the held bias [residual unit].

    Returns
    -------
    ndarray, shape (p, p)
    """
    from scipy import sparse
    jacobian, _, bread = _jacobian_and_bread(jacobian)
    _, label = np.unique(np.asarray(blocks), return_inverse=True)
    sums = _block_indicator(label, int(label.max()) + 1) @ jacobian
    sums = sums.toarray() if sparse.issparse(sums) else np.asarray(sums)
    return bread @ (sums.T @ sums) @ bread * bias_rms ** 2


#: t-statistic of the slow remainder's share of the residual variance above which the covariance models it
SLOW_REMAINDER_T = 3.0


def _spans(n: int, groups: np.ndarray | None) -> list[tuple[int, int]]:
    """(start, stop) of each run of equal labels in `groups` (one span of `n` without groups)."""
    groups = np.zeros(n, dtype=int) if groups is None else np.asarray(groups)
    bounds = np.concatenate(([0], np.flatnonzero(np.diff(groups)) + 1, [n]))
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]


def slow_remainder(residuals: np.ndarray, groups: np.ndarray | None = None, most_lags: int = 500) -> dict:
    """The residual as white noise plus a slow first-order (AR(1)) remainder, fitted to its autocorrelation.

    A model that misses a little (another simulator, a real rig) leaves a residual that is mostly white
    measurement noise plus a small smooth misfit lasting seconds. Its autocorrelation is then about
    ``share * phi**k`` at every lag ``k >= 1``: small at lag 1, yet still there at lag 100. Andrews' AR(1) rule
    (:func:`bandwidth`) reads only the lag-1 value and picks blocks far shorter than the misfit's correlation, so
    the sandwich under-counts it. Here the autocorrelation at lags 1 .. `most_lags` (pooled within `groups`, at most
    a quarter of the shortest group) is fitted by least squares over a grid of correlation lengths.

    Returns
    -------
    dict
        ``share`` [-]: the remainder's share of the residual variance; ``correlation_samples`` [samples]: its
        correlation length ``-1/ln(phi)``; ``t_statistic`` [-]: share over its standard error under white noise
        (``1/sqrt(n sum phi^2k)``); ``phi`` [-].
    """
    r = np.asarray(residuals, dtype=float)
    n = r.size
    spans = _spans(n, groups)
    shortest = min(b - a for a, b in spans)
    lags = int(max(4, min(most_lags, shortest // 4)))
    sums, pairs = np.zeros(lags + 1), np.zeros(lags + 1)
    for a, b in spans:
        x = r[a:b] - r[a:b].mean()
        spectrum = np.fft.rfft(x, 2 * x.size)
        sums += np.fft.irfft(spectrum * np.conj(spectrum))[:lags + 1]
        pairs += x.size - np.arange(lags + 1)
    if not sums[0] > 0:
        return {'share': 0.0, 'phi': 0.0, 'correlation_samples': 0.0, 't_statistic': 0.0}
    acf = (sums[1:] / pairs[1:]) / (sums[0] / pairs[0])     # the mean of the products at each lag
    k = np.arange(1, lags + 1)
    # each group's mean removed lowers every lag's product by about the same amount: a constant beside phi**k
    best = (0.0, 0.0, float(np.sum((acf - acf.mean()) ** 2)), 0.0)
    for length in np.geomspace(1.0, 4.0 * lags, 80):
        phi = math.exp(-1.0 / length)
        basis = np.column_stack([phi ** k, np.ones(lags)])
        (share, _), *_ = np.linalg.lstsq(basis, acf, rcond=None)
        if share <= 0:
            continue
        misfit = float(np.sum((acf - basis @ np.linalg.lstsq(basis, acf, rcond=None)[0]) ** 2))
        if misfit < best[2]:
            centred = basis[:, 0] - basis[:, 0].mean()
            best = (float(share), phi, misfit, float(share) * math.sqrt(float(centred @ centred) * n))
    share, phi, _, t = best
    return {'share': min(share, 1.0), 'phi': phi, 'correlation_samples': -1.0 / math.log(phi) if phi > 0 else 0.0,
            't_statistic': t}


def _ar1_correlation_times(x: np.ndarray, phi: float) -> np.ndarray:
    """``Phi @ x`` for the correlation matrix ``Phi[i, j] = phi**|i-j|`` (rows of `x`): an FFT convolution with the
    kernel ``phi**|k|`` over every lag the rows span (exact, no truncation; numpy only)."""
    m = x.shape[0]
    kernel = phi ** np.abs(np.arange(-(m - 1), m))
    size = 1 << int(math.ceil(math.log2(3 * m)))
    product = np.fft.rfft(x, size, axis=0) * np.fft.rfft(kernel, size)[:, None]
    return np.fft.irfft(product, size, axis=0)[m - 1:2 * m - 1]


def remainder_covariance(jacobian, residuals: np.ndarray, groups: np.ndarray | None = None,
                         sample_spacing: float = 1.0) -> tuple[np.ndarray, dict]:
    """Sandwich covariance of least-squares parameters that counts a slow remainder in the residual.

    First :func:`hac_covariance`. Then the residual is fitted as white noise plus a slow AR(1) remainder
    (:func:`slow_remainder`); where the remainder is significant (t >= :data:`SLOW_REMAINDER_T`) the meat is the
    modelled one, ``J' S J`` with ``S = var(r) ((1 - share) I + share Phi)`` within each group (independent
    groups), so a misfit correlated over hundreds of samples is counted as such. Each parameter keeps the larger
    of its two variances (the modelled covariance scaled by ``D S D``, ``D`` >= 1 diagonal, so it stays positive
    semi-definite).

    Parameters
    ----------
    jacobian : ndarray or scipy.sparse matrix, shape (n, p)
    residuals : ndarray, shape (n,)
    groups : ndarray of int, shape (n,), optional
        Independent groups (multiple-shooting segments).
    sample_spacing : float
        Time between residuals [s], for the correlation time reported.

    Returns
    -------
    covariance : ndarray, shape (p, p)
    remainder : dict
        ``share`` [-], ``correlation_time`` [s], ``t_statistic`` [-] of :func:`slow_remainder`, ``modelled``
        (bool): whether the covariance counts it, and where it does ``widening`` [-]: each parameter's sigma over
        its block-sum (HAC) sigma, in column order.
    """
    from scipy import sparse
    r = np.asarray(residuals, dtype=float)
    try:
        hac = hac_covariance(jacobian, r, groups)
    except np.linalg.LinAlgError:  # pragma: no cover - pinv rarely fails
        p = jacobian.shape[1]
        return np.full((p, p), np.nan), {'modelled': False}
    fitted = slow_remainder(r, groups)
    remainder = {'share': fitted['share'], 'correlation_time': fitted['correlation_samples'] * sample_spacing,
                 't_statistic': fitted['t_statistic'], 'modelled': False}
    if not (fitted['t_statistic'] >= SLOW_REMAINDER_T and 0.0 < fitted['phi'] < 1.0):
        return hac, remainder
    share, phi = fitted['share'], fitted['phi']
    jacobian, is_sparse, bread = _jacobian_and_bread(jacobian)
    p = jacobian.shape[1]
    meat = np.zeros((p, p))
    for a, b in _spans(r.size, groups):
        block = jacobian[a:b]
        block = block.toarray() if sparse.issparse(block) else np.asarray(block)
        columns = np.flatnonzero(np.any(block != 0, axis=0))
        dense = block[:, columns]
        correlated = (1.0 - share) * dense + share * _ar1_correlation_times(dense, phi)
        meat[np.ix_(columns, columns)] += dense.T @ correlated
    modelled = bread @ meat @ bread * float(np.mean(r ** 2))
    with np.errstate(invalid='ignore', divide='ignore'):
        ratio = np.diag(hac) / np.diag(modelled)
    widen = np.sqrt(np.where(np.isfinite(ratio) & (ratio > 1.0), ratio, 1.0))
    covariance = modelled * np.outer(widen, widen)
    with np.errstate(invalid='ignore', divide='ignore'):
        widening = np.sqrt(np.diag(covariance) / np.diag(hac))
    remainder.update(modelled=True, widening=[float(w) if np.isfinite(w) else 1.0 for w in widening])
    return covariance, remainder


def diebold_mariano(error_reference: np.ndarray, error_candidate: np.ndarray) -> tuple[float, float]:
    """Diebold--Mariano statistic for "the candidate predicts better" and the mean squared-error gain.

    Parameters
    ----------
    error_reference, error_candidate : ndarray, shape (n,)
        Held-out prediction errors [rad] of the reference and the candidate model at the same samples.

    Returns
    -------
    statistic : float
        mean(d) / sqrt(LRV(d) / n) with ``d = e_ref^2 - e_cand^2``: about N(0, 1) when both predict equally
        well; large positive when the candidate is better.
    gain : float
        mean(d) [rad^2]: how much the mean-square error falls.
    """
    d = np.asarray(error_reference, dtype=float) ** 2 - np.asarray(error_candidate, dtype=float) ** 2
    finite = np.isfinite(d)
    d = d[finite]
    if d.size < 10:
        return float('nan'), float('nan')
    mean = float(np.mean(d))
    # The statistic is scale-free: computed on d / max|d|, the squares of a diverging model's errors (1e160 rad^2
    # and more) cannot overflow into a NaN bandwidth; the gain keeps its unit.
    scale = float(np.max(np.abs(d)))
    scaled = d / scale if scale > 0 and math.isfinite(scale) else d
    lrv = long_run_variance(scaled)
    if not lrv > 0:
        return (math.inf if mean > 0 else -math.inf if mean < 0 else 0.0), mean
    return float(np.mean(scaled) / math.sqrt(lrv / d.size)), mean


__all__ = ['bandwidth', 'long_run_variance', 'effective_samples', 'hac_covariance', 'input_covariance',
           'held_bias_covariance', 'diebold_mariano', 'slow_remainder', 'remainder_covariance',
           'SLOW_REMAINDER_T']
