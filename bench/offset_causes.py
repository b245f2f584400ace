"""Where a spurious "angle offset" on a clean record comes from: the measurements behind issue #11's offset rule.

For a record, the nominal model and nominal + angle_offset are fitted (as the diagnosis does) and the offset's
estimate, standard error, t, training BIC change and held-out Diebold-Mariano statistic are printed.

* ``structure``: noise-free records (no noise, no quantisation) with each nominal parameter of the simulator moved
  by x0.75 and x1.25 in turn: a structural mismatch between the simulator and the diagnosis model would show as a
  nonzero offset here.
* ``decompose``: one clean record of bench/false_alarms.py (``--seed``, default 9006), its noise drawn again in
  independent streams per signal (``--draws`` draws): noise on every signal, on the angle only, on Va and Ia only,
  and every signal noisy but the thrust input replaced by the true back-EMF (Kw x the true motor speed). The
  spread of the estimate over the draws against its mean reported standard error says whether the standard error
  is honest.

Run:  .venv/bin/python bench/offset_causes.py [structure|decompose|both] [--seed 9006] [--draws 8] [--json PATH]
      (structure ~20 s, decompose ~2 s per draw and variant on the 2-core machine)
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from _common import add_json_argument, figure, write_json  # noqa: E402
from false_alarms import MOVED, duty_cap  # noqa: E402


def probe(trajectory, voltage_override=None) -> dict:
    """Fit nominal and nominal + angle_offset to the measured columns; the offset's evidence (SI; mrad in names)."""
    from aeropend_core.diagnosis.compare import PreparedRecord, compare, prepare
    from aeropend_core.diagnosis.diagnose import assess
    from aeropend_core.io.recording import from_columns
    prep = prepare(from_columns(trajectory.columns(with_truth=False), source='offset causes'))
    if voltage_override is not None:      # the true back-EMF as the thrust input (R = 0, as with the observer)
        prep = PreparedRecord(time=prep.time, armature_voltage=prep.armature_voltage,
                              armature_current=prep.armature_current, angle=prep.angle,
                              sample_time=prep.sample_time, voltage=voltage_override,
                              current=np.zeros_like(voltage_override), step_indices=prep.step_indices,
                              noise_rms=prep.noise_rms, split=prep.split, motor=prep.motor,
                              gate_voltage=prep.gate_voltage, gaps=prep.gaps, angle_step=prep.angle_step)
    base = compare(prep, ())
    augmented = compare(prep, ('angle_offset',), start=base.parameters)
    candidate = assess(prep, base, augmented, 'angle_offset')
    return {'offset_mrad': candidate.parameters['angle_offset'] * 1e3,
            'standard_error_mrad': candidate.standard_errors['angle_offset'] * 1e3,
            't': candidate.t_statistic, 'delta_bic': candidate.delta_bic, 'dm': candidate.dm_statistic,
            'share': candidate.share_removed, 'significant': candidate.significant,
            'observer': None if prep.motor is None else prep.motor.kind}


def structure() -> list[dict]:
    from aeropend_core.model.parameters import DEFAULT_PARAMETERS
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.simulate import simulate
    rows = []
    for name in MOVED:
        for factor in (0.75, 1.25):
            parameters = DEFAULT_PARAMETERS.scaled(**{name: factor})
            cap = duty_cap(parameters)
            duty = lhc_schedule(60.0, duty_range=(0.0, cap), duty_cap=cap, seed=7101).duty(duration=60.0)
            row = {'moved': name, 'factor': factor, **probe(simulate(duty, parameters=parameters))}
            rows.append(row)
            print(f'noise-free, {name} x{factor}: offset {row["offset_mrad"]:+.4f} mrad, t {row["t"]:.1f}',
                  flush=True)
    return rows


def decompose(seed: int, draws: int) -> dict:
    import dataclasses

    from aeropend_core.model.parameters import DEFAULT_PARAMETERS
    from aeropend_core.sim.excitation import lhc_schedule, staircase_schedule
    from aeropend_core.sim.noise import ANGLE_LSB, CURRENT_LSB, quantise, sigma_for_psnr
    from aeropend_core.sim.simulate import simulate
    rng = np.random.default_rng(seed)          # the parameters, PSNR and schedule of false_alarms.record(seed)
    parameters = DEFAULT_PARAMETERS.scaled(**{name: float(rng.uniform(0.75, 1.25)) for name in MOVED})
    cap = duty_cap(parameters)
    psnr = float(rng.uniform(30.0, 60.0))
    schedule = (staircase_schedule(step=cap / 14, top=cap) if seed % 2 else
                lhc_schedule(60.0, duty_range=(0.0, cap), duty_cap=cap, seed=seed))
    clean = simulate(schedule.duty(duration=60.0), parameters=parameters)
    true_emf = parameters.back_emf_constant * clean.truth['motor_speed']
    signals = ('armature_voltage', 'armature_current', 'angle')
    steps = {'angle': ANGLE_LSB, 'armature_current': CURRENT_LSB}
    variants = {'every signal noisy': signals, 'angle noisy only': ('angle',),
                'Va and Ia noisy only': ('armature_voltage', 'armature_current'),
                'every signal noisy, true back-EMF as input': signals}
    results = {name: [] for name in variants}
    for draw in range(draws):
        noise = {s: np.random.default_rng([draw, i]).normal(0.0, sigma_for_psnr(np.max(np.abs(getattr(clean, s))),
                                                                                  psnr), len(clean.time))
                 for i, s in enumerate(signals)}
        for name, noisy in variants.items():
            trajectory = dataclasses.replace(clean)
            for s in signals:
                value = getattr(clean, s) + (noise[s] if s in noisy else 0.0)
                setattr(trajectory, s, quantise(value, steps[s]) if s in steps else value)
            row = probe(trajectory, true_emf if 'true back-EMF' in name else None)
            results[name].append(row)
            print(f'draw {draw} {name:44s} offset {row["offset_mrad"]:+.3f} +- {row["standard_error_mrad"]:.3f} '
                  f'mrad, t {row["t"]:.1f}, observer {row["observer"]}', flush=True)
    summary = {}
    for name, rows in results.items():
        offsets = np.array([r['offset_mrad'] for r in rows])
        summary[name] = {'spread_mrad': float(np.std(offsets, ddof=1)) if len(rows) > 1 else float('nan'),
                         'mean_standard_error_mrad': float(np.mean([r['standard_error_mrad'] for r in rows])),
                         'mean_offset_mrad': float(np.mean(offsets)), 'largest_t': float(max(r['t'] for r in rows))}
        print(f'{name:44s}: estimate spread {summary[name]["spread_mrad"]:.3f} mrad over {draws} draws, mean '
              f'reported standard error {summary[name]["mean_standard_error_mrad"]:.3f} mrad, largest t '
              f'{summary[name]["largest_t"]:.1f}')
    return {'seed': seed, 'psnr_db': psnr, 'duty_cap': cap, 'draws': draws, 'summary': summary,
            'rows': {name: rows for name, rows in results.items()}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('part', nargs='?', default='both', choices=('structure', 'decompose', 'both'))
    parser.add_argument('--seed', type=int, default=9006, help='false_alarms.py record to decompose')
    parser.add_argument('--draws', type=int, default=8, help='noise draws of the decomposition')
    add_json_argument(parser)
    args = parser.parse_args()
    if args.draws < 1:
        parser.error('--draws must be at least 1')
    from threadpoolctl import threadpool_limits
    started = time.perf_counter()
    details, figures = {}, []
    with threadpool_limits(1):
        if args.part in ('structure', 'both'):
            details['structure'] = structure()
            largest = max(abs(r['offset_mrad']) for r in details['structure'])
            print(f'noise-free records, every parameter moved +-25 %: largest |offset| {largest:.4f} mrad')
            figures.append(figure('largest |offset| on noise-free records', largest, 'mrad'))
        if args.part in ('decompose', 'both'):
            details['decompose'] = decompose(args.seed, args.draws)
            for name, row in details['decompose']['summary'].items():
                figures.append(figure(f'offset spread, {name}', row['spread_mrad'], 'mrad',
                                      baseline=row['mean_standard_error_mrad'],
                                      baseline_name='mean reported standard error',
                                      ratio_meaning='above 1: the standard error is too small'))
    write_json(args.json, 'offset_causes', figures, wall_seconds=round(time.perf_counter() - started, 1), **details)


if __name__ == '__main__':
    main()
