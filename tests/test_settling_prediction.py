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
