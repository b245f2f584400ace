"""The first design of a rebuilt seed (rebuild.py's pickle) over DRAWS noise draws: on the model it was designed on
(what the design's prediction is one draw of) and on the seed's truth (what the benchmark's run is one draw of):
per step, the overshoot's and settling's median and range, and how many draws miss the template.

    nice -n 10 .venv/bin/python bench/results/2026-12-07-s25-loop/draws.py angle_offset 3 20
"""
import pickle
import sys
import warnings

import numpy as np

sys.path.insert(0, "bench")
import closed_loop as cl  # noqa: E402
from aeropend_core.control.loop import FeedforwardMap, noise_draws  # noqa: E402
from aeropend_core.sim.noise import MeasurementNoise  # noqa: E402

warnings.simplefilter("ignore")
case, seed, n = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
data = pickle.load(open(f"/tmp/loopdev25/run-{case}-{seed}.pkl", "rb"))
controller, (truth, truth_effects) = data["controller"], data["truth"]
schedule = controller.schedule
reference = schedule.reference()
feedforward = FeedforwardMap(controller.parameters, controller.effects)
noise = MeasurementNoise(psnr_db=cl.PSNR, quantise=True)
for label, parameters, effects in (("model", controller.parameters, controller.effects),
                                   ("truth", truth, truth_effects)):
    draws = noise_draws(controller.gains, reference, feedforward, parameters, effects, noise,
                        range(seed + 3000, seed + 3000 + n), schedule, duty_limit=controller.gains.u_clamp_max,
                        workers=1)
    missed = sum(any(m.misses(cl.TEMPLATE) for m in metrics) for _run, metrics in draws)
    print(f"{label}: {missed} of {n} draws miss the template", flush=True)
    for k in range(len(draws[0][1])):
        over = np.array([metrics[k].overshoot for _run, metrics in draws])
        settle = np.array([metrics[k].settling_time for _run, metrics in draws])
        print(f"  step {k}: overshoot median {np.median(over):.2f} % (range {over.min():.2f}-{over.max():.2f}, "
              f"sd {over.std(ddof=1):.2f}; over 10 % in {np.sum(over > 10)}), settling median {np.median(settle):.2f}"
              f" s (range {settle.min():.2f}-{settle.max():.2f})", flush=True)
