"""A continuously varying input (a duty chirp) on aeropend's own simulator: the nominal fit must not be biased.

Before session 19 a 0.1-2.5 Hz chirp gave thrust gain +11.8 % (z +7) and Ra +3.4 % (z +19) on a clean record of the
default rig: the measured Va - R Ia was used as the thrust voltage, and Ia lags Va by La/Ra (about one sample), which
left ~11 % of the back-EMF's swing in it. The motor observer (which models La) now runs on a continuous Va too.
"""
from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from aeropend_core.model.parameters import DEFAULT_PARAMETERS as RIG
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate
from aeropend_core.signals.preprocess import detect_steps, piecewise_constant, sharp_steps, smooth_between_steps

SAMPLE_TIME = 1 / 490


def chirp_record(top_hz: float, psnr_db: float, seed: int):
    """40 s of the default rig under a linear duty chirp 0.1 Hz -> `top_hz` [Hz] around 0.27 +- 0.18 (rest 0.5 s)."""
    time = np.arange(int(40 / SAMPLE_TIME)) * SAMPLE_TIME
    duty = np.clip(0.27 + 0.18 * np.sin(2 * np.pi * (0.1 * time + (top_hz - 0.1) / 80 * time ** 2)), 0.0, 0.6)
    duty[:245] = 0.0
    return simulate(duty, RIG, noise=MeasurementNoise(psnr_db, True), seed=seed)


def test_a_noisy_chirp_is_not_taken_for_steps_and_only_its_real_jump_is_sharp():
    """At 40 dB the step detector cuts the sweep into many levels and their spread stays within the noise; the
    levels' slopes give it away. Of the detected steps only the jump from rest (sample 245) is a one-sample jump."""
    record = chirp_record(2.5, 40.0, seed=7)
    voltage = record.armature_voltage
    steps = detect_steps(voltage, SAMPLE_TIME)
    assert steps.size > 100
    assert piecewise_constant(voltage, steps) is None
    np.testing.assert_array_equal(sharp_steps(voltage, steps), [245])
    smoothed = smooth_between_steps(voltage, [245], SAMPLE_TIME)
    true_voltage = record.truth['armature_voltage']
    assert np.std(smoothed - true_voltage) < 0.4 * np.std(voltage - true_voltage)
    assert smoothed[245] == pytest.approx(true_voltage[245], abs=4 * np.std(voltage - true_voltage))


def test_steps_stay_piecewise_constant(clean_record):
    steps = detect_steps(clean_record.armature_voltage, clean_record.sample_time)
    assert piecewise_constant(clean_record.armature_voltage, steps) is not None


@pytest.mark.parametrize('top_hz, psnr_db, seed', [(2.5, 55.0, 5), (1.0, 40.0, 6)])
def test_nominal_fit_of_a_chirp_is_unbiased(top_hz, psnr_db, seed):
    """Known truth (the default rig): each nominal parameter within 2 % of it and within 3 of its own sigma."""
    from aeropend_core.diagnosis.diagnose import diagnose
    from aeropend_core.io.recording import from_columns
    record = chirp_record(top_hz, psnr_db, seed)
    with threadpool_limits(1):
        found = diagnose(from_columns(record.columns(with_truth=False), source='chirp'), candidates=(), drift=False,
                         discovery=False)
    assert found.prepared.motor is not None
    values, errors = found.reported_parameters(found.current), found.reported_errors(found.current)
    for name in ('gravity_stiffness', 'damping', 'thrust_gain', 'armature_resistance'):
        truth = getattr(RIG, name)
        assert values[name] == pytest.approx(truth, rel=0.02), name
        assert abs(values[name] - truth) <= 3 * errors[name], (name, values[name], errors[name])
