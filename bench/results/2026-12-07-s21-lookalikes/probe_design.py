"""Does the project's experiment-design code separate the cable from its cubic look-alike? (a 40 s cable record)

Run (repository root):  nice -n 10 .venv/bin/python bench/results/2026-12-07-s21-lookalikes/probe_design.py cable 43100
"""
import sys
import time

from aeropend_core.diagnosis.diagnose import diagnose
from aeropend_core.diagnosis.experiment_design import confounded_models, design_experiment
from aeropend_core.diagnosis.discovery import term_effect
from aeropend_core.io.recording import from_columns
from aeropend_core.model.effects import catalog_scope
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate


def _record(effects, seed, duration=40.0):
    """The record of tests/test_lookalike_check.py (40 s LHC steps, duty <= 0.7, 40 dB, quantised)."""
    with catalog_scope():
        effects = {term_effect(name[5:]) if name.startswith('term ') else name: value
                   for name, value in effects.items()}
        duty = lhc_schedule(duration, duty_range=(0.0, 0.7), duty_cap=0.7, seed=seed).duty(duration=duration)
        trajectory = simulate(duty, effects=effects, noise=MeasurementNoise(psnr_db=40.0, quantise=True),
                              seed=seed + 1)
    return from_columns(trajectory.columns(with_truth=False), source=f'look-alike seed {seed}')

from aeropend_core.present.verdict_text import verdict_of
with catalog_scope():
    truth = {'cable_torque': 30.0} if sys.argv[1] == 'cable' else {'term angle^3': -5.0}
    r = diagnose(_record(truth, seed=int(sys.argv[2])))
    print(r.verdict, verdict_of(r)[:300])
    t = time.perf_counter()
    models = confounded_models(r)
    print('models', [m.effects if hasattr(m, 'effects') else m for m in models])
    d = design_experiment(models, r.noise_rms, duration=30.0, seed=1)
    print(round(time.perf_counter() - t, 1), 's')
    print(d)
