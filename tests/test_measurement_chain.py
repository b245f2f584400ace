"""The fake device's analog front end (aeropend_core.testing.measurement_chain) against independent computations:
the RC ladder's group delay, the encoder wrap, the ADC noise, and the current held inside a PWM-resolved armature
current (against a brute-force integration of the circuit)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from aeropend_core.model.parameters import DEFAULT_PARAMETERS
from aeropend_core.rig import protocol as P
from aeropend_core.rig.calibration import HOLD_DELAY, held_current_offset, hold_after_pulse_start
from aeropend_core.testing.measurement_chain import MeasurementChain

TS = P.SAMPLE_PERIOD


def test_angle_filter_delays_a_ramp_by_three_rc():
    """A slow ramp through the unbuffered 2nd-order ladder (R = 4.7 kOhm, C = 1 uF) lags by 3 RC = 14.1 ms."""
    chain = MeasurementChain(encoder_ripple=False, adc_noise_counts=0.0)
    assert chain.group_delay == pytest.approx(3 * 4.7e3 * 1e-6)
    state = chain.start(P.Calibration(), DEFAULT_PARAMETERS)
    n = 2000
    rate = 0.5                                       # rad/s: ~80 counts/s, slow against the filter
    angle = -0.3 + rate * TS * np.arange(n)
    _, counts, _ = state.counts(angle, np.zeros(n), np.zeros(n), np.zeros(n))
    ideal = angle / P.DEFAULT_ANGLE_SCALE + P.DEFAULT_ANGLE_ZERO
    lag_counts = np.mean((ideal - counts)[500:])      # after the start-up transient; rounding averages out
    lag_seconds = lag_counts * P.DEFAULT_ANGLE_SCALE / rate
    assert lag_seconds == pytest.approx(chain.group_delay, abs=0.3e-3)


def test_encoder_wraps_at_1023():
    """The AS5040 is absolute over a turn: a magnet mounted with the hanging rod at 1000 counts wraps to 0."""
    chain = MeasurementChain(angle_filter=False, adc_noise_counts=0.0)
    state = chain.start(P.Calibration(angle_zero=1000.0), DEFAULT_PARAMETERS)
    angle = np.array([0.0, 20 * P.DEFAULT_ANGLE_SCALE, 30 * P.DEFAULT_ANGLE_SCALE, -1000 * P.DEFAULT_ANGLE_SCALE])
    _, counts, _ = state.counts(angle, np.zeros(4), np.zeros(4), np.zeros(4))
    assert counts.tolist() == [1000, 1020, 6, 0]


def test_adc_noise_has_the_stated_deviation():
    chain = MeasurementChain(angle_filter=False, pwm_current=False, adc_noise_counts=0.8)
    state = chain.start(P.Calibration(), DEFAULT_PARAMETERS, seed=4)
    n = 20000
    current, angle, _ = state.counts(np.full(n, 0.1234), np.full(n, 0.5), np.zeros(n), np.zeros(n))
    # Gaussian noise then rounding: variance sigma^2 + 1/12 count^2 (a value between counts).
    assert np.std(angle) == pytest.approx(math.sqrt(0.8 ** 2 + 1 / 12), rel=0.05)
    assert np.std(current) == pytest.approx(math.sqrt(0.8 ** 2 + 1 / 12), rel=0.05)


def brute_force_held_current(duty, hold, resistance, inductance, steps=4000, periods=30):
    """Euler integration of La dI/dt = v(t) - Ra I over many PWM periods (drive Va/duty for duty x Ts)."""
    voltage = DEFAULT_PARAMETERS.voltage_from_duty(duty)
    dt = TS / steps
    on = np.arange(steps) < duty * steps
    drive = np.where(on, voltage / duty, 0.0)
    current = 0.0
    trace = np.empty(steps)
    for _ in range(periods):
        for k in range(steps):
            trace[k] = current
            current += dt * (drive[k] - resistance * current) / inductance
    return trace[int(round(hold / dt))] - trace.mean()


@pytest.mark.parametrize('duty', [0.02, 0.1, 0.5, 0.7])
def test_current_held_in_the_pwm_period_matches_the_circuit(duty):
    p = DEFAULT_PARAMETERS
    hold = float(hold_after_pulse_start(duty, TS))      # phase-correct: pulse centre + 16.19 us
    assert hold == pytest.approx(duty * TS / 2 + HOLD_DELAY)
    model = float(held_current_offset(duty, p.voltage_from_duty(duty), p.armature_resistance,
                                      p.armature_inductance, TS, hold))
    truth = brute_force_held_current(duty, hold, p.armature_resistance, p.armature_inductance)
    assert model == pytest.approx(truth, abs=2e-3)
    assert 0.02 < model < 0.08                          # tens of mA above the period average
    assert held_current_offset(0.0, 0.0, p.armature_resistance, p.armature_inductance, TS, HOLD_DELAY) == 0.0
