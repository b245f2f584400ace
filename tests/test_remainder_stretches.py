"""The remainder's correlation time where the held-out part's stride is broken once (session 21, closing note s19:
``remainder._stretches`` took the smallest index step as the stride, so one short step made every run one sample
long and the correlation time NaN). Known truth: an AR(1) residual of correlation time 0.2 s (1/e at 0.2 s) on a
held-out index at stride 4 (490 Hz), with one step of 1 where two pieces meet; tolerance 25 % (two 20 s pieces of a
0.2 s process: ~100 correlation times each)."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from aeropend_core.diagnosis.remainder import _stretches, remainder_of


def test_one_short_step_does_not_cut_the_runs():
    index = np.concatenate([np.arange(0, 400, 4), np.arange(397, 800, 4)])
    runs = _stretches(index)
    assert [r.size for r in runs] == [100, 101]


def test_the_correlation_time_of_a_known_remainder_with_a_broken_stride():
    sample_time, tau = 1.0 / 490.0, 0.2
    n = 2 * 9800
    rng = np.random.default_rng(3)
    decay = math.exp(-sample_time / tau)
    residual = np.empty(n)
    residual[0] = 0.0
    shocks = rng.normal(0.0, 0.01 * math.sqrt(1 - decay ** 2), n)
    for k in range(1, n):
        residual[k] = decay * residual[k - 1] + shocks[k]
    index = np.concatenate([np.arange(0, n // 2, 4), np.arange(n // 2 - 3, n, 4)])
    prep = SimpleNamespace(angle=residual, sample_time=sample_time, heldout=SimpleNamespace(residual_index=index))
    comparison = SimpleNamespace(noise_rms=0.001, rms_error=float(np.sqrt(np.mean(residual[index] ** 2))),
                                 evaluation=SimpleNamespace(simulated=np.zeros(n)))
    found = remainder_of(prep, comparison)
    assert math.isfinite(found.correlation_time)
    assert abs(found.correlation_time - tau) <= 0.25 * tau, found.correlation_time
