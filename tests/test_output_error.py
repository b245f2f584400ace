"""Unit tests of the output-error fit on its own (``diagnosis.compare.fit_model`` over ``diagnosis.output_error``):
simulated records whose truth is the default rig (tests/conftest.py ``clean_record``: 60 s, LHC, 40 dB, 10-bit)."""
from __future__ import annotations

import pytest

from aeropend_core.diagnosis import output_error
from aeropend_core.diagnosis.compare import fit_model, prepare
from aeropend_core.io.recording import from_columns
from aeropend_core.model.parameters import DEFAULT_PARAMETERS as P
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate

#: The nominal parameters and their truth (per unit inertia, SI).
TRUTH = {'gravity_stiffness': P.gravity_stiffness, 'damping': P.damping, 'thrust_gain': P.thrust_gain}


def prepared(record):
    return prepare(from_columns(record.columns(with_truth=False), source='simulated'))


@pytest.fixture(scope='module')
def clean_prep(clean_record):
    return prepared(clean_record)


def test_nominal_parameters_recovered_within_2_percent(clean_prep):
    """Free-run multiple shooting on the training part: mgd/J, c/J and the thrust gain within 2 % of the truth
    (measured here: 0.4-0.6 %), with finite, positive standard errors."""
    fit = fit_model(clean_prep)
    for name, truth in TRUTH.items():
        assert fit.parameters[name] == pytest.approx(truth, rel=0.02), name
        assert 0 < fit.standard_errors[name] < 0.02 * truth, name
    assert fit.success


def test_sparse_jacobian_gives_the_dense_answer(clean_prep, monkeypatch):
    """Long records keep the Jacobian sparse and take LSMR steps; forced on a short one, the fit is the same."""
    dense = fit_model(clean_prep)
    monkeypatch.setattr(output_error, 'SPARSE_SEGMENTS', 0)
    sparse = fit_model(clean_prep)
    for name in TRUTH:
        assert sparse.parameters[name] == pytest.approx(dense.parameters[name], rel=1e-4), name
        assert sparse.standard_errors[name] == pytest.approx(dense.standard_errors[name], rel=1e-2), name


def test_an_effect_in_the_structure_is_fitted_with_the_nominal_terms(clean_record):
    """Coulomb friction of 4 rad/s^2 hidden in the simulator: fitted with it, its size within 5 % and the nominal
    parameters still within 2 %."""
    record = simulate(clean_record.duty, effects={'coulomb_friction': 4.0},
                      noise=MeasurementNoise(psnr_db=40, quantise=True), seed=7)
    fit = fit_model(prepared(record), ['coulomb_friction'])
    assert fit.parameters['friction_acceleration'] == pytest.approx(4.0, rel=0.05)
    for name, truth in TRUTH.items():
        assert fit.parameters[name] == pytest.approx(truth, rel=0.02), name


def test_a_dead_zone_gate_is_held_over_each_sample_like_the_armature_voltage():
    """The gate switches with Va, which is held over each sample: the model's free run matches a fine integration
    of the held gate (on at odd and at even samples), in the compiled kernel and in its numpy twin. Read as point
    values the gate switched half a sample early on average (error here 0.57 % of the swing, 6x the bound);
    the fit absorbed that lead as -0.75 % on gravity_stiffness and thrust_gain of 300 s dead-zone records."""
    import numpy as np
    ts, n = 1.0 / 490.0, 800
    gravity, damping, gain, threshold = 130.0, 1.5, 20.0, 0.6
    voltage = np.full(n, 1.2)
    gate_signal = np.full(n, 0.3)
    for on, off in ((101, 250), (400, 551)):      # switches at odd and at even samples
        gate_signal[on:off] = 1.0
    structure = output_error.Structure(('dead_zone',))
    data = output_error.SegmentedData(voltage, np.zeros(n), np.zeros(n), [(0, n)], ts, gate_signal)
    row = structure.row({'gravity_stiffness': gravity, 'damping': damping, 'thrust_gain': gain,
                         'threshold_voltage': threshold})[None, :]
    compiled = data.simulate(structure, row, np.zeros((1, 1, 2)))[0]
    twin = np.full((1, n), np.nan)
    output_error._simulate_numpy(row, voltage, np.zeros(n), gate_signal, np.array([0]), np.array([n]),
                                 np.zeros((1, 1, 2)), ts, False, True, twin, [])
    # reference: RK4 with 64 sub-steps per sample, the thrust held over each sample
    state, reference, h = np.zeros(2), np.empty(n), ts / 64

    def rate(x, u):
        return np.array([x[1], -gravity * np.sin(x[0]) - damping * x[1] + u])
    for i in range(n):
        reference[i] = state[0]
        u = gain * voltage[i] ** 2 * (gate_signal[i] >= threshold)
        for _ in range(64):
            k1 = rate(state, u)
            k2 = rate(state + 0.5 * h * k1, u)
            k3 = rate(state + 0.5 * h * k2, u)
            state = state + h / 6 * (k1 + 2 * k2 + 2 * k3 + rate(state + h * k3, u))
    index = data.residual_index
    swing = np.ptp(reference)
    assert swing > 0.2
    assert np.max(np.abs(compiled[index] - reference[index])) < 0.001 * swing
    assert np.allclose(twin[0, index], compiled[index], rtol=0, atol=1e-9 * swing)


def _user_data(n=2400, ts=1.0 / 490.0):
    import numpy as np
    rng = np.random.default_rng(5)
    voltage = np.repeat(rng.uniform(0.4, 2.2, n // 200), 200)
    return output_error.SegmentedData(voltage, 0.15 * voltage, np.zeros(n), [(0, n // 2), (n // 2, n)], ts)


def test_a_users_effect_runs_compiled_with_the_python_paths_values(clean_record, scoped_catalog):
    """A user's effect (with the thrust keyword, beside a built-in lag and friction) runs in the compiled kernel:
    its free run equals the numpy path's (which calls the Python function) to rounding. And a user's function that
    is a built-in effect's law (drag -Cd W|W|) fits to the built-in's value and sigma on the same record."""
    import numpy as np
    from aeropend_core.diagnosis.user_kernel import compiled_user_terms
    from aeropend_core.model.effects import EffectParameter, register_effect

    @register_effect('test_user_inflow', 'thrust falls with the rod rate', replace=True,
                     parameters=[EffectParameter('test_user_loss', 's/rad', 'loss', 0.05, 0.0, 1.0)])
    def inflow(angle, angular_rate, test_user_loss, thrust):
        return -test_user_loss * thrust * angular_rate

    @register_effect('test_user_drag', 'drag written by a user', replace=True,
                     parameters=[EffectParameter('test_user_drag_coefficient', '1/rad', 'Cd', 4.0, 0.0, 100.0)])
    def drag(angle, angular_rate, test_user_drag_coefficient):
        return -test_user_drag_coefficient * angular_rate * np.abs(angular_rate)

    data = _user_data()
    structure = output_error.Structure(('thrust_lag', 'test_user_inflow', 'coulomb_friction'))
    assert compiled_user_terms(structure.user_terms()) is not None
    values = {**TRUTH, 'armature_resistance': 1.0, 'time_constant': 0.1, 'test_user_loss': 0.05,
              'friction_acceleration': 2.0}
    rows = np.array([structure.row(values), structure.row({**values, 'test_user_loss': 0.2})])
    initial = np.zeros((2, 2, 2))
    initial[:, :, 0] = 0.3
    compiled = data.simulate(structure, rows, initial)
    python = np.full_like(compiled, np.nan)
    output_error._simulate_numpy(rows, data.voltage, data.current, data.gate_signal, data.seg_start,
                                 data.seg_stop, initial, data.sample_time, True, False, python,
                                 structure.user_terms())
    index = data.residual_index
    assert np.ptp(compiled[:, index]) > 0.2 and np.ptp(compiled[0, index] - compiled[1, index]) > 1e-3
    assert np.allclose(compiled[:, index], python[:, index], rtol=0, atol=1e-12)
    # beside a discovered term (the discovery stage on a model with the user's effect): both compiled
    from aeropend_core.diagnosis.discovery import find_term, term_effect
    both = output_error.Structure(('test_user_inflow', term_effect(find_term('sin(2*angle)'))))
    assert compiled_user_terms(both.user_terms()) is not None
    rows = np.array([both.row({**values, 'test_user_loss': 0.05, both.parameter_names[-1]: c})
                     for c in (0.0, 3.0)])
    compiled = data.simulate(both, rows, initial)
    python = np.full_like(compiled, np.nan)
    output_error._simulate_numpy(rows, data.voltage, data.current, data.gate_signal, data.seg_start,
                                 data.seg_stop, initial, data.sample_time, False, False, python,
                                 both.user_terms())
    assert np.ptp(compiled[0, index] - compiled[1, index]) > 1e-3
    assert np.allclose(compiled[:, index], python[:, index], rtol=0, atol=1e-12)

    record = simulate(clean_record.duty[:int(25.0 / clean_record.sample_time)], effects={'quadratic_drag': 4.0},
                      noise=MeasurementNoise(psnr_db=40, quantise=True), seed=7)
    prep = prepared(record)
    builtin, user = fit_model(prep, ['quadratic_drag']), fit_model(prep, ['test_user_drag'])
    assert builtin.parameters['drag_coefficient'] == pytest.approx(4.0, rel=0.3)
    assert user.parameters['test_user_drag_coefficient'] == pytest.approx(
        builtin.parameters['drag_coefficient'], rel=1e-6)
    assert user.standard_errors['test_user_drag_coefficient'] == pytest.approx(
        builtin.standard_errors['drag_coefficient'], rel=1e-4)


_SOFT_TABLE = {'gain': 30.0}


def test_a_users_effect_numba_cannot_compile_runs_in_python_and_says_so_once(scoped_catalog):
    """A function reading a Python dict cannot be compiled: it runs in the numpy path (same free run as that path
    gives) and the user is told once which effect runs in Python and what to do. One that compiles to other values
    (int64 overflows where Python's integers do not) is caught by the check against Python, also with a
    coefficient whose typical and start values are 0 (as in a written module)."""
    import warnings

    import numpy as np
    from aeropend_core.diagnosis.user_kernel import compiled_user_terms
    from aeropend_core.model.effects import EffectParameter, register_effect

    @register_effect('test_user_table', 'a spring from a table', replace=True,
                     parameters=[EffectParameter('test_user_table_scale', '1/s^2', 'scale', 1.0, 0.0, 10.0)])
    def table(angle, angular_rate, test_user_table_scale):
        return -test_user_table_scale * _SOFT_TABLE['gain'] * angle

    data = _user_data()
    structure = output_error.Structure(('test_user_table',))
    row = structure.row({**TRUTH, 'armature_resistance': 1.0, 'test_user_table_scale': 2.0})[None, :]
    initial = np.zeros((1, 2, 2))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        first = data.simulate(structure, row, initial)
        second = data.simulate(structure, row, initial)
    said = [str(w.message) for w in caught if 'test_user_table' in str(w.message)]
    assert len(said) == 1 and 'runs in Python' in said[0] and 'math or numpy' in said[0], said
    python = np.full_like(first, np.nan)
    output_error._simulate_numpy(row, data.voltage, data.current, data.gate_signal, data.seg_start,
                                 data.seg_stop, initial, data.sample_time, False, False, python,
                                 structure.user_terms())
    assert np.array_equal(first, python, equal_nan=True) and np.array_equal(first, second, equal_nan=True)

    @register_effect('test_user_overflow', 'a spring in exact integers', replace=True,
                     parameters=[EffectParameter('test_user_overflow_scale', '1/s^2', 'scale', 0.0, -1.0, 1.0)])
    def overflow(angle, angular_rate, test_user_overflow_scale):    # Python's integers do not overflow; int64
        return -test_user_overflow_scale * float(int(angle * 1e7) ** 3) * 1e-21

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        assert compiled_user_terms(output_error.Structure(('test_user_overflow',)).user_terms()) is None
    said = [str(w.message) for w in caught if 'test_user_overflow' in str(w.message)]
    assert len(said) == 1 and 'where Python gives' in said[0], said     # checked at a non-zero scale


def test_a_fitted_model_that_runs_away_is_flagged_not_squared_into_an_overflow(clean_prep):
    """A fit whose parameters make the model unstable on this input (here the damping turned to -50 1/s: the rod
    spins up without bound) is evaluated without a floating-point warning and flagged ``diverged``; judged as a
    candidate it gives no evidence and no standard errors (before: its squared overflow was averaged into the error
    statistics and its covariance could give a sigma of 1e-6 on a coefficient of 200)."""
    import dataclasses
    import math
    import warnings

    from aeropend_core.diagnosis.candidates import assess
    from aeropend_core.diagnosis.compare import Comparison, evaluate
    base, stable = fit_model(clean_prep), fit_model(clean_prep, ['coulomb_friction'])
    runaway = dataclasses.replace(stable, parameters={**stable.parameters, 'damping': -50.0})
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        healthy, flagged = evaluate(clean_prep, stable), evaluate(clean_prep, runaway)
        judged = assess(clean_prep, Comparison((), base, evaluate(clean_prep, base)),
                        Comparison(('coulomb_friction',), runaway, flagged), 'coulomb_friction')
    assert not healthy.diverged and math.isfinite(healthy.rms_error)
    assert flagged.diverged
    assert not judged.significant and not judged.heldout_only
    assert all(math.isnan(sigma) for sigma in judged.standard_errors.values()), judged.standard_errors
    assert 'grows without bound' in judged.explanation, judged.explanation
