"""Simulation arrays of every built-in effect alone and all together, open loop (`simulate`) and closed loop
(`simulate_loop`, one loop and four together by `simulate_loops`), saved to an .npz: run once on the base tree
(PYTHONPATH=/tmp/loop26/base) and once on this tree, then compare with cmp_npz.py (bit for bit, sign bits too).

    nice -n 10 .venv/bin/python bench/results/2026-12-07-s26-loop/cmp_sim.py OUT.npz
"""
import sys

import numpy as np

from aeropend_core.control.law import PidGains
from aeropend_core.control.loop import FeedforwardMap, simulate_loop, simulate_loops
from aeropend_core.model.effects import CATALOG, resolve_effects
from aeropend_core.model.parameters import DEFAULT_PARAMETERS
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate

VALUES = {'friction_acceleration': 3.0, 'drag_coefficient': 0.05, 'cable_stiffness': 2.0, 'angle_offset': 0.03,
          'threshold_voltage': 0.9, 'time_constant': 0.15, 'filter_delay': 0.02}
cases = {'none': {}}
for name, effect in CATALOG.items():
    if not effect.compiled:
        continue
    values = {p.name: VALUES.get(p.name, 0.1) for p in effect.parameters}
    try:
        resolve_effects({name: values})
        cases[name] = {name: values}
    except Exception as error:      # noqa: BLE001
        print('skip', name, error)
cases['all'] = {k: v for c in list(cases.values()) for k, v in c.items()}
print(list(cases))
out = {}
rng = np.random.default_rng(3)
duty = np.repeat(rng.uniform(0.1, 0.7, 60), 245)
for label, effects in cases.items():
    try:
        trajectory = simulate(duty, effects=effects, noise=MeasurementNoise(psnr_db=40), seed=5)
    except Exception as error:      # noqa: BLE001
        print('open loop skip', label, error)
        continue
    for key, value in trajectory.columns().items():
        out[f'{label}/{key}'] = value
gains = PidGains(p=1.5, i=0.7, d=0.2, derivative_filter_time=0.02, u_clamp_min=0.0, u_clamp_max=0.8,
                 antiwindup='back_calculation', feedforward_gain=1.0)
reference = np.repeat([0.3, 0.7, 0.5, 0.9], 2450)
keys = ('duty', 'angle', 'armature_voltage', 'armature_current', 'integral', 'unsaturated', 'tripped')
for label, effects in cases.items():
    run = simulate_loop(gains, reference, None, effects=effects, noise=MeasurementNoise(psnr_db=50, quantise=True),
                        seed=2, duty_limit=0.8)
    for key in keys:
        out[f'loop/{label}/{key}'] = getattr(run, key)
    for key, value in run.truth.items():
        out[f'loop/{label}/truth/{key}'] = value
    runs = simulate_loops([(gains, DEFAULT_PARAMETERS.replace(gravity_stiffness=DEFAULT_PARAMETERS.gravity_stiffness
                                                              * (1 + 0.05 * j)), 10 + j) for j in range(4)],
                          reference[:4900], FeedforwardMap(), effects, MeasurementNoise(psnr_db=45, quantise=True),
                          duty_limit=0.8)
    for j, run in enumerate(runs):
        for key in keys:
            out[f'loops/{label}/{j}/{key}'] = getattr(run, key)
np.savez(sys.argv[1], **out)
print(len(out), 'arrays')
