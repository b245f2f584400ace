"""The filters a diagnosis uses without importing scipy.signal (aeropend_core/signals/filters.py, issue 41) give
scipy.signal's numbers: bit for bit where they follow its steps (Savitzky-Golay, the first-order lag, the
zero-phase second-order sections and the Butterworth design)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from aeropend_core.signals import filters


def _signals():
    rng = np.random.default_rng(7)
    time = np.arange(3000) / 490.0
    smooth = 0.6 * np.sin(2.1 * time) + 0.2 * np.cos(7.3 * time) + 0.3 * (time > 2.5)
    return [rng.normal(size=257), smooth + rng.normal(scale=0.01, size=time.size), np.cumsum(rng.normal(size=999))]


@pytest.mark.parametrize('window,order,deriv,delta', [(31, 3, 0, 1.0), (31, 3, 1, 1 / 490), (25, 3, 2, 1 / 490),
                                                      (11, 2, 0, 1.0), (12, 3, 1, 0.01), (5, 4, 3, 0.5)])
def test_savgol_filter_is_scipys_bit_for_bit(window, order, deriv, delta):
    for x in _signals():
        expected = signal.savgol_filter(x, window, order, deriv=deriv, delta=delta)
        assert np.array_equal(filters.savgol_filter(x, window, order, deriv=deriv, delta=delta), expected)
    with pytest.raises(ValueError):
        filters.savgol_filter(np.ones(5), 7, 3)


@pytest.mark.parametrize('decay', [0.0, 0.3, 0.9, 0.99929])
def test_first_order_lag_is_lfilter_bit_for_bit(decay):
    for x in _signals():
        expected = signal.lfilter([1.0 - decay], [1.0, -decay], x, zi=[decay * x[0]])[0]
        assert np.array_equal(filters.first_order_lag(x, decay), expected)


@pytest.mark.parametrize('cutoff', [0.01, 0.0612, 0.2, 0.5, 0.93])
def test_butterworth_design_and_zero_phase_filter_are_scipys(cutoff):
    expected = signal.butter(2, cutoff, output='sos')
    designed = filters.butter_lowpass_sos(cutoff)
    assert designed.shape == expected.shape
    assert np.array_equal(designed, expected)
    for x in _signals():
        assert np.array_equal(filters.sosfiltfilt(expected, x), signal.sosfiltfilt(expected, x))
    with pytest.raises(ValueError):
        filters.butter_lowpass_sos(1.0)
    with pytest.raises(ValueError):
        filters.sosfiltfilt(expected, np.ones(9))


@pytest.mark.parametrize('delay,step', [(0.0141, 1 / 490), (0.0005, 1 / 490), (0.05, 1 / 4900), (0.002, 0.0448)])
def test_the_angle_sensors_filter_pieces_are_scipys_bit_for_bit(delay, step):
    tau = delay / 3.0
    den = [tau * tau, 3.0 * tau, 1.0]
    b, a, _ = signal.cont2discrete(([1.0], den), step, method='foh')
    got_b, got_a = filters.foh_transfer_function([1.0], den, step)
    assert np.array_equal(got_b, b) and np.array_equal(got_a, a)
    b = np.atleast_1d(np.squeeze(b))
    b, a = b / a[0], a / a[0]
    for x in _signals():
        past = np.arange(1, 3) * step
        zi = signal.lfiltic(b, a, x[0] - 0.3 * (past + delay), x[0] - 0.3 * past)
        assert np.array_equal(filters.lfiltic(b, a, x[0] - 0.3 * (past + delay), x[0] - 0.3 * past), zi)
        expected, state = signal.lfilter(b, a, x, zi=zi)
        got, got_state = filters.lfilter(b, a, x, zi=zi)
        assert np.array_equal(got, expected) and np.array_equal(got_state, state)
        assert np.array_equal(filters.lfilter_zi(b, a), signal.lfilter_zi(b, a))


def test_autocorrelation_is_scipys_and_welch_density_within_1e_12():
    for x in _signals():
        centred = x - x.mean()
        assert np.array_equal(filters.autocorrelation(centred), signal.correlate(centred, centred, mode='full',
                                                                                 method='fft'))
        for segment in (64, 100, 255, x.size):
            expected_f, expected = signal.welch(centred, fs=490.0, nperseg=segment)
            got_f, got = filters.welch_density(centred, 490.0, segment)
            assert np.array_equal(got_f, expected_f)
            np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-14 * float(np.max(expected)))
