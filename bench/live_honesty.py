"""Live honesty: `aeropend run` beside a CPU hog; samples the identification node received vs published, and every
window that lost samples shown with its flag.

One case = one `aeropend run` (simulator, real time, --duration s, recorded to a temporary bag, no diagnosis) beside
``stress-ng --cpu N`` (N = --hog; 0: no hog), with ``aeropend monitor --json`` listening to the identification
node's /diagnostics, in a private ROS domain on this machine. Each case runs the code of a source tree (--tree,
default: this one; e.g. an export of an older commit for the baseline).

Measured per case:

- published: the samples in the bag (the recorder loses none here; its own loss accounting is read too) and the
  sim's count printed by `run` when it does;
- received by the identification node: its ``samples_received`` / ``samples_missed`` (gaps between received
  samples, by sequence number) from its last /diagnostics status;
- windows: published ones, and of them the damaged ones (``lost_samples`` > 0 or a data-quality finding on their
  status); withheld / refused / skipped windows;
- honesty: damaged windows whose console line in `run` carries no flag (the console's published-window lines are
  matched to the statuses in order). The goal is 0.

Usage::

    nice -n 10 .venv/bin/python bench/live_honesty.py --duration 60 --hog 2
    nice -n 10 .venv/bin/python bench/live_honesty.py --tree /tmp/base --label baseline

Writes ``<label>.json`` and appends to ``summary.md`` in --out (default bench/results/2026-11-27-live).
"""
from __future__ import annotations

import argparse
import json
import os
import random
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from aeropend_ros.testing import interrupt  # noqa: E402
CLI = 'import sys; from aeropend_core.cli import main; sys.exit(main())'
#: A published window's console line: the new form ("window  30.0- 55.0 s: held-out fit ...; data clean") or the
#: old one ("window ending t =  55.0 s: held-out fit ...").
FIT_LINE = re.compile(r'window\s+(?:ending t =\s*|[-\d.]+-\s*)([-\d.]+) s: held-out fit')


def console_states(console: str) -> dict[str, int]:
    """Windows by what `run`'s console said of them: the new lines ("window a-b s: ...; data clean", "data FLAGGED",
    "WITHHELD", "not analysed", "SKIPPED") or the old ones ("window ending t = ...: held-out fit" with no state,
    "window: window not analysed ...", "window: window ... skipped")."""
    counts = dict.fromkeys(('clean', 'flagged', 'published_without_state', 'withheld', 'refused', 'skipped'), 0)
    for line in console.splitlines():
        text = line.strip()
        if not text.startswith('window'):
            continue
        if 'held-out fit' in text:
            key = ('clean' if text.endswith('data clean') else 'flagged' if 'data FLAGGED' in text
                   else 'published_without_state')
        elif 'WITHHELD' in text or 'window not analysed' in text or 'not published' in text:
            key = 'withheld'
        elif 'SKIPPED' in text or ' skipped: ' in text:
            key = 'skipped'
        elif 'not analysed' in text or 'insufficient' in text:
            key = 'refused'
        else:
            continue
        counts[key] += 1
    return counts


def _environment(tree: Path) -> dict[str, str]:
    env = dict(os.environ)
    env['PYTHONPATH'] = str(tree)
    env['ROS_DOMAIN_ID'] = str(random.randint(120, 200))
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['MPLBACKEND'] = 'Agg'
    env.pop('DISPLAY', None)
    return env


def run_case(tree: Path, duration: float, hog: int, label: str) -> dict:
    """One `aeropend run` beside the hog, measured (module docstring)."""
    env = _environment(tree)
    work = Path(tempfile.mkdtemp(prefix='live_honesty_'))
    hog_process = None
    if hog:
        if shutil.which('stress-ng') is None:
            raise SystemExit('stress-ng is not installed (apt-get install stress-ng), or use --hog 0')
        hog_process = subprocess.Popen(['stress-ng', '--cpu', str(hog), '--timeout', f'{int(duration + 300)}s'],
                                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    monitor = subprocess.Popen([sys.executable, '-c', CLI, 'monitor', '--json', str(work / 'monitor.jsonl'),
                                '--no-plot', '--duration', f'{duration + 240:g}'], env=env, cwd=tree,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    load_before = os.getloadavg()[0]
    started = time.monotonic()
    try:
        run = subprocess.run([sys.executable, '-c', CLI, 'run', '--duration', f'{duration:g}', '--no-diagnose',
                              '--record', str(work)], env=env, cwd=tree, capture_output=True, text=True,
                             timeout=duration + 600)
    finally:
        wall = time.monotonic() - started
        load_after = os.getloadavg()[0]
        time.sleep(3.0)               # the last statuses reach the monitor (reliable); then stop it
        interrupt(monitor)
        if hog_process is not None:
            hog_process.terminate()
            hog_process.wait(timeout=30)
    console = run.stdout + run.stderr
    result = {'label': label, 'tree': str(tree), 'duration_s': duration, 'hog_cpus': hog, 'exit_status':
              run.returncode, 'wall_s': round(wall, 1), 'load_average_before': load_before,
              'load_average_after': load_after}
    # published: the bag
    bags = [p for p in work.iterdir() if p.is_dir()]
    if bags:
        sys.path.insert(0, str(tree))
        from aeropend_core.io.bag import read_samples
        sequence = read_samples(bags[0])['sequence']
        result['bag_samples'] = int(sequence.size)
        result['bag_sequence_span'] = int(sequence.max() - sequence.min() + 1) if sequence.size else 0
    # the node's statuses
    statuses = []
    if (work / 'monitor.jsonl').exists():
        statuses = [json.loads(line) for line in (work / 'monitor.jsonl').read_text().splitlines() if line.strip()]
    last = statuses[-1]['values'] if statuses else {}
    result['node_samples_received'] = int(last.get('samples_received', -1))
    result['node_samples_missed'] = int(last.get('samples_missed', -1))
    published = [s['values'] for s in statuses if 'fit_percent' in s['values']]
    damaged = [bool(v.get('data_quality')) or v.get('lost_samples', '0') != '0' for v in published]
    result['windows_published'] = len(published)
    result['windows_damaged'] = sum(damaged)
    result['lost_samples_in_windows'] = [int(v.get('lost_samples', 0)) for v in published]
    result['windows_withheld_or_refused'] = sum(1 for s in statuses if s['level'] in ('WARN', 'ERROR')
                                                and 'fit_percent' not in s['values']
                                                and ('not analysed' in s['message'] or 'not published' in
                                                     s['message'] or 'insufficient' in s['message']))
    result['windows_skipped'] = int(last.get('windows_skipped', 0))
    # the console: one line per published window, in order
    lines = [line for line in console.splitlines() if FIT_LINE.search(line)]
    result['console_window_lines'] = len(lines)
    unflagged = 0
    for line, bad in zip(lines, damaged):
        if bad and 'FLAGGED' not in line:
            unflagged += 1
    result['damaged_windows_shown_without_flag'] = unflagged
    result['console_lines_matched'] = min(len(lines), len(published))
    result['received_line'] = next((line.strip() for line in console.splitlines()
                                    if 'identification node: received' in line), '')
    result['console_states'] = console_states(console)
    result['console'] = [line for line in console.splitlines() if 'window' in line or 'identification' in line]
    shutil.rmtree(work, ignore_errors=True)
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0], allow_abbrev=False)
    parser.add_argument('--tree', type=Path, default=ROOT, help='source tree whose code runs (default: this one)')
    parser.add_argument('--label', default='current', help='name of the case in the results (default current)')
    parser.add_argument('--duration', type=float, default=60.0, help='length of each run [s] (default 60)')
    parser.add_argument('--hog', type=int, default=2, help='stress-ng --cpu workers beside the run (default 2)')
    parser.add_argument('--repeat', type=int, default=1, help='runs of the case (default 1)')
    parser.add_argument('--out', type=Path, default=ROOT / 'bench' / 'results' / '2026-11-27-live')
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    results = []
    for k in range(args.repeat):
        result = run_case(args.tree.resolve(), args.duration, args.hog, args.label)
        print(json.dumps({key: value for key, value in result.items() if key != 'console'}), flush=True)
        results.append(result)
    (args.out / f'{args.label}.json').write_text(json.dumps(results, indent=2) + '\n')
    with (args.out / 'summary.md').open('a') as summary:
        for r in results:
            summary.write(
                f'| {r["label"]} | {r["hog_cpus"]} | {r["load_average_before"]:.1f} / {r["load_average_after"]:.1f} | '
                f'{r.get("bag_samples", "?")} | {r["node_samples_received"]} | {r["node_samples_missed"]} | '
                f'{r["windows_published"]} | {r["windows_damaged"]} | {r["windows_withheld_or_refused"]} | '
                f'{r["windows_skipped"]} | {r["damaged_windows_shown_without_flag"]} |\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
