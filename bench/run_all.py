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
window in detail), bench_simulate (simulator × real time), bench_diagnose (diagnosis time for 60 s), bench_user_effect
(a user effect module against the same term built in),
bench_long_record (diagnose 60/600/3600 s records, each in its own process: wall time and peak memory; --quick
stops at 600 s), bench_first_window (the first window after a fresh set-up, fresh numba caches), bench_decoder
(bridge frame decoding), bench_recorder (recorder throughput and loss), bench_sim_node (sim node rate and jitter),
robustness (noise robustness of the diagnosis, when bench/robustness.py exists) and, only with --with-load-test,
load_test (the 10-minute full-graph load test, when bench/load_test.py exists).

Run:  .venv/bin/python bench/run_all.py [--quick] [--with-load-test] [--only NAME ...] [--skip NAME ...] [--out DIR]
                                        [--wait-idle LOAD]

Run time on the project's 2-core machine, measured while others loaded it (load average 4-5): the default run
without robustness 7.4 min (noise_sweep 5.1 of them, ~2.5 min idle), plus the robustness sweep; --quick 4.7 min
(robustness --quick 2.6 of them); --with-load-test adds about 12 min. bench_long_record adds ~11 min to the default
run (its 1-hour record's diagnosis ~9.5 min) and ~1 min to --quick; bench_first_window ~0.5-2 min (it compiles the
kernels twice, into fresh caches). Benchmark figures need an otherwise idle
machine: the load average before and after each benchmark is recorded next to its figures.
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from _common import figure, machine_info

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
    Bench('bench_user_effect', 'a user effect module against the same term built in (diagnosis CPU)', [],
          ['--duration', '30']),
    Bench('bench_long_record', 'diagnosis of long records: wall time and peak memory (60/600/3600 s)', [],
          ['--durations', '60', '600'], timeout_s=3600.0),
    Bench('bench_first_window', 'first identification window after a fresh set-up (numba cache)', [], []),
    Bench('bench_decoder', 'bridge serial frame decoder throughput', [], ['--frames', '100000', '--repeat', '2']),
    Bench('bench_recorder', 'recorder throughput and loss', [], ['--rates', '20000', '--seconds', '3']),
    Bench('bench_sim_node', 'sim node rate and jitter', ['--seconds', '30'], ['--seconds', '10']),
    Bench('bench_foxglove', 'Foxglove forwarding: CPU and delivery', ['--seconds', '20'], ['--seconds', '8']),
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
    """Whether `script` takes command-line option `option` (scripts written by others may lack --json/--quick)."""
    source = script.read_text(encoding='utf-8')
    if option == '--json' and 'add_json_argument(' in source:
        return True
    return f"'{option}'" in source or f'"{option}"' in source


def run_process(command: list[str], timeout_s: float) -> tuple[int | None, str, str]:
    """Run `command` in its own process group, echoing its output live (indented); on timeout or Ctrl-C stop the
    whole group (the benchmark's nodes too) with SIGINT, then SIGKILL. Returns (exit code or None when stopped,
    stdout, stderr)."""
    process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               bufsize=1, start_new_session=True)
    captured = {'stdout': [], 'stderr': []}

    def pump(stream, key):
        for line in stream:
            captured[key].append(line)
            print('   ' + line, end='', flush=True)

    readers = [threading.Thread(target=pump, args=(process.stdout, 'stdout'), daemon=True),
               threading.Thread(target=pump, args=(process.stderr, 'stderr'), daemon=True)]
    for reader in readers:
        reader.start()
    note = ''
    try:
        code = process.wait(timeout=timeout_s)
    except (subprocess.TimeoutExpired, KeyboardInterrupt) as stop:
        for sig, wait in ((signal.SIGINT, 15.0), (signal.SIGKILL, 5.0)):
            try:
                os.killpg(process.pid, sig)
            except ProcessLookupError:
                break
            try:
                process.wait(timeout=wait)
                break
            except subprocess.TimeoutExpired:
                continue
        if isinstance(stop, KeyboardInterrupt):
            raise
        code, note = None, f'\nrun_all: stopped after the {timeout_s:g} s time limit\n'
    for reader in readers:
        reader.join(timeout=5)
    return code, ''.join(captured['stdout']), ''.join(captured['stderr']) + note


def robustness_figures(data: dict) -> list[dict]:
    """Key figures from bench/robustness.py's own JSON schema (it writes no "figures" list)."""
    figures = []
    at40 = [p for p in data['vs_psnr'] if p['psnr'] == 40.0 and p['factor'] == 1.0]
    if at40:
        correct, runs = sum(p['counts']['correct'] for p in at40), sum(p['runs'] for p in at40)
        figures.append(figure(f'hidden effects named correctly, typical size, 40 dB ({len(at40)} effects)',
                              correct / runs, 'fraction', target='1.0', met=correct == runs))
    clean = [p for p in data['clean'] if p['psnr'] == 40.0]
    if clean:
        figures.append(figure('false alarms on data with nothing hidden, 40 dB', clean[0]['false_alarm_rate'],
                              'fraction', target='0', met=clean[0]['false_alarm_rate'] == 0))
    for effect, t in data['thresholds'].items():
        figures.append(figure(f'{effect}: smallest size named reliably at {data["magnitude_psnr"]:g} dB',
                              t['value'], t['unit'], baseline=t['typical'], baseline_name='typical size',
                              ratio=t['factor'], ratio_meaning='of the typical size'))
    figures.append(figure('mean diagnosis time per 60 s record', data['mean_diagnosis_seconds'], 's'))
    return figures


def load_test_figures(data: dict) -> list[dict]:
    """Key figures from bench/load_test.py's own JSON schema (it writes no "figures" list)."""
    figures = []
    for role, e in data['memory'].items():
        figures.append(figure(f'{role}: RSS growth after warm-up', e['rss_growth_mb'], 'MB',
                              baseline=e['rss_warm_mb'], baseline_name='RSS at warm-up',
                              ratio_meaning='growth / RSS at warm-up', target='flat', met=bool(e['flat'])))
    samples = data['samples']['independent']
    figures.append(figure('samples lost (bag read independently)', samples['missing'], 'samples',
                          baseline=samples['published'], baseline_name='published', target='0',
                          met=samples['missing'] == 0 and samples['gaps'] == 0))
    i = data['identification']
    figures.append(figure('identification compute per window (mean)', i['compute_time_s'].get('mean'), 's',
                          baseline=i['hop_s'], baseline_name='hop between windows', ratio_meaning='compute / hop',
                          target='keeps up', met=bool(i['keeps_up'])))
    return figures


ADAPTERS = {'robustness': robustness_figures, 'load_test': load_test_figures}


def collect(name: str, json_path: Path, takes_json: bool = True) -> dict:
    """{'figures', 'json'[, 'error']} from a benchmark's JSON file (its "figures" list, or an adapter)."""
    if not json_path.exists():
        return {'figures': [], 'json': None,
                'error': 'no JSON written' if takes_json else 'script has no --json option: figures only in the log'}
    data = json.loads(json_path.read_text(encoding='utf-8'))
    if 'figures' in data:
        return {'figures': data['figures'], 'json': json_path.name}
    try:
        return {'figures': ADAPTERS[name](data), 'json': json_path.name}
    except (KeyError, TypeError, ValueError, ZeroDivisionError) as error:
        return {'figures': [], 'json': json_path.name,
                'error': f'its JSON has no "figures" list and its own schema was not understood ({error!r})'}


def shown(path: Path) -> str:
    """`path` relative to the repository when inside it (the benchmarks run with the repository as cwd)."""
    path = path.resolve()
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def run_one(bench: Bench, out: Path, quick: bool) -> dict:
    json_path = out / f'{bench.name}.json'
    json_path.unlink(missing_ok=True)
    args = list(bench.quick_args if quick else bench.args)
    if bench.optional and quick and not accepts(bench.script, '--quick'):
        args = [a for a in args if a != '--quick']
    takes_json = accepts(bench.script, '--json')
    command = [sys.executable, str(bench.script.relative_to(ROOT)), *args]
    if bench.pass_out and accepts(bench.script, '--out'):
        command += ['--out', shown(out)]
    if takes_json:
        command += ['--json', shown(json_path)]
    load_before = os.getloadavg()
    print(f'== {bench.name}: {" ".join(command[1:])}   (load average {load_before[0]:.2f})', flush=True)
    start = time.perf_counter()
    code, stdout, stderr = run_process(command, bench.timeout_s)
    wall = time.perf_counter() - start
    load_after = os.getloadavg()
    (out / f'{bench.name}.log').write_text(stdout + ('\n--- stderr ---\n' + stderr if stderr.strip() else ''),
                                           encoding='utf-8')
    if code != 0:
        print(f'!! {bench.name} exited with {code}; last lines of stderr:\n' + '\n'.join(stderr.splitlines()[-15:]),
              flush=True)
    record = {'name': bench.name, 'what': bench.what, 'command': ' '.join(command[1:]), 'exit_code': code,
              'wall_time_s': wall, 'load_average_before': list(load_before), 'load_average_after': list(load_after),
              'figures': [], 'details': None, 'json': None}
    record.update(collect(bench.name, json_path, takes_json))
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


def busy_note(run: dict) -> list[str]:
    """A warning line when the machine was not idle (1-min load average above a quarter of the cores)."""
    loads = [b['load_average_before'][0] for b in run['benchmarks'] if not b.get('skipped')]
    cores = run['machine']['cores'] or 1
    if loads and max(loads) > cores / 4:
        return [f'- **Busy machine**: 1-min load average up to {max(loads):.1f} on {cores} cores before a benchmark '
                'started: timings are pessimistic and noisy; rerun on an idle machine for the record.']
    return []


def summary_markdown(run: dict) -> str:
    m = run['machine']
    lines = [f'# Benchmark results {run["date"]}{" (--quick)" if run["quick"] else ""}'
             + (f' — INTERRUPTED during {run["interrupted"]}' if run.get('interrupted') else ''), '',
             f'- **Date**: {run["started_utc"]} UTC; total {run["total_wall_time_s"] / 60:.1f} min; '
             f'command `{run["command"]}`',
             f'- **Machine**: {m["cpu"]}, {m["cores"]} cores, {m["ram_gib"]} GiB RAM; {m["os"]}',
             f'- **Software**: Python {m["python"]}, ' + ', '.join(f'{k} {v}' for k, v in m['versions'].items() if v)
             + (f', ROS {m["ros_distro"]}' if m.get('ros_distro') else ''),
             f'- **Code**: commit {run["git"]["commit"][:10]}'
             + (f' with {run["git"]["dirty_files"]} uncommitted file(s)' if run['git']['dirty_files'] else ''),
             *busy_note(run),
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


def wait_idle(load: float, limit_s: float = 600.0) -> None:
    """Sleep until the 1-min load average is below `load` (at most `limit_s`; the record shows the load anyway)."""
    deadline = time.monotonic() + limit_s
    if os.getloadavg()[0] >= load:
        print(f'   waiting for the 1-min load average to fall below {load:g} (now {os.getloadavg()[0]:.2f})',
              flush=True)
    while os.getloadavg()[0] >= load and time.monotonic() < deadline:
        time.sleep(5.0)


def resummarise(folder: Path) -> int:
    results = folder / 'results.json'
    if not results.exists():
        print(f'run_all: {results} not found: give a folder written by run_all.py', file=sys.stderr)
        return 2
    run = json.loads(results.read_text(encoding='utf-8'))
    for record in run['benchmarks']:
        if not record.get('skipped'):
            record.pop('error', None)
            record.update(collect(record['name'], folder / f'{record["name"]}.json', '--json' in record['command']))
    results.write_text(json.dumps(run, indent=1, ensure_ascii=False) + '\n', encoding='utf-8')
    run['out'] = folder
    (folder / 'summary.md').write_text(summary_markdown(run), encoding='utf-8')
    print(f'rewrote {folder / "summary.md"}')
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0], epilog='See the module docstring.')
    parser.add_argument('--quick', action='store_true', help='shorter variants of every benchmark (~5 min)')
    parser.add_argument('--with-load-test', action='store_true',
                        help='also run bench/load_test.py (10 minutes of the full graph)')
    names = [b.name for b in BENCHES]
    parser.add_argument('--only', nargs='+', choices=names, metavar='NAME', help=f'run only these: {names}')
    parser.add_argument('--skip', nargs='+', choices=names, default=[], metavar='NAME', help='skip these')
    parser.add_argument('--out', type=Path, default=None,
                        help='output folder (default bench/results/<UTC date>[-quick]/)')
    parser.add_argument('--wait-idle', type=float, metavar='LOAD', default=None,
                        help='before each benchmark wait (up to 10 min) until the 1-min load average is below LOAD')
    parser.add_argument('--resummarise', type=Path, metavar='DIR', default=None,
                        help='run nothing: re-read the benchmarks\' JSON files in DIR and rewrite its summary.md')
    args = parser.parse_args()
    if args.resummarise:
        return resummarise(args.resummarise)

    def interrupt(_signum, _frame):
        raise KeyboardInterrupt
    signal.signal(signal.SIGTERM, interrupt)     # stop the running benchmark's process group as on Ctrl-C
    signal.signal(signal.SIGINT, interrupt)      # also when started with SIGINT ignored (a background job)
    started = dt.datetime.now(dt.timezone.utc)
    out = args.out or BENCH / 'results' / (started.strftime('%Y-%m-%d') + ('-quick' if args.quick else ''))
    out.mkdir(parents=True, exist_ok=True)
    run = {'date': started.strftime('%Y-%m-%d'), 'started_utc': started.strftime('%Y-%m-%d %H:%M'),
           'quick': args.quick, 'command': 'python bench/run_all.py ' + ' '.join(sys.argv[1:]),
           'machine': machine_info(), 'git': git_commit(), 'benchmarks': []}
    print(f'machine: {run["machine"]["cpu"]}, {run["machine"]["cores"]} cores; results -> {shown(out)}', flush=True)
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
        try:
            if args.wait_idle is not None:
                wait_idle(args.wait_idle)
            run['benchmarks'].append(run_one(bench, out, args.quick))
        except KeyboardInterrupt:
            print(f'\nrun_all: interrupted during {bench.name} (its processes stopped); writing what ran',
                  flush=True)
            run['interrupted'] = bench.name
            break
    run['total_wall_time_s'] = time.perf_counter() - start
    run['out'] = out
    (out / 'summary.md').write_text(summary_markdown(run), encoding='utf-8')
    run['out'] = shown(out)
    (out / 'results.json').write_text(json.dumps(run, indent=1, ensure_ascii=False) + '\n', encoding='utf-8')
    # a missed target is a "NO" in the table (some scripts also exit 1 then); a failure is a crash or no figures
    failed = [b['name'] for b in run['benchmarks'] if not b.get('skipped') and (b['exit_code'] is None or b.get(
        'error') == 'no JSON written')]
    print(f'\nwrote {shown(out / "summary.md")} and results.json; total {run["total_wall_time_s"] / 60:.1f} min'
          + (f'; FAILED: {", ".join(failed)}' if failed else ''), flush=True)
    return 130 if run.get('interrupted') else 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
