"""Diagnosis time for a 60 s recording with every catalog candidate (target < 5 s on this machine).

Baseline measured in the same run: one output-error fit of the nominal model (the unit of work a diagnosis
repeats once per candidate). The ratio says how many such fits a whole diagnosis costs.

Run:  .venv/bin/python bench/bench_diagnose.py [--duration 60] [--json PATH]   (~10 s)

The diagnosis includes the search for several effects (forward selection with backward elimination, which
repeats the candidates on top of each effect found) and the per-stretch drift test.
"""
import argparse
import time

from _common import add_json_argument, figure, write_json

from aeropend_core.diagnosis.compare import compare, prepare
from aeropend_core.diagnosis.diagnose import diagnose
from aeropend_core.present.verdict_text import verdict_of
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.io.recording import from_columns
from aeropend_core.sim.simulate import simulate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--duration', type=float, default=60.0)
    add_json_argument(parser)
    args = parser.parse_args()
    duty = lhc_schedule(args.duration, seed=3).duty(duration=args.duration)
    trajectory = simulate(duty, effects={'coulomb_friction': 4.0}, noise=MeasurementNoise(40.0, True), seed=4)
    recording = from_columns(trajectory.columns(with_truth=False))
    diagnose(recording, candidates=['cable_torque'])               # JIT compile / cache warm-up
    start = time.perf_counter()
    prep = prepare(recording)
    compare(prep, ())
    one_fit = time.perf_counter() - start
    start = time.perf_counter()
    result = diagnose(recording)
    total = time.perf_counter() - start
    print(f'{args.duration:g} s recording, {len(result.candidates)} candidates: diagnosis {total:.2f} s '
          f'(target < 5 s: {"met" if total < 5 else "NOT met"})')
    print(f'baseline, prepare + one nominal fit and evaluation: {one_fit:.2f} s; ratio {total / one_fit:.1f}')
    print(f'verdict: {verdict_of(result)}')
    write_json(args.json, 'bench_diagnose', [
        figure(f'diagnosis time, {args.duration:g} s recording, {len(result.candidates)} candidates', total, 's',
               baseline=one_fit, baseline_name='prepare + one nominal output-error fit and evaluation',
               ratio=total / one_fit, ratio_meaning='diagnosis / one nominal fit (cost in fits)',
               target='< 5 s', met=total < 5),
    ], duration_s=args.duration, verdict=result.verdict, missing_effect=result.missing_effect,
        hidden_effect='coulomb_friction', correct=result.missing_effect == 'coulomb_friction',
        message=verdict_of(result))


if __name__ == '__main__':
    main()
