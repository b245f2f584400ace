"""Exact sensitivities of the output-error simulation (aeropend_core.diagnosis.sensitivity, issue 41): the kernel's
derivatives equal central differences of the simulation itself, and a fit with them gives the fit with forward
differences (the method before) to stated tolerances."""
from __future__ import annotations

import numpy as np
import pytest

from aeropend_core.diagnosis import output_error as oe
from aeropend_core.diagnosis.sensitivity import sensitivity_kernel

TS = 1.0 / 490.0


def _inputs(n=3000, seed=3):
    rng = np.random.default_rng(seed)
    voltage = np.repeat(rng.uniform(0.3, 2.4, n // 150 + 1), 150)[:n]
    current = 0.2 * voltage + 0.01 * rng.standard_normal(n)
    return voltage, current


def _simulate(theta, voltage, current, segments, initial, lag_on, gate_on):
    out = np.full((1, len(voltage)), np.nan)
    starts = np.array([s for s, _ in segments], dtype=np.int64)
    stops = np.array([e for _, e in segments], dtype=np.int64)
    oe._simulate_kernel(np.ascontiguousarray(theta[None, :]), voltage, current, voltage, starts, stops,
                        np.ascontiguousarray(initial[None]), TS, lag_on, gate_on, out, -1, 0, oe.no_extra, False,
                        oe.FRICTION_SMOOTHING)
    return out[0]


def _sensitivities(theta, voltage, current, segments, initial, lag_on, gate_on, columns):
    n = len(voltage)
    out = np.full((1, n), np.nan)
    d_columns = np.zeros((n, len(columns)))
    d_initial = np.zeros((n, 2))
    sensitivity_kernel(theta, voltage, current, voltage, np.array([s for s, _ in segments], dtype=np.int64),
                       np.array([e for _, e in segments], dtype=np.int64), np.ascontiguousarray(initial), TS,
                       lag_on, gate_on, oe.FRICTION_SMOOTHING, oe.MIN_TIME_CONSTANT, oe.FRICTION_STABILITY,
                       float(oe.STRIDE), np.array(columns, dtype=np.int64), out, d_columns, d_initial)
    return out[0], d_columns, d_initial


@pytest.mark.parametrize('lag_on, gate_on, friction', [(False, False, 0.5), (True, True, 0.5),
                                                       (True, False, 20.0), (False, True, 20.0)])
def test_the_sensitivities_are_the_derivative_of_the_discrete_simulation(lag_on, gate_on, friction):
    """Every smooth column (gravity, damping, thrust gain, resistance, dry friction in both of its smoothing
    regimes, drag, angle term, offset, lag time) and both initial states against central differences of the
    simulation kernel: largest error within 1e-5 of the column's largest derivative (central differences of
    relative step 1e-5 are good to ~1e-8 here; a missing term of the chain rule is off by 1e-2 to 1)."""
    voltage, current = _inputs()
    segments = [(0, 1500), (1500, 3000)]
    theta = np.array([40.0, 1.2, 30.0, 0.9, friction, 0.3, 0.5, 0.02, 0.05, 0.6])
    initial = np.array([[0.3, -0.5], [0.1, 0.8]])
    columns = list(range(9))
    out, d_columns, d_initial = _sensitivities(theta, voltage, current, segments, initial, lag_on, gate_on, columns)
    index = np.isfinite(out)
    assert np.allclose(out[index], _simulate(theta, voltage, current, segments, initial, lag_on, gate_on)[index],
                       rtol=0, atol=1e-12)
    for c in columns:
        step = 1e-5 * max(abs(theta[c]), 1.0)
        up, down = theta.copy(), theta.copy()
        up[c] += step
        down[c] -= step
        numeric = (_simulate(up, voltage, current, segments, initial, lag_on, gate_on)
                   - _simulate(down, voltage, current, segments, initial, lag_on, gate_on))[index] / (2 * step)
        exact = d_columns[index, c]
        assert np.max(np.abs(exact - numeric)) <= 1e-5 * max(np.max(np.abs(numeric)), 1e-9), c
    for j in range(2):
        step = 1e-6
        up, down = initial.copy(), initial.copy()
        up[:, j] += step
        down[:, j] -= step
        numeric = (_simulate(theta, voltage, current, segments, up, lag_on, gate_on)
                   - _simulate(theta, voltage, current, segments, down, lag_on, gate_on))[index] / (2 * step)
        assert np.max(np.abs(d_initial[index, j] - numeric)) <= 1e-5 * np.max(np.abs(numeric)), j


def test_the_fits_jacobian_with_sensitivities_is_the_differenced_one(monkeypatch):
    """The Jacobian the optimiser gets (the nominal model: exact columns) against the forward differences it got
    before, at the same point: within 1e-4 of each column's size (forward differences of
    relative step 1e-6 carry ~1e-6 truncation and rounding)."""
    voltage, current = _inputs(4000, seed=8)
    n = len(voltage)
    data = oe.SegmentedData(voltage, current, np.zeros(n), [(0, 2000), (2000, 4000)], TS)
    names = [name for name in oe.Structure(()).parameter_names]
    start = {'gravity_stiffness': 40.0, 'damping': 1.0, 'thrust_gain': 30.0, 'armature_resistance': 0.9}
    structure = oe.Structure(())
    truth_rows = structure.row(start)[None, :]
    data.angle = np.nan_to_num(data.simulate(structure, truth_rows, np.array([[[0.2, 0.0], [0.1, 0.3]]]))[0])
    captured = {}

    def capture(method):
        def spy(fun, x0, jac, **kwargs):
            captured[method] = jac(x0)
            raise _Stop
        return spy

    for method in ('exact', 'differences'):
        monkeypatch.setenv(oe.JACOBIAN_VARIABLE, method)
        monkeypatch.setattr(oe, 'least_squares', capture(method))
        with pytest.raises(_Stop):
            oe.fit_output_error(data, structure, {**start, 'damping': 1.3}, fixed={})
    exact, differenced = captured['exact'], captured['differences']
    assert exact.shape == differenced.shape == (len(data.residual_index), len(names) + 4)
    for c in range(exact.shape[1]):
        size = np.max(np.abs(differenced[:, c]))
        assert np.max(np.abs(exact[:, c] - differenced[:, c])) <= 1e-4 * size, c


class _Stop(Exception):
    pass


#: (hidden effect, its size, effects fitted): friction (exact columns), lag (exact, with its basin search), dead zone
#: (the threshold differenced and profiled) and the nominal model on a record with friction (a misfit model).
ANSWER_CASES = [({'coulomb_friction': 4.0}, ('coulomb_friction',)), ({'thrust_lag': 0.15}, ('thrust_lag',)),
                ({'dead_zone': 0.6}, ('dead_zone',)), ({'coulomb_friction': 4.0}, ())]


@pytest.mark.parametrize('hidden, fitted', ANSWER_CASES)
def test_a_fit_with_exact_sensitivities_gives_the_differenced_fits_answer(hidden, fitted, monkeypatch):
    """The fit the diagnosis makes (basins, threshold profile, input ensemble), with exact sensitivities and with
    forward differences (the method before): every parameter within 2 % of its sigma of the other's and every sigma
    within 1 % (measured on a 60 s record: parameters within 3e-6 relative, sigmas within 1.3e-4)."""
    from aeropend_core.diagnosis.compare import fit_model, prepare
    from aeropend_core.io.recording import from_columns
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import simulate
    duty = lhc_schedule(40, seed=11).duty(duration=40)
    record = simulate(duty, effects=hidden, noise=MeasurementNoise(psnr_db=40, quantise=True), seed=11)
    prep = prepare(from_columns(record.columns(with_truth=False), source='simulated'))
    fits = {}
    for method in ('exact', 'differences'):
        monkeypatch.setenv(oe.JACOBIAN_VARIABLE, method)
        fits[method] = fit_model(prep, fitted)
    exact, differenced = fits['exact'], fits['differences']
    assert exact.free_names == differenced.free_names
    for name in differenced.free_names:
        sigma = differenced.standard_errors[name]
        assert np.isfinite(sigma) and sigma > 0, name
        assert abs(exact.parameters[name] - differenced.parameters[name]) <= 0.02 * sigma, name
        assert exact.standard_errors[name] == pytest.approx(sigma, rel=0.01), name


def test_a_parameter_the_output_does_not_move_gets_an_infinite_sigma_not_a_zero_one():
    """A blind Jacobian column (the data say nothing about that parameter: a 0.09 ms filter delay on a 22 Hz log)
    is found in dense and sparse Jacobians, so its sigma is infinite rather than the pseudo-inverse's ~0."""
    from scipy import sparse

    from aeropend_core.diagnosis.output_error import blind_columns
    jacobian = np.array([[1.0, 0.0, 2.0, 5.0], [3.0, 1e-14, -1.0, 0.0], [0.5, 0.0, 0.0, 7.0]])
    assert blind_columns(jacobian, 3).tolist() == [False, True, False]
    assert blind_columns(sparse.csr_array(jacobian), 3).tolist() == [False, True, False]
    assert blind_columns(np.zeros((3, 2)), 2).tolist() == [True, True]
    assert blind_columns(jacobian * 1e-20, 4).tolist() == [False, True, False, False]   # relative, not absolute


@pytest.mark.parametrize('effects, segments', [((), [(5000, 6200)]), (('thrust_lag',), [(5000, 6200), (7000, 7900)]),
                                               (('thrust_lag',), [(30, 1200)]), (('coulomb_friction',), [(0, 900)])])
def test_the_jacobian_of_a_stretch_is_the_one_computed_over_the_whole_record(effects, segments, monkeypatch):
    """The sensitivity kernel runs on the window of the record the segments (and the lag's run-in) cover, not on
    the whole record: a few seconds of a long record (the drift test's stretches) give the Jacobian the whole-record
    arrays gave, bit for bit, with and without a lag, and when the run-in reaches the record's start."""
    voltage, current = _inputs(9000, seed=4)
    n = len(voltage)
    data = oe.SegmentedData(voltage, current, np.zeros(n), segments, TS)
    structure = oe.Structure(effects)
    values = {'gravity_stiffness': 40.0, 'damping': 1.0, 'thrust_gain': 30.0, 'armature_resistance': 0.9,
              'time_constant': 0.3, 'friction_acceleration': 2.0}
    row = structure.row(values)
    initial = np.array([[0.2, 0.1]] * len(segments))
    exact = np.array([c if c < 9 else -1 for c in range(len(row))][:len(row)], dtype=np.int64)
    scale = np.ones(len(exact))
    measured = np.zeros(len(data.residual_index))
    lo, hi = oe._kernel_window(data, structure, row)
    assert hi == segments[-1][1] and (lo > 0) == (segments[0][0] > 1000)
    windowed = oe._exact_jacobian(data, structure, row, initial, exact, scale, measured)
    monkeypatch.setattr(oe, '_kernel_window', lambda *_args: (0, n))
    whole = oe._exact_jacobian(data, structure, row, initial, exact, scale, measured)
    assert np.any(windowed[0] != 0.0)
    assert np.array_equal(windowed[0], whole[0])
    for mine, theirs in zip(windowed[1], whole[1]):
        assert np.array_equal(mine, theirs)


def test_rates_without_friction_skip_the_tanh_and_equal_the_full_formula_bit_for_bit():
    """s26: without dry friction (fc = 0) the output-error and sensitivity kernels skip its tanh
    (:func:`aeropend_core.diagnosis.sensitivity.friction_term`). The rate sum equals the formula with the zero term
    fc tanh(w / smooth), sign bits included, on states with zeros of both signs, a zero or tiny damping (products
    that underflow) and a gated thrust of either zero; and a nonzero or -0 coefficient keeps the product."""
    import math

    import numba

    from aeropend_core.diagnosis.sensitivity import friction_term

    @numba.njit
    def both(a, y, b, w, t, fc, cd, kc, smooth):
        skipped = -a * math.sin(y) - b * w + t - friction_term(fc, w, smooth) - cd * w * abs(w) - kc * y
        full = -a * math.sin(y) - b * w + t - fc * math.tanh(w / smooth) - cd * w * abs(w) - kc * y
        return skipped, full

    values = [0.0, -0.0, 1e-300, -1e-300, 5e-324, -5e-324, 0.3, -0.3, 2.0, -2.0]
    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(3000):
        y, w, t = (values[k] if k < len(values) else rng.normal() for k in rng.integers(0, len(values) + 2, 3))
        a, b, cd, kc = (float(rng.choice([0.0, 0.0, 130.0, 0.4, 1e-300])) for _ in range(4))
        for fc in (0.0, -0.0, 3.0):
            skipped, full = both(a, y, b, w, t, fc, cd, kc, oe.FRICTION_SMOOTHING)
            assert skipped == full or (math.isnan(skipped) and math.isnan(full)), (a, y, b, w, t, fc)
            assert math.copysign(1.0, skipped) == math.copysign(1.0, full), (a, y, b, w, t, fc)
            checked += 1
    assert checked == 9000


@pytest.mark.parametrize('lag_on, gate_on, friction', [(False, False, 0.0), (True, True, 0.5), (True, False, 20.0),
                                                       (False, True, 0.0), (True, True, 0.0)])
def test_the_sensitivity_pass_simulates_the_simulations_numbers_bit_for_bit(lag_on, gate_on, friction):
    """s26: a fit with exact sensitivities takes its residuals from the sensitivity pass (one kernel call where a
    simulation and a pass were two): its simulated angle must be the simulation kernel's, bit for bit, with a gate
    that cuts negative drive voltages (zeros of both signs in the thrust) and a lag whose run-in starts gated."""
    rng = np.random.default_rng(11)
    voltage, current = _inputs(4000, seed=6)
    voltage = voltage - 0.8                                 # some levels below 0 V: gated thrust of sign -0
    segments = [(0, 1500), (1500, 2900), (2900, 4000)]
    theta = np.array([130.0, 2.0, 140.0, 1.0, friction, 0.01, 0.3, 0.02, 0.05, 0.4])
    initial = rng.normal(0.0, 0.2, (len(segments), 2))
    simulated = _simulate(theta, voltage, current, segments, initial, lag_on, gate_on)
    passed, _, _ = _sensitivities(theta, voltage, current, segments, initial, lag_on, gate_on, [0, 1, 2, 3, 8])
    assert np.isfinite(simulated).sum() > 1500
    assert np.array_equal(simulated.view(np.int64), passed.view(np.int64))


def test_the_block_jacobian_is_the_coo_forms_bit_for_bit():
    """s26: a long record's sparse Jacobian is built in compressed-row form directly
    (:func:`aeropend_core.diagnosis.jacobian_blocks.block_jacobian`); it must be the COO form's (the code before)
    once converted: the same entries in the same order, so LSMR's products, and the fit, are the same bit for bit."""
    from scipy import sparse

    from aeropend_core.diagnosis.jacobian_blocks import block_jacobian

    rng = np.random.default_rng(2)
    m, p, n_seg = 700, 5, 9
    seg = np.sort(rng.integers(0, n_seg, m))
    dense = rng.normal(size=(m, p))
    dense[rng.random((m, p)) < 0.05] = 0.0                 # explicit zeros (clipped rows) stay entries
    dense[3, 1] = -0.0
    initial = [rng.normal(size=m), rng.normal(size=m)]
    n = p + 2 * n_seg
    columns = np.concatenate([np.tile(np.arange(p), m), p + 2 * seg, p + 2 * seg + 1])
    rows = np.concatenate([np.repeat(np.arange(m), p), np.arange(m), np.arange(m)])
    before = sparse.csr_array((np.concatenate([dense.ravel(), initial[0], initial[1]]), (rows, columns)), shape=(m, n))
    after = block_jacobian(dense, initial, seg, n)
    assert after.shape == before.shape and after.nnz == before.nnz == m * (p + 2)
    assert np.array_equal(after.indptr, before.indptr) and np.array_equal(after.indices, before.indices)
    assert np.array_equal(after.data.view(np.int64), before.data.view(np.int64))
    x, y = rng.normal(size=n), rng.normal(size=m)
    assert np.array_equal(after @ x, before @ x) and np.array_equal(after.T @ y, before.T @ y)
