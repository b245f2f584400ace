"""The data-quality gate on many records: false alarms on clean data, the answer to every fault, and its cost.

Clean records: simulated LHC runs over seeds, PSNR 20-60 dB and noise-free, quantised or not, every catalog effect,
duty up to 0.7 or 0.9, 25 or 60 s, whole and cut into 6 s and 25 s windows (the node's windows). Faults: every fault
of aeropend_core.testing.faults on each 60 s clean record (not only the seed the tests use). Cost: the gate's time
per 60 s record against identify_pendulum's on the same record, measured in the same run.

Run: .venv/bin/python bench/quality_sweep.py [--seeds 12]
"""
from __future__ import annotations

import argparse
import time
from collections import Counter

import numpy as np

from aeropend_core.identify.pendulum import identify_pendulum
from aeropend_core.io.recording import from_columns
from aeropend_core.model.parameters import SAMPLE_TIME
from aeropend_core.signals.quality import DataQualityError, check_recording
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate
from aeropend_core.testing.faults import FAULTS

EFFECTS = [{}, {'coulomb_friction': 4.0}, {'cable_torque': 20.0}, {'dead_zone': 0.6}, {'thrust_lag': 0.15},
           {'angle_offset': 0.05}, {'quadratic_drag': 4.0}]
PSNRS = [20.0, 30.0, 40.0, 50.0, 60.0, None]


def record(seed: int) -> tuple[dict, str]:
    psnr, quantise = PSNRS[seed % len(PSNRS)], seed % 4 != 0
    effects, duty_max = EFFECTS[seed % len(EFFECTS)], 0.9 if seed % 3 == 0 else 0.7
    duration = 25.0 if seed % 5 == 0 else 60.0
    duty = lhc_schedule(duration, seed=seed, duty_range=(0.0, duty_max), duty_cap=duty_max).duty(duration=duration)
    noise = MeasurementNoise(psnr_db=psnr, quantise=quantise) if (psnr or quantise) else None
    run = simulate(duty, effects=effects, noise=noise, seed=seed)
    label = f'seed {seed} psnr {psnr} quantise {quantise} {effects or "clean"} duty<={duty_max} {duration:g} s'
    return {k: np.asarray(v, dtype=float) for k, v in run.columns(with_truth=False).items()}, label


def outcome(columns: dict, context: str = 'file') -> list[tuple[str, str]]:
    try:
        report = check_recording(from_columns(columns), sample_time=SAMPLE_TIME, context=context)
    except DataQualityError as error:
        return [(error.finding.code, 'refused')]
    return [(f.code, f.severity) for f in report.findings]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seeds', type=int, default=24)
    args = parser.parse_args()
    alarms, windows, window_alarms, gate_times, fit_times = [], 0, [], [], []
    answers: dict[str, Counter] = {fault.name: Counter() for fault in FAULTS}
    silent_cases = []
    for seed in range(args.seeds):
        columns, label = record(seed)
        found = outcome(columns)
        if found:
            alarms.append((label, found))
        for width in (6.0, 25.0):
            m = int(width / SAMPLE_TIME)
            for start in range(0, len(columns['t']) - m, m // 2):
                windows += 1
                found = outcome({k: v[start:start + m] for k, v in columns.items()}, 'window')
                if found:
                    window_alarms.append((label, width, start, found))
        if len(columns['t']) * SAMPLE_TIME < 59:
            continue
        started = time.perf_counter()
        check_recording(from_columns(columns), sample_time=SAMPLE_TIME)
        gate_times.append(time.perf_counter() - started)
        started = time.perf_counter()
        identify_pendulum(columns['t'], columns['armature_voltage'], columns['armature_current'], columns['angle'],
                          duty=columns['duty'])
        fit_times.append(time.perf_counter() - started)
        for fault in FAULTS:
            corrupted = fault.apply(columns)
            found = outcome(corrupted)
            if (fault.code, fault.severity) in found:
                answers[fault.name]['expected'] += 1
            elif found and found[0][1] == 'refused':
                answers[fault.name]['other refusal'] += 1
            elif found:
                answers[fault.name]['other finding'] += 1
            elif all(np.array_equal(corrupted[k], columns[k]) for k in columns):
                answers[fault.name]['no change'] += 1          # e.g. wrapping an angle that never goes negative
            else:
                answers[fault.name]['silent'] += 1
                silent_cases.append((label, fault.name))
    print(f'clean records: {args.seeds}, with findings: {len(alarms)}')
    for label, found in alarms:
        print(f'  {label}: {found}')
    print(f'clean windows (6 s and 25 s, file gate in window context): {windows}, with findings: {len(window_alarms)}')
    codes = Counter(code for *_, found in window_alarms for code in found)
    print(f'  by finding: {dict(codes)}; in records with the duty below 0.9 (the rod never over the top): '
          f'{sum("duty<=0.9" not in label for label, *_ in window_alarms)}')
    print('faults on every 60 s clean record (expected finding / another refusal / another finding / the fault '
          'changed nothing / silent):')
    for fault in FAULTS:
        a = answers[fault.name]
        print(f'  {fault.name:24s} {fault.code:22s} {fault.severity:9s} {a["expected"]:3d} {a["other refusal"]:3d} '
              f'{a["other finding"]:3d} {a["no change"]:3d} {a["silent"]:3d}')
    print(f'silent: {silent_cases}')
    if gate_times:
        print(f'gate {np.median(gate_times) * 1e3:.1f} ms per 60 s record (median of {len(gate_times)}); '
              f'identify_pendulum {np.median(fit_times) * 1e3:.1f} ms on the same records; ratio '
              f'{np.median(gate_times) / np.median(fit_times):.2f}')


if __name__ == '__main__':
    main()
