"""`control design` speed and quality: the tree's design against a baseline commit's, in the same run.

Five models (the nominal one, a thrust lag of 0.15 s, Coulomb friction 4 rad/s^2, a dead zone of 0.6 V, a rig
whose parameters are off by +-15 %), the course template at 40 deg (settling <= 2 s, overshoot <= 10 %, error <=
5 %, duty <= 0.8, the CLI's 50 dB); each design is timed (wall clock, alternating old and new, the median of
``--repeats``) and its predicted metrics on the design schedule are compared: the new one must not be worse.
The baseline is ``aeropend_core/control/design.py`` of ``--baseline`` (a commit), imported from ``git show``.

    nice -n 10 .venv/bin/python bench/design_speed.py --baseline 908db1e --repeats 3
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import math
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

from aeropend_core.control import design as current
from aeropend_core.control.metrics import Template
from aeropend_core.errors import AeropendError
from aeropend_core.model.parameters import DEFAULT_PARAMETERS
from aeropend_core.sim.noise import MeasurementNoise

ROOT = Path(__file__).resolve().parent.parent
MODELS = {
    'nominal': (DEFAULT_PARAMETERS, {}),
    'thrust_lag 0.15 s': (DEFAULT_PARAMETERS, {'thrust_lag': {'time_constant': 0.15}}),
    'coulomb_friction 4': (DEFAULT_PARAMETERS, {'coulomb_friction': {'friction_acceleration': 4.0}}),
    'dead_zone 0.6 V': (DEFAULT_PARAMETERS, {'dead_zone': {'threshold_voltage': 0.6}}),
    'rig +-15 %': (DEFAULT_PARAMETERS.scaled(thrust_coefficient=0.9, gravity_stiffness=1.1, damping=0.85,
                                             armature_resistance=1.15, motor_inertia=1.15), {}),
}


def baseline_module(commit: str):
    text = subprocess.run(['git', 'show', f'{commit}:aeropend_core/control/design.py'], cwd=ROOT, check=True,
                          capture_output=True, text=True).stdout
    path = Path(tempfile.mkdtemp()) / 'design_baseline.py'
    path.write_text(text)
    spec = importlib.util.spec_from_file_location('design_baseline', path)
    module = importlib.util.module_from_spec(spec)
    sys.modules['design_baseline'] = module
    spec.loader.exec_module(module)
    return module


def one(module, parameters, effects) -> tuple[float, dict]:
    started = time.perf_counter()
    try:
        result = module.design(Template(), math.radians(40), parameters, effects,
                               noise=MeasurementNoise(psnr_db=50.0, quantise=True))
        outcome = {'gains': result.gains.as_dict(), 'misses': result.misses(),
                   'steps': [{item: m.value(item) for item in ('overshoot', 'settling', 'error', 'duty')}
                             for m in result.metrics]}
    except module.TemplateNotMet as refusal:
        outcome = {'refused': dict(refusal.misses)}
    except AeropendError as refusal:
        outcome = {'refused': {'model': str(refusal)}}
    return time.perf_counter() - started, outcome


def worst(outcome: dict, item: str) -> float:
    if 'refused' in outcome:
        return math.nan
    return max(step[item] if item != 'error' else abs(step[item]) for step in outcome['steps'])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--baseline', default='908db1e', help='commit whose design.py is the baseline')
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--json', type=Path, default=None)
    args = parser.parse_args()
    warnings.simplefilter('ignore')
    old = baseline_module(args.baseline)
    one(old, DEFAULT_PARAMETERS, {})      # compile / warm both
    one(current, DEFAULT_PARAMETERS, {})
    rows = []
    print('| model | old s | new s | ratio | old worst overshoot / settling / error | new worst overshoot / settling '
          '/ error | old met | new met |')
    print('|' + '---|' * 8)
    for name, (parameters, effects) in MODELS.items():
        times = {'old': [], 'new': []}
        outcomes = {}
        for _ in range(args.repeats):
            for label, module in (('old', old), ('new', current)):
                seconds, outcome = one(module, parameters, effects)
                times[label].append(seconds)
                outcomes[label] = outcome
        t_old, t_new = statistics.median(times['old']), statistics.median(times['new'])
        cells = {label: '/'.join(f'{worst(outcomes[label], item):.3g}' for item in ('overshoot', 'settling', 'error'))
                 for label in ('old', 'new')}
        met = {label: ('refused' not in outcomes[label]) and not outcomes[label]['misses'] for label in ('old', 'new')}
        print(f'| {name} | {t_old:.2f} | {t_new:.2f} | {t_new / t_old:.2f} | {cells["old"]} | {cells["new"]} | '
              f'{met["old"]} | {met["new"]} |', flush=True)
        rows.append({'model': name, 'seconds_old': times['old'], 'seconds_new': times['new'], 'old': outcomes['old'],
                     'new': outcomes['new']})
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1, default=float))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
