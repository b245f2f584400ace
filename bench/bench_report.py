"""Size and write time of the HTML diagnosis report for a 60 s and a 600 s record (issue #24: <= 2 MB and <= 2 s to
write for 60 s).

Baseline measured in the same run: the diagnosis of the same record (the report is written after it; the ratio says
what the report adds to `aeropend diagnose --report`). Times are wall-clock and process CPU; on a shared machine
the CPU time is the steadier figure. The 600 s record is diagnosed with two candidates only (the report's size and
write time depend on the record's length, not on the number of candidates beyond a table row and a chart row each).

Run:  nice -n 10 .venv/bin/python bench/bench_report.py [--durations 60 600] [--json PATH] [--keep DIR]   (~3-6 min)
"""
import argparse
import os
import tempfile
import time
from pathlib import Path

from _common import add_json_argument, figure, write_json

from aeropend_core.diagnosis.diagnose import diagnose
from aeropend_core.io.recording import from_columns
from aeropend_core.model.parameters import SAMPLE_TIME
from aeropend_core.present.report import write_report
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate

#: Candidates of the long record's diagnosis (see the module docstring).
LONG_CANDIDATES = ['cable_torque', 'thrust_lag']


def timed(work):
    """(result, wall [s], process CPU [s]) of work()."""
    wall, cpu = time.perf_counter(), time.process_time()
    result = work()
    return result, time.perf_counter() - wall, time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--durations', type=float, nargs='+', default=[60.0, 600.0])
    parser.add_argument('--keep', metavar='DIR', default=None, help='keep the reports in this folder')
    add_json_argument(parser)
    args = parser.parse_args()
    folder = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix='bench_report_'))
    folder.mkdir(parents=True, exist_ok=True)
    figures, details = [], {}
    warm = simulate(lhc_schedule(25.0, seed=1).duty(SAMPLE_TIME, 25.0), effects={'coulomb_friction': 4.0},
                    noise=MeasurementNoise(40.0, True), seed=1)
    warm_diagnosis = diagnose(from_columns(warm.columns(with_truth=False)), candidates=['cable_torque'])
    write_report(warm_diagnosis, folder / 'warm.html')           # JIT compile, imports, font cache
    for duration in args.durations:
        duty = lhc_schedule(duration, seed=3).duty(SAMPLE_TIME, duration)
        run = simulate(duty, effects={'coulomb_friction': 4.0}, noise=MeasurementNoise(40.0, True), seed=4)
        recording = from_columns(run.columns(with_truth=False), source=f'bench_{duration:g}s.csv')
        candidates = None if duration <= 120 else LONG_CANDIDATES
        diagnosis, diagnosis_wall, diagnosis_cpu = timed(lambda: diagnose(recording, candidates=candidates))
        path = folder / f'report_{duration:g}s.html'
        _, write_wall, write_cpu = timed(lambda: write_report(diagnosis, path, source=recording.source))
        size = path.stat().st_size
        print(f'{duration:g} s record ({recording.time.size} samples, '
              f'{len(diagnosis.candidates)} candidates): report {size / 1e6:.2f} MB, written in {write_wall:.2f} s '
              f'wall / {write_cpu:.2f} s CPU; diagnosis {diagnosis_wall:.1f} s wall / {diagnosis_cpu:.1f} s CPU; '
              f'report / diagnosis {write_cpu / diagnosis_cpu:.3f} (CPU)')
        target = duration == 60
        figures += [
            figure(f'report size, {duration:g} s record', size / 1e6, 'MB', target='<= 2 MB' if target else '',
                   met=size <= 2e6 if target else None),
            figure(f'report write time (CPU), {duration:g} s record', write_cpu, 's', baseline=diagnosis_cpu,
                   baseline_name=f'diagnosis of the same record (CPU, {len(diagnosis.candidates)} candidates)',
                   ratio_meaning='report write / diagnosis', target='<= 2 s' if target else '',
                   met=write_cpu <= 2.0 if target else None),
            figure(f'report write time (wall), {duration:g} s record', write_wall, 's', baseline=diagnosis_wall,
                   baseline_name='diagnosis of the same record (wall)', ratio_meaning='report write / diagnosis'),
        ]
        details[f'{duration:g}s'] = {'samples': int(recording.time.size), 'candidates': len(diagnosis.candidates),
                                     'path': str(path)}
    print(f'reports in {folder}; load average at the end {os.getloadavg()[0]:.1f} '
          f'on {os.cpu_count()} cores')
    write_json(args.json, 'bench_report', figures, **details)


if __name__ == '__main__':
    main()
