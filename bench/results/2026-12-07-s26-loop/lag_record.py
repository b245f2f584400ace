"""The slow test record of a hidden 0.15 s thrust lag (50 dB, seed 21): the full closed-loop diagnosis (every
candidate) with the noise left out and fed back, its time and the named lag.

    nice -n 10 .venv/bin/python bench/results/2026-12-07-s26-loop/lag_record.py
"""
import time
import warnings

from aeropend_core.control.law import PidGains
from aeropend_core.control.loop import FeedforwardMap, simulate_loop
from aeropend_core.control.reference import ReferenceSchedule
from aeropend_core.control.loop_diagnosis import diagnose_loop
from aeropend_core.sim.noise import MeasurementNoise

warnings.simplefilter('ignore')
gains = PidGains(p=1.2074, i=0.129, d=0.1255, derivative_filter_time=0.02, u_clamp_max=0.8)
schedule = ReferenceSchedule.steps_between([20, 40, 60, 30], hold=5.0)
run = simulate_loop(gains, schedule.reference(), FeedforwardMap(), effects={'thrust_lag': 0.15},
                    noise=MeasurementNoise(psnr_db=50, quantise=True), seed=21, duty_limit=0.7)
for fed in (False, True):
    t = time.perf_counter()
    c = time.process_time()
    r = diagnose_loop(run.time, run.angle, run.duty, run.reference, run.feedforward, gains, 0.7,
                      feed_back_noise=fed)
    f = r.best_model()
    print(f'fed {fed}: {time.perf_counter() - t:.1f} s wall {time.process_time() - c:.1f} s CPU, named {r.named}, '
          f'tc {f.values.get("time_constant"):.4f} +- {f.sigmas.get("time_constant"):.4f} (truth 0.15), '
          f'confounded {r.confounded_with}')
