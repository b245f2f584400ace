"""How far one ulp of data moves a WSINDy fit: the yardstick for agreement bars between fast and straightforward paths.

Every sample of every signal of a seeded full-state window (bench_wsindy's problem: 10 s at 490 Hz, white noise at
the stated PSNR) is moved by one ulp (×(1 ± 2.2e-16), random sign), and the fit repeated. Reported per method: the
largest relative change of a selected coefficient, the largest change in units of that coefficient's standard
error, and how many equations changed their support. Methods: the full method with pysindy's 18-term library (Va
in every equation), the full method with the default library, the plain GLS + MSTLS method.

A faster implementation that only reorders sums moves the fit by about as much as this; the agreement bar of
tests/test_wsindy_agreement.py (same support, 1e-6 relative or 1e-3 σ) sits above it.

Run:  .venv/bin/python bench/wsindy_ulp_sensitivity.py [--seeds 5] [--psnr 30 40 50]   (~5 s)
"""
from __future__ import annotations

import argparse

import numpy as np

from _common import PLAIN, SAME_LIBRARY, SIGNALS, make_window

from aeropend_core.identify.pendulum import identify_full_state

METHODS = {'full method, pysindy library': dict(SAME_LIBRARY), 'full method, default library': {},
           'plain GLS + MSTLS, pysindy library': dict(SAME_LIBRARY, **PLAIN)}


def one_ulp(data: dict[str, np.ndarray], seed: int) -> dict[str, np.ndarray]:
    """`data` with every signal sample moved to a neighbouring float (up or down at random)."""
    rng = np.random.default_rng(seed)
    moved = dict(data)
    for name in SIGNALS:
        x = data[name]
        moved[name] = np.where(rng.random(x.size) < 0.5, np.nextafter(x, np.inf), np.nextafter(x, -np.inf))
    return moved


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--seeds', type=int, default=5, help='windows per PSNR (seeds 0..N-1)')
    parser.add_argument('--psnr', type=float, nargs='+', default=[30.0, 40.0, 50.0], help='PSNR values [dB]')
    args = parser.parse_args()
    worst = {name: [0.0, 0.0, 0, 0] for name in METHODS}   # relative, sigmas, support changes, equations
    for seed in range(args.seeds):
        for psnr in args.psnr:
            data = make_window(seed, psnr)
            moved = one_ulp(data, seed)
            for name, options in METHODS.items():
                before = identify_full_state(data, **options).result
                after = identify_full_state(moved, **options).result
                for a, b in zip(before.equations, after.equations):
                    worst[name][3] += 1
                    if a.selected != b.selected:
                        worst[name][2] += 1
                        continue
                    for term, value in a.coefficients.items():
                        change = abs(b.coefficients[term] - value)
                        worst[name][0] = max(worst[name][0], change / abs(value))
                        worst[name][1] = max(worst[name][1], change / a.standard_errors[term])
    print(f'one ulp of data, {args.seeds} seeds x PSNR {", ".join(f"{p:g}" for p in args.psnr)} dB:')
    print(f'{"method":36s} {"max rel. coef change":>21s} {"max change / sigma":>19s} {"support changes":>16s}')
    for name, (relative, sigmas, changed, total) in worst.items():
        print(f'{name:36s} {relative:21.2e} {sigmas:19.2e} {changed:>9d} of {total}')


if __name__ == '__main__':
    main()
