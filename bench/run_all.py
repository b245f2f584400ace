"""Run every benchmark, one process each, one after another, and write the record of the run.

Each benchmark script runs in its own subprocess (so none disturbs another, and each starts cold the same way) with
``--json PATH``; it prints its usual report (kept in ``<name>.log``) and writes its key figures (value, the baseline
measured in the same run, ratio, units, target) to ``<name>.json``. This script then writes, in the output folder
(default ``bench/results/<UTC date>/``, ``...-quick/`` with --quick):

* ``results.json``: date, git commit, machine (CPU model, cores, RAM, OS, Python, numpy/scipy/pysindy versions),
  and per benchmark its command, wall time, exit code, load average before and after, and its figures;
* ``summary.md``: one table (benchmark, figure, value, baseline measured in the same run, ratio, target, met?),
  the run conditions per benchmark, and the noise sweep's table;
* ``noise_sweep.png`` (and the other files the benchmarks write).

Benchmarks, in order: noise_sweep (WSINDy vs pysindy weak vs strong-form SINDy over PSNR), bench_wsindy (one 40 dB
window in detail), bench_simulate (simulator × real time), bench_diagnose (diagnosis time for 60 s), bench_decoder
(bridge frame decoding), bench_recorder (recorder throughput and loss), bench_sim_node (sim node rate and jitter),
robustness (noise robustness of the diagnosis, when bench/robustness.py exists) and, only with --with-load-test,
load_test (the 10-minute full-graph load test, when bench/load_test.py exists).

Run:  .venv/bin/python bench/run_all.py [--quick] [--with-load-test] [--only NAME ...] [--skip NAME ...] [--out DIR]

Run time on the project's 2-core machine: about 6 min by default (plus the robustness sweep), about 2 min with
--quick; --with-load-test adds about 11 min. Benchmark figures need an otherwise idle machine: the load average
before and after each benchmark is recorded next to its figures.
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from _common import machine_info

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / 'bench'


@dataclass
class Bench:
    name: str
    what: str
    args: list[str] = field(default_factory=list)          # default run
    quick_args: list[str] = field(default_factory=list)    # --quick run
    optional: bool = False          # written by someone else; skipped (and said so) when the script is absent
    opt_in: str = ''                # run only when this flag of run_all is given
    pass_out: bool = False          # the script takes --out DIR for its own files (markdown, plots)
    timeout_s: float = 1800.0

    @property
    def script(self) -> Path:
        return BENCH / f'{self.name}.py'


BENCHES = [
    Bench('noise_sweep', 'WSINDy vs pysindy weak vs strong-form SINDy, PSNR 60..20 dB',
          ['--seeds', '5'], ['--quick']),
    Bench('bench_wsindy', 'WSINDy vs pysindy weak, one 40 dB window in detail', [], ['--repeats', '5']),
    Bench('bench_simulate', 'simulator speed (x real time)', [], ['--repeat', '2']),
    Bench('bench_diagnose', 'diagnosis time for a 60 s recording', [], []),
    Bench('bench_decoder', 'bridge serial frame decoder throughput', [], ['--frames', '100000', '--repeat', '2']),
    Bench('bench_recorder', 'recorder throughput and loss', [], ['--rates', '20000', '--seconds', '3']),
    Bench('bench_sim_node', 'sim node rate and jitter', ['--seconds', '60'], ['--seconds', '10']),
    Bench('robustness', 'noise robustness of the missing-physics diagnosis', [], ['--quick'], optional=True,
          pass_out=True),
    Bench('load_test', '10-minute full-graph load test', [], [], optional=True, opt_in='with_load_test',
          pass_out=True, timeout_s=3600.0),
]


def git_commit() -> dict:
    def git(*args):
        return subprocess.run(['git', *args], cwd=ROOT, capture_output=True, text=True, check=False).stdout.strip()
    return {'commit': git('rev-parse', 'HEAD'), 'dirty_files': len(git('status', '--porcelain').splitlines())}


def accepts(script: Path, option: str) -> bool:
    """Whether `script` mentions command-line option `option` (scripts written by others may lack --json/--quick)."""
    return f"'{option}'" in script.read_text(encoding='utf-8') or f'"{option}"' in script.read_text(encoding='utf-8')


def run_one(bench: Bench, out: Path, quick: bool) -> dict:
    json_path = out / f'{bench.name}.json'
    json_path.unlink(missing_ok=True)
    args = list(bench.quick_args if quick else bench.args)
    if bench.optional and quick and not accepts(bench.script, '--quick'):
        args = [a for a in args if a != '--quick']
    takes_json = accepts(bench.script, '--json')
    command = [sys.executable, str(bench.script.relative_to(ROOT)), *args]
    if bench.pass_out and accepts(bench.script, '--out'):
        command += ['--out', str(out)]
    if takes_json:
        command += ['--json', str(json_path)]
    load_before = os.getloadavg()
    print(f'== {bench.name}: {" ".join(command[1:])}   (load average {load_before[0]:.2f})', flush=True)
    start = time.perf_counter()
    try:
        done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=bench.timeout_s,
                              check=False)
        code, stdout, stderr = done.returncode, done.stdout, done.stderr
    except subprocess.TimeoutExpired as expired:
        code = None
        stdout = expired.stdout.decode() if isinstance(expired.stdout, bytes) else (expired.stdout or '')
        stderr = (expired.stderr.decode() if isinstance(expired.stderr, bytes) else (expired.stderr or '')) + \
            f'\nrun_all: timed out after {bench.timeout_s:g} s'
    wall = time.perf_counter() - start
    load_after = os.getloadavg()
    (out / f'{bench.name}.log').write_text(stdout + ('\n--- stderr ---\n' + stderr if stderr.strip() else ''),
                                           encoding='utf-8')
    print(stdout.rstrip(), flush=True)
    if code != 0:
        print(f'!! {bench.name} exited with {code}; last lines of stderr:\n' + '\n'.join(stderr.splitlines()[-15:]),
              flush=True)
    record = {'name': bench.name, 'what': bench.what, 'command': ' '.join(command[1:]), 'exit_code': code,
              'wall_time_s': wall, 'load_average_before': list(load_before), 'load_average_after': list(load_after),
              'figures': [], 'details': None, 'json': None}
    if json_path.exists():
        data = json.loads(json_path.read_text(encoding='utf-8'))
        record.update(figures=data.get('figures', []), json=json_path.name)
        if 'figures' not in data:
            record['error'] = 'its JSON has no "figures" list (the common schema of bench/_common.py)'
    elif takes_json:
        record['error'] = 'no JSON written'
    else:
        record['error'] = 'script has no --json option: figures only in the log'
    return record


def fmt(value) -> str:
    if value is None:
        return '–'
    if isinstance(value, bool):
        return 'yes' if value else 'no'
    if isinstance(value, int):
        return f'{value:,}'
    if isinstance(value, float):
        if value != value:
            return '–'
        magnitude = abs(value)
        if magnitude >= 10000:
            return f'{value:,.0f}'
        if magnitude >= 100:
            return f'{value:.0f}'
        if magnitude >= 1:
            return f'{value:.3g}' if magnitude < 10 else f'{value:.1f}'
        return f'{value:.3g}'
    return str(value)


def summary_markdown(run: dict) -> str:
    m = run['machine']
    lines = [f'# Benchmark results {run["date"]}{" (--quick)" if run["quick"] else ""}', '',
             f'- **Date**: {run["started_utc"]} UTC; total {run["total_wall_time_s"] / 60:.1f} min; '
             f'command `{run["command"]}`',
             f'- **Machine**: {m["cpu"]}, {m["cores"]} cores, {m["ram_gib"]} GiB RAM; {m["os"]}',
             f'- **Software**: Python {m["python"]}, ' + ', '.join(f'{k} {v}' for k, v in m['versions'].items() if v)
             + (f', ROS {m["ros_distro"]}' if m.get('ros_distro') else ''),
             f'- **Code**: commit {run["git"]["commit"][:10]}'
             + (f' with {run["git"]["dirty_files"]} uncommitted file(s)' if run['git']['dirty_files'] else ''),
             '', 'Every baseline is measured in the same run on the same data/machine. Ratio: see "ratio means" '
             '(speed-ups are baseline time / ours). Target and met? only where a target exists.', '',
             '| benchmark | figure | value | baseline (same run) | ratio | ratio means | target | met? |',
             '| --- | --- | ---: | --- | ---: | --- | --- | --- |']
    for b in run['benchmarks']:
        if not b['figures']:
            note = b.get('error') or (f'skipped: {b["skipped"]}' if b.get('skipped') else 'no key figures')
            lines.append(f'| {b["name"]} | {note}; see its section below / its log | | | | | | |')
        for f in b['figures']:
            baseline = '' if f.get('baseline') is None else \
                f'{fmt(f["baseline"])} {f["units"]}' + (f' ({f["baseline_name"]})' if f.get('baseline_name') else '')
            ratio = '' if f.get('ratio') is None else f'{f["ratio"]:.3g}'
            met = {True: '**yes**', False: '**NO**', None: ''}[f.get('met')]
            lines.append(f'| {b["name"]} | {f["name"]} | {fmt(f["value"])} {f["units"]} | {baseline} | {ratio} | '
                         f'{f.get("ratio_meaning", "")} | {f.get("target", "")} | {met} |')
    lines += ['', '## Run conditions', '',
              '| benchmark | command | wall time | exit | load average before → after (1 min) |',
              '| --- | --- | ---: | ---: | --- |']
    for b in run['benchmarks']:
        if b.get('skipped'):
            lines.append(f'| {b["name"]} | skipped: {b["skipped"]} | | | |')
            continue
        lines.append(f'| {b["name"]} | `{b["command"]}` | {b["wall_time_s"]:.0f} s | {b["exit_code"]} | '
                     f'{b["load_average_before"][0]:.2f} → {b["load_average_after"][0]:.2f} |')
    for name, title in (('noise_sweep', 'Noise sweep (bench/noise_sweep.py)'),
                        ('robustness', 'Noise robustness of the diagnosis (bench/robustness.py)'),
                        ('load_test', 'Load test (bench/load_test.py)')):
        ran = [b for b in run['benchmarks'] if b['name'] == name and not b.get('skipped')]
        table = run['out'] / f'{name}.md'
        if ran and table.exists():
            lines += ['', f'## {title}', '', table.read_text(encoding='utf-8').strip()]
            lines += [f'![{name}]({p.name})' for p in sorted(run['out'].glob(f'{name}*.png'))]
    return '\n'.join(lines) + '\n'


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0], epilog='See the module docstring.')
    parser.add_argument('--quick', action='store_true', help='shorter variants of every benchmark (~2 min)')
    parser.add_argument('--with-load-test', action='store_true',
                        help='also run bench/load_test.py (10 minutes of the full graph)')
    names = [b.name for b in BENCHES]
    parser.add_argument('--only', nargs='+', choices=names, metavar='NAME', help=f'run only these: {names}')
    parser.add_argument('--skip', nargs='+', choices=names, default=[], metavar='NAME', help='skip these')
    parser.add_argument('--out', type=Path, default=None,
                        help='output folder (default bench/results/<UTC date>[-quick]/)')
    args = parser.parse_args()
    started = dt.datetime.now(dt.timezone.utc)
    out = args.out or BENCH / 'results' / (started.strftime('%Y-%m-%d') + ('-quick' if args.quick else ''))
    out.mkdir(parents=True, exist_ok=True)
    run = {'date': started.strftime('%Y-%m-%d'), 'started_utc': started.strftime('%Y-%m-%d %H:%M'),
           'quick': args.quick, 'command': 'python bench/run_all.py ' + ' '.join(sys.argv[1:]),
           'machine': machine_info(), 'git': git_commit(), 'benchmarks': []}
    print(f'machine: {run["machine"]["cpu"]}, {run["machine"]["cores"]} cores; results -> {out}', flush=True)
    start = time.perf_counter()
    for bench in BENCHES:
        skip = None
        if args.only and bench.name not in args.only or bench.name in args.skip:
            continue
        if bench.opt_in and not getattr(args, bench.opt_in):
            skip = f'needs --{bench.opt_in.replace("_", "-")}'
        elif not bench.script.exists():
            skip = f'{bench.script.relative_to(ROOT)} not present'
        if skip:
            print(f'== {bench.name}: skipped ({skip})', flush=True)
            run['benchmarks'].append({'name': bench.name, 'what': bench.what, 'skipped': skip, 'figures': []})
            continue
        run['benchmarks'].append(run_one(bench, out, args.quick))
    run['total_wall_time_s'] = time.perf_counter() - start
    run['out'] = out
    (out / 'summary.md').write_text(summary_markdown(run), encoding='utf-8')
    run['out'] = str(out.relative_to(ROOT)) if out.is_relative_to(ROOT) else str(out)
    (out / 'results.json').write_text(json.dumps(run, indent=1, ensure_ascii=False) + '\n', encoding='utf-8')
    # a missed target is a "NO" in the table (some scripts also exit 1 then); a failure is a crash or no figures
    failed = [b['name'] for b in run['benchmarks'] if not b.get('skipped') and (b['exit_code'] is None or b.get(
        'error') == 'no JSON written')]
    print(f'\nwrote {out / "summary.md"} and results.json; total {run["total_wall_time_s"] / 60:.1f} min'
          + (f'; FAILED: {", ".join(failed)}' if failed else ''), flush=True)
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
