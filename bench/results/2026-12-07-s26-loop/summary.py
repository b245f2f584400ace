"""Table of coverage.py's rows: per case and method, records within 2 sigma of the truth per parameter, and the
median |relative error|.

    .venv/bin/python bench/results/2026-12-07-s26-loop/summary.py bench/results/2026-12-07-s26-loop/coverage-70000.jsonl
"""
import json
import math
import sys
from collections import defaultdict

import numpy as np

rows = [json.loads(line) for line in open(sys.argv[1]) if line.strip()]
cells = defaultdict(lambda: defaultdict(list))
for row in rows:
    for method in ('left_out', 'fed'):
        fit = row[method]
        for name, truth in row['truth'].items():
            sigma = fit['sigmas'].get(name)
            if sigma is None or not math.isfinite(sigma):
                continue
            error = fit['values'][name] - truth
            cells[(row['case'], name)][method].append((abs(error) <= 2 * sigma, abs(error / truth)))
print('| case | parameter | records | within 2 sigma: noise left out | noise fed back | median abs error: left out '
      '| fed back |')
print('| --- | --- | --- | --- | --- | --- | --- |')
for (case, name), methods in cells.items():
    a, b = methods['left_out'], methods['fed']
    print(f'| {case} | {name} | {len(a)} | {sum(x for x, _ in a)} | {sum(x for x, _ in b)} | '
          f'{100 * np.median([e for _, e in a]):.2f} % | {100 * np.median([e for _, e in b]):.2f} % |')
for method in ('left_out', 'fed'):
    hits = [x for methods in cells.values() for x, _ in methods[method]]
    print(f'{method}: {sum(hits)} of {len(hits)} within 2 sigma')
