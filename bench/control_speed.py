"""`aeropend control design` and `aeropend control check` end to end (the command a user types: interpreter start,
imports, numba's cache, the work, the output), this tree against a baseline tree, in the same run.

Each tree runs under the same interpreter with ``PYTHONPATH`` set to it (a ``git archive`` of the baseline commit,
e.g. ``git archive 9232bd8 | tar -x -C /tmp/base``). One untimed run of each command warms each tree's numba cache;
then the trees alternate, ``--repeats`` times, and the median wall and CPU times (user + system of the process, all
threads: less sensitive to the machine's load than the wall) are reported with the load average (1 min) before each
run. Commands:

* ``control design --at 40deg -o gains.yaml --json d.json`` (the nominal model; the course template);
* ``control check BAG --design GAINS.yaml --json c.json`` on ``--bag`` (a closed-loop record of ~60 s).

The design's gains and predicted worst overshoot/settling of both trees are printed beside the times (the new one
must not design worse); the check's verdict must be the same.

    nice -n 10 .venv/bin/python bench/control_speed.py --baseline-tree /tmp/base --bag BAG --gains GAINS.yaml
"""
from __future__ import annotations

import argparse
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CLI = 'import sys; from aeropend_core.cli import main; sys.exit(main())'


def run(tree: Path, arguments: list[str]) -> tuple[float, float, float, subprocess.CompletedProcess]:
    """(wall seconds, CPU seconds (user + system, all threads), 1-min load average before, the process) of
    `aeropend ARGUMENTS` on `tree`'s code."""
    # without PYTHONDONTWRITEBYTECODE (the sessions' shell sets it): a user's installation compiles its modules once,
    # not at every run (as bench_speed.py); the warm-up writes both trees' bytecode
    env = {**{k: v for k, v in os.environ.items() if k != 'PYTHONDONTWRITEBYTECODE'}, 'PYTHONPATH': str(tree)}
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    done = subprocess.run([sys.executable, '-c', CLI, *arguments], env=env, cwd=tree, capture_output=True,
                          text=True, timeout=900)
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, load, done


def design_summary(path: Path) -> str:
    data = json.loads(path.read_text())
    gains = data.get('gains') or {}
    steps = data.get('predicted_steps') or []
    worst = {}
    for item in ('overshoot', 'settling_time'):
        values = [step.get(item) for step in steps if isinstance(step, dict) and isinstance(step.get(item), float)]
        worst[item] = max(values) if values else float('nan')
    return (f'p {gains.get("p", float("nan")):.4g} i {gains.get("i", float("nan")):.4g} d '
            f'{gains.get("d", float("nan")):.4g}; worst overshoot {worst["overshoot"]:.2f} %, settling '
            f'{worst["settling_time"]:.2f} s')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--baseline-tree', type=Path, required=True)
    parser.add_argument('--bag', type=Path, required=True, help='closed-loop bag for `control check`')
    parser.add_argument('--gains', type=Path, required=True, help='the controller file the bag ran')
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--only', choices=('design', 'check'), default=None, help='time one command only')
    args = parser.parse_args()
    trees = {'base': args.baseline_tree.resolve(), 'new': ROOT}
    scratch = Path(tempfile.mkdtemp(prefix='control-speed-'))
    commands = {
        'design': lambda label: ['control', 'design', '--at', '40deg', '-o', str(scratch / f'{label}.yaml'),
                                 '--json', str(scratch / f'{label}-design.json')],
        'check': lambda label: ['control', 'check', str(args.bag.resolve()), '--design', str(args.gains.resolve()),
                                '--json', str(scratch / f'{label}-check.json')],
    }
    if args.only:
        commands = {args.only: commands[args.only]}
    for name, command in commands.items():          # warm each tree's numba cache
        for label, tree in trees.items():
            seconds, _, _, done = run(tree, command(label))
            if done.returncode != 0:
                print(f'{label} {name} failed ({done.returncode}): {done.stderr[-800:]}', file=sys.stderr)
                return 1
            print(f'warm-up {label} {name}: {seconds:.2f} s', flush=True)
    print('| command | base s (median) | new s (median) | new / base | base CPU s | new CPU s | CPU new / base '
          '| load 1 min (min-max) | base runs s | new runs s |')
    print('|---|---|---|---|---|---|---|---|---|---|')
    rows = {}
    for name, command in commands.items():
        times = {label: [] for label in trees}
        cpus = {label: [] for label in trees}
        loads = []
        for _ in range(args.repeats):
            for label, tree in trees.items():
                seconds, cpu, load, done = run(tree, command(label))
                if done.returncode != 0:
                    print(f'{label} {name} failed: {done.stderr[-800:]}', file=sys.stderr)
                    return 1
                times[label].append(seconds)
                cpus[label].append(cpu)
                loads.append(load)
        base, new = statistics.median(times['base']), statistics.median(times['new'])
        cpu_base, cpu_new = statistics.median(cpus['base']), statistics.median(cpus['new'])
        rows[name] = {'base': times['base'], 'new': times['new'], 'cpu': cpus, 'loads': loads}
        print(f'| {name} | {base:.2f} | {new:.2f} | {new / base:.2f} | {cpu_base:.2f} | {cpu_new:.2f} | '
              f'{cpu_new / cpu_base:.2f} | {min(loads):.1f}-{max(loads):.1f} | '
              f'{", ".join(f"{t:.2f}" for t in times["base"])} | {", ".join(f"{t:.2f}" for t in times["new"])} |',
              flush=True)
    if 'design' in commands:
        for label in trees:
            print(f'{label} design: {design_summary(scratch / f"{label}-design.json")}')
        gains = {label: json.loads((scratch / f'{label}-design.json').read_text()).get('gains') or {}
                 for label in trees}
        numbers = [key for key, value in gains['base'].items() if isinstance(value, float)]
        worst = max((abs(gains['new'].get(key, math.nan) - gains['base'][key]) / max(abs(gains['base'][key]), 1e-12)
                     for key in numbers), default=math.nan)
        print(f'design gains, largest relative difference new vs base: {worst:.3g} ({len(numbers)} numbers)')
    if 'check' in commands:
        for label in trees:
            check = json.loads((scratch / f'{label}-check.json').read_text())
            print(f'{label} check: {check.get("verdict")}')
    (scratch / 'times.json').write_text(json.dumps(rows, indent=1))
    print(f'(files in {scratch})')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
