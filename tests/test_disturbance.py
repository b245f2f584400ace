"""A catalog effect judged against a modelled remainder (issue #40 item 1): the AR disturbance model of a free-run
residual (aeropend_core.diagnosis.disturbance) recovers a known filter, calls white noise white, and a gain that a
low-order filter predicts anyway is not evidence."""

import numpy as np
import pytest

from aeropend_core.diagnosis.disturbance import DECIMATED_STEP, decimated_pieces, fit_disturbance


def ar1(n, a, sigma, rng):
    x = np.zeros(n)
    e = rng.normal(0.0, sigma, n)
    for t in range(1, n):
        x[t] = a * x[t - 1] + e[t]
    return x


def test_an_ar1_remainder_is_recovered_and_white_noise_is_order_zero():
    rng = np.random.default_rng(3)
    model = fit_disturbance([ar1(1500, 0.9, 1e-3, rng), ar1(900, 0.9, 1e-3, rng)])
    assert model.order >= 1
    assert abs(model.coefficients[0] - 0.9) < 0.05 if model.order == 1 else sum(model.coefficients) > 0.8
    assert model.innovation_ms == pytest.approx(1e-6, rel=0.1)     # the innovations' variance, truth 1e-6 rad^2
    white = fit_disturbance([rng.normal(0.0, 1e-3, 2000)])
    assert white.order == 0 and white.innovation_ms == pytest.approx(1e-6, rel=0.1)


def test_decimation_averages_blocks_stretch_by_stretch_and_skips_short_ones():
    sample_time = 0.002
    index = np.concatenate([np.arange(0, 4000, 2), np.arange(5000, 5100, 2)])    # a long stretch and a short one
    residual = np.arange(6000, dtype=float)
    pieces = decimated_pieces(residual, index, sample_time)
    block = round(DECIMATED_STEP / (2 * sample_time))
    assert len(pieces) == 1 and pieces[0].size == 2000 // block
    assert pieces[0][0] == pytest.approx(np.mean(residual[index[:block]]))


def test_a_slow_lookalike_gain_is_predicted_by_the_filter():
    """A candidate that removes a slow, smooth part of the residual gains a lot of mean square but little once the
    remainder is modelled (a low-order filter predicts that part from the past residual anyway)."""
    rng = np.random.default_rng(5)
    t = np.arange(3000)
    smooth = 3e-3 * np.sin(2 * np.pi * t / 300.0)          # what the look-alike removes: slow and predictable
    remainder = ar1(t.size, 0.9, 1e-3, rng)
    base = remainder + smooth
    lookalike = remainder
    reduction_raw = 1.0 - np.mean(lookalike ** 2) / np.mean(base ** 2)
    reduction_modelled = 1.0 - fit_disturbance([lookalike]).innovation_ms / fit_disturbance([base]).innovation_ms
    assert reduction_raw > 0.4 and abs(reduction_modelled) < 0.05, (reduction_raw, reduction_modelled)
