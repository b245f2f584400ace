"""Detection table of the missing-physics loop: each catalog effect hidden in turn, several seeds.

For each case: the verdict, the recommended effect, its estimate against the truth, and the held-out model error
beyond the noise before -> after adding it. Data: 60 s LHC duty steps (cable: duty up to 0.9, the large-angle
experiment the tool recommends for it), PSNR 40 dB on Va, Ia, angle + 10-bit quantisation, only measured columns.

Run:  .venv/bin/python bench/diagnosis_table.py [--seeds 1 2 3] [--psnr 40]
"""
import argparse
import time

from aeropend_core.diagnosis.compare import excess_error
from aeropend_core.diagnosis.diagnose import diagnose
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.model.parameters import DEFAULT_PARAMETERS
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.io.recording import from_columns
from aeropend_core.sim.simulate import simulate

CASES = {'none': None, 'coulomb_friction': 4.0, 'quadratic_drag': 4.0, 'cable_torque': 20.0,
         'angle_offset': 0.05, 'thrust_lag': 0.15, 'dead_zone': 0.6}
MAX_DUTY = {'cable_torque': 0.9}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--seeds', type=int, nargs='+', default=[1, 2, 3])
    parser.add_argument('--psnr', type=float, default=40.0)
    args = parser.parse_args()
    print(f'{"hidden":17s} {"seed":>4s} {"verdict":15s} {"named":17s} {"estimate":>9s} {"truth":>7s} {"err %":>6s} '
          f'{"beyond noise before->after [mrad]":>34s} {"noise":>6s} {"s":>5s}')
    hits = total = 0
    for effect, value in CASES.items():
        for seed in args.seeds:
            max_duty = MAX_DUTY.get(effect, 0.7)
            duty = lhc_schedule(60, duty_range=(0, max_duty), duty_cap=max_duty, seed=seed).duty(duration=60)
            effects = None if value is None else {effect: value}
            trajectory = simulate(duty, DEFAULT_PARAMETERS, effects, noise=MeasurementNoise(args.psnr, True),
                                  seed=seed + 100)
            start = time.perf_counter()
            found = diagnose(from_columns(trajectory.columns(with_truth=False)))
            seconds = time.perf_counter() - start
            named = found.missing_effect or '-'
            correct = named == (effect if value is not None else '-')
            hits += correct
            total += 1
            estimate, error, before_after = '', '', ''
            if found.missing_effect:
                best = next(c for c in found.candidates if c.effect == found.missing_effect)
                estimate = next(iter(best.parameters.values()))
                if value is not None and named == effect:
                    error = f'{(estimate - value) / value * 100:+.1f}'
                estimate = f'{estimate:.4g}'
                before_after = f'{best.excess_before * 1e3:.2f} -> {best.excess_after * 1e3:.2f}'
            else:
                before_after = f'{excess_error(found.current.rms_error, found.noise_rms) * 1e3:.2f}'
            print(f'{effect:17s} {seed:4d} {found.verdict:15s} {named:17s} {estimate:>9s} '
                  f'{"" if value is None else value:>7} {error:>6s} {before_after:>34s} '
                  f'{found.noise_rms * 1e3:6.2f} {seconds:5.1f}', flush=True)
    print(f'correct verdicts: {hits}/{total}')


if __name__ == '__main__':
    main()
