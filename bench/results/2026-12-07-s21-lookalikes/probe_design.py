"""Does the project's experiment-design code separate the cable from its cubic look-alike? (a 40 s cable record)

Run (repository root):  nice -n 10 .venv/bin/python bench/results/2026-12-07-s21-lookalikes/probe_design.py cable 43100
"""
import sys
import time

sys.path.insert(0, 'tests')
from test_lookalike_check import _record
from aeropend_core.diagnosis.diagnose import diagnose
from aeropend_core.diagnosis.experiment_design import confounded_models, design_experiment
from aeropend_core.model.effects import catalog_scope
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
