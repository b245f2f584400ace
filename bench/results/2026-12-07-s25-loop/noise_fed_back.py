"""A probe of the next step (not in the library): the closed-loop fit with the record's own noise fed back. The
record's angle noise is estimated as the measured angle minus its zero-phase low-pass (Butterworth, CUTOFF Hz), and
the model's loop is simulated with that sequence added to the angle its law reads (the compiled loop, the noise
columns replaced), so the duty carries the same jitter as on the rig. Fits gravity and the thrust scale (and the
dead zone's threshold unless held) on the training part, as the diagnosis does.

    nice -n 10 .venv/bin/python bench/results/2026-12-07-s25-loop/noise_fed_back.py test      # the test's record
    nice -n 10 .venv/bin/python bench/results/2026-12-07-s25-loop/noise_fed_back.py dead_zone 0  # rebuild.py's
"""
import pickle
import sys
import warnings

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import butter, filtfilt

import aeropend_core.control.loop as loop_module
from aeropend_core.control.law import PidGains
from aeropend_core.control.loop import FeedforwardMap, simulate_loop
from aeropend_core.control.metrics import noise_sigma
from aeropend_core.control.reference import ReferenceSchedule
from aeropend_core.model.parameters import DEFAULT_PARAMETERS
from aeropend_core.sim.noise import MeasurementNoise

warnings.simplefilter("ignore")
CUTOFF = 15.0
TS = 0.00204
if sys.argv[1] == "test":
    gains = PidGains(p=1.2074, i=0.129, d=0.1255, derivative_filter_time=0.02, u_clamp_max=0.8)
    schedule = ReferenceSchedule.steps_between([30, 50, 40], hold=5.0)
    run = simulate_loop(gains, schedule.reference(), FeedforwardMap(), effects={"dead_zone": 0.9},
                        noise=MeasurementNoise(psnr_db=40, quantise=True), seed=24, duty_limit=0.7)
    model, truth, threshold_truth, duty_limit = DEFAULT_PARAMETERS, DEFAULT_PARAMETERS, 0.9, 0.7
else:
    data = pickle.load(open(f"/tmp/loopdev25/run-{sys.argv[1]}-{sys.argv[2]}.pkl", "rb"))
    controller, run, (truth, truth_effects) = data["controller"], data["run"], data["truth"]
    gains, model, duty_limit = controller.gains, controller.parameters, controller.gains.u_clamp_max
    threshold_truth = truth_effects["dead_zone"]["threshold_voltage"]
b, a = butter(4, CUTOFF / (0.5 / TS))
estimate = run.angle - filtfilt(b, a, run.angle)
print(f"noise sigma {noise_sigma(run.angle):.5f}, estimate's sd {estimate.std():.5f}", flush=True)


class _Fed:
    """A stand-in for the loop's generator: the voltage and current columns zero, the angle column the estimate."""

    def __init__(self, *_args):
        self.calls = 0

    def normal(self, _mean, _sigma, n):
        self.calls += 1
        return estimate[:n].copy() if self.calls == 3 else np.zeros(n)


split = int(0.7 * run.angle.size)
initial = float(np.median(run.angle[:24]))


def simulate(parameters, threshold, fed):
    original = loop_module.np.random.default_rng
    if fed:
        loop_module.np.random.default_rng = _Fed
    try:
        return simulate_loop(gains, run.reference, run.feedforward, parameters,
                             {"dead_zone": {"threshold_voltage": threshold}},
                             MeasurementNoise(psnr_db=40, quantise=True) if fed else None, 0, initial, TS, duty_limit,
                             method="compiled").angle
    finally:
        loop_module.np.random.default_rng = original


for fed in (False, True):
    for hold in (True, False):
        free = ("gravity_stiffness", "lever_per_inertia")
        start = np.array([getattr(model, n) for n in free] + ([] if hold else [0.6]))

        def residual(x, fed=fed, hold=hold):
            parameters = model.replace(**dict(zip(free, x[:2])))
            d = simulate(parameters, threshold_truth if hold else x[2], fed)[:split] - run.angle[:split]
            return np.where(np.isfinite(d), d, 10.0)

        lower = [0.6 * v for v in start[:2]] + ([] if hold else [0.0])
        upper = [1.6 * v for v in start[:2]] + ([] if hold else [3.0])
        fit = least_squares(residual, start, bounds=(lower, upper), x_scale=np.maximum(np.abs(start), 0.01),
                            diff_step=1e-3, max_nfev=80)
        p = model.replace(**dict(zip(free, fit.x[:2])))
        print(f"noise {'fed back' if fed else 'left out'}, threshold {'held at the truth' if hold else 'free'}: "
              f"gravity {p.gravity_stiffness:.2f} (truth {truth.gravity_stiffness:.2f}), thrust_gain "
              f"{p.thrust_gain:.2f} (truth {truth.thrust_gain:.2f}), ratio/truth's "
              f"{p.thrust_gain / p.gravity_stiffness / (truth.thrust_gain / truth.gravity_stiffness):.4f}"
              + ("" if hold else f", threshold {fit.x[2]:.3f} V (truth {threshold_truth:.3f})")
              + f", train rss {2 * fit.cost:.4f} (floor ~{split * noise_sigma(run.angle) ** 2:.4f})", flush=True)
