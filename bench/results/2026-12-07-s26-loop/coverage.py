"""Coverage of the closed-loop fits' +- with and without the record's noise fed back to the simulated law.

Per case and fresh seed: the truth as bench/closed_loop.py draws it (every parameter x U(0.85, 1.15), the hidden
effect at a random size, 40 dB, the 10-bit angle), the nominal-parameters design (bench/closed_loop.py's first
column) run on it over its design schedule, then `diagnose_loop` told the structure (``add`` = the hidden effect, no
other candidate; a dead zone's threshold held at the truth, as the flow holds the open-loop diagnosis's value) on
a model whose motor and damping are the truth's (as if identified open loop) and whose gravity and thrust
scale start at the nominal values. Gravity, the thrust gain and the effect's
parameter are compared with the truth: |fit - truth| <= 2 sigma (the sigma diagnose_loop gives;
a threshold has none). Each record is fitted twice: feed_back_noise False (before s26), True.

    nice -n 10 .venv/bin/python bench/results/2026-12-07-s26-loop/coverage.py --seed-base 70000 --seeds 10 \
        --out bench/results/2026-12-07-s26-loop/coverage-70000.jsonl
"""
import argparse
import json
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from closed_loop import AT, CASES, PSNR, TEMPLATE, run_on_truth, truth_of  # noqa: E402

from aeropend_core.control.controller_file import Controller  # noqa: E402
from aeropend_core.control.design import design  # noqa: E402
from aeropend_core.control.loop_diagnosis import diagnose_loop  # noqa: E402
from aeropend_core.model.effects import get_effect  # noqa: E402
from aeropend_core.model.parameters import DEFAULT_PARAMETERS  # noqa: E402
from aeropend_core.sim.noise import MeasurementNoise  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument('--seed-base', type=int, default=70000)
    parser.add_argument('--seeds', type=int, default=10)
    parser.add_argument('--first-seed', type=int, default=0)
    parser.add_argument('--cases', default=','.join(CASES))
    parser.add_argument('--out', type=Path, required=True)
    args = parser.parse_args()
    warnings.simplefilter('ignore')
    nominal_design = design(TEMPLATE, AT, noise=MeasurementNoise(psnr_db=PSNR, quantise=True))
    controller = Controller(nominal_design.gains, template=TEMPLATE, design=nominal_design.summary())
    print('gains', controller.gains.as_dict(), flush=True)
    with args.out.open('a') as out:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            for case in args.cases.split(','):
                rng = np.random.default_rng(args.seed_base + 1000 * CASES.index(case) + seed)
                parameters, effects = truth_of(case, rng)
                run = run_on_truth(controller, controller.schedule, parameters, effects, seed)
                model = parameters.replace(gravity_stiffness=DEFAULT_PARAMETERS.gravity_stiffness,
                                           lever_per_inertia=DEFAULT_PARAMETERS.lever_per_inertia)
                row = {'case': case, 'seed': seed, 'truth_effects': effects,
                       'truth': {'gravity_stiffness': parameters.gravity_stiffness,
                                 'thrust_gain': parameters.thrust_gain}}
                for values in effects.values():
                    row['truth'].update(values)
                for fed in (False, True):
                    started = time.perf_counter()
                    result = diagnose_loop(run.time, run.angle, run.duty, run.reference, run.feedforward,
                                           controller.gains, controller.gains.u_clamp_max, model,
                                           add=tuple(effects), candidates=tuple(effects),
                                           model_effects=effects if case == 'dead_zone' else {},
                                           feed_back_noise=fed)
                    fit = result.base
                    sigmas = dict(fit.sigmas)
                    sigmas['thrust_gain'] = (fit.sigmas['lever_per_inertia'] / fit.parameters.lever_per_inertia
                                             * fit.parameters.thrust_gain)
                    values = {'gravity_stiffness': fit.parameters.gravity_stiffness,
                              'thrust_gain': fit.parameters.thrust_gain}
                    values.update({name: value for name, value in fit.values.items()
                                   if any(p.name == name for e in effects for p in get_effect(e).parameters)})
                    z = {name: (values[name] - truth) / sigmas[name] if sigmas.get(name) else math.nan
                         for name, truth in row['truth'].items()}
                    row['fed' if fed else 'left_out'] = {
                        'values': values, 'sigmas': {name: sigmas.get(name) for name in values}, 'z': z,
                        'beyond_noise': fit.beyond_noise, 'noise_rms': result.noise_rms,
                        'seconds': time.perf_counter() - started}
                print(case, seed, ' | '.join(
                    f"{key}: " + ', '.join(f'{n} {row[key]["values"][n]:.4g} z {row[key]["z"][n]:+.2f}'
                                           for n in row['truth']) for key in ('left_out', 'fed')), flush=True)
                out.write(json.dumps(row) + '\n')
                out.flush()
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
