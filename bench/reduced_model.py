"""Reduced model (duty + angle only, no current): parameters and named effects on simulated records.

For each seed: a 60 s simulation at 40 dB with 10-bit quantisation (`aeropend simulate`'s defaults otherwise),
optionally with a hidden effect; only t, duty and angle are kept (Va comes from the duty by eq (8)), and the
record is diagnosed (the reduced model, ``--no-drift``). Reported: gravity_stiffness and damping of the final
model (with the effects found) against the truth, the motor map, and which effects were named. Run::

    nice -n 10 python bench/reduced_model.py --seeds 1 2 3 --cases clean coulomb_friction=4 angle_offset=0.05

Prints one JSON line per run and a summary; takes ~1 min of wall time per run on a loaded 2-core machine.
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from aeropend_core.diagnosis.diagnose import diagnose
from aeropend_core.io.recording import Recording
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, SAMPLE_TIME
from aeropend_core.signals.quality import check_recording
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate


def run(seed: int, case: str, duration: float = 60.0, psnr: float = 40.0) -> dict:
    effects = {}
    if case != 'clean':
        name, value = case.split('=')
        from aeropend_core.model.effects import parse_effect_assignments
        effects = parse_effect_assignments([f'{name}={value}'])
    schedule = lhc_schedule(duration, duty_range=(0.0, 0.7), seed=seed, duty_cap=0.7)
    trajectory = simulate(schedule.duty(SAMPLE_TIME, duration), parameters=DEFAULT_PARAMETERS, effects=effects,
                          noise=MeasurementNoise(psnr, True), seed=seed)
    columns = trajectory.columns(with_truth=False)
    recording = Recording(np.asarray(columns['t']), {'duty': np.asarray(columns['duty']),
                                                      'angle': np.asarray(columns['angle'])}, f'seed {seed} {case}')
    recording = check_recording(recording, sample_time=SAMPLE_TIME).recording
    started = time.perf_counter()
    result = diagnose(recording, drift=False)
    values = result.reported_parameters(result.final)        # the model with the effects found
    return {'seed': seed, 'case': case, 'seconds': round(time.perf_counter() - started, 1),
            'gravity_stiffness_error': values['gravity_stiffness'] / DEFAULT_PARAMETERS.gravity_stiffness - 1,
            'damping_error': values['damping'] / DEFAULT_PARAMETERS.damping - 1,
            'motor_time_constant': values.get('motor_time_constant'),
            'voltage_map_curvature': values.get('voltage_map_curvature'),
            'named': result.missing_effects, 'verdict': result.verdict,
            'parameter_warnings': result.parameter_warnings}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--seeds', type=int, nargs='+', default=[1, 2, 3])
    parser.add_argument('--cases', nargs='+', default=['clean', 'coulomb_friction=4', 'angle_offset=0.05'])
    args = parser.parse_args()
    rows = []
    for case in args.cases:
        for seed in args.seeds:
            row = run(seed, case)
            rows.append(row)
            print(json.dumps(row), flush=True)
    for case in args.cases:
        mine = [r for r in rows if r['case'] == case]
        within = sum(abs(r['gravity_stiffness_error']) <= 0.05 and abs(r['damping_error']) <= 0.05 for r in mine)
        target = case.split('=')[0]
        named = sum(target in r['named'] for r in mine) if case != 'clean' else sum(not r['named'] for r in mine)
        print(f'{case}: a and b within 5 % in {within}/{len(mine)}; '
              f'{"named" if case != "clean" else "nothing named"} in {named}/{len(mine)}; worst |a err| '
              f'{max(abs(r["gravity_stiffness_error"]) for r in mine):.3f}, worst |b err| '
              f'{max(abs(r["damping_error"]) for r in mine):.3f}')


if __name__ == '__main__':
    main()
