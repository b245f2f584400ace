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
           'held_bias_covariance', 'diebold_mariano']
