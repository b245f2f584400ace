"""A dead zone's threshold carries a ± from a profile of the training cost (issue 40 item 3): on a continuous input
the spacing of the input levels (every sample a new one) gave ~1e-4 V for errors of 0.001-0.7 V."""
from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import pytest

from aeropend_core.diagnosis.threshold_profile import (PROFILE_CHI2, once_per_gate_pattern, profile_statistic,
                                                       threshold_profile)

EFFECTIVE = 400.0
BEST_RMS = 0.002


def _quadratic_refit(center: float, width: float, slope: float = 0.0, flat_below: bool = False):
    """A refit whose statistic is ((t - center) / width)^2 (flat below the center with `flat_below`), and whose
    nuisance parameter moves by `slope` [1/V] per volt of the threshold."""
    def refit(threshold: float):
        u = (threshold - center) / width
        if flat_below and u < 0:
            u = 0.0
        rms = BEST_RMS * math.exp(u * u / (2 * EFFECTIVE))
        return SimpleNamespace(residual_rms=rms, parameters={'threshold_voltage': threshold,
                                                             'angle_offset': slope * (threshold - center)})
    return refit


def _best(center: float):
    return SimpleNamespace(residual_rms=BEST_RMS, effective_samples=EFFECTIVE, n_residuals=5000,
                           parameters={'threshold_voltage': center, 'angle_offset': 0.0})


def test_the_statistic_is_the_likelihood_ratio_with_the_effective_count():
    assert profile_statistic(BEST_RMS, BEST_RMS, EFFECTIVE) == 0.0
    assert profile_statistic(BEST_RMS * math.exp(0.5 / EFFECTIVE), BEST_RMS, EFFECTIVE) == pytest.approx(1.0)
    assert profile_statistic(float('nan'), BEST_RMS, EFFECTIVE) == math.inf      # a failed fit is outside


@pytest.mark.parametrize('width', [0.01, 0.05, 0.2])
def test_a_quadratic_profile_gives_its_own_sigma_and_carries_it_into_a_correlated_parameter(width):
    """Statistic ((t - t0)/s)^2: the 95 % crossing is at 1.96 s, so the 1σ is s (within the bisection's 15 %);
    a nuisance parameter moving 0.1 per volt of the threshold gets 0.1 s."""
    profile = threshold_profile(_quadratic_refit(0.6, width, slope=0.1), _best(0.6), 'threshold_voltage', 0.0, 2.0)
    assert profile['sigma'] == pytest.approx(width, rel=0.15)
    low, high = profile['interval']
    assert low == pytest.approx(0.6 - math.sqrt(PROFILE_CHI2) * width, abs=0.15 * width)
    assert high == pytest.approx(0.6 + math.sqrt(PROFILE_CHI2) * width, abs=0.15 * width)
    assert profile['spread']['angle_offset'] == pytest.approx(0.1 * width, rel=0.15)
    assert profile['refits'] <= 16


def test_a_side_the_data_cannot_bound_reaches_its_limit():
    """No rise below the estimate (any smaller threshold fits as well, e.g. no dead zone at all): the interval
    reaches 0 V and the 1σ is the whole distance to it / 1.96, not the rising side's."""
    profile = threshold_profile(_quadratic_refit(0.5, 0.02, flat_below=True), _best(0.5), 'threshold_voltage',
                                0.0, 2.0)
    assert profile['interval'][0] == 0.0
    assert profile['sigma'] == pytest.approx(0.5 / 1.96)


@pytest.mark.slow
def test_a_dead_zone_under_a_chirp_has_its_truth_within_two_sigma_and_a_useful_sigma():
    """Own simulator, 24 s duty chirp 0.1 -> 1 Hz (every sample a new input level), dead zone 0.55 V, 45 dB: the
    threshold within 2σ of the truth, the 1σ wider than the level-spacing rule's but below 0.1 V (a dead zone of
    0.3-0.9 V is still located); before, the 1σ was the level spacing / sqrt(12), ~1e-4 V."""
    from aeropend_core.diagnosis.compare import compare, prepare
    from aeropend_core.io.recording import from_columns
    from aeropend_core.model.parameters import DEFAULT_PARAMETERS as rig
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import simulate
    truth = 0.55
    time = np.arange(int(24 * 490)) / 490.0
    duty = np.clip(0.27 + 0.18 * np.sin(2 * np.pi * (0.1 * time + 0.9 / 48 * time ** 2)), 0.0, 0.6)
    duty[:245] = 0.0
    trajectory = simulate(duty, rig, effects={'dead_zone': truth}, noise=MeasurementNoise(45.0, True), seed=11)
    comparison = compare(prepare(from_columns(trajectory.columns(with_truth=False))), ('dead_zone',))
    fit = comparison.fit
    estimate, sigma = fit.parameters['threshold_voltage'], fit.standard_errors['threshold_voltage']
    level_rule = fit.extra['threshold_profile']['conditional_errors']['threshold_voltage']
    assert abs(estimate - truth) <= 2 * sigma, (estimate, sigma)
    assert level_rule < sigma < 0.1
    low, high = fit.extra['threshold_profile']['interval']
    assert low < estimate < high


def test_a_threshold_of_another_basin_that_fits_as_well_widens_the_interval():
    """The refits see only the estimate's basin; a threshold simulated before the fit (an RMS at or above its
    profile) within the limit is inside however far it lies, and one beyond the limit changes nothing."""
    refit, best = _quadratic_refit(0.05, 0.01), _best(0.05)
    alone = threshold_profile(refit, best, 'threshold_voltage', 0.0, 2.0)
    near_rms = BEST_RMS * math.exp(1.0 / (2 * EFFECTIVE))         # statistic 1 at 0.7 V
    far_rms = BEST_RMS * math.exp(9.0 / (2 * EFFECTIVE))          # statistic 9 at 1.5 V
    both = threshold_profile(refit, best, 'threshold_voltage', 0.0, 2.0,
                             ranking=[(0.7, near_rms), (1.5, far_rms)])
    assert alone['interval'][1] < 0.1
    assert both['interval'][1] == pytest.approx(0.7)
    assert both['sigma'] == pytest.approx(0.65 / 1.96)


def test_a_refit_that_stops_short_of_the_optimum_is_not_read_as_a_rise():
    """Every warm-started refit ends 0.5 % above the best fit's RMS (statistic ~4 everywhere at n_eff 400): the
    same refit at the estimate is the reference, so the interval is the profile's own, not the estimate alone."""
    quadratic = _quadratic_refit(0.6, 0.05)

    def short(threshold: float):
        fit = quadratic(threshold)
        return SimpleNamespace(residual_rms=fit.residual_rms * 1.005, parameters=fit.parameters)
    profile = threshold_profile(short, _best(0.6), 'threshold_voltage', 0.0, 2.0)
    assert profile_statistic(BEST_RMS * 1.005, BEST_RMS, EFFECTIVE) > PROFILE_CHI2
    assert profile['sigma'] == pytest.approx(0.05, rel=0.15)


@dataclass
class _Fit:
    residual_rms: float
    parameters: dict


def test_a_refit_runs_once_per_pattern_of_gated_samples():
    """Thresholds between the same two input levels gate the same samples: one refit, returned with each one's
    threshold; a threshold across a level refits; a failed refit stays failed."""
    calls = []

    def refit(threshold: float):
        calls.append(threshold)
        if threshold > 0.5:
            return None
        return _Fit(residual_rms=0.01 + threshold, parameters={'threshold_voltage': threshold, 'angle_offset': 0.02})
    cached = once_per_gate_pattern(refit, np.array([0.0, 0.2, 0.4, 0.2, 0.6]), 'threshold_voltage')
    first, second = cached(0.05), cached(0.15)
    assert calls == [0.05]
    assert second.parameters == {'threshold_voltage': 0.15, 'angle_offset': 0.02}
    assert second.residual_rms == first.residual_rms and first.parameters['threshold_voltage'] == 0.05
    assert cached(0.25).parameters['threshold_voltage'] == 0.25 and calls == [0.05, 0.25]
    assert cached(0.55) is None and cached(0.58) is None and calls == [0.05, 0.25, 0.55]


def test_two_thresholds_that_gate_the_same_samples_give_the_same_fit_bit_for_bit():
    """The premise of once_per_gate_pattern on the real fit: a 24 s staircase record with a dead zone, refitted with
    the threshold held at two values between the same two input levels, from the same start."""
    from aeropend_core.diagnosis.compare import fit_model, prepare
    from aeropend_core.diagnosis.output_error import fit_output_error
    from aeropend_core.io.recording import from_columns
    from aeropend_core.model.parameters import DEFAULT_PARAMETERS as rig
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import simulate
    levels = np.repeat([0.0, 0.35, 0.2, 0.45, 0.3, 0.25] * 2, int(2 * 490))
    trajectory = simulate(levels, rig, effects={'dead_zone': 0.3}, noise=MeasurementNoise(45.0, True), seed=5)
    prep = prepare(from_columns(trajectory.columns(with_truth=False)))
    fit = fit_model(prep, ('dead_zone',))
    gated = np.sort(np.unique(prep.train.gate_signal))
    below = gated[np.searchsorted(gated, fit.parameters['threshold_voltage']) - 1]
    above = gated[np.searchsorted(gated, fit.parameters['threshold_voltage'])]
    a, b = below + 0.3 * (above - below), below + 0.7 * (above - below)
    refits = [fit_output_error(prep.train, fit.structure, fit.parameters, fixed={'armature_resistance':
              fit.parameters['armature_resistance'], 'threshold_voltage': t}, max_iterations=30, covariance=False)
              for t in (a, b)]
    assert np.array_equal(refits[0].residuals, refits[1].residuals)
    assert all(refits[0].parameters[n] == refits[1].parameters[n] for n in fit.parameters if n != 'threshold_voltage')
