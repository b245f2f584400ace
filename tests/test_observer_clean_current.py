"""The motor observer on a clean current channel (issue 40, "no confident wrong basin"; session 21).

Second-rig seed 48047 (thrust lag 0.166 s, angle filter 34 ms) with the angle at its drawn 44.8 dB and Va, Ia at
70 dB (a clean current sense beside a noisy encoder). The observer explains the current to ~2.2 mA, beyond 1.5x the
current's tiny noise (0.8 mA, mostly its rounding), and the old rule dropped it; the fit then ran on Va - R Ia, whose
La dIa/dt error (~22 mV RMS against the observer's bound of ~2.7 mV) put the filter's delay at its 50 ms bound with
z +5.2, gravity and thrust gain at z +3.3 (a confident wrong number). The observer is now kept when its thrust
voltage is the better one, and the fit told the true structure comes out within 2 sigma of every truth (measured
|z| <= 0.6; tolerance 2 sigma: the ± must hold the truth). The rule's own cases are checked on built MotorFits.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from threadpoolctl import threadpool_limits

from aeropend_core.diagnosis.candidates import assess
from aeropend_core.diagnosis.compare import compare, prepare
from aeropend_core.diagnosis.diagnose import diagnose
from aeropend_core.diagnosis.checks import DOES_NOT_FIT
from aeropend_core.identify.plausibility import pinned_at_bound
from aeropend_core.io.recording import from_columns
from aeropend_core.signals import motor
from aeropend_core.signals.motor import MotorFit
from aeropend_core.model.effects import CATALOG
from aeropend_core.testing import second_rig

#: The second rig's effects on seed 48047 as bench/second_rig.py draws them, and its nominal parameters checked
EFFECTS_48047 = ['inflow_time_constant', 'filter_rc']
NOMINAL = ('gravity_stiffness', 'damping', 'thrust_gain')


def _fit(error: float, noise: float, fallback: float, resistance: float = 1.0) -> MotorFit:
    return MotorFit(parameters={'motor_resistance': resistance}, back_emf=np.zeros(3), current_rms_error=error,
                    current_noise_rms=noise, kind='inductance', fallback_voltage_error=fallback)


def test_the_rule_weighs_the_observer_against_its_fallback():
    # within 1.5x the noise: adequate as before, not "kept against the fallback"
    assert _fit(0.0012, 0.001, math.nan).adequate and not _fit(0.0012, 0.001, 0.02).kept_against_fallback
    # beyond it, no fallback error to weigh (the quasi-static model): dropped, as before
    assert not _fit(0.003, 0.001, math.nan).adequate
    # beyond it, bound R x sqrt(3^2 - 1^2) mA = 2.8 mV against a fallback of 20 mV: kept
    kept = _fit(0.003, 0.001, 0.02)
    assert kept.voltage_error_bound == pytest.approx(math.sqrt(8.0) * 1e-3)
    assert kept.adequate and kept.kept_against_fallback
    # a misfit as large as the fallback's own error (a motor the observer cannot write): dropped
    assert not _fit(0.03, 0.001, 0.04).adequate


def _told_fit(rule_margin: float, monkeypatch):
    monkeypatch.setattr(motor, 'FALLBACK_MARGIN', rule_margin)
    seed = 48047
    record = second_rig.draw(seed, effects=EFFECTS_48047, inputs_psnr_db=70.0)
    kinds = {kind: (name, parameter) for name, effect in CATALOG.items() if effect.builtin
             for kind, parameter in effect.kernel_terms}
    truth = {kinds[k][1]: v for k, v in record.truth.items() if k in kinds}
    truth.update({k: v for k, v in record.truth.items() if k in NOMINAL})
    effects = sorted({kinds[k][0] for k in record.truth if k in kinds})
    prep = prepare(from_columns(record.columns, source=f'second rig seed {seed}, Va and Ia at 70 dB'))
    return prep, compare(prep, effects).fit, truth


@pytest.mark.slow
def test_a_clean_current_keeps_the_observer_and_the_fit_holds_the_truth(monkeypatch):
    prep, fit, truth = _told_fit(motor.FALLBACK_MARGIN, monkeypatch)
    assert prep.motor is not None and prep.motor.kept_against_fallback
    assert prep.motor.current_rms_error > 1.5 * prep.motor.current_noise_rms    # the old rule's drop
    assert set(truth) == {'gravity_stiffness', 'damping', 'thrust_gain', 'time_constant', 'filter_delay'}
    for name, value in truth.items():
        z = (fit.parameters[name] - value) / fit.standard_errors[name]
        assert abs(z) <= 2.0, (name, fit.parameters[name], fit.standard_errors[name], value)
    # the filter's delay is well inside its 50 ms bound, not on it
    assert fit.parameters['filter_delay'] + 2 * fit.standard_errors['filter_delay'] < 0.05


def test_a_parameter_on_a_bound_of_its_range_is_pinned():
    assert pinned_at_bound('filter_delay', 0.05) and pinned_at_bound('filter_delay', 0.05 - 1e-9)
    assert not pinned_at_bound('filter_delay', 0.049) and not pinned_at_bound('filter_delay', 0.0)
    assert not pinned_at_bound('gravity_stiffness', 1e9) and not pinned_at_bound('filter_delay', math.nan)


@pytest.mark.slow
def test_the_old_rule_put_the_filter_on_its_bound_which_carries_no_finite_sigma(monkeypatch):
    """The case before the fix (the rule with no fallback margin): the observer dropped, the filter's delay on its
    50 ms bound. It is said at its bound, its reported sigma is infinite (no finite z), the verdict says the model
    does not fit, and as a candidate it is not significant."""
    monkeypatch.setattr(motor, 'FALLBACK_MARGIN', 0.0)
    record = second_rig.draw(48047, effects=EFFECTS_48047, inputs_psnr_db=70.0)
    recording = from_columns(record.columns, source='second rig seed 48047, Va and Ia at 70 dB')
    with threadpool_limits(1):
        told = diagnose(recording, effects=('angle_filter', 'thrust_lag'), candidates=(), drift=False,
                        discovery=False)
    assert told.prepared.motor is None
    assert told.current.parameters['filter_delay'] == pytest.approx(0.05, abs=1e-6)
    assert math.isinf(told.reported_errors(told.current)['filter_delay'])
    assert 'at the bound' in told.parameter_warnings['filter_delay']
    assert told.verdict == DOES_NOT_FIT
    # as a candidate beside the lag: pinned at its upper bound, so its t statistic is 0
    with threadpool_limits(1):
        lag_only = compare(told.prepared, ['thrust_lag'])
        candidate = assess(told.prepared, lag_only, told.current, 'angle_filter')
    assert candidate.t_statistic == 0.0
