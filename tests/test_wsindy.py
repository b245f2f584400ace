"""Weak SINDy core against small systems with known truth (independent of the rig simulator).

The reference system is a damped pendulum driven by a held (zero-order-hold) input, integrated interval by
interval with tight tolerances: y'' = -a sin y - c y' + k u^2.
"""
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from aeropend_core.wsindy import library as lib
from aeropend_core.wsindy import selection, test_functions
from aeropend_core.errors import AeropendError, InsufficientDataError
from aeropend_core.wsindy.weak_form import (
    Equation,
    choose_support,
    fit_weak_sindy,
    kernel_derivatives,
)
from aeropend_core.wsindy.test_functions import spectral_corner

A, C, K = 131.75, 13.82, 30.0
DT = 1 / 490


def driven_pendulum(seed=0, n=4900, n_steps=10):
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(0.2, 2.3, n_steps), n // n_steps + 1)[:n]
    x = np.zeros(2)
    out = np.empty((n, 2))
    for i in range(n):
        out[i] = x
        x = solve_ivp(lambda _t, s, ui=u[i]: [s[1], -A * np.sin(s[0]) - C * s[1] + K * ui * ui], (0, DT), x,
                      rtol=1e-10, atol=1e-12).y[:, -1]
    return np.arange(n) * DT, u, out[:, 0], out[:, 1]


@pytest.fixture(scope='module')
def pendulum():
    return driven_pendulum()


def second_order(extra=()):
    terms = (lib.sine('angle'), lib.derivative('angle'), lib.product('u', 'u', hold=True), *extra)
    return Equation('angle', terms, order=2)


def noisy(x, psnr_db, rng):
    return x + rng.normal(0, np.max(np.abs(x)) * 10 ** (-psnr_db / 20), x.shape)


def test_test_function_decays_at_first_interior_point():
    for m in (8, 20, 60, 200):
        p = test_functions.test_function_power(m, 1e-10)
        assert (1 - ((m - 1) / m) ** 2) ** p <= 1e-10
        assert (1 - ((m - 1) / m) ** 2) ** (p - 1) > 1e-10 or p == 2


def test_kernel_derivative_matches_finite_difference():
    m, p = 30, 6
    w = kernel_derivatives(m, p, DT, 2) / DT
    w[:, [0, -1]] *= 2  # undo the trapezoid end weights (φ vanishes there anyway)
    fd = np.gradient(w[0], DT)
    assert np.allclose(w[1][2:-2], fd[2:-2], rtol=0, atol=0.02 * np.max(np.abs(w[1])))


def test_spectral_corner_tracks_bandwidth():
    t = np.arange(8192) * DT
    rng = np.random.default_rng(1)
    slow = np.sin(2 * np.pi * 1.0 * t) + 1e-3 * rng.normal(size=t.size)
    fast = np.sin(2 * np.pi * 8.0 * t) + 1e-3 * rng.normal(size=t.size)
    # The corner lies above the signal's own wavenumber (1 Hz -> 16.7 cycles per record) and moves up with it.
    assert spectral_corner(slow) > 16.7
    assert spectral_corner(fast) > 8 * 16.7
    assert spectral_corner(fast) > 1.5 * spectral_corner(slow)
    assert choose_support(slow)[0] > choose_support(fast)[0]


def test_second_order_weak_form_recovers_coefficients_clean(pendulum):
    t, u, y, _ = pendulum
    fit = fit_weak_sindy(t, {'angle': y, 'u': u}, [second_order()], threshold=None)['angle']
    # Clean data: only quadrature error remains (tolerance 0.2 %).
    assert fit.coefficient('sin(angle)') == pytest.approx(-A, rel=2e-3)
    assert fit.coefficient('dangle/dt') == pytest.approx(-C, rel=2e-3)
    assert fit.coefficient('u^2') == pytest.approx(K, rel=2e-3)


def test_held_input_quadrature_matters(pendulum):
    """Trapezoid quadrature of a held input shifts it by half a sample: ~1 % bias; the midpoint rule removes it."""
    t, u, y, _ = pendulum
    eq = Equation('angle', (lib.sine('angle'), lib.derivative('angle'), lib.product('u', 'u')), order=2)
    trapezoid = fit_weak_sindy(t, {'angle': y, 'u': u}, [eq], threshold=None)['angle'].coefficient('u^2')
    assert abs(trapezoid / K - 1) > 5e-3


def test_second_order_noise_and_quantisation_within_stated_error(pendulum):
    t, u, y, _ = pendulum
    rng = np.random.default_rng(7)
    y_meas = np.round(noisy(y, 50, rng) / (2 * np.pi / 1024)) * (2 * np.pi / 1024)
    fit = fit_weak_sindy(t, {'angle': y_meas, 'u': u}, [second_order()], threshold=None)['angle']
    for term, truth in (('sin(angle)', -A), ('dangle/dt', -C), ('u^2', K)):
        # 1.5 % tolerance at 50 dB + 10-bit quantisation on 10 s; and the error is within 4 standard errors.
        assert fit.coefficient(term) == pytest.approx(truth, rel=0.015)
        assert abs(fit.coefficient(term) - truth) < 4 * fit.standard_errors[term] + 1e-3 * abs(truth)


def test_mstls_drops_spurious_terms_first_order(pendulum):
    t, u, y, w = pendulum
    rng = np.random.default_rng(3)
    sig = {'angle': noisy(y, 50, rng), 'angular_rate': noisy(w, 50, rng), 'u': u}
    terms = tuple(lib.polynomial(['angle', 'angular_rate'], 2) + [lib.sine('angle'),
                                                                 lib.product('u', 'u', hold=True)])
    result = fit_weak_sindy(t, sig, [Equation('angle', terms), Equation('angular_rate', terms)])
    assert set(result['angle'].selected) == {'angular_rate'}
    assert set(result['angular_rate'].selected) == {'sin(angle)', 'angular_rate', 'u^2'}
    assert result['angular_rate'].coefficient('u^2') == pytest.approx(K, rel=0.02)


def test_segments_are_fitted_together():
    t1, u1, y1, _ = driven_pendulum(seed=1, n=2450, n_steps=5)
    t2, u2, y2, _ = driven_pendulum(seed=2, n=2450, n_steps=5)
    both = fit_weak_sindy([t1, t2], [{'angle': y1, 'u': u1}, {'angle': y2, 'u': u2}], [second_order()],
                          threshold=None)['angle']
    one = fit_weak_sindy(t1, {'angle': y1, 'u': u1}, [second_order()], threshold=None)['angle']
    assert both.n_test_functions > one.n_test_functions
    assert both.coefficient('u^2') == pytest.approx(K, rel=3e-3)


def test_inputs_enter_only_where_asked(pendulum):
    t, u, y, _ = pendulum
    fit = fit_weak_sindy(t, {'angle': y, 'u': u}, [second_order()])['angle']
    assert not any('sin(u' in name or 'cos(u' in name for name in fit.candidates)


def test_too_short_window_is_refused(pendulum):
    t, u, y, _ = pendulum
    with pytest.raises(InsufficientDataError, match='shorter than the test-function support'):
        fit_weak_sindy(t[:40], {'angle': y[:40], 'u': u[:40]}, [second_order()], half_width=30)


def test_nan_is_refused(pendulum):
    t, u, y, _ = pendulum
    y = y.copy()
    y[100] = np.nan
    with pytest.raises(InsufficientDataError, match='NaN'):
        fit_weak_sindy(t, {'angle': y, 'u': u}, [second_order()])


def test_constant_target_is_refused(pendulum):
    t, u, _, _ = pendulum
    with pytest.raises(InsufficientDataError, match='constant'):
        fit_weak_sindy(t, {'angle': np.full_like(t, 0.3), 'u': u}, [second_order()])


def test_missing_signal_and_bad_sampling_are_named(pendulum):
    t, u, y, _ = pendulum
    with pytest.raises(AeropendError, match="'u'"):
        fit_weak_sindy(t, {'angle': y}, [second_order()])
    t_bad = t.copy()
    t_bad[500:] += 0.05
    with pytest.raises(AeropendError, match='uniformly sampled'):
        fit_weak_sindy(t_bad, {'angle': y, 'u': u}, [second_order()])


def test_fixed_threshold_and_excluded_samples(pendulum):
    t, u, y, w = pendulum
    terms = (lib.variable('angular_rate'), lib.variable('angle'), lib.sine('angle'), lib.product('u', 'u', hold=True))
    fixed = fit_weak_sindy(t, {'angle': y, 'angular_rate': w, 'u': u}, [Equation('angle', terms)],
                           threshold=0.05)['angle']
    assert fixed.threshold == 0.05
    assert set(fixed.selected) == {'angular_rate'}
    assert fixed.coefficient('angular_rate') == pytest.approx(1.0, rel=1e-3)
    exclude = np.zeros(t.size, bool)
    exclude[::490] = True  # one sample per second: every support covering one is dropped
    full = fit_weak_sindy(t, {'angle': y, 'u': u}, [second_order()], threshold=None, half_width=40)['angle']
    masked = fit_weak_sindy(t, {'angle': y, 'u': u}, [second_order()], threshold=None, half_width=40,
                            exclude=exclude)['angle']
    assert 0 < masked.n_test_functions < full.n_test_functions
    assert masked.coefficient('u^2') == pytest.approx(K, rel=5e-3)


def test_exhaustive_search_matches_brute_force():
    """The depth-first small-support search (incremental Cholesky, pruning) finds the same best support as
    scoring every combination with a fresh solve, including nearly collinear columns and kept terms."""
    import itertools
    rng = np.random.default_rng(0)
    for trial in range(60):
        n = int(rng.integers(4, 11))
        a = rng.normal(size=(60, n))
        if trial % 3 == 0:
            a[:, 1] = a[:, 0] + 1e-3 * rng.normal(size=60)
        truth = np.zeros(n)
        truth[rng.choice(n, 3, replace=False)] = rng.normal(size=3)
        b = a @ truth + 0.05 * rng.normal(size=60)
        an = a / np.linalg.norm(a, axis=0)
        gram, rhs = an.T @ an, an.T @ b / np.linalg.norm(b)
        keep = np.zeros(n, bool)
        keep[0] = trial % 2 == 1
        usable = np.ones(n, bool)
        w_ls = selection._solve_subset(gram, rhs, usable, 1e-12)
        gwls = gram @ w_ls
        c0 = float(w_ls @ gwls)
        free = np.flatnonzero(~keep)
        size = min(4, free.size)
        best, best_support = np.inf, None
        for k in range(1, size + 1):
            for combo in itertools.combinations(free, k):
                support = keep.copy()
                support[list(combo)] = True
                w = selection._solve_subset(gram, rhs, support, 1e-12)
                value = selection._loss(gram, w, gwls, c0, np.sqrt(c0), 0.8, n)
                if value < best - 1e-12:
                    best, best_support = value, support
        found = selection._exhaustive(gram, rhs, gwls, c0, np.sqrt(c0), 0.8, n, keep, free, size, np.inf, 1e-12)
        assert np.array_equal(found, best_support), trial


def _straightforward_mstls(gram, rhs, keep, usable, ridge, alpha, grid):
    """The MSTLS λ sweep of selection._select written plainly: every thresholding step and every candidate
    support solved afresh (no memo, no skipping of supports scored before), scored with the same loss."""
    w_ls = selection._solve_subset(gram, rhs, usable, 1e-12)
    gwls = gram @ w_ls
    c0 = float(w_ls @ gwls)
    denom = np.sqrt(max(c0, 0.0)) or 1.0
    n_terms = max(int(np.count_nonzero(usable)), 1)
    w_full = selection._solve_subset(gram, rhs, usable, ridge)
    best_loss, best_w, best_lam = np.inf, w_ls, 0.0
    for lam in grid:
        support, w = usable.copy(), w_full
        for _ in range(usable.size + 1):
            new = support & (((np.abs(w) >= lam) & (np.abs(w) <= 1 / lam)) | keep)
            if np.array_equal(new, support):
                break
            support = new
            w = selection._solve_subset(gram, rhs, support, ridge)
        w = selection._solve_subset(gram, rhs, w != 0.0, 1e-12)
        value = selection._loss(gram, w, gwls, c0, denom, alpha, n_terms)
        if value < best_loss - 1e-12:
            best_loss, best_w, best_lam = value, w, lam
    return best_w, best_lam


@pytest.mark.parametrize('n', [18, 70])
def test_memoised_threshold_sweep_equals_straightforward_sweep(n):
    """The λ sweep remembers recent solves keyed by the support's bit mask (libraries of up to 62 terms; more
    solve every time): it must give exactly (bit for bit) the coefficients and λ of solving every support
    afresh, on seeded problems with sparse truth, nearly collinear columns and kept terms."""
    rng = np.random.default_rng(n)
    grid = selection.THRESHOLD_GRID
    for trial in range(6):
        a = rng.normal(size=(4 * n, n))
        a[:, 1] = a[:, 0] + 1e-3 * rng.normal(size=4 * n)
        truth = np.zeros(n)
        truth[rng.choice(n, 4, replace=False)] = rng.normal(size=4) * 10.0 ** rng.uniform(-2, 1, 4)
        b = a @ truth + 0.05 * rng.normal(size=4 * n)
        an = a / np.linalg.norm(a, axis=0)
        gram, rhs = an.T @ an, an.T @ b / np.linalg.norm(b)
        keep = np.zeros(n, bool)
        keep[2] = trial % 2 == 1
        usable = np.ones(n, bool)
        fast_w, fast_lam = selection._select(gram, rhs, keep, usable, 1e-6, 0.8, grid, False, 0)
        plain_w, plain_lam = _straightforward_mstls(gram, rhs, keep, usable, 1e-6, 0.8, grid)
        assert np.array_equal(fast_w, plain_w), trial
        assert fast_lam == plain_lam, trial
        assert 0 < np.count_nonzero(fast_w) < n, trial     # the sweep really thresholded something


def test_term_partial_derivatives_match_central_differences():
    rng = np.random.default_rng(2)
    signals = {'a': rng.normal(size=40) + 2, 'b': rng.normal(size=40), 'c': rng.normal(size=40)}
    terms = (lib.polynomial(['a', 'b', 'c'], 3, include_constant=True) + lib.sine_cosine('a')
             + [lib.derivative('b'), lib.variable('c', hold=True), lib.product('a', 'a', 'b', hold=True)])
    for term in terms:
        numeric = lib.Term(term.name, term.variables, term.function)   # no partial: central difference
        for name in signals:
            exact = term.derivative_wrt(signals, name)
            assert np.allclose(exact, numeric.derivative_wrt(signals, name), rtol=1e-6, atol=1e-8), (term.name, name)
            if name not in term.variables:
                assert not np.any(exact)


def test_banded_forward_substitution_matches_lapack():
    """The whitening's banded forward substitution (row by row over all right-hand sides) gives LAPACK dtbtrs'
    L⁻¹B (within rounding; the fit on the benchmark window was bit for bit the same), and refuses a zero pivot."""
    from scipy.linalg import lapack

    from aeropend_core.wsindy.noise_model import _banded_lower_solve, _cholesky_band
    rng = np.random.default_rng(3)
    for k, band, ncol in ((1216, 9, 19), (150, 8, 5), (40, 0, 3), (7, 6, 2)):
        ab = np.zeros((band + 1, k))
        ab[0] = 4.0 + rng.random(k)
        for u in range(1, band + 1):
            ab[u, :k - u] = 0.3 * rng.standard_normal(k - u) / u
        chol = _cholesky_band(ab)
        rhs = np.asfortranarray(rng.standard_normal((k, ncol)))
        expected, info = lapack.dtbtrs(chol, rhs, uplo='L')
        assert info == 0
        got = _banded_lower_solve(chol, rhs)
        assert got.shape == expected.shape and got.flags.f_contiguous
        np.testing.assert_allclose(got, expected, rtol=1e-13, atol=1e-13 * np.max(np.abs(expected)))
    chol[0, 3] = 0.0
    assert _banded_lower_solve(chol, rhs).shape[0] == 0


def test_banded_cholesky_matches_lapack():
    """The whitening's banded Cholesky factor (LAPACK's unblocked dpbtf2 step for step) equals dpbtrf's within
    rounding (bit for bit with OpenBLAS on this machine), and a matrix that is not positive definite is refused
    with the 1-based column, as LAPACK's info."""
    from scipy.linalg import lapack

    from aeropend_core.wsindy.noise_model import _band_cholesky_unblocked
    rng = np.random.default_rng(4)
    for k, band in ((1216, 9), (150, 8), (30, 0), (9, 5)):
        ab = np.zeros((band + 1, k), order='F')
        ab[0] = 4.0 + rng.random(k)
        for u in range(1, band + 1):
            ab[u, :k - u] = 0.3 * rng.standard_normal(k - u) / u
        expected, info = lapack.dpbtrf(ab.copy(order='F'), lower=1)
        got = ab.copy(order='F')
        assert info == 0 and _band_cholesky_unblocked(got) == 0
        np.testing.assert_allclose(got, expected, rtol=1e-13, atol=1e-13)
    ab = np.zeros((2, 5), order='F')
    ab[0] = [1.0, 1.0, -1.0, 1.0, 1.0]
    assert _band_cholesky_unblocked(ab) == 3


def test_removal_scoring_equals_one_solve_per_candidate():
    """The backward path scores every single-term removal from one factorisation (inverse downdate): it must pick
    the same term and return exactly (bit for bit) the weights and loss of solving each candidate support afresh,
    on seeded problems with sparse truth, kept terms and nearly collinear columns (where it falls back to the
    per-candidate solves)."""
    rng = np.random.default_rng(11)
    for trial in range(40):
        n = int(rng.integers(3, 19))
        a = rng.normal(size=(8 * n, n))
        if trial % 4 == 0:
            a[:, 1] = a[:, 0] + 1e-6 * rng.normal(size=8 * n)    # Cholesky pivot below 1e-8: fallback path
        truth = np.zeros(n)
        truth[rng.choice(n, min(3, n), replace=False)] = rng.normal(size=min(3, n))
        b = a @ truth + 0.05 * rng.normal(size=8 * n)
        an = a / np.linalg.norm(a, axis=0)
        gram, rhs = an.T @ an, an.T @ b / np.linalg.norm(b)
        w_ls = selection._solve_subset(gram, rhs, np.ones(n, bool), 1e-12)
        gwls = gram @ w_ls
        c0 = float(w_ls @ gwls)
        support = rng.random(n) < 0.8
        support[:2] = True
        candidates = support.copy()
        candidates[int(rng.integers(n))] = False
        args = (gram, rhs, support.copy(), candidates, 1e-12, gwls, c0, np.sqrt(c0), 0.8, n)
        fast = selection._best_removal(*args)
        plain = selection._best_single_change(gram, rhs, support.copy(), candidates, False, *args[4:])
        assert fast[1] == plain[1], trial
        assert fast[0] == plain[0] and np.array_equal(fast[2], plain[2]), trial


def test_options_are_held_once_and_an_unknown_one_is_named():
    """The settings live in one WeakSindyOptions (issue #44); a call may change fields by keyword, and an unknown
    setting is a clear error naming the known ones, not a TypeError deep inside."""
    from aeropend_core.errors import AeropendError
    from aeropend_core.wsindy import library
    from aeropend_core.wsindy.weak_form import Equation, WeakSindyOptions, fit_weak_sindy
    time = np.arange(0.0, 5.0, 0.002)
    signals = {'x': np.exp(-2 * time)}
    equation = [Equation('x', library.polynomial(['x'], degree=1))]
    by_object = fit_weak_sindy(time, signals, equation, WeakSindyOptions(threshold=None, half_width=40))
    by_keyword = fit_weak_sindy(time, signals, equation, threshold=None, half_width=40)
    assert by_object['x'].coefficients == by_keyword['x'].coefficients
    assert by_object['x'].half_width == 40 and by_object['x'].coefficients['x'] == pytest.approx(-2.0, rel=1e-3)
    with pytest.raises(AeropendError, match=r"unknown weak SINDy option\(s\) \['treshold'\]"):
        fit_weak_sindy(time, signals, equation, treshold=0.1)


def test_blocked_weak_rows_equal_the_sliding_window_rows():
    """The blocked quadrature (data cut into blocks of the stride; the padding past the record's end is written
    as zeros, not pre-filled, and must be: the kernel's zero padding times uninitialised memory could be 0·NaN)
    gives the rows of the plain sliding-window product, including supports whose blocks reach past the end; and
    the noise model's blocked window dots do the same for several channels."""
    from aeropend_core.wsindy.noise_model import _window_dots
    from aeropend_core.wsindy.quadrature import _weak_rows
    rng = np.random.default_rng(11)
    for n, width, step, ncol in ((500, 41, 10, 3), (333, 25, 7, 1), (97, 13, 4, 5)):
        columns = rng.standard_normal((n, ncol))
        weights = rng.standard_normal(width)
        count = (n - width) // step + 1
        starts = np.arange(count) * step + (n - width - (count - 1) * step)   # the last support ends at n
        expected = _weak_rows(columns, weights, starts, 0)                     # step 0: sliding-window path
        assert not np.array_equal(expected, np.zeros_like(expected))
        np.testing.assert_allclose(_weak_rows(columns, weights, starts, step), expected, rtol=1e-12,
                                   atol=1e-12 * np.max(np.abs(expected)))
        kernels = rng.standard_normal((ncol, 2, width))
        first = int(starts[0])
        dots = _window_dots(np.ascontiguousarray(columns.T), kernels, first, step, count)
        direct = np.array([[sum(kernels[c, k] @ columns[s:s + width, c] for c in range(ncol)) for k in range(2)]
                           for s in starts])
        np.testing.assert_allclose(dots, direct, rtol=1e-12, atol=1e-12 * np.max(np.abs(direct)))


def test_sandwich_block_sums_are_those_of_add_at():
    """The reported (sandwich) covariance sums the scores per block with bincount: the same additions in the same
    order as np.add.at, so the covariance is the one the unbuffered scatter gave, bit for bit."""
    from aeropend_core.wsindy.noise_model import _bartlett_width, _sandwich_covariance
    rng = np.random.default_rng(5)
    rows, j = 900, 6
    a = rng.standard_normal((rows, j))
    resid = np.convolve(rng.standard_normal(rows + 9), np.ones(10) / 10, mode='valid')   # correlated rows
    sel = np.array([0, 2, 3, 5])
    groups = np.repeat([0, 1, 2], [300, 450, 150])
    bread = np.linalg.inv(a[:, sel].T @ a[:, sel])
    sigma2 = float(resid @ resid) / (rows - sel.size)
    got = _sandwich_covariance(a, resid, sel, sigma2 * bread, groups)
    # the former implementation, written out
    scores = a[:, sel] * resid[:, None]
    width = _bartlett_width(resid)
    assert width > 1
    meat = np.zeros((sel.size, sel.size))
    shifts = (0, width // 2)
    for shift in shifts:
        block = np.empty(rows, dtype=np.int64)
        label, start = 0, 0
        for stop in [*(np.flatnonzero(np.diff(groups)) + 1), rows]:
            block[start:stop] = label + (np.arange(stop - start) + shift) // width
            label = int(block[stop - 1]) + 1
            start = stop
        sums = np.zeros((label, sel.size))
        np.add.at(sums, block, scores)
        meat += sums.T @ sums
    expected = (sigma2 * bread / sigma2) @ (meat / len(shifts)) @ (sigma2 * bread / sigma2) * rows / (rows - sel.size)
    assert np.array_equal(got, expected)


def test_equations_fitted_on_threads_equal_the_sequential_fits(pendulum, monkeypatch):
    """fit_weak_sindy fits the equations of a call on EQUATION_WORKERS threads: the answer is the same bit for bit
    whatever the number of workers (coefficients, standard errors, covariances, λ), in the equations' order."""
    from aeropend_core.wsindy import weak_form
    t, u, y, w = pendulum
    rng = np.random.default_rng(7)
    data = {'angle': noisy(y, 40, rng), 'rate': noisy(w, 40, rng), 'u': u}
    equations = [second_order(),
                 Equation('rate', (lib.sine('angle'), lib.variable('rate'), lib.product('u', 'u', hold=True),
                                   lib.variable('angle'), lib.constant())),
                 Equation('angle', (lib.variable('rate'), lib.variable('angle'), lib.constant()))]
    fits = {}
    for workers in (1, 2, 3):
        monkeypatch.setattr(weak_form, 'EQUATION_WORKERS', workers)
        fits[workers] = fit_weak_sindy(t, data, equations)
    for workers in (2, 3):
        for one, other in zip(fits[1].equations, fits[workers].equations):
            assert one.name == other.name
            assert one.coefficients == other.coefficients and one.standard_errors == other.standard_errors
            assert np.array_equal(one.covariance, other.covariance)
            assert one.threshold == other.threshold or (np.isnan(one.threshold) and np.isnan(other.threshold))
    assert fits[1]['rate'].coefficients                                   # the test compares real fits
