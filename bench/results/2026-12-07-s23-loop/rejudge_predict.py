"""Re-run the 'predict' part of bench/closed_loop.py on the seeds of a finished run (its cases.jsonl) with this
tree's metrics: the first design's model rebuilt as the run built it (the open-loop record regenerated from the
seed and diagnosed, with the named effect added when it was), the other controller measured on the truth and
predicted on the model with the same noise seeds, and its settling judged as a point (+-20 %) and against the range
of 20 noise draws. Only seeds whose first design met (no redesign: the loop's model is not rebuilt here).

    nice -n 10 .venv/bin/python bench/results/2026-12-07-s23-loop/rejudge_predict.py CASES.jsonl [--cases clean,...]
"""
import argparse
import json
import sys
import warnings
from pathlib import Path


sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
import closed_loop as cl  # noqa: E402

from aeropend_core.control.controller_file import Controller  # noqa: E402
from aeropend_core.control.hold_doubt import HoldDoubt  # noqa: E402
from aeropend_core.control.law import PidGains  # noqa: E402
from aeropend_core.control.model_source import model_from_dict  # noqa: E402
from aeropend_core.model.parameters import DEFAULT_PARAMETERS  # noqa: E402

parser = argparse.ArgumentParser()
parser.add_argument('cases', type=Path)
parser.add_argument('--cases', dest='only', default=','.join(cl.CASES))
parser.add_argument('--seed-base', type=int, required=True)
args = parser.parse_args()
warnings.simplefilter('ignore')
rows = [json.loads(line) for line in args.cases.read_text().splitlines() if line.strip()]
for r in rows:
    if 'predict' not in r or r['case'] not in args.only.split(',') or r['loop'].get('redesign') == 'designed':
        continue
    seed, case = r['seed'], r['case']
    parameters = DEFAULT_PARAMETERS.scaled(**r['truth_scales'])
    effects = r['truth_effects']
    if r.get('first_added'):
        _, open_loop = cl.identify_open_loop(parameters, effects, args.seed_base + 100 * seed + cl.CASES.index(case))
        model = cl.diagnosed_with(open_loop, tuple(r['first_added']), True)
    else:
        model = model_from_dict(r['identified'], 'open-loop diagnosis')
        held = r['identified']['hold_doubt']
        model = model.with_hold_doubt(None if held is None else HoldDoubt(tuple(held['factors']), (),
                                                                          tuple(held['tolerance'])))
    controller = Controller(PidGains(**r['nominal_gains']), model.parameters, model.effects, cl.TEMPLATE, 'x')
    new = cl.predict_other(controller, parameters, effects, seed)
    for k, (old, step) in enumerate(zip(r['predict']['steps'], new['steps'])):
        print(json.dumps({'case': case, 'seed': seed, 'step': k, 'old_measured': old['settling_measured'],
                          'old_predicted': old['settling_predicted'], 'old_ok': old['settling_ok'],
                          'overshoot_measured': step['overshoot_measured'],
                          'overshoot_predicted': step['overshoot_predicted'], 'overshoot_ok': step['overshoot_ok'],
                          'measured': step['settling_measured'], 'predicted': step['settling_predicted'],
                          'ok': step['settling_ok'], 'range': step['settling_range'],
                          'in_range': step['settling_in_range']}), flush=True)
