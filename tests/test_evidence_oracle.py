"""The HAC long-run variance, the HAC sandwich covariance and the drift trend test against an independent
implementation (statsmodels), on data with known autocorrelation.

Our estimators are written for speed (overlapping batch means, block sums linear in n, sparse Jacobians); the
Bartlett-kernel Newey--West estimators of statsmodels are the textbook form. Batch means of width b equal the
Bartlett estimator with lag truncation b − 1 (weights 1 − j/b) up to edge terms of order b/n, so the two agree
within a tolerance stated per check; the trend test is ordinary least squares of a line, so it agrees exactly.
"""
from __future__ import annotations

import numpy as np
import pytest

from aeropend_core import stats as evidence
from aeropend_core.diagnosis.drift import trend_test

sandwich = pytest.importorskip('statsmodels.stats.sandwich_covariance')
sm = pytest.importorskip('statsmodels.api')


def ar1(rng: np.random.Generator, n: int, rho: float) -> np.ndarray:
    """A stationary AR(1) series of unit innovation variance."""
    from scipy.signal import lfilter
    e = rng.standard_normal(n + 500)
    return lfilter([1.0], [1.0, -rho], e)[500:]


@pytest.mark.parametrize('rho', [0.0, 0.5, 0.9])
def test_long_run_variance_matches_the_bartlett_estimator(rho):
    rng = np.random.default_rng(11)
    x = ar1(rng, 50_000, rho)
    width = evidence.bandwidth(x)
    ours = evidence.long_run_variance(x, width)
    centred = (x - x.mean())[:, None]
    # statsmodels returns the sum of the weighted autocovariances over the n samples (not yet divided by n)
    theirs = (float(sandwich.S_hac_simple(centred, nlags=width - 1)[0, 0]) / x.size if width > 1
              else float(np.mean(centred ** 2)))
    # edge terms of order width/n (width ~ 1..60 here): 1 % is ~10x that
    assert ours == pytest.approx(theirs, rel=0.01), (width, ours, theirs)
    # and both near the truth 1/(1-rho)^2 for unit innovations (estimation error of a HAC estimate: ~10 %)
    assert ours == pytest.approx(1.0 / (1.0 - rho) ** 2, rel=0.25)


def test_hac_sandwich_matches_statsmodels_ols_hac():
    """Least squares y = X b + u with AR(1) regressors and errors: our sandwich (half-overlapping block sums) against
    statsmodels' Newey--West HAC of the same fit (Bartlett, maxlags = width − 1, no small-sample correction)."""
    rng = np.random.default_rng(5)
    n = 200_000
    X = np.column_stack([np.ones(n), ar1(rng, n, 0.8), ar1(rng, n, 0.5)])
    y = X @ np.array([1.0, 2.0, -0.5]) + ar1(rng, n, 0.7)
    fit = sm.OLS(y, X).fit()
    residuals = fit.resid
    width = evidence.bandwidth(residuals)
    ours = evidence.hac_covariance(X, residuals, width=width)
    theirs = fit.get_robustcov_results(cov_type='HAC', maxlags=width - 1, use_correction=False).cov_params()
    # block sums are a Bartlett kernel in expectation; their realisation differs by a few % at n/width ~ 10^4 blocks
    np.testing.assert_allclose(np.sqrt(np.diag(ours)), np.sqrt(np.diag(theirs)), rtol=0.05)
    # the sandwich is not the i.i.d. covariance: correlated errors and regressors widen it (by sqrt((1 + ρxρu) /
    # (1 − ρxρu)) ≈ 1.9 and 1.4 here), far beyond the 5 % tolerance above
    iid = np.sqrt(np.diag(fit.cov_params()))
    assert np.all(np.sqrt(np.diag(ours))[1:] > 1.25 * iid[1:])


def test_sparse_jacobian_gives_the_same_sandwich():
    from scipy import sparse
    rng = np.random.default_rng(8)
    X = np.column_stack([np.ones(5000), ar1(rng, 5000, 0.6)])
    r = ar1(rng, 5000, 0.6)
    np.testing.assert_allclose(evidence.hac_covariance(sparse.csr_array(X), r, width=12),
                               evidence.hac_covariance(X, r, width=12), rtol=1e-10)


@pytest.mark.parametrize('slope', [0.0, -0.03])
def test_trend_test_is_ols_of_a_line(slope):
    rng = np.random.default_rng(3)
    times = np.linspace(10.0, 200.0, 12)
    values = 130.0 + slope * times + rng.normal(0.0, 1.5, times.size)
    row = trend_test(times, values, 'gravity_stiffness')
    fit = sm.OLS(values, sm.add_constant(times)).fit()
    assert row['slope'] == pytest.approx(fit.params[1], rel=1e-10)
    assert row['t_statistic'] == pytest.approx(fit.tvalues[1], rel=1e-10)
    assert row['p_value'] == pytest.approx(fit.pvalues[1], rel=1e-8)
