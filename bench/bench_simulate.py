"""Simulator speed: seconds of rig time simulated per second of wall time (target >= 200x real time).

Default path: compiled fixed-step RK4 (numba). Baselines measured in the same run: the reference path (LSODA on each
stretch of constant input, also used for users' own effects) and scipy's solve_ivp(LSODA) in ONE call over the
whole record with the input looked up by time (what a straightforward implementation does).

Run:  .venv/bin/python bench/bench_simulate.py [--duration 60] [--repeat 3] [--json PATH]   (~5 s)
"""
import argparse
import time

import numpy as np
from scipy.integrate import solve_ivp

from _common import add_json_argument, figure, write_json

from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.model.parameters import DEFAULT_PARAMETERS as P
from aeropend_core.model.parameters import SAMPLE_TIME
from aeropend_core.sim.simulate import RigSimulator, simulate


def naive(duty: np.ndarray) -> np.ndarray:
    voltage = np.asarray(P.voltage_from_duty(duty))
    simulator = RigSimulator()
    rhs_for = simulator._rhs_factory          # same equations, one rhs per voltage level

    def rhs(t, x):
        k = min(int(t / SAMPLE_TIME), len(voltage) - 1)
        return rhs_for(float(voltage[k]))(t, x)

    t_eval = np.arange(len(duty)) * SAMPLE_TIME
    solution = solve_ivp(rhs, (0, t_eval[-1]), np.zeros(4), method='LSODA', t_eval=t_eval, rtol=1e-6,
                         atol=[1e-6, 1e-3, 1e-7, 1e-6])
    return solution.y[2]


def best_of(repeat, function, *args, **kwargs):
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        result = function(*args, **kwargs)
        times.append(time.perf_counter() - start)
    return min(times), result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--duration', type=float, default=60.0)
    parser.add_argument('--repeat', type=int, default=3)
    add_json_argument(parser)
    args = parser.parse_args()
    duty = lhc_schedule(args.duration, seed=1).duty(duration=args.duration)
    simulate(duty[:100])                                                   # compile / load the numba cache
    ours, trajectory = best_of(args.repeat, simulate, duty, effects={'coulomb_friction': 4.0, 'thrust_lag': 0.15})
    plain, _ = best_of(args.repeat, simulate, duty)
    reference, _ = best_of(args.repeat, simulate, duty, method='lsoda')
    baseline, angle = best_of(1, naive, duty)
    agreement = np.max(np.abs(angle - simulate(duty).truth['angle']))
    print(f'record: {args.duration:g} s at 490 Hz ({len(duty)} samples), best of {args.repeat}')
    print(f'simulate, nominal:                {plain:7.3f} s  = {args.duration / plain:7.0f} x real time')
    print(f'simulate, friction + thrust lag:  {ours:7.3f} s  = {args.duration / ours:7.0f} x real time')
    print(f'reference path, LSODA per constant-input stretch: {reference:7.3f} s  = '
          f'{args.duration / reference:5.0f} x real time')
    print(f'baseline, one LSODA call, input by time lookup:   {baseline:7.3f} s  = '
          f'{args.duration / baseline:5.0f} x real time')
    print(f'compiled vs reference: {reference / plain:.1f}x; vs one-call baseline: {baseline / plain:.1f}x; '
          f'max angle difference to the baseline {agreement:.2e} rad')
    print('target >= 200x real time:', 'met' if args.duration / plain >= 200 else 'NOT met')
    speed = args.duration / plain
    write_json(args.json, 'bench_simulate', [
        figure(f'simulator speed, nominal model, {args.duration:g} s record', speed, 'x real time',
               baseline=args.duration / baseline, baseline_name='one solve_ivp(LSODA) call, input by time lookup',
               ratio=baseline / plain, ratio_meaning='speed-up (baseline time / ours)', target='>= 200x real time',
               met=speed >= 200),
        figure('simulator speed, friction + thrust lag', args.duration / ours, 'x real time',
               baseline=args.duration / reference, baseline_name='reference path (LSODA per constant-input stretch)',
               ratio=reference / ours, ratio_meaning='speed-up (baseline time / ours)'),
    ], duration_s=args.duration, repeat=args.repeat,
        seconds={'nominal': plain, 'effects': ours, 'reference_lsoda': reference, 'one_call_lsoda': baseline},
        max_angle_difference_rad=float(agreement))


if __name__ == '__main__':
    main()
