"""The reported +- count a slow remainder in the residual; the decisions keep the block-sum sigma (issue 40).

A model that misses a little leaves white noise plus a small misfit correlated over hundreds of samples. Andrews'
AR(1) bandwidth reads the lag-1 correlation only (small), so the block sums are far shorter than the misfit and
the +- came out narrow: on the second simulator the nominal parameters' z had RMS 1.2-1.9 where the residual held
such a remainder. Known truth here: linear least squares with a known slow AR(1) remainder added to white noise.
Session 23 widened the sigma inside the decisions and a look-alike that should have read "confounded" named a cable
torque; here the block-sum covariance is returned unchanged and only the extra variance is kept for the reported +-
(aeropend_core.diagnosis.remainder_doubt), after every decision.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from aeropend_core.diagnosis.remainder_doubt import remainder_dict, widen_for_slow_remainder
from aeropend_core.diagnosis.slow_remainder import SLOW_REMAINDER_T, sandwich_and_remainder, slow_remainder
from aeropend_core.stats import hac_covariance


def remainder_covariance(jacobian, residuals, groups=None, sample_spacing=1.0):
    """The block-sum covariance with the remainder's extra variance added on the diagonal (the reported sigma's)."""
    covariance, remainder = sandwich_and_remainder(jacobian, residuals, groups, sample_spacing)
    extra = np.asarray(remainder.get('extra_variance', np.zeros(covariance.shape[0])))
    return covariance + np.diag(extra), remainder

SEGMENTS, LENGTH = 3, 2400


def _design(rng):
    t = np.arange(SEGMENTS * LENGTH) / 245.0          # [s] a 40 s record at 245 Hz (the fit's stride)
    steps = np.sign(np.sin(2 * np.pi * 0.11 * t + rng.uniform(0, 6)))
    return np.column_stack([np.sin(2 * np.pi * 0.37 * t), np.cos(2 * np.pi * 0.23 * t) * steps, np.ones_like(t)])


def _ar1(rng, n, phi, sd):
    from scipy.signal import lfilter
    x = lfilter([1.0], [1.0, -phi], rng.normal(0.0, sd * np.sqrt(1 - phi ** 2), n + 2000))[2000:]
    return x


def _trial(rng, share, correlation_samples):
    x = _design(rng)
    n = len(x)
    phi = np.exp(-1.0 / correlation_samples)
    groups = np.repeat(np.arange(SEGMENTS), LENGTH)
    noise = rng.normal(0.0, np.sqrt(1 - share), n)
    if share > 0:
        noise = noise + np.concatenate([_ar1(rng, LENGTH, phi, np.sqrt(share)) for _ in range(SEGMENTS)])
    beta = np.array([0.5, -0.3, 0.1])
    y = x @ beta + noise
    estimate, *_ = np.linalg.lstsq(x, y, rcond=None)
    residuals = y - x @ estimate
    jacobian = -x                                     # d residual / d beta
    old = hac_covariance(jacobian, residuals, groups)
    new, remainder = remainder_covariance(jacobian, residuals, groups, sample_spacing=1 / 245.0)
    z_old = (estimate - beta) / np.sqrt(np.diag(old))
    z_new = (estimate - beta) / np.sqrt(np.diag(new))
    assert np.allclose(sandwich_and_remainder(jacobian, residuals, groups)[0], old)     # the decisions' sigma kept
    return z_old, z_new, remainder


def test_a_slow_remainder_beside_white_noise_is_counted_and_the_sigma_covers_the_truth():
    rng = np.random.default_rng(20261207)
    z_old, z_new, modelled = [], [], []
    for _ in range(150):
        old, new, remainder = _trial(rng, share=0.15, correlation_samples=150.0)
        z_old.append(old)
        z_new.append(new)
        modelled.append(remainder['modelled'])
    z_old, z_new = np.abs(np.array(z_old)), np.abs(np.array(z_new))
    # the AR(1) bandwidth misses the remainder: far below 95 % within 2 sigma (this is what fails before)
    assert np.mean(z_old <= 2) < 0.85
    assert np.mean(modelled) > 0.95
    # the modelled remainder gives the stated coverage for the input's coefficients, and is not far too wide
    for column in (0, 1):
        within_two = np.mean(z_new[:, column] <= 2)
        within_one = np.mean(z_new[:, column] <= 1)
        assert 0.90 <= within_two <= 0.995, (column, within_two)
        assert 0.55 <= within_one <= 0.85, (column, within_one)
    # a constant (a segment's level: the slowest regressor there is) is the hardest case: the remainder's fitted
    # correlation time scatters (10-90 %: 0.5-2x the truth) and the constant feels all of it. Much better, not there
    assert np.mean(z_new[:, 2] <= 2) >= 0.8 > np.mean(z_old[:, 2] <= 2) + 0.3


def test_white_residuals_keep_the_block_sum_sandwich():
    rng = np.random.default_rng(7)
    kept = 0
    for _ in range(60):
        x = _design(rng)
        residuals = rng.normal(0.0, 1.0, len(x))
        groups = np.repeat(np.arange(SEGMENTS), LENGTH)
        new, remainder = remainder_covariance(-x, residuals, groups)
        if not remainder['modelled']:
            kept += 1
            assert np.allclose(new, hac_covariance(-x, residuals, groups))
    assert kept >= 57          # a t >= 3 gate: about 1 % of white records read as a remainder (one-sided)


def test_the_remainder_fit_reads_share_and_correlation_time():
    rng = np.random.default_rng(11)
    n = SEGMENTS * LENGTH
    residuals = rng.normal(0.0, np.sqrt(0.7), n) + np.concatenate(
        [_ar1(rng, LENGTH, np.exp(-1 / 80.0), np.sqrt(0.3)) for _ in range(SEGMENTS)])
    fitted = slow_remainder(residuals, np.repeat(np.arange(SEGMENTS), LENGTH))
    assert fitted['t_statistic'] >= SLOW_REMAINDER_T
    assert 0.15 <= fitted['share'] <= 0.45
    assert 40 <= fitted['correlation_samples'] <= 160


@pytest.mark.parametrize('sparse_jacobian', [False, True])
def test_a_sparse_jacobian_gives_the_dense_answer(sparse_jacobian):
    from scipy import sparse
    rng = np.random.default_rng(3)
    x = _design(rng)
    residuals = rng.normal(0.0, 0.8, len(x)) + np.concatenate(
        [_ar1(rng, LENGTH, np.exp(-1 / 100.0), 0.6) for _ in range(SEGMENTS)])
    groups = np.repeat(np.arange(SEGMENTS), LENGTH)
    dense, _ = remainder_covariance(-x, residuals, groups)
    other, remainder = remainder_covariance(sparse.csr_array(-x) if sparse_jacobian else -x, residuals, groups)
    assert remainder['modelled']
    assert np.allclose(dense, other, rtol=1e-9)


def test_the_correlation_product_is_the_matrix_product():
    from aeropend_core.diagnosis.slow_remainder import _ar1_correlation_times
    rng = np.random.default_rng(5)
    x = rng.normal(size=(37, 3))
    phi = 0.93
    matrix = phi ** np.abs(np.subtract.outer(np.arange(37), np.arange(37)))
    assert np.allclose(_ar1_correlation_times(x, phi), matrix @ x, atol=1e-12)


@dataclass(frozen=True)
class _Fit:
    standard_errors: dict
    extra: dict


@dataclass(frozen=True)
class _Comparison:
    fit: _Fit
    effects: tuple = ('coulomb_friction',)


@dataclass(frozen=True)
class _Found:
    effect: str
    standard_errors: dict


@dataclass(frozen=True)
class _Catalog:
    current: _Comparison
    selected: _Comparison | None
    final: _Comparison
    found: tuple


def _remainder(**extra_variance):
    return {'share': 0.2, 'correlation_time': 0.8, 't_statistic': 7.5, 'modelled': True,
            'extra_variance': dict(extra_variance)}


def test_the_reported_sigma_adds_the_remainders_variance_once_and_says_so():
    """Known numbers: sigma 0.3 with an extra variance of 0.16 reads 0.5; a parameter without extra keeps its sigma;
    the selected effect's sigma widens by its model's extra variance; a second call widens nothing more."""
    current = _Comparison(_Fit({'damping': 0.3, 'thrust_gain': 2.0}, {'slow_remainder': _remainder(damping=0.16)}),
                          effects=())
    selected = _Comparison(_Fit({'damping': 0.3, 'friction_acceleration': 0.03},
                                {'slow_remainder': _remainder(damping=0.16, friction_acceleration=0.0016)}))
    found = (_Found('coulomb_friction', {'friction_acceleration': 0.03}),)
    catalog = _Catalog(current, selected, selected, found)
    widened, notes = widen_for_slow_remainder(catalog)
    assert widened.current.fit.standard_errors == pytest.approx({'damping': 0.5, 'thrust_gain': 2.0})
    assert widened.selected.fit.standard_errors['friction_acceleration'] == pytest.approx(0.05)
    assert widened.final is widened.selected
    assert widened.found[0].standard_errors['friction_acceleration'] == pytest.approx(0.05)
    assert widened.current.fit.extra['slow_remainder']['widening'] == pytest.approx({'damping': 5 / 3})
    assert len(notes) == 2 and 'slow remainder (20% of its variance, correlated over 0.8 s' in notes[0]
    assert 'damping x1.67' in notes[0] and 'decided without it' in notes[0]
    assert remainder_dict(widened.current)['widening']['damping'] == pytest.approx(5 / 3)
    again, _ = widen_for_slow_remainder(widened)
    assert again.current.fit.standard_errors == widened.current.fit.standard_errors
    assert again.found[0].standard_errors == widened.found[0].standard_errors


def test_without_a_modelled_remainder_nothing_is_widened_or_said():
    current = _Comparison(_Fit({'damping': 0.3}, {'slow_remainder': {'share': 0.01, 'correlation_time': 0.1,
                                                                     't_statistic': 1.2, 'modelled': False}}))
    widened, notes = widen_for_slow_remainder(_Catalog(current, None, current, ()))
    assert widened.current.fit.standard_errors == {'damping': 0.3} and notes == []
    assert remainder_dict(widened.current)['modelled'] is False


@pytest.mark.slow
def test_a_diagnosis_on_the_second_simulator_widens_its_reported_sigma_and_says_so():
    """Seed 52007 of the second rig (a development seed: cable spring and dry friction, 59 dB): the told fit leaves a
    slow remainder (the rig's tanh friction and its own integrator are not the model's). The reported +- count it,
    the note, the comparison's Doubt and the JSON say so; the fit's block-sum sigma is what they grow from."""
    import json

    from aeropend_core.diagnosis.diagnose import diagnose
    from aeropend_core.io.recording import from_columns
    from aeropend_core.present.results_text import comparison_dict, comparison_text
    from aeropend_core.testing import second_rig
    record = second_rig.draw(52007, effects=['friction_torque', 'cable_spring'])
    told = diagnose(from_columns(record.columns, source='second rig 52007'),
                    effects=('cable_torque', 'coulomb_friction'), candidates=(), drift=False, discovery=False)
    remainder = told.current.fit.extra['slow_remainder']
    assert remainder['modelled'] and remainder['t_statistic'] >= SLOW_REMAINDER_T
    assert 0 < remainder['share'] < 1 and remainder['correlation_time'] > 0.05       # [s]: slow, not the noise
    widening = remainder['widening']
    assert max(widening.values()) > 1.05
    reported = told.reported_errors(told.current)
    for name, growth in widening.items():
        block_sum = told.current.fit.standard_errors[name] / growth
        assert reported[name] == pytest.approx(np.hypot(block_sum, np.sqrt(remainder['extra_variance'][name])))
    assert any('slow remainder' in note for note in told.notes)
    assert 'slow remainder' in comparison_text(told.current)
    assert comparison_dict(told.current)['slow_remainder']['widening'] == widening
    numbers = json.loads(json.dumps(told.to_dict(), default=float))
    assert numbers['slow_remainder']['model']['widening'] == pytest.approx(widening)
