"""Settling time as the check measures and predicts it (issue #39, s23): a hold's last sample does not decide it,
and the prediction is an interval over the noise draws of the model."""
from __future__ import annotations

import math

import numpy as np

from aeropend_core.control.metrics import moving_mean, step_metrics
from aeropend_core.model.parameters import SAMPLE_TIME
from aeropend_core.sim.noise import ANGLE_LSB


def test_one_noisy_sample_at_the_holds_end_does_not_make_a_settled_step_unsettled():
    """Known truth: a 25 deg step that settles as exp(-t / 0.1 s) enters its 3-count band at 0.1 ln(step / band)
    = 0.32 s and stays; one sample of +0.06 rad noise (4 sigma at 40 dB) at the hold's end is not a failure to
    settle. With the ends of the smoothing held (s22), that sample weighed 13/24 of the last mean and the step read
    "not settled" (settling = the 5 s hold)."""
    t = np.arange(0.0, 5.0, SAMPLE_TIME)
    initial, target = 0.0, math.radians(25)
    angle = target + (initial - target) * np.exp(-t / 0.1)
    angle[-1] += 0.06
    m = step_metrics(t, angle, np.full(t.size, 0.4), 0.0, t[-1] + SAMPLE_TIME, initial, target)
    band = 3 * ANGLE_LSB
    expected = 0.1 * math.log(abs(target - initial) / band)
    assert m.band == band
    assert m.settled
    assert abs(m.settling_time - expected) < 0.03


def test_the_shrunk_smoothing_is_the_mean_of_the_samples_there_are():
    values = np.array([1.0, 2.0, 3.0, 4.0, 10.0])
    np.testing.assert_allclose(moving_mean(values, 4, ends='shrink'), [1.5, 2.0, 2.5, 19 / 4, 17 / 3])


def _gains():
    from aeropend_core.control.law import PidGains
    # s22's other controller on a clean seed: 0.7 x the first design's p and d
    return PidGains(p=1.18, i=0.77, d=0.18, derivative_filter_time=0.03, u_clamp_max=0.8)


def test_the_check_gives_the_predicted_settling_range_over_noise_draws_and_a_run_of_the_model_falls_in_it():
    """Known truth: the rig is the model. Six runs of it (other noise seeds than the check's) are checked; the
    predicted settling's range over 20 noise draws holds the measured settling in at least 16 of their 18 steps
    (when the model is right, each with probability 19/21 = 90 %). The point prediction alone was within +-20 % of
    the measured in 212 of 252 such steps (s23 probe): the range is what the check can honestly promise. On a rig
    with a 0.2 s thrust lag the model lacks, some step falls outside the range."""
    from aeropend_core.control.check import check_record
    from aeropend_core.control.controller_file import Controller
    from aeropend_core.control.loop import FeedforwardMap, simulate_loop
    from aeropend_core.control.reference import ReferenceSchedule
    from aeropend_core.sim.noise import MeasurementNoise

    gains = _gains()
    controller = Controller(gains)
    schedule = ReferenceSchedule.steps_between([25, 50, 30], hold=4.0, start_hold=2.0)

    def run(effects, seed):
        return simulate_loop(gains, schedule.reference(), FeedforwardMap(), effects=effects,
                             noise=MeasurementNoise(psnr_db=40.0, quantise=True), seed=seed, duty_limit=0.8)

    inside = total = 0
    for seed in range(100, 106):
        record = run({}, seed)
        result = check_record(record.time, record.angle, record.duty, controller, schedule, seed=7)
        for step in result.steps:
            low, high, draws, _ = step.settling_range
            assert draws == 20 and low <= step.predicted.settling_time <= high
            assert low <= step.settling_median <= high
            total += 1
            inside += bool(step.settling_in_range)
        data = result.to_dict()['steps'][0]['predicted_settling_range']
        assert data['draws'] == 20 and data['shortest_s'] <= data['median_s'] <= data['longest_s']
    assert total == 18 and inside >= 16
    lagged = run({'thrust_lag': {'time_constant': 0.2}}, 100)
    result = check_record(lagged.time, lagged.angle, lagged.duty, controller, schedule, seed=7)
    assert not all(step.settling_in_range for step in result.steps)
    assert 'noise draws of the model' in result.as_text()


def test_the_feedforward_taken_once_per_reference_value_gives_the_loop_of_the_per_sample_feedforward():
    """The compiled loop now calls the feedforward once per distinct reference value (a schedule holds a few) instead
    of once per sample: the same record, bit for bit, as the per-sample values passed as an array."""
    from aeropend_core.control.loop import FeedforwardMap, simulate_loop
    from aeropend_core.control.reference import ReferenceSchedule
    from aeropend_core.sim.noise import MeasurementNoise

    reference = ReferenceSchedule.steps_between([25, 50, 30], hold=1.0, start_hold=0.5).reference()
    feedforward = FeedforwardMap(effects={'dead_zone': {'threshold_voltage': 0.7}})
    per_sample = np.array([feedforward(float(value)) for value in reference])
    noise = MeasurementNoise(psnr_db=40.0, quantise=True)
    once = simulate_loop(_gains(), reference, feedforward, noise=noise, seed=3, duty_limit=0.8)
    each = simulate_loop(_gains(), reference, per_sample, noise=noise, seed=3, duty_limit=0.8)
    np.testing.assert_array_equal(once.feedforward, per_sample)
    np.testing.assert_array_equal(once.angle, each.angle)
    np.testing.assert_array_equal(once.duty, each.duty)


def test_the_shared_noise_draws_give_each_seeds_run_and_the_checks_ranges_of_those_seeds():
    """loop.noise_draws (s24: the one helper behind the design's noise edge and the check's range) gives, in seed
    order and on threads, what one simulate_loop and schedule_metrics per seed give; settling_ranges over the same
    seeds is their shortest and longest settling, draw count, unsettled count and median."""
    from concurrent.futures import ThreadPoolExecutor

    from aeropend_core.control.check import settling_ranges
    from aeropend_core.control.loop import FeedforwardMap, feedforward_per_sample, noise_draws, simulate_loop
    from aeropend_core.control.metrics import schedule_metrics
    from aeropend_core.control.reference import ReferenceSchedule
    from aeropend_core.sim.noise import MeasurementNoise

    schedule = ReferenceSchedule.steps_between([25, 45], hold=2.0, start_hold=1.0)
    reference = schedule.reference()
    feedforward = feedforward_per_sample(FeedforwardMap(), reference)
    noise = MeasurementNoise(psnr_db=40.0, quantise=True)
    seeds = [11, 3, 7, 5]
    alone = []
    for seed in seeds:
        run = simulate_loop(_gains(), reference, feedforward, noise=noise, seed=seed, duty_limit=0.8)
        alone.append((run, schedule_metrics(run.time, run.angle, run.duty, schedule)))
    from aeropend_core.model.parameters import DEFAULT_PARAMETERS
    with ThreadPoolExecutor(2) as pool:
        shared = noise_draws(_gains(), reference, feedforward, DEFAULT_PARAMETERS, {}, noise, seeds, schedule,
                             duty_limit=0.8, pool=pool)
    assert len(shared) == len(seeds)
    for (run, metrics), (run_alone, metrics_alone) in zip(shared, alone):
        np.testing.assert_array_equal(run.angle, run_alone.angle)
        assert [m.settling_time for m in metrics] == [m.settling_time for m in metrics_alone]
    ranges = settling_ranges(_gains(), reference, feedforward, DEFAULT_PARAMETERS, {}, noise, schedule, seeds,
                             duty_limit=0.8)
    assert len(ranges) == 2
    for index, (start, (low, high, draws, unsettled, median)) in enumerate(sorted(ranges.items())):
        times = [metrics[index].settling_time for _run, metrics in alone]
        assert math.isclose(start, round(alone[0][1][index].start, 6))
        assert (low, high, draws) == (min(times), max(times), len(seeds))
        assert math.isclose(median, (sorted(times)[1] + sorted(times)[2]) / 2)        # four draws: the middle two
        assert unsettled == sum(not metrics[index].settled for _run, metrics in alone)
