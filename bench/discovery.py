"""The discovery stage on effects outside the catalog and on clean records, and what it costs in time.

Records: 60 s, rod below 80 deg, 10-bit quantisation.
* Outside the catalog (bench/discovery_effects.py, loaded as --effects-module loads a file): Stribeck breakaway,
  |W|^1.5 damping, thrust falling with the rod's speed (inflow), a second-harmonic torque, a cubic spring, and a
  friction saturating as tanh(W/0.5) (not in the vocabulary: the nearest term must do, or nothing). Latin-hypercube
  steps up to duty 0.7, PSNR 40 dB, nominal parameters. Found = a proven term that brings the held-out error
  beyond the noise below half the noise RMS.
* Clean: bench/false_alarms.py's records (parameters +-25 %, LHC and staircase, PSNR 30-60 dB), seeds 9000+. A
  false proposal = any discovered term.
  ``--seed-base`` draws a fresh set (records BASE .. BASE + clean - 1); the diagnosis runs as ``aeropend diagnose``
  does by default (drift test on, discovery on).
* Catalog: bench/diagnosis_table.py's records (each catalog effect hidden in turn, LHC, 40 dB, seeds 1-3) with
  the discovery stage on: a correct catalog verdict replaced (a discovered term or a confounded verdict where the
  table names the hidden effect) is counted.
* Outside the catalog, in the motor (aeropend_core.testing.motor_rigs, OUTSIDE_MOTOR): a winding whose resistance
  rises with the dissipated power, a brush drop, armature reaction; same schedule and noise. Found = a proven motor
  term that brings the current's held-out error beyond its noise below half the current's noise (motor_* fields).
* Time: one 60 s record diagnosed with and without the discovery stage in the same run (ratio).
* ``--force-discovery``: the stage runs on every record (its gate off), to see what the stage alone would propose.

Run:  nice -n 10 .venv/bin/python bench/discovery.py [--clean 20] [--seed-base 9000]
          [--part all|outside|clean|catalog] [--out FOLDER]
      (CPU seconds are measured with time.process_time, so a loaded machine changes the wall time, not them)
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

OUTSIDE = {
    'stribeck': {'test_stribeck': {'test_stribeck_level': 5.0, 'test_stribeck_speed': 0.15}},
    'power_damping_1.5': {'test_power_damping': 1.5},
    'inflow': {'test_inflow': 0.05},
    'second_harmonic': {'test_second_harmonic': 6.0},
    'cubic_spring': {'test_cubic_spring': 30.0},
    'saturating_friction': {'test_saturating_friction': 4.0},
}


#: Motor effects outside the catalog (aeropend_core.testing.motor_rigs): (effect, size). A winding whose resistance
#: rises with the dissipated power (thermal resistance 40 K/W, thermal lag 20 s: the library's heat proxy uses 30 s),
#: a brush drop of 0.15 V, armature reaction weakening the field by 10 % per ampere.
OUTSIDE_MOTOR = {'motor_heating': ('heating', 40.0), 'motor_brush_drop': ('brush_drop', 0.15),
                 'motor_armature_reaction': ('armature_reaction', 0.1)}


def outside_record(name: str, seed: int = 11):
    if name in OUTSIDE_MOTOR:
        return motor_record(name, seed)
    from aeropend_core.io.recording import from_columns
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import simulate
    from aeropend_core.model.effects import CATALOG, load_effects_module
    builtin = set(CATALOG)
    load_effects_module(str(ROOT / 'discovery_effects.py'))
    try:        # the simulator has them; the diagnosis must not (they would be catalog candidates)
        schedule = lhc_schedule(60.0, duty_range=(0.0, 0.7), duty_cap=0.7, seed=seed)
        trajectory = simulate(schedule.duty(duration=60.0), effects=OUTSIDE[name],
                              noise=MeasurementNoise(psnr_db=40.0, quantise=True), seed=seed + 1)
    finally:
        for extra in set(CATALOG) - builtin:
            CATALOG.pop(extra)
    return from_columns(trajectory.columns(with_truth=False), source=name)


def motor_record(name: str, seed: int = 11):
    """The same schedule and noise as :func:`outside_record` with a motor effect (OUTSIDE_MOTOR)."""
    from aeropend_core.io.recording import from_columns
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.testing.motor_rigs import simulate_motor_effect
    effect, size = OUTSIDE_MOTOR[name]
    schedule = lhc_schedule(60.0, duty_range=(0.0, 0.7), duty_cap=0.7, seed=seed)
    trajectory = simulate_motor_effect(schedule.duty(duration=60.0), effect, size,
                                       noise=MeasurementNoise(psnr_db=40.0, quantise=True), seed=seed + 1)
    return from_columns(trajectory.columns(with_truth=False), source=name)


def catalog_record(effect: str, value, seed: int):
    """bench/diagnosis_table.py's record with `effect` hidden at `value` (None: nothing hidden)."""
    from diagnosis_table import MAX_DUTY

    from aeropend_core.io.recording import from_columns
    from aeropend_core.model.parameters import DEFAULT_PARAMETERS
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import simulate
    max_duty = MAX_DUTY.get(effect, 0.7)
    duty = lhc_schedule(60, duty_range=(0, max_duty), duty_cap=max_duty, seed=seed).duty(duration=60)
    trajectory = simulate(duty, DEFAULT_PARAMETERS, None if value is None else {effect: value},
                          noise=MeasurementNoise(40.0, True), seed=seed + 100)
    return from_columns(trajectory.columns(with_truth=False), source=f'{effect} seed {seed}')


def row_of(found, seconds: float) -> dict:
    from aeropend_core.diagnosis.compare import excess_error
    noise = found.noise_rms
    proven = found.discovery.proven if found.discovery is not None else []
    best = proven[0] if proven else None
    tried = found.discovery.terms[0] if found.discovery is not None and found.discovery.terms else None
    return {'verdict': found.verdict, 'catalog_set': found.missing_effects, 'noise_mrad': round(noise * 1e3, 3),
            'beyond_noise_before_mrad': round(excess_error(found.final.rms_error, noise) * 1e3, 3),
            'discovery_ran': found.discovery is not None,
            'term': best.term.expression if best else None, 'status': best.status if best else
            (tried.status if tried else None), 'best_candidate': tried.term.expression if tried else None,
            'beyond_noise_after_mrad': round(best.excess_after * 1e3, 3) if best else None,
            'below_half_noise': bool(best and best.excess_after < 0.5 * noise), 'seconds': round(seconds, 1),
            **motor_row(found)}


def motor_row(found) -> dict:
    """The motor equation's discovery: the current's held-out error beyond its noise before -> after [mA]."""
    motor = found.motor_discovery
    if motor is None:
        return {'motor_searched': False}
    best = motor.proven[0] if motor.proven else None
    tried = motor.terms[0] if motor.terms else None
    noise = motor.noise_rms
    return {'motor_searched': True, 'motor_note': motor.note, 'current_noise_mA': round(noise * 1e3, 3),
            'current_beyond_noise_before_mA': round(motor.excess_before * 1e3, 3) if motor.terms else None,
            'motor_term': best.term.expression if best else None,
            'motor_coefficient': [round(best.value, 6), round(best.sigma, 6), best.term.unit] if best else None,
            'motor_best_candidate': tried.term.expression if tried else None,
            'current_beyond_noise_after_mA': round(best.excess_after * 1e3, 3) if best else None,
            'motor_below_half_noise': bool(best and best.excess_after < 0.5 * noise)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0], allow_abbrev=False)
    parser.add_argument('--clean', type=int, default=20, help='clean records (default 20)')
    parser.add_argument('--seed-base', type=int, default=None,
                        help='first clean seed (default: false_alarms.SEED_BASE, 9000)')
    parser.add_argument('--seeds', type=int, nargs='+', default=[1, 2, 3], help='catalog part: seeds (default 1 2 3)')
    parser.add_argument('--part', choices=('all', 'outside', 'clean', 'catalog'), default='all',
                        help='run only the timing + outside-catalog part or only the clean records (two processes '
                             'write discovery-outside.json and discovery-clean.json)')
    parser.add_argument('--force-discovery', action='store_true',
                        help='run the discovery stage on every record (its gate, error beyond 0.25 x the noise, set '
                             'off): does the stage itself propose terms where nothing is missing? Writes '
                             'discovery-PART-forced.json')
    parser.add_argument('--out', default=str(ROOT / 'results' / '2026-11-27-discovery'))
    args = parser.parse_args()
    from threadpoolctl import threadpool_limits

    from aeropend_core.diagnosis.diagnose import diagnose
    from false_alarms import SEED_BASE, record
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results: dict = {'outside': {}, 'clean': [], 'catalog': [], 'timing': {}}
    base_seed = SEED_BASE if args.seed_base is None else args.seed_base
    target = out / ('discovery' + ('' if args.part == 'all' else f'-{args.part}')
                    + ('-forced' if args.force_discovery else '') + '.json')
    if args.force_discovery:
        import aeropend_core.diagnosis.diagnose as stages
        stages.DISCOVERY_NOISE = -1.0       # read at call time: the stage runs whatever the catalog leaves

    def save() -> None:         # after every record: a run cut short keeps what it measured
        found_count = sum(r['below_half_noise'] for n, r in results['outside'].items() if n not in OUTSIDE_MOTOR)
        false = sum(1 for r in results['clean'] if r['term'] or r.get('motor_term'))
        motor_false = sum(1 for r in results['clean'] if r.get('motor_term'))
        motor_found = sum(r.get('motor_below_half_noise', False) for name, r in results['outside'].items()
                          if name in OUTSIDE_MOTOR)
        replaced = sum(1 for r in results['catalog'] if r['replaced'])
        alarms = sum(r['verdict'] != 'nothing_missing' for r in results['clean'])
        results['summary'] = {'catalog_verdicts_replaced': f'{replaced} of {len(results["catalog"])}',
                              'clean_discovery_ran': f'{sum(r["discovery_ran"] for r in results["clean"])} of '
                                                     f'{len(results["clean"])}',
                              'clean_not_nothing_missing': f'{alarms} of {len(results["clean"])}',
                              'outside_found_below_half_noise': f'{found_count} of '
                              f'{sum(n not in OUTSIDE_MOTOR for n in results["outside"])}',
                              'clean_false_proposals': f'{false} of {len(results["clean"])}',
                              'clean_false_motor_proposals': f'{motor_false} of {len(results["clean"])}',
                              'motor_outside_found_below_half_noise': f'{motor_found} of '
                              f'{sum(n in OUTSIDE_MOTOR for n in results["outside"])}'}
        target.write_text(json.dumps(results, indent=1))

    with threadpool_limits(1):
        if args.part in ('all', 'outside'):
            recording = outside_record('inflow')
            for label, flag in (('without_discovery', False), ('with_discovery', True)):
                started, wall = time.process_time(), time.perf_counter()
                found = diagnose(recording, drift=True, discovery=flag)
                results['timing'][label + '_cpu_s'] = round(time.process_time() - started, 2)
                results['timing'][label + '_wall_s'] = round(time.perf_counter() - wall, 2)
                results['timing'][label + '_discovery_ran'] = found.discovery is not None
                results['timing']['load_average_1min'] = round(os.getloadavg()[0], 2)
            timing = results['timing']
            timing['ratio'] = round(timing['with_discovery_cpu_s'] / timing['without_discovery_cpu_s'], 2)
            print('timing', timing, flush=True)
            save()
            for name in list(OUTSIDE) + list(OUTSIDE_MOTOR):
                started = time.process_time()
                found = diagnose(outside_record(name), drift=False)
                results['outside'][name] = row = row_of(found, time.process_time() - started)
                print(name, row, flush=True)
                save()
        if args.part in ('all', 'clean'):
            for index in range(args.clean):
                recording, meta = record(base_seed + index)
                started = time.process_time()
                found = diagnose(recording, drift=True)
                row = {**meta, **row_of(found, time.process_time() - started)}
                results['clean'].append(row)
                print('clean', row, flush=True)
                save()
        if args.part in ('all', 'catalog'):
            from diagnosis_table import CASES
            for effect, value in CASES.items():
                for seed in args.seeds:
                    recording = catalog_record(effect, value, seed)
                    started = time.process_time()
                    found = diagnose(recording, drift=True)
                    row = {'hidden': effect, 'seed': seed, **row_of(found, time.process_time() - started)}
                    # the table's correct call: the hidden effect named (or nothing when nothing is hidden)
                    named = found.missing_effect
                    row['named'] = named
                    row['catalog_correct'] = named == (effect if value is not None else None)
                    # replaced: a term proven or confounded by the discovery stage, and the verdict is not the
                    # table's plain 'effect_found' naming the hidden effect
                    terms = found.discovery.terms if found.discovery is not None else []
                    touched = any(t.status in ('proven', 'confounded') for t in terms) or bool(row.get('motor_term'))
                    row['replaced'] = bool(value is not None and touched and not (
                        found.verdict == 'effect_found' and row['catalog_correct']))
                    results['catalog'].append(row)
                    print('catalog', row, flush=True)
                    save()
    print(json.dumps(results['summary']))
    return 0


if __name__ == '__main__':
    sys.exit(main())
