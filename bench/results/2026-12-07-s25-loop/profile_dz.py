"""The closed-loop threshold of a rebuilt seed (rebuild.py's pickle): the diagnosis's fit as the benchmark runs it,
and the training cost profiled over the threshold (gravity and thrust scale refitted at each value).

    nice -n 10 .venv/bin/python bench/results/2026-12-07-s25-loop/profile_dz.py dead_zone 0
"""
import pickle
import sys
import warnings

import numpy as np
from scipy.optimize import least_squares

from aeropend_core.control.loop_diagnosis import BASE_BOUNDS, DEFAULT_FREE, _Problem, diagnose_loop
from aeropend_core.control.metrics import noise_sigma

warnings.simplefilter("ignore")
case, seed = sys.argv[1], int(sys.argv[2])
data = pickle.load(open(f"/tmp/loopdev25/run-{case}-{seed}.pkl", "rb"))
controller, run, (truth, truth_effects) = data["controller"], data["run"], data["truth"]
print("truth", truth_effects, "thrust_gain", truth.thrust_gain, "gravity", truth.gravity_stiffness, flush=True)
print("model", controller.effects, "thrust_gain", controller.parameters.thrust_gain, "gravity",
      controller.parameters.gravity_stiffness, flush=True)
if "fit" in sys.argv[3:] or "held" in sys.argv[3:]:
    result = diagnose_loop(run.time, run.angle, run.duty, run.reference, run.feedforward, controller.gains,
                           controller.gains.u_clamp_max, controller.parameters, add=("dead_zone",),
                           candidates=("dead_zone",),
                           model_effects=controller.effects if "held" in sys.argv[3:] else None)
    print(result.as_text(), flush=True)
noise = noise_sigma(run.angle)
problem = _Problem(controller.gains, run.reference, run.feedforward, run.angle, controller.gains.u_clamp_max,
                   0.00204, controller.parameters, DEFAULT_FREE)
starts = np.array([getattr(controller.parameters, n) for n in DEFAULT_FREE])
split = problem.split
volts = []
for threshold in [float(v) for v in sys.argv[3:] if v not in ("fit", "held")] or np.arange(0.5, 1.41, 0.05):
    def residual(x):
        parameters = controller.parameters.replace(**dict(zip(DEFAULT_FREE, x)))
        simulated = problem.simulate(parameters, {"dead_zone": {"threshold_voltage": threshold}})
        d = simulated[:split] - run.angle[:split]
        return np.where(np.isfinite(d), d, 10.0)
    fit = least_squares(residual, starts, bounds=(BASE_BOUNDS[0] * starts, BASE_BOUNDS[1] * starts),
                        x_scale=starts, diff_step=1e-3, max_nfev=80)
    parameters = controller.parameters.replace(**dict(zip(DEFAULT_FREE, fit.x)))
    simulated = problem.simulate(parameters, {"dead_zone": {"threshold_voltage": threshold}})
    test = simulated[split:] - run.angle[split:]
    rms = 1e3 * np.sqrt(np.mean(test ** 2))
    print(f"threshold {threshold:.3f} V: train rss {2 * fit.cost:.5f}, test rms {rms:.3f} mrad"
          f" (noise {1e3 * noise:.3f}), thrust_gain {parameters.thrust_gain:.2f}, gravity "
          f"{parameters.gravity_stiffness:.2f}", flush=True)
