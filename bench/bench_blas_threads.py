"""One BLAS thread against OpenBLAS's default threads, for aeropend's own products and a whole diagnosis.

aeropend pins BLAS to one thread in the CLI, in ``diagnose()`` and in the test processes
(:mod:`aeropend_core.blas`). This measures why, in one run: the product of the input-covariance step
(``(p x n) @ (n x members)`` with p = 11 parameters, n = 10,959 residuals, 16 ensemble members: the shape of a 60 s
diagnosis) and ``aeropend diagnose`` of a 60 s friction record in a fresh process, each with the default threads
(the baseline: ``OPENBLAS_NUM_THREADS`` set to the core count, which aeropend leaves alone) and with one thread.
Run it idle and beside a CPU hog (``stress-ng --cpu 2``): the default threads cost most when the cores are busy.

Run:  .venv/bin/python bench/bench_blas_threads.py [--repeats 3] [--json PATH]   (~2 min of CPU)
"""
import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import add_json_argument, figure, time_both_blas, write_json

ROOT = Path(__file__).resolve().parents[1]
CODE = 'import sys; from aeropend_core.cli import main; sys.exit(main())'


def aeropend(*argv: str, threads: int | None) -> tuple[float, float]:
    """CPU and wall seconds of ``aeropend ARGV`` in a fresh process (threads: None = aeropend's one thread)."""
    env = {**os.environ, 'PYTHONPATH': str(ROOT)}
    for name in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
        env.pop(name, None)
    if threads is not None:
        env['OPENBLAS_NUM_THREADS'] = str(threads)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run([sys.executable, '-c', CODE, *argv], env=env, check=True, capture_output=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--repeats', type=int, default=3)
    add_json_argument(parser)
    args = parser.parse_args()
    rng = np.random.default_rng(1)
    left, right = rng.standard_normal((11, 10959)), rng.standard_normal((10959, 16))
    product = time_both_blas(lambda: left @ right, repeats=20)
    print(f'product (11 x 10959) @ (10959 x 16): default threads {product["default BLAS threads"] * 1e3:.2f} ms, '
          f'one thread {product["1 BLAS thread"] * 1e3:.2f} ms')
    cores = os.cpu_count() or 1
    with tempfile.TemporaryDirectory() as folder:
        record = str(Path(folder) / 'friction.csv')
        subprocess.run([sys.executable, '-c', CODE, 'simulate', '-o', record, '--duration', '60', '--seed', '5',
                        '--psnr', '40', '--quantise', '--effect', 'coulomb_friction=4', '--no-truth', '--quiet'],
                       env={**os.environ, 'PYTHONPATH': str(ROOT)}, check=True)
        runs = {'one thread': [], 'default threads': []}
        for _ in range(args.repeats):          # alternated, so that a change of load hits both alike
            runs['one thread'].append(aeropend('diagnose', record, '--quiet', threads=None))
            runs['default threads'].append(aeropend('diagnose', record, '--quiet', threads=cores))
    cpu = {k: statistics.median(c for c, _ in v) for k, v in runs.items()}
    wall = {k: statistics.median(w for _, w in v) for k, v in runs.items()}
    for k in runs:
        print(f'aeropend diagnose, 60 s record, {k}: CPU {cpu[k]:.2f} s, wall {wall[k]:.2f} s (median of '
              f'{args.repeats})')
    load = os.getloadavg()[0]
    print(f'load average at the end: {load:.1f}')
    write_json(args.json, 'blas_threads', [
        figure('product, one thread', product['1 BLAS thread'], 's', baseline=product['default BLAS threads'],
               baseline_name='default threads', ratio_meaning='< 1: one thread is faster'),
        figure('diagnose CPU, one thread', cpu['one thread'], 's', baseline=cpu['default threads'],
               baseline_name='default threads', ratio_meaning='< 1: one thread is faster'),
        figure('diagnose wall, one thread', wall['one thread'], 's', baseline=wall['default threads'],
               baseline_name='default threads', ratio_meaning='< 1: one thread is faster')], cores=cores)


if __name__ == '__main__':
    main()
