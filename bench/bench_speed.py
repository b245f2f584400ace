"""Speed of the user's loop (issue 41): a base commit (default 2ced43e, main when the issue was filed) and this tree
side by side, in one run, on the same records.

Both trees run with this tree's Python environment (.venv): the base is checked out as a git worktree (made here
when missing) and put first on PYTHONPATH, so the only difference is the source. Each measurement is a fresh
process, as a user's command: its wall time is the process's whole life (start-up, reading, diagnosis, JSON) and
its peak memory the resident high-water mark of that one child (``ru_maxrss`` from ``os.wait4``). The runs of the
two trees alternate, so both see the same load; the figures are medians over ``--repeats``. Each tree diagnoses
a 60 s record once before any timing (the numba cache compiled, not timed).

Rows: ``aeropend --help``; two refusals (a mistyped effect for ``aeropend run``; a missing file for ``aeropend
diagnose``); a 60 s record (490 Hz, LHC duty steps, Coulomb friction 4 rad/s^2 hidden, 40 dB PSNR with 10-bit
quantisation) diagnosed end to end; the same for ``--long`` seconds (default 600) once per tree; the long/60 s
ratio; peak RSS. Each tree's verdict and friction estimate +- 1 sigma are printed: the answer should not change.
Targets (issue 41): 60 s >= 4x faster than the base (<= 2.5 s on an idle 2-core machine), 600 s <= 10x the 60 s,
peak RSS <= 500 MB, --help <= 0.3 s. Then bench/bench_wsindy.py runs in this tree (WSINDy >= 15x pysindy's weak
form on the same window; its own baseline in the same run).

Run:  .venv/bin/python bench/bench_speed.py [--base 2ced43e] [--repeats 3] [--long 600] [--json PATH]
      (~10 min on a loaded 2-core machine; the first run also compiles the base tree's numba cache, ~2 min)
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import add_json_argument, figure, write_json

from aeropend_core.io.recording import write_csv
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]
HIDDEN = {'coulomb_friction': 4.0}
CLI = 'import sys; from aeropend_core.cli import main; sys.exit(main())'
#: The thread-count variables aeropend_core.blas respects: unset, as in a user's shell. Also unset: the switch that
#: stops Python writing bytecode (set where the project's sessions run). With it every run compiled all of
#: aeropend_core's modules from source (81 on the diagnose path), which a user's installation does once; the
#: warm-up now writes each tree's bytecode, as a user's first run does.
UNSET_VARIABLES = ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS', 'BLIS_NUM_THREADS',
                    'PYTHONDONTWRITEBYTECODE')


def base_tree(commit: str, path: Path | None) -> Path:
    """A checkout of `commit` (a detached git worktree of this repository, made when missing)."""
    path = path or Path(tempfile.gettempdir()) / f'aeropend-base-{commit}'
    if not (path / 'aeropend_core').is_dir():
        subprocess.run(['git', '-C', str(ROOT), 'worktree', 'add', '--detach', str(path), commit], check=True,
                       capture_output=True)
    return path


def run(tree: Path, argv: list[str], cwd: Path) -> tuple[float, float, int, str]:
    """(wall time [s], peak RSS [MB], exit status, standard error) of `aeropend ARGV` from `tree`, fresh process."""
    env = {k: v for k, v in os.environ.items() if k not in UNSET_VARIABLES}
    env['PYTHONPATH'] = str(tree)
    start = time.perf_counter()
    child = subprocess.Popen([sys.executable, '-c', CLI, *argv], cwd=cwd, env=env, stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True)
    stderr = child.stderr.read()
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - start
    child.returncode = os.waitstatus_to_exitcode(status)
    return wall, usage.ru_maxrss / 1024.0, child.returncode, stderr


def source_of(tree: Path, cwd: Path) -> str:
    """The aeropend_core a child started for `tree` imports (to be sure PYTHONPATH picked the tree)."""
    env = {**os.environ, 'PYTHONPATH': str(tree)}
    return subprocess.run([sys.executable, '-c', 'import aeropend_core; print(aeropend_core.__file__)'], cwd=cwd,
                          env=env, capture_output=True, text=True, check=True).stdout.strip()


def answer(path: Path) -> dict:
    """Verdict, named effect and the friction estimate +- 1 sigma of a diagnosis JSON."""
    data = json.loads(path.read_text())
    # the verdict's entry first: its +- carries the doubts the verdict states (the friction law's among them); the
    # candidate table's is the white-noise evidence sigma, narrower
    named = [e for e in data.get('missing_effects') or [] if isinstance(e, dict)]
    friction = next((c for c in named + data['candidates'] if c.get('effect') == 'coulomb_friction'), None)
    value = friction['parameters'].get('friction_acceleration') if friction else None
    sigma = friction['standard_errors'].get('friction_acceleration') if friction else None
    return {'verdict': data['verdict'], 'missing_effect': data['missing_effect'], 'friction': value,
            'friction_sigma': sigma}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--base', default='2ced43e', help='commit to compare with')
    parser.add_argument('--base-tree', type=Path, default=None, help='an existing checkout of --base')
    parser.add_argument('--repeats', type=int, default=3, help='timed runs per tree of the fast rows')
    parser.add_argument('--long', type=float, default=600.0, help='duration of the long record [s]; 0: skip')
    parser.add_argument('--no-wsindy', action='store_true', help='skip bench/bench_wsindy.py')
    add_json_argument(parser)
    args = parser.parse_args()
    trees = {'base': base_tree(args.base, args.base_tree), 'new': ROOT}
    work = Path(tempfile.mkdtemp(prefix='aeropend-speed-'))
    for name, tree in trees.items():
        found = source_of(tree, work)
        if not found.startswith(str(tree)):
            raise SystemExit(f'{name}: PYTHONPATH={tree} imports {found}; cannot compare')
    records = {}
    for duration in (60.0, args.long) if args.long else (60.0,):
        duty = lhc_schedule(duration, seed=3).duty(duration=duration)
        trajectory = simulate(duty, effects=HIDDEN, noise=MeasurementNoise(40.0, True), seed=4)
        records[duration] = work / f'record_{duration:g}s.csv'
        write_csv(records[duration], trajectory.columns(with_truth=False))
    load_before = os.getloadavg()
    for name, tree in trees.items():          # warm-up: numba caches compiled, files in the page cache
        wall, _, status, err = run(tree, ['diagnose', str(records[60.0]), '--quiet'], work)
        print(f'warm-up {name}: {wall:.1f} s (exit {status})', flush=True)
        if status != 0:
            raise SystemExit(f'{name} failed to diagnose the 60 s record:\n{err}')
    rows: dict[str, dict[str, list[float]]] = {name: {} for name in trees}
    peak: dict[str, float] = {name: 0.0 for name in trees}
    answers: dict[str, dict] = {}
    commands = {'help': ['--help'], 'refusal_run': ['run', '--effect', 'no_such_effect=1'],
                'refusal_diagnose': ['diagnose', 'missing.csv']}
    for repeat in range(args.repeats):
        for name, tree in trees.items():
            for row, argv in commands.items():
                times = [run(tree, argv, work)[0] for _ in range(3)]
                rows[name].setdefault(row, []).append(min(times))
            output = work / f'{name}_60.json'
            wall, rss, status, err = run(tree, ['diagnose', str(records[60.0]), '--quiet', '--json', str(output)],
                                         work)
            if status != 0:
                raise SystemExit(f'{name}: diagnose failed:\n{err}')
            rows[name].setdefault('diagnose_60', []).append(wall)
            peak[name] = max(peak[name], rss)
            answers[f'{name} 60 s'] = answer(output)
            print(f'repeat {repeat + 1} {name}: 60 s record {wall:.2f} s, --help {rows[name]["help"][-1]:.3f} s',
                  flush=True)
    if args.long:
        for name, tree in trees.items():
            output = work / f'{name}_long.json'
            wall, rss, status, err = run(tree, ['diagnose', str(records[args.long]), '--quiet', '--json',
                                                str(output)], work)
            if status != 0:
                raise SystemExit(f'{name}: diagnose of the long record failed:\n{err}')
            rows[name]['diagnose_long'] = [wall]
            peak[name] = max(peak[name], rss)
            answers[f'{name} {args.long:g} s'] = answer(output)
            print(f'{name}: {args.long:g} s record {wall:.1f} s, peak RSS {rss:.0f} MB', flush=True)
    load_after = os.getloadavg()
    median = {name: {row: statistics.median(values) for row, values in tree_rows.items()}
              for name, tree_rows in rows.items()}
    base, new = median['base'], median['new']
    lines = [f'| measurement | base {args.base} | this tree | base / this tree |', '| --- | --- | --- | --- |']
    labels = {'help': '`aeropend --help` [s]', 'refusal_run': '`aeropend run --effect no_such_effect=1` refused [s]',
              'refusal_diagnose': '`aeropend diagnose missing.csv` refused [s]',
              'diagnose_60': '60 s record, `aeropend diagnose` end to end [s]',
              'diagnose_long': f'{args.long:g} s record, end to end [s]'}
    for row, label in labels.items():
        if row in base:
            lines.append(f'| {label} | {base[row]:.3f} | {new[row]:.3f} | {base[row] / new[row]:.2f}x |')
    if 'diagnose_long' in base:
        lines.append(f'| {args.long:g} s / 60 s | {base["diagnose_long"] / base["diagnose_60"]:.1f} | '
                     f'{new["diagnose_long"] / new["diagnose_60"]:.1f} | |')
    lines.append(f'| peak RSS, any diagnosis [MB] | {peak["base"]:.0f} | {peak["new"]:.0f} | |')
    print('\n'.join(lines))
    print(f'load average (1, 5, 15 min): before {", ".join(f"{x:.1f}" for x in load_before)}; after '
          f'{", ".join(f"{x:.1f}" for x in load_after)}; {os.cpu_count()} cores')
    for key, value in answers.items():
        sigma = f' +- {value["friction_sigma"]:.4g}' if value['friction_sigma'] is not None else ''
        print(f'answer {key}: {value["verdict"]}, {value["missing_effect"]}, friction_acceleration '
              f'{value["friction"]:.4g}{sigma} rad/s^2 (truth {HIDDEN["coulomb_friction"]:g})')
    wsindy = None
    if not args.no_wsindy:
        wsindy_json = work / 'wsindy.json'
        subprocess.run([sys.executable, str(ROOT / 'bench' / 'bench_wsindy.py'), '--repeats', '3', '--json',
                        str(wsindy_json)], cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
        wsindy = json.loads(wsindy_json.read_text())['figures'][0]
        print(f'WSINDy full method {wsindy["value"]:.1f} ms per 10 s window, pysindy weak form '
              f'{wsindy["baseline"]:.1f} ms: {wsindy["ratio"]:.1f}x (target >= 15x)')
    speed_up = base['diagnose_60'] / new['diagnose_60']
    figures = [
        figure('60 s record, aeropend diagnose end to end', new['diagnose_60'], 's', baseline=base['diagnose_60'],
               baseline_name=f'the same at {args.base}', ratio=speed_up, ratio_meaning='speed-up (base / this tree)',
               target='>= 4x (<= 2.5 s idle)', met=speed_up >= 4),
        figure('aeropend --help', new['help'], 's', baseline=base['help'], baseline_name=f'the same at {args.base}',
               target='<= 0.3 s', met=new['help'] <= 0.3),
        figure('peak RSS of a diagnosis', peak['new'], 'MB', baseline=peak['base'],
               baseline_name=f'the same at {args.base}', target='<= 500 MB', met=peak['new'] <= 500),
    ]
    if 'diagnose_long' in new:
        ratio = new['diagnose_long'] / new['diagnose_60']
        figures.append(figure(f'{args.long:g} s record end to end', new['diagnose_long'], 's',
                              baseline=new['diagnose_60'], baseline_name='the 60 s record, this tree', ratio=ratio,
                              ratio_meaning=f'{args.long:g} s / 60 s', target='<= 10x', met=ratio <= 10))
    if wsindy is not None:
        figures.append(wsindy)
    write_json(args.json, 'bench_speed', figures, base=args.base, medians=median, repeats=args.repeats,
               peak_rss_mb=peak, answers=answers, load_before=load_before, load_after=load_after, table=lines)


if __name__ == '__main__':
    main()
