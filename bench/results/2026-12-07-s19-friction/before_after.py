"""Within 1/2 sigma before (the noise's sigma alone) and after (with the friction law's shape doubt), from the rows
of bench/second_rig.py (--rows) and bench/sigma_coverage.py (--out .../records.json).

Run: .venv/bin/python bench/results/2026-12-07-s19-friction/before_after.py ROWS.jsonl [records.json]
"""
import json
import math
import sys
from collections import defaultdict


def table(pairs):
    """pairs: {parameter: [(z_before, z_after, growth)]} -> markdown lines."""
    lines = ['| parameter | records | before: within 1 / 2 sigma | after: within 1 / 2 sigma | median sigma growth |',
             '| --- | --- | --- | --- | --- |']
    for name in sorted(pairs):
        rows = pairs[name]
        n = len(rows)

        def share(k, bound):
            return 100.0 * sum(abs(r[k]) <= bound for r in rows) / n
        growth = sorted(r[2] for r in rows)[n // 2]
        lines.append(f'| {name} | {n} | {share(0, 1):.0f} % / {share(0, 2):.0f} % | {share(1, 1):.0f} % / '
                     f'{share(1, 2):.0f} % | {growth:.1f}x |')
    return lines


def second_rig(path):
    pairs = defaultdict(list)
    for line in open(path):
        r = json.loads(line)
        if r.get('refused'):
            continue
        for name, truth in r['truth'].items():
            est, sigma = r['estimates'].get(name), r['sigmas'].get(name)
            if est is None or sigma is None or not sigma > 0:
                continue
            move = r.get('friction_law_doubt', {}).get(name, 0.0)
            noise = math.sqrt(max(sigma ** 2 - move ** 2, 0.0))
            if not noise > 0:
                continue
            pairs[name].append(((est - truth) / noise, (est - truth) / sigma, sigma / noise))
    return pairs


def own(path):
    pairs = defaultdict(list)
    for r in json.load(open(path))['records']:
        for name, e in r.get('parameters', {}).items():
            noise = e.get('sigma_noise', e['sigma'])
            if not (isinstance(noise, float) and noise > 0):
                continue
            pairs[name].append(((e['estimate'] - e['truth']) / noise, e['z'], e['sigma'] / noise))
    return pairs


if __name__ == '__main__':
    print('\n'.join(table(second_rig(sys.argv[1]))))
    if len(sys.argv) > 2:
        print()
        print('\n'.join(table(own(sys.argv[2]))))
