"""A/B of weak_form.EQUATION_WORKERS 1 vs 2 on bench_wsindy's window (seed 0, 40 dB, pysindy's 18-term library):
the rounds alternate the order, each round the minimum wall time of 5 fits with the caches cleared (as
bench_wsindy's run_ours). Run from the repository root:

    .venv/bin/python bench/results/2026-12-08-s27-loop/ab_workers.py 20
"""
import statistics
import sys
import time

sys.path.insert(0, 'bench')
from _common import SAME_LIBRARY, make_window  # noqa: E402

import aeropend_core.wsindy.weak_form as wf  # noqa: E402
from aeropend_core.identify.pendulum import identify_full_state  # noqa: E402
from aeropend_core.wsindy.noise_model import clear_caches  # noqa: E402


def main() -> None:
    data = make_window(0, 40.0)
    identify_full_state(data, **SAME_LIBRARY)
    results = {1: [], 2: []}
    for r in range(int(sys.argv[1])):
        for workers in ((1, 2) if r % 2 == 0 else (2, 1)):
            wf.EQUATION_WORKERS = workers
            times = []
            for _ in range(5):
                clear_caches()
                t0 = time.perf_counter()
                identify_full_state(data, **SAME_LIBRARY)
                times.append(time.perf_counter() - t0)
            results[workers].append(min(times))
    for workers, values in results.items():
        print(f'workers {workers}: min-of-5 per round, ms: median {statistics.median(values) * 1e3:.1f}, '
              f'range {min(values) * 1e3:.1f}-{max(values) * 1e3:.1f}')
    ratios = [a / b for a, b in zip(results[1], results[2])]
    print(f'1 worker / 2 workers per round: median {statistics.median(ratios):.2f}, '
          f'range {min(ratios):.2f}-{max(ratios):.2f} ({len(ratios)} rounds)')


if __name__ == '__main__':
    main()
