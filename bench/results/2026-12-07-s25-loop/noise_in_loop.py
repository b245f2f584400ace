"""Why the closed-loop threshold lands high (rebuild.py's pickle): the diagnosis simulates the loop from the reference
without the measurement noise that the rig's law feeds back. The training cost of the TRUE parameters over the
threshold, (a) noise-free as the diagnosis simulates, (b) the mean of DRAWS noisy loops (the noise in the loop,
other draws than the record's).

    nice -n 10 .venv/bin/python bench/results/2026-12-07-s25-loop/noise_in_loop.py dead_zone 0 8
"""
import pickle
import sys
import warnings

import numpy as np

from aeropend_core.control.loop import simulate_loop
from aeropend_core.control.metrics import noise_sigma
from aeropend_core.sim.noise import MeasurementNoise

warnings.simplefilter("ignore")
case, seed, draws = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
data = pickle.load(open(f"/tmp/loopdev25/run-{case}-{seed}.pkl", "rb"))
controller, run, (truth, truth_effects) = data["controller"], data["run"], data["truth"]
split = int(0.7 * run.angle.size)
initial = float(np.median(run.angle[:24]))
print("truth", truth_effects, "noise", noise_sigma(run.angle), "floor rss", split * noise_sigma(run.angle) ** 2)


def loop(threshold, noise, draw_seed):
    return simulate_loop(controller.gains, run.reference, run.feedforward, truth,
                         {"dead_zone": {"threshold_voltage": threshold}}, noise, draw_seed, initial, 0.00204,
                         controller.gains.u_clamp_max, method="compiled")


for threshold in (0.7, 0.8, 0.933, 1.0, 1.1, 1.2, 1.3):
    free = loop(threshold, None, None).angle
    noisy = np.mean([loop(threshold, MeasurementNoise(psnr_db=40.0, quantise=True), 7000 + k).angle
                     for k in range(draws)], axis=0)
    # the mean of DRAWS noisy runs still carries noise/sqrt(DRAWS) of its own
    rss_free = np.sum((free - run.angle)[:split] ** 2)
    rss_mean = np.sum((noisy - run.angle)[:split] ** 2)
    duty_free = loop(threshold, None, None).duty
    print(f"threshold {threshold:.3f} V: rss noise-free {rss_free:.4f}; rss mean of {draws} noisy loops "
          f"{rss_mean:.4f}; mean duty noise-free {duty_free.mean():.4f}, record {run.duty.mean():.4f}", flush=True)
