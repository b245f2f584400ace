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
