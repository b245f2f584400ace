"""Close the experiment loop on the simulator: are the confounded pairs decided by one designed experiment?

For each confounded pair and seed:

1. a first record: 60 s of the run's Latin hypercube (duty up to the pair's cap), the true effect hidden, 40 dB;
   its diagnosis alone (the verdict of the first record);
2. the two competing models fitted on it (:func:`competing_models`) and the separating experiment designed
   (``--design-seconds`` s, duty and angle limits as ``aeropend run --until-decided``), its predicted separation
   and the original excitation's (a Latin hypercube of the same length);
3. the designed schedule played on the simulator (same truth, 40 dB) and the separation *measured* on it
   (:func:`measured_separation`: both models fitted on the whole played record), noisy and noise-free;
4. the joint diagnosis of both records (:func:`diagnose_joint`): decided correctly?

Niced; results (JSON + a Markdown table) in bench/results/2026-11-27-experiment/.

    nice -n 10 python bench/experiment_loop.py [--seeds 2] [--candidates 40] [--refinements 20]
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

from aeropend_core.diagnosis.compare import prepare
from aeropend_core.diagnosis.diagnose import diagnose
from aeropend_core.diagnosis.experiment_design import (competing_models, design_experiment, measured_separation,
                                                       steps_to_duty)
from aeropend_core.diagnosis.joint import diagnose_joint
from aeropend_core.io.recording import from_columns
from aeropend_core.present.json_output import finite_json
from aeropend_core.present.verdict_text import verdict_of
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate

OUT = Path(__file__).resolve().parent / 'results' / '2026-11-27-experiment'
#: (name, hidden truth, true model's effects, rival's effects, duty cap of the first record)
PAIRS = [('thrust_lag 15 ms vs angle_filter', {'thrust_lag': 0.015}, ('thrust_lag',), ('angle_filter',), 0.7),
         ('angle_offset 20 mrad vs cable_torque (small angles)', {'angle_offset': 0.02}, ('angle_offset',),
          ('cable_torque',), 0.3)]
PSNR = 40.0


def record(duty, truth, seed, noisy=True, source='simulated'):
    run = simulate(duty, effects=truth, noise=MeasurementNoise(PSNR, True) if noisy else None, seed=seed)
    return from_columns(run.columns(with_truth=False), source=source)


def one_case(name, truth, right, wrong, cap, seed, args) -> dict:
    started = time.process_time()
    duty = lhc_schedule(60.0, duty_range=(0.0, cap), duty_cap=cap, seed=seed).duty(duration=60.0)
    first = record(duty, truth, seed + 1, source='first')
    prep = prepare(first)
    alone = diagnose(prep, drift=False)
    models = competing_models(prep, [right, wrong])
    design = design_experiment(models, prep.noise_rms, duration=args.design_seconds, duty_limit=0.7,
                               candidates=args.candidates, refinements=args.refinements, seed=seed,
                               original_duty_limit=cap)
    played = steps_to_duty(design.schedule.steps)
    second = record(played, truth, seed + 2, source='designed')
    measured = measured_separation(second, [right, wrong], prep.noise_rms)
    clean = measured_separation(record(played, truth, seed + 2, noisy=False), [right, wrong], prep.noise_rms)
    joint = diagnose_joint([first, second], drift=False)
    pinned = [f.effect for f in joint.found if not f.confounded_with]
    decided = joint.verdict == 'effect_found' and right[0] in pinned and wrong[0] not in pinned
    return {'pair': name, 'seed': seed, 'first_verdict': alone.verdict, 'first_message': verdict_of(alone),
            'predicted_separation': design.separation, 'predicted_at_fitted': design.separation_fitted,
            'baseline_separation': design.baseline_separation, 'gain': design.gain,
            'measured_separation_40dB': measured['separation'], 'measured_separation_noise_free': clean['separation'],
            'measured_better_model': [right, wrong][measured['better']][0], 'joint_verdict': joint.verdict,
            'joint_message': verdict_of(joint), 'decided_correctly': decided, 'blocks': [b.text() for b in
                                                                                   design.schedule.blocks],
            'max_angle_deg': math.degrees(design.max_angle), 'cpu_seconds': time.process_time() - started}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seeds', type=int, default=2)
    parser.add_argument('--candidates', type=int, default=40)
    parser.add_argument('--refinements', type=int, default=20)
    parser.add_argument('--design-seconds', type=float, default=30.0)
    args = parser.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    rows = []
    for k in range(args.seeds):
        for name, truth, right, wrong, cap in PAIRS:
            row = one_case(name, truth, right, wrong, cap, 9100 + 10 * k + len(rows), args)
            rows.append(row)
            print(json.dumps({key: row[key] for key in ('pair', 'seed', 'first_verdict', 'predicted_separation',
                                                        'baseline_separation', 'measured_separation_40dB',
                                                        'measured_separation_noise_free', 'joint_verdict',
                                                        'decided_correctly', 'cpu_seconds')}), flush=True)
            write(rows, args)       # after every case: a long run stopped early keeps what it measured


def write(rows: list[dict], args) -> None:
    (OUT / 'results.json').write_text(json.dumps(finite_json({'rows': rows, 'psnr_db': PSNR,
                                                              'settings': vars(args)}), indent=2) + '\n')
    lines = ['| pair | seed | first record alone | predicted (x noise RMS) | original excitation | measured, 40 dB | '
             'measured, noise-free | joint verdict | decided correctly | CPU s |', '|' + '---|' * 10]
    for r in rows:
        lines.append(f'| {r["pair"]} | {r["seed"]} | {r["first_verdict"]} | {r["predicted_separation"]:.3g} | '
                     f'{r["baseline_separation"]:.3g} | {r["measured_separation_40dB"]:.3g} | '
                     f'{r["measured_separation_noise_free"]:.3g} | {r["joint_verdict"]} | {r["decided_correctly"]} | '
                     f'{r["cpu_seconds"]:.0f} |')
    (OUT / 'table.md').write_text('\n'.join(lines) + '\n')


if __name__ == '__main__':
    main()
