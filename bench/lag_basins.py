"""Is a thrust lag found with its true size from any Latin-hypercube schedule, or reported as ambiguous?

Each seed: the default rig with every nominal parameter moved by a factor U(0.8, 1.2), a thrust lag of U(0.05, 0.3) s,
60 s of Latin-hypercube steps (seed = schedule seed), PSNR 40 dB on Va, Ia and the angle plus 10-bit quantisation;
the fit is told the structure (``compare(record, ('thrust_lag',))``, i.e. ``--add thrust_lag``). Reported per seed:
the time constant from the default start alone (what the fit returned before the basin search), the answer after
the search (:mod:`aeropend_core.diagnosis.basins`), whether an ambiguity was reported, and the z of the time
constant, gravity stiffness and thrust gain. A seed passes when the time constant is within 2 sigma and 15 % of
the truth, or an ambiguity is reported that lists a basin within 15 % of the truth.

Run:  nice -n 10 .venv/bin/python bench/lag_basins.py [--seeds 40] [--seed-base 52000] [--workers 2] [--json PATH]
      (about 20-40 s of CPU per seed)
"""
from __future__ import annotations

import argparse
import sys
import time
from multiprocessing import get_context
from pathlib import Path

ROOT = Path(__file__).resolve().parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from _common import add_json_argument, figure, write_json  # noqa: E402

SEED_BASE = 52000
MOVED = ('armature_resistance', 'back_emf_constant', 'motor_inertia', 'propeller_torque_coefficient',
         'thrust_coefficient', 'gravity_stiffness', 'damping', 'lever_per_inertia')


def run(seed: int) -> dict:
    import numpy as np
    from threadpoolctl import threadpool_limits

    from aeropend_core.diagnosis.compare import compare
    from aeropend_core.io.recording import from_columns
    from aeropend_core.model.parameters import DEFAULT_PARAMETERS
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import simulate
    from false_alarms import duty_cap
    rng = np.random.default_rng(seed)
    parameters = DEFAULT_PARAMETERS.scaled(**{name: float(rng.uniform(0.8, 1.2)) for name in MOVED})
    tau = float(rng.uniform(0.05, 0.3))
    cap = duty_cap(parameters)
    duty = lhc_schedule(60.0, duty_range=(0.0, cap), duty_cap=cap, seed=seed).duty(duration=60.0)
    trajectory = simulate(duty, parameters, {'thrust_lag': {'time_constant': tau}},
                          noise=MeasurementNoise(40.0, True), seed=seed + 1)
    started = time.perf_counter()
    with threadpool_limits(1):
        comparison = compare(from_columns(trajectory.columns(with_truth=False), source=f'lag seed {seed}'),
                             ('thrust_lag',))
    fit = comparison.fit
    estimate, sigma = fit.parameters['time_constant'], fit.standard_errors['time_constant']
    ambiguity = fit.extra.get('ambiguity')
    basins = [b['time_constant'] for b in (ambiguity or {}).get('basins', [])]
    close = abs(estimate / tau - 1) <= 0.15 and abs(estimate - tau) <= 2 * sigma
    listed = bool(ambiguity) and any(abs(b / tau - 1) <= 0.15 for b in basins)
    truth = {'gravity_stiffness': parameters.gravity_stiffness, 'thrust_gain': parameters.thrust_gain,
             'time_constant': tau}
    return {'seed': seed, 'truth_time_constant': tau,
            'local_start_time_constant': fit.extra.get('local_start', {}).get('time_constant', estimate),
            'time_constant': estimate, 'sigma': sigma, 'ambiguous': bool(ambiguity), 'basins': basins,
            'z': {n: (fit.parameters[n] - v) / fit.standard_errors[n] for n, v in truth.items()},
            'passed': bool(close or listed), 'seconds': round(time.perf_counter() - started, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--seeds', type=int, default=40)
    parser.add_argument('--seed-base', type=int, default=SEED_BASE)
    parser.add_argument('--workers', type=int, default=2)
    add_json_argument(parser)
    args = parser.parse_args()
    if args.seeds < 1 or args.workers < 1:
        parser.error('--seeds and --workers must be at least 1')
    started = time.perf_counter()
    rows = []
    with get_context('spawn').Pool(args.workers) as pool:
        for r in pool.imap(run, range(args.seed_base, args.seed_base + args.seeds), chunksize=1):
            rows.append(r)
            local_ok = abs(r['local_start_time_constant'] / r['truth_time_constant'] - 1) <= 0.15
            print(f'{r["seed"]} truth {r["truth_time_constant"]:.3f} s  default start '
                  f'{r["local_start_time_constant"]:.3f}'
                  f'{"" if local_ok else " (wrong basin)"}  searched {r["time_constant"]:.3f} +- {r["sigma"]:.3f}'
                  f'{"  AMBIGUOUS " + str([round(b, 3) for b in r["basins"]]) if r["ambiguous"] else ""}  z '
                  + ' '.join(f'{n}={z:+.1f}' for n, z in r['z'].items())
                  + f'  {"pass" if r["passed"] else "FAIL"}  {r["seconds"]} s', flush=True)
    wall = time.perf_counter() - started
    passed = sum(r['passed'] for r in rows)
    wrong_before = sum(abs(r['local_start_time_constant'] / r['truth_time_constant'] - 1) > 0.15 for r in rows)
    print(f'passed {passed} of {len(rows)} (found within 15 % and 2 sigma, or ambiguous with the true basin '
          f'listed); from the default start alone {wrong_before} of {len(rows)} stopped in a wrong basin; '
          f'wall {wall:.0f} s on {args.workers} workers')
    write_json(args.json, 'lag_basins', [figure('thrust lag found or reported ambiguous', passed / len(rows),
                                                'fraction', target='1.0', met=passed == len(rows))],
               records=rows, wall_seconds=round(wall, 1), seed_base=args.seed_base)


if __name__ == '__main__':
    main()
