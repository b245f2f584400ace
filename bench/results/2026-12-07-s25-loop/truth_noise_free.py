"""The s24 dead-zone seed 0 (rebuild.py's pickle): the model's and the truth's parameters side by side, and the
noise-free closed loop's training cost of the TRUE parameters (and of the model with one group of the truth's) over
the threshold.

    nice -n 10 .venv/bin/python bench/results/2026-12-07-s25-loop/truth_noise_free.py
"""
import pickle
import warnings

import numpy as np

from aeropend_core.control.loop_diagnosis import DEFAULT_FREE, _Problem
from aeropend_core.control.metrics import noise_sigma

warnings.simplefilter("ignore")
d = pickle.load(open("/tmp/loopdev25/run-dead_zone-0.pkl", "rb"))
c, run, (truth, te) = d["controller"], d["run"], d["truth"]
m = c.parameters
for k, v in truth.as_dict().items():
    mv = m.as_dict()[k]
    if isinstance(v, float):
        print(f"{k:32s} truth {v:12.5g} model {mv:12.5g} ratio {mv / v if v else float('nan'):.3f}")
print("thrust_gain", truth.thrust_gain, m.thrust_gain, "L/J", truth.lever_per_inertia, m.lever_per_inertia)
problem = _Problem(c.gains, run.reference, run.feedforward, run.angle, c.gains.u_clamp_max, 0.00204, m, DEFAULT_FREE)
s = problem.split
noise = noise_sigma(run.angle)
print("N", run.angle.size, "split", s, "noise", noise, "noise floor rss", s * noise ** 2)
for thr in (0.85, 0.933, 1.0, 1.1, 1.196, 1.3):
    sim = problem.simulate(truth, {"dead_zone": {"threshold_voltage": thr}})
    r = sim - run.angle
    print(f"truth params thr {thr}: train rss {np.sum(r[:s]**2):.4f} test rms {1e3*np.sqrt(np.mean(r[s:]**2)):.3f}")
# the model with one group of the truth's parameters
motor = ('armature_resistance', 'armature_inductance', 'back_emf_constant', 'torque_constant', 'motor_inertia',
         'motor_friction', 'propeller_torque_coefficient')
for name, group in (('damping', ('damping',)), ('motor', motor),
                    ('gravity+L/J', ('gravity_stiffness', 'lever_per_inertia', 'thrust_coefficient'))):
    p = m.replace(**{k: getattr(truth, k) for k in group})
    for thr in (0.933, 1.196):
        sim = problem.simulate(p, {"dead_zone": {"threshold_voltage": thr}})
        r = sim - run.angle
        print(f"model with truth's {name} thr {thr}: train rss {np.sum(r[:s]**2):.4f}")
