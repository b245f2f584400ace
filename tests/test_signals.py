"""Unit tests of the signal-conditioning stage on its own: step detection, noise-level estimates, step bridging,
and the motor observer, on a simulated record whose truth is known (tests/conftest.py ``clean_record``)."""
from __future__ import annotations

import numpy as np
import pytest

from aeropend_core.model.parameters import DEFAULT_PARAMETERS as P
from aeropend_core.signals.motor import fit_motor
from aeropend_core.signals.preprocess import bridge_steps, detect_steps, estimate_noise_std, noise_rms


def true_steps(record) -> np.ndarray:
    """Samples where the duty (hence Va by eq 8) changes."""
    return np.flatnonzero(np.diff(record.duty)) + 1


def test_every_duty_step_is_found_at_its_sample_and_nothing_else(clean_record):
    found = detect_steps(clean_record.armature_voltage, clean_record.sample_time)
    np.testing.assert_array_equal(found, true_steps(clean_record))


def test_detect_steps_ignores_pure_noise():
    rng = np.random.default_rng(3)
    assert detect_steps(1.5 + 0.01 * rng.standard_normal(5000), 1 / 490).size == 0


@pytest.mark.parametrize('estimate', [noise_rms, estimate_noise_std])
def test_noise_level_of_angle_and_current_within_10_percent(clean_record, estimate):
    """Both estimates read the white noise under a moving, stepped, quantised signal (truth: measured - true)."""
    for name in ('angle', 'armature_current'):
        measured = getattr(clean_record, name)
        truth = np.std(measured - clean_record.truth[name])
        assert estimate(measured) == pytest.approx(truth, rel=0.10), name


def test_noise_of_white_gaussian_signal_is_its_sigma():
    rng = np.random.default_rng(0)
    t = np.arange(20000) / 490
    signal = np.sin(2 * np.pi * 0.3 * t) + 0.02 * rng.standard_normal(t.size)
    assert noise_rms(signal) == pytest.approx(0.02, rel=0.05)
    assert estimate_noise_std(signal) == pytest.approx(0.02, rel=0.05)


def test_bridge_steps_replaces_the_settling_samples_by_a_line():
    signal = np.r_[np.zeros(10), 5.0 * np.ones(3), np.ones(10)]   # a kick of 5 after the step at 10, level 1 after
    bridged = bridge_steps(signal, np.array([10]), settling=3)
    np.testing.assert_allclose(bridged[10:13], [0.25, 0.5, 0.75])
    np.testing.assert_array_equal(bridged[:10], signal[:10])
    np.testing.assert_array_equal(bridged[13:], signal[13:])


def test_motor_observer_recovers_the_motor_rates_and_back_emf(clean_record):
    """p1 = Kw Kt/(Jm Ra), p2 = F/Jm, p3 = Kd (N2/N1)^3/(Jm Kw) from the default parameters: within 5 %; the
    observed back-EMF within 1 % of its range of Kw times the true motor speed."""
    steps = detect_steps(clean_record.armature_voltage, clean_record.sample_time)
    fit = fit_motor(clean_record.armature_voltage, clean_record.armature_current, steps, clean_record.sample_time)
    jm, kw = P.motor_inertia, P.back_emf_constant
    expected = {'motor_drive_rate': kw * P.torque_constant / (jm * P.armature_resistance),
                'motor_friction_rate': P.motor_friction / jm,
                'motor_drag_rate': P.propeller_torque_coefficient / P.gear_ratio ** 3 / (jm * kw),
                'motor_resistance': P.armature_resistance}
    for name, value in expected.items():
        assert fit.parameters[name] == pytest.approx(value, rel=0.05), name
    assert fit.adequate
    emf = kw * clean_record.truth['motor_speed']
    error = fit.back_emf[100:] - emf[100:]
    assert np.sqrt(np.mean(error ** 2)) < 0.01 * np.ptp(emf)

