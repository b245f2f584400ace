"""The weak-form identify's error per sample rate over several seeds (issue #21: the size its rate warning states,
``aeropend_core.identify.record.WEAK_FORM_RATE_BIAS``).

Records as in bench/rate_sweep.py (default rig, Latin hypercube, 40 dB, 10-bit, 30 s), one per seed, decimated by
keeping every Nth sample, through :func:`aeropend_core.identify.pendulum.identify_pendulum` as ``aeropend identify``
calls it (the duty given). Prints each seed's relative errors of gravity_stiffness, damping and thrust_gain and,
per rate, the one with the largest |error| for each parameter (signed).

Usage:
  nice -n 10 python bench/lowrate_weak_form.py --out bench/results/2026-11-27-lowrate/weak_form.json
"""
from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from rate_sweep import DURATION, TRUTH, MeasurementNoise, lhc_schedule, simulate  # noqa: E402

from aeropend_core.identify.pendulum import identify_pendulum  # noqa: E402

SEEDS = (11, 12, 13, 14)
EVERY = (1, 2, 5, 10, 20)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', default='-')
    options = parser.parse_args()
    rows = {every: {'rate_hz': round(490.0 / every, 2), 'seeds': {}} for every in EVERY}
    for seed in SEEDS:
        duty = lhc_schedule(DURATION, seed=seed).duty(duration=DURATION)
        columns = simulate(duty, noise=MeasurementNoise(40.0, True), seed=seed).columns(with_truth=False)
        for every in EVERY:
            pick = slice(None, None, every)
            signals = [np.asarray(columns[k][pick], dtype=float)
                       for k in ('t', 'armature_voltage', 'armature_current', 'angle')]
            with warnings.catch_warnings():
                warnings.simplefilter('ignore', RuntimeWarning)
                fitted = identify_pendulum(*signals, duty=np.asarray(columns['duty'][pick], dtype=float)).parameters
            rows[every]['seeds'][seed] = {k: round(fitted[k] / v - 1.0, 4) for k, v in TRUTH.items()}
            print(json.dumps({'seed': seed, 'rate_hz': rows[every]['rate_hz'], **rows[every]['seeds'][seed]}),
                  file=sys.stderr, flush=True)
    for row in rows.values():
        row['largest_error'] = {k: max((v[k] for v in row['seeds'].values()), key=abs) for k in TRUTH}
    text = json.dumps(list(rows.values()), indent=1) + '\n'
    if options.out != '-':
        Path(options.out).write_text(text)
    else:
        print(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
