"""The fast paths of weak SINDy against the straightforward ones, on seeded full-state windows of the simulator.

Agreement bar for a faster path that does not round exactly like the straightforward one: the **same support**
(selected terms) and every coefficient within **1e-6 relative or 1e-3 of its own standard error, whichever is
looser**. Why that bar and not bit for bit: the fit itself is that sensitive to rounding. Perturbing the data by
one ulp per sample (×(1 ± 2.2e-16)) moves the coefficients by up to 1.3e-7 relative with the full method and
pysindy's 18-term library, 1.5e-7 with the default library and 1.3e-5 (5.8e-5 σ) with the plain GLS method
(5 seeds × 30/40/50 dB on one machine, `bench/wsindy_ulp_sensitivity.py`; how much depends on the CPU and BLAS,
`test_one_ulp_of_data_stays_inside_the_agreement_bar` checks only that it stays inside the bar); a change in the
order of a sum moves the result by about as much as that.

The straightforward path writes the noise model out with dense (or plainly sparse) matrices, one row per test
function (the kernel of type a shifted to its start, K_a):

- residual covariance (:func:`_dense_measurement_band`): R_v = Σ_a K_a·diag(c_av), c_av(t) = −Σ_{j of type a}
  w_j ∂θ_j/∂v(t) (c_0v = 1 for the target's lhs), Σ = Σ_v σ_v² R_v R_vᵀ, its band;
- noise compensation (:func:`_dense_noise_gram`): Σ⁻¹ from the Cholesky factor,
  q_ab(t) = Σ_{r,s} (Σ⁻¹)[r,s] k_a(t − start_r) k_b(t − start_s), C_jk = Σ_v σ_v² Σ_t J_j(t) J_k(t) q_ab(t).
"""
import numpy as np
import pytest
from scipy import linalg, sparse

from aeropend_core.identify.pendulum import FULL_STATE_TARGETS, identify_full_state
from aeropend_core.model.parameters import SAMPLE_TIME
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import add_noise
from aeropend_core.sim.simulate import simulate
from aeropend_core.wsindy import weak_form

SIGNALS = FULL_STATE_TARGETS + ('armature_voltage',)
#: the two libraries the project uses: Va in every equation (the benchmark's, pysindy's) and the default one
LIBRARIES = {'same as pysindy': {'voltage_in': FULL_STATE_TARGETS}, 'default': {}}
RELATIVE, SIGMAS = 1e-6, 1e-3


def window(seed: int, psnr_db: float = 40.0, duration: float = 10.0) -> dict[str, np.ndarray]:
    """One simulated LHC window at 490 Hz with white noise at `psnr_db` on every signal (as the benchmark's)."""
    trajectory = simulate(lhc_schedule(duration, seed=seed).duty(SAMPLE_TIME, duration), seed=seed)
    rng = np.random.default_rng(1000 + seed)
    data = {'t': trajectory.time}
    for name in SIGNALS:
        data[name] = add_noise(trajectory.truth[name], psnr_db, rng)
    return data


def _shifted(model, a):
    """(K, n) sparse: row r is the kernel of type a placed at the start of test function r."""
    k = len(model.rows)
    starts = model.first + model.rows * model.step
    width = model.kernels.shape[1]
    rows = np.repeat(np.arange(k), width)
    cols = (starts[:, None] + np.arange(width)).ravel()
    inside = cols < model.n
    values = np.tile(model.kernels[a], k)
    return sparse.csr_matrix((values[inside], (rows[inside], cols[inside])), shape=(k, model.n))


def _dense_measurement_band(model, w):
    """weak_form's residual covariance Σ = Σ_v σ_v² R_v R_vᵀ over the used rows, written out; its band in
    LAPACK lower storage (rows as the fast path: grid band + 1) and the bandwidth."""
    k = len(model.rows)
    sigma_total = sparse.csr_matrix((k, k))
    for sigma, is_target, idx, types, jac in model.signals:
        response = _shifted(model, 0) if is_target else sparse.csr_matrix((k, model.n))
        if w is not None:
            for a in sorted(set(types.tolist())):
                c = -(w[idx][types == a] @ jac[types == a])
                response = response + _shifted(model, a) @ sparse.diags(c)
        sigma_total = sigma_total + sigma ** 2 * (response @ response.T)
    if sigma_total.nnz == 0:          # no noisy signal enters: unit white noise on the target (as the fast path)
        response = _shifted(model, 0)
        sigma_total = response @ response.T
    dense = sigma_total.toarray()
    band = model.pairs.shape[2] - 1
    ab = np.zeros((band + 1, k))
    for u in range(band + 1):
        ab[u, :k - u] = np.diagonal(dense, -u)
    return ab, band


def _dense_noise_gram(model, chol, n_terms):
    """weak_form's noise compensation (C, c) written out with dense Σ⁻¹ and one sparse row per test function."""
    k = chol.shape[1]
    inverse = linalg.cho_solve_banded((chol, True), np.eye(k))

    def shifted(a):
        return _shifted(model, a)

    def q(a, b):
        return np.asarray(shifted(a).multiply(inverse @ shifted(b).toarray()).sum(axis=0)).ravel()

    gram = np.zeros((n_terms, n_terms))
    rhs = np.zeros(n_terms)
    cache = {}
    for sigma, is_target, idx, types, jac in model.signals:
        for j in range(idx.size):
            for i in range(idx.size):
                pair = (min(types[i], types[j]), max(types[i], types[j]))
                weight = cache[pair] if pair in cache else cache.setdefault(pair, q(*pair))
                gram[idx[i], idx[j]] += sigma ** 2 * np.sum(jac[i] * jac[j] * weight)
            if is_target:
                pair = (0, types[j])
                weight = cache[pair] if pair in cache else cache.setdefault(pair, q(*pair))
                rhs[idx[j]] += sigma ** 2 * np.sum(jac[j] * weight)
    return gram, rhs


def _fits(data, **options):
    return {eq.name: eq for eq in identify_full_state(data, **options).result.equations}


def _assert_agree(fast, plain, label):
    for name, eq in plain.items():
        got = fast[name]
        assert got.selected == eq.selected, (label, name, got.selected, eq.selected)
        for term, value in eq.coefficients.items():
            allowed = max(RELATIVE * abs(value), SIGMAS * eq.standard_errors[term])
            assert abs(got.coefficients[term] - value) <= allowed, (label, name, term, got.coefficients[term], value)
            assert got.standard_errors[term] == pytest.approx(eq.standard_errors[term], rel=1e-6), (label, term)


def test_dense_measurement_band_is_the_fast_one_on_real_equations():
    """The straightforward residual covariance is the fast one (relative 1e-12) on a real equation, both with the
    target-only noise (no w yet) and with every signal's noise for a given w: the reference itself is checked."""
    from aeropend_core.wsindy import noise_model
    captured = []
    original = weak_form._measurement_band

    def spy(model, w):
        captured.append((model, None if w is None else w.copy()))
        return original(model, w)
    weak_form._measurement_band = spy
    try:
        _fits(window(3), **LIBRARIES['default'])
    finally:
        weak_form._measurement_band = original
    assert any(w is None for _, w in captured) and any(w is not None for _, w in captured)
    for model, w in captured:
        fast, band = noise_model._measurement_band(model, w)
        dense, dense_band = _dense_measurement_band(model, w)
        assert band == dense_band
        k = fast.shape[1]
        for u in range(band + 1):       # entries past the last row are not part of the matrix
            np.testing.assert_allclose(fast[u, :k - u], dense[u, :k - u], rtol=1e-12,
                                       atol=1e-12 * np.max(np.abs(dense[0])))


@pytest.mark.slow
@pytest.mark.parametrize('library', LIBRARIES)
def test_fast_noise_model_agrees_with_the_dense_formulas(library, monkeypatch):
    """The full method with the fast residual covariance (fused coefficient products, blocked window products)
    and the fast noise compensation (band of Σ⁻¹, banded overlap, vectorised weighted products) against the same
    fit with both written out with dense matrices: same support, coefficients within the bar, on seeded windows
    at 30 and 40 dB (one window each: a second 40 dB seed took the same paths and a third of the test's time;
    more seeds and noise levels are `bench/wsindy_ulp_sensitivity.py`'s business)."""
    options = LIBRARIES[library]
    cases = [(0, 40.0), (2, 30.0)]
    fast = [_fits(window(seed, psnr), **options) for seed, psnr in cases]
    monkeypatch.setattr(weak_form, '_noise_gram', _dense_noise_gram)
    monkeypatch.setattr(weak_form, '_measurement_band', _dense_measurement_band)
    for (seed, psnr), got in zip(cases, fast):
        plain = _fits(window(seed, psnr), **options)
        _assert_agree(got, plain, (library, seed, psnr))
        assert sum(len(eq.selected) for eq in plain.values()) >= 8    # real fits, not empty supports


def test_one_ulp_of_data_stays_inside_the_agreement_bar():
    """One ulp of data moves the fit by less than the bar, on the same support (so the bar is not so tight that
    rounding alone breaks it). How far it moves (1e-10 .. 1e-7 relative, depending on the CPU, the BLAS build and
    its kernel) is a measurement of this machine, not a property of the method: `bench/wsindy_ulp_sensitivity.py`
    reports it, this test does not assert it."""
    largest = 0.0
    for seed in (0, 1):
        data = window(seed)
        rng = np.random.default_rng(seed)
        moved = dict(data)
        for name in SIGNALS:
            x = data[name]
            moved[name] = np.where(rng.random(x.size) < 0.5, np.nextafter(x, np.inf), np.nextafter(x, -np.inf))
        for options in LIBRARIES.values():
            a, b = _fits(data, **options), _fits(moved, **options)
            _assert_agree(b, a, ('one ulp', seed))
            largest = max(largest, max(abs(b[n].coefficients[t] / v - 1) for n in a
                                       for t, v in a[n].coefficients.items()))
    assert largest < RELATIVE, largest
