"""Size and write time of the HTML diagnosis report for a 60 s and a 600 s record (issue #24: <= 2 MB and <= 2 s to
write for 60 s).

Two baselines measured in the same run:

- the report code of an earlier commit (``--baseline-rev``, default ``c5449b8``: the matplotlib-PNG report before
  the plots became inline SVG), taken from git with ``git archive`` and run on the *same* pickled diagnosis in its
  own process; the ratio says how much faster and how much larger or smaller the report became;
- the diagnosis of the same record (the report is written after it; the ratio says what the report adds to
  ``aeropend diagnose --report``).

Each write is timed in a fresh process after one warm-up write (imports, caches), ``--repeats`` times; the minimum
and the median process CPU time are reported (on a shared machine CPU time is the steadier figure; the load average
is printed and stored). The 600 s record is diagnosed with two candidates only (the report's size and write time
depend on the record's length, not on the number of candidates beyond a table row and a chart row each) and
without the discovery stage (its terms hold functions that cannot be pickled for the other process; it adds a
paragraph of text to the page, no plot).

Run:  nice -n 10 .venv/bin/python bench/bench_report.py [--durations 60 600] [--json PATH] [--keep DIR]   (~4-8 min)
"""
import argparse
import json
import os
import pickle
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

from _common import add_json_argument, figure, write_json

from aeropend_core.diagnosis.diagnose import diagnose
from aeropend_core.io.recording import from_columns
from aeropend_core.model.parameters import SAMPLE_TIME
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]

#: Candidates of the long record's diagnosis (see the module docstring).
LONG_CANDIDATES = ['cable_torque', 'thrust_lag']

#: Run in a fresh process: load the pickled diagnosis, write the report once to warm up, then `repeats` times;
#: print the CPU and wall times [s] and the size [bytes] as JSON.
WRITER = """
import json, pickle, sys, time
from aeropend_core.present.report import write_report
diagnosis, source = pickle.load(open(sys.argv[1], 'rb'))
out, repeats = sys.argv[2], int(sys.argv[3])
write_report(diagnosis, out, source=source)
cpu, wall = [], []
for _ in range(repeats):
    c, w = time.process_time(), time.perf_counter()
    write_report(diagnosis, out, source=source)
    cpu.append(time.process_time() - c)
    wall.append(time.perf_counter() - w)
import os
print(json.dumps({'cpu': cpu, 'wall': wall, 'bytes': os.path.getsize(out)}))
"""


def timed(work):
    """(result, wall [s], process CPU [s]) of work()."""
    wall, cpu = time.perf_counter(), time.process_time()
    result = work()
    return result, time.perf_counter() - wall, time.process_time() - cpu


def code_tree(revision: str | None, folder: Path) -> Path:
    """A folder whose ``aeropend_core`` is this checkout's (revision None) or `revision`'s from git."""
    if revision is None:
        return ROOT
    target = folder / f'tree_{revision}'
    target.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(['git', '-C', str(ROOT), 'archive', revision, 'aeropend_core'], check=True,
                             capture_output=True).stdout
    archive_path = folder / f'{revision}.tar'
    archive_path.write_bytes(archive)
    with tarfile.open(archive_path) as tar:
        tar.extractall(target, filter='data')
    return target


def write_in_process(tree: Path, pickled: Path, out: Path, repeats: int) -> dict:
    """Times of :data:`WRITER` run with `tree` first on the import path."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    result = subprocess.run([sys.executable, '-c', WRITER, str(pickled), str(out), str(repeats)], env=env,
                            capture_output=True, text=True, check=True)
    return json.loads(result.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--durations', type=float, nargs='+', default=[60.0, 600.0])
    parser.add_argument('--repeats', type=int, default=3, help='timed writes per report (after one warm-up)')
    parser.add_argument('--baseline-rev', default='c5449b8',
                        help='git revision whose report code is the baseline ("" for none)')
    parser.add_argument('--keep', metavar='DIR', default=None, help='keep the reports in this folder')
    add_json_argument(parser)
    args = parser.parse_args()
    folder = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix='bench_report_'))
    folder.mkdir(parents=True, exist_ok=True)
    print(f'load average at the start {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores')
    trees = {'this': code_tree(None, folder)}
    if args.baseline_rev:
        trees['baseline'] = code_tree(args.baseline_rev, folder)
    figures, details = [], {'baseline_rev': args.baseline_rev, 'load_average_at_start': os.getloadavg()[0]}
    for duration in args.durations:
        duty = lhc_schedule(duration, seed=3).duty(SAMPLE_TIME, duration)
        run = simulate(duty, effects={'coulomb_friction': 4.0}, noise=MeasurementNoise(40.0, True), seed=4)
        recording = from_columns(run.columns(with_truth=False), source=f'bench_{duration:g}s.csv')
        candidates = None if duration <= 120 else LONG_CANDIDATES
        diagnosis, diagnosis_wall, diagnosis_cpu = timed(lambda: diagnose(recording, candidates=candidates,
                                                                          discovery=duration <= 120))
        pickled = folder / f'diagnosis_{duration:g}s.pkl'
        pickled.write_bytes(pickle.dumps((diagnosis, recording.source)))
        results = {name: write_in_process(tree, pickled, folder / f'report_{duration:g}s_{name}.html', args.repeats)
                   for name, tree in trees.items()}
        this = results['this']
        base = results.get('baseline')
        cpu, wall = min(this['cpu']), statistics.median(this['wall'])
        line = (f'{duration:g} s record ({recording.time.size} samples, {len(diagnosis.candidates)} candidates): '
                f'report {this["bytes"] / 1e6:.2f} MB, CPU min {cpu:.2f} s / median '
                f'{statistics.median(this["cpu"]):.2f} s, wall median {wall:.2f} s; diagnosis {diagnosis_cpu:.1f} s '
                f'CPU ({diagnosis_wall:.1f} s wall); report / diagnosis {cpu / diagnosis_cpu:.3f} (CPU)')
        if base is not None:
            line += (f'; baseline {args.baseline_rev}: {base["bytes"] / 1e6:.2f} MB, CPU min {min(base["cpu"]):.2f} s '
                     f'-> this / baseline {cpu / min(base["cpu"]):.2f} (CPU), {this["bytes"] / base["bytes"]:.2f} '
                     '(size)')
        print(line, flush=True)
        target = duration == 60
        size = this['bytes']
        figures += [
            figure(f'report size, {duration:g} s record', size / 1e6, 'MB', target='<= 2 MB' if target else '',
                   met=size <= 2e6 if target else None,
                   baseline=base['bytes'] / 1e6 if base else None,
                   baseline_name=f'report code at {args.baseline_rev} (matplotlib PNG), same diagnosis',
                   ratio_meaning='this / baseline'),
            figure(f'report write time (CPU, min of {args.repeats}), {duration:g} s record', cpu, 's',
                   baseline=min(base['cpu']) if base else None,
                   baseline_name=f'report code at {args.baseline_rev} (matplotlib PNG), same diagnosis, same run',
                   ratio_meaning='this / baseline', target='<= 2 s' if target else '',
                   met=cpu <= 2.0 if target else None),
            figure(f'report write time (CPU) against the diagnosis, {duration:g} s record', cpu, 's',
                   baseline=diagnosis_cpu,
                   baseline_name=f'diagnosis of the same record (CPU, {len(diagnosis.candidates)} candidates)',
                   ratio_meaning='report write / diagnosis'),
            figure(f'report write time (wall, median), {duration:g} s record', wall, 's',
                   baseline=statistics.median(base['wall']) if base else None,
                   baseline_name=f'report code at {args.baseline_rev} (wall, median)', ratio_meaning='this / baseline'),
        ]
        details[f'{duration:g}s'] = {'samples': int(recording.time.size), 'candidates': len(diagnosis.candidates),
                                     'diagnosis_cpu_s': diagnosis_cpu, 'writes': results}
    print(f'reports in {folder}; load average at the end {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores')
    write_json(args.json, 'bench_report', figures, **details)


if __name__ == '__main__':
    main()
