"""First identification window after a fresh set-up: is it on time?

The online identification (identification_node's worker) analyses a 25 s window every 5 s (hop). Its kernels are
numba functions cached on disk; compiled on first use they cost seconds, and the windows that come due meanwhile
are skipped. scripts/setup.sh runs scripts/warm_numba_cache.py so that the cache is filled at set-up time.

Three fresh processes, each with a numba cache folder of its own (NUMBA_CACHE_DIR, so that nothing from this
checkout's __pycache__ is reused):

* cold: an empty cache, no warm-up (what the first window cost before the set-up warmed the cache);
* set-up: scripts/warm_numba_cache.py into a second empty cache (its wall time is the set-up's extra cost);
* after set-up: a new process on that warmed cache, as the node's worker after `scripts/setup.sh`.

In each analysing process: the import time of the analysis stack (the worker does it at spawn, before any window),
the first window's analyze_window time, and a second window's (steady state, the same-run baseline). Target: the
first window after set-up within the hop (5 s), i.e. no window skipped.

Run:  .venv/bin/python bench/bench_first_window.py [--json PATH]   (~1-2 min: the cold run compiles everything)
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import add_json_argument, figure, write_json

ROOT = Path(__file__).resolve().parents[1]
#: The node's defaults: window length and hop [s].
WINDOW_S = 25.0
HOP_S = 5.0

CHILD = r'''
import json, sys, time
started = time.perf_counter()
from aeropend_core.diagnosis.online import analyze_window
import aeropend_core.identify.pendulum, aeropend_core.diagnosis.output_error, aeropend_core.signals.preprocess
imported = time.perf_counter() - started
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate
window = float(sys.argv[1])
run = simulate(lhc_schedule(2 * window, seed=11).duty(duration=2 * window), noise=MeasurementNoise(40.0, True), seed=11)
n = len(run.time) // 2
times = []
for part in (slice(0, n), slice(n, 2 * n)):
    t0 = time.perf_counter()
    result = analyze_window(run.time[part] - run.time[part][0], run.armature_voltage[part],
                            run.armature_current[part], run.angle[part])
    times.append(time.perf_counter() - t0)
print(json.dumps({'import_s': imported, 'first_window_s': times[0], 'second_window_s': times[1],
                  'fit_percent': result.fit_percent}))
'''


def run(command: list[str], cache: str) -> tuple[float, str]:
    """Wall time [s] and standard output of `command` with NUMBA_CACHE_DIR=`cache`."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    started = time.perf_counter()
    done = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - started
    if done.returncode != 0:
        raise SystemExit(f'bench_first_window: {" ".join(command[:3])} failed ({done.returncode}):\n{done.stderr}')
    return wall, done.stdout


def analyse(cache: str) -> dict:
    wall, out = run([sys.executable, '-c', CHILD, str(WINDOW_S)], cache)
    result = json.loads(out.strip().splitlines()[-1])
    result['process_wall_s'] = wall
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_json_argument(parser)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix='aeropend-numba-cold-') as cold_cache, \
            tempfile.TemporaryDirectory(prefix='aeropend-numba-setup-') as setup_cache:
        cold = analyse(cold_cache)
        setup_wall, _ = run([sys.executable, str(ROOT / 'scripts' / 'warm_numba_cache.py')], setup_cache)
        warm = analyse(setup_cache)
    for label, row in (('cold (empty cache, no warm-up)', cold), ('after set-up (warmed cache)', warm)):
        print(f'{label:32s}: imports {row["import_s"]:5.2f} s, first window {row["first_window_s"]:6.2f} s, '
              f'second window {row["second_window_s"]:5.2f} s (fit {row["fit_percent"]:.1f} %)')
    print(f'set-up warm-up (scripts/warm_numba_cache.py into an empty cache): {setup_wall:.1f} s')
    on_time = warm['first_window_s'] <= HOP_S
    print(f'first window after set-up: {warm["first_window_s"]:.2f} s against a {HOP_S:g} s hop '
          f'({"on time" if on_time else "LATE: windows are skipped"}); '
          f'{warm["first_window_s"] / warm["second_window_s"]:.2f}x a steady window; cold it took '
          f'{cold["first_window_s"]:.1f} s')
    write_json(args.json, 'bench_first_window', [
        figure(f'first {WINDOW_S:g} s window after a fresh set-up (warmed numba cache)', warm['first_window_s'], 's',
               baseline=warm['second_window_s'], baseline_name='the second window in the same process (steady)',
               ratio_meaning='first / steady window', target=f'<= {HOP_S:g} s (the hop: no window skipped)',
               met=on_time),
        figure(f'first {WINDOW_S:g} s window with an empty numba cache (no set-up warm-up)', cold['first_window_s'],
               's', baseline=cold['second_window_s'], baseline_name='the second window in the same process',
               ratio_meaning='first / steady window'),
        figure('set-up warm-up of the numba cache (scripts/warm_numba_cache.py, empty cache)', setup_wall, 's'),
    ], window_s=WINDOW_S, hop_s=HOP_S, cold=cold, after_setup=warm, setup_wall_s=setup_wall)


if __name__ == '__main__':
    main()
