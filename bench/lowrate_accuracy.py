"""Accuracy of diagnose's nominal parameters per sample rate over several seeds (issue #21; the rate doubts
that ``aeropend diagnose`` prints next to its numbers, :data:`aeropend_core.signals.rate_accuracy.RATE_ACCURACY`).

Records as in bench/rate_sweep.py (default rig, Latin hypercube, 40 dB, 10-bit, 30 s), one per seed, decimated by
keeping every Nth sample, each through ``diagnose --only angle_offset --no-drift`` (as the sweep runs it).
Per rate: each seed's relative errors of gravity_stiffness, damping and thrust_gain against the truth, and the
largest |error| over the seeds.

Usage:
  nice -n 10 python bench/lowrate_accuracy.py --out bench/results/2026-11-27-lowrate/accuracy.json
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from rate_sweep import TRUTH, analyse, record  # noqa: E402

SEEDS = (11, 12, 13, 14)
EVERY = (1, 5, 10, 20)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', default='-')
    parser.add_argument('--seeds', type=int, nargs='*', default=list(SEEDS))
    parser.add_argument('--every', type=int, nargs='*', default=list(EVERY))
    options = parser.parse_args()
    records = {seed: record(seed) for seed in options.seeds}
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for every in options.every:
            row = {'rate_hz': round(490.0 / every, 2), 'seeds': {}}
            for seed, columns in records.items():
                result = analyse(columns, every, Path(folder), f's{seed}_{every}', 'diagnose',
                                 ['--quiet', '--no-drift', '--only', 'angle_offset'])
                if result['exit'] != 0:
                    row['seeds'][seed] = {'exit': result['exit'], 'message': result['message']}
                    continue
                row['seeds'][seed] = {name: round(result['parameters'][name] / truth - 1.0, 4)
                                      for name, truth in TRUTH.items() if result['parameters'][name] is not None}
            done = [v for v in row['seeds'].values() if 'exit' not in v]
            row['largest_abs_error'] = {name: max((abs(v[name]) for v in done if name in v), default=None)
                                        for name in TRUTH}
            row['completed'] = f'{len(done)}/{len(row["seeds"])}'
            rows.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
    text = json.dumps(rows, indent=1) + '\n'
    if options.out != '-':
        Path(options.out).write_text(text)
    else:
        print(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
