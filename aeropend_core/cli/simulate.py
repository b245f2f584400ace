"""Simulate the rig under a Latin-hypercube duty excitation and write a CSV of what the rig would measure.

Columns: t [s], duty [1], armature_voltage [V], armature_current [A], angle [rad], then the simulator's truth
(true_armature_current, true_motor_speed, true_angle, true_angular_rate, true_thrust, true_armature_voltage).

With --input the duty comes from your own CSV (a ``duty`` column, fraction 0..1, and optionally ``t`` [s]: held
between its stamps and sampled at the rig's 490 Hz); with --model the rig is the model of an `aeropend diagnose
--json` file (its fitted parameters and added effects) instead of the nominal one.

Examples:
  aeropend simulate -o run.csv --duration 60 --seed 1 --psnr 40 --quantise --effect coulomb_friction=4
  aeropend simulate -o mine.csv --model diagnosis.json --input duty.csv
"""
from __future__ import annotations

import argparse
import sys


from aeropend_core.errors import AeropendError
from aeropend_core.io.paths import output_target
from aeropend_core.io.recording import write_csv
from aeropend_core.model.effects import parse_effect_assignments
from aeropend_core.model.parameters import PRESETS, SAMPLE_TIME


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('-o', '--output', default='-', help='CSV file to write (default: standard output); a '
                        'symbolic link is written through, a device or a named pipe refused')
    parser.add_argument('--duration', type=float, default=60.0, help='length of the record [s] (default 60)')
    parser.add_argument('--seed', type=int, default=0, help='seed of the excitation and the noise (default 0)')
    parser.add_argument('--psnr', type=float, default=0.0, metavar='DB',
                        help='measurement noise PSNR [dB] on Va, Ia and angle, 20 log10(max|x|/sigma); 0 = no noise '
                             '(as in `aeropend run`; default 0)')
    parser.add_argument('--quantise', action='store_true', help='10-bit angle and current ADC quantisation')
    parser.add_argument('--effect', action='append', default=[], metavar='NAME=VALUE',
                        help='hidden effect (repeatable), e.g. coulomb_friction=4 or thrust_lag.time_constant=0.2')
    parser.add_argument('--effects-module', action='append', default=[], metavar='FILE.py',
                        help='a Python file that registers your own effects (register_effect): --effect can then '
                             'name them as hidden truth')
    parser.add_argument('--preset', choices=sorted(PRESETS), default='default', help='nominal parameter set')
    parser.add_argument('--max-duty', type=float, default=0.7, help='upper end of the duty range (default 0.7)')
    parser.add_argument('--no-truth', action='store_true', help='write only the measured columns')
    parser.add_argument('--input', metavar='DUTY.csv', default=None,
                        help='drive the rig with this duty (CSV column duty, fraction 0..1; optional t [s]) instead '
                             'of the Latin-hypercube excitation; --duration is then the input\'s')
    parser.add_argument('--model', metavar='DIAGNOSIS.json', default=None,
                        help='simulate the model of an `aeropend diagnose --json` file (fitted parameters and added '
                             'effects; --effect adds to them) instead of --preset')
    parser.add_argument('--quiet', action='store_true', help='no "wrote N samples" line on standard error')
    from aeropend_core.cli._checks import add_json_argument
    add_json_argument(parser, 'what was simulated (file, samples, duration, rate, seed, noise, effects, columns)')


#: Longest record `aeropend simulate` writes [s] (1 h: 1.8 million samples, ~200 MB of CSV with the truth).
MAX_DURATION = 3600.0
#: PSNR range [dB] of the noise: above 200 dB the noise is below float precision. ``--psnr 0`` means no noise at all
#: (as in `aeropend run`), not noise as large as the signal's peak.
PSNR_RANGE = (0.0, 200.0)


def check_arguments(args: argparse.Namespace) -> None:
    """Refuse values that would give an empty, absurd or never-ending simulation (AeropendError)."""
    if not 0 < args.duration <= MAX_DURATION:
        raise AeropendError(f'--duration must be in (0, {MAX_DURATION:g}] s, got {args.duration} s; '
                            'simulate longer records in pieces (different --seed)')
    if args.duration < 2 * SAMPLE_TIME:
        raise AeropendError(f'--duration {args.duration:g} s is shorter than two samples '
                            f'({2 * SAMPLE_TIME:.4f} s at {1 / SAMPLE_TIME:g} Hz)')
    if args.psnr != 0 and not PSNR_RANGE[0] < args.psnr <= PSNR_RANGE[1]:
        raise AeropendError(f'--psnr must be 0 (no noise) or in ({PSNR_RANGE[0]:g}, {PSNR_RANGE[1]:g}] dB, got '
                            f'{args.psnr}; typical rig values are 30-60 dB')
    if not 0 < args.max_duty <= 1:
        raise AeropendError(f'--max-duty must be in (0, 1], got {args.max_duty}')
    if args.seed < 0:
        raise AeropendError(f'--seed must be a whole number >= 0, got {args.seed}')
    if args.json == '-' and args.output == '-':
        raise AeropendError('--json - and the CSV cannot both go to standard output; give the CSV a file (-o run.csv) '
                            'or the JSON one (--json run.json)')


def main(args: argparse.Namespace) -> int:
    check_arguments(args)
    from aeropend_core.model.effects import load_effects_module
    for path in args.effects_module:
        load_effects_module(path)
    effects = parse_effect_assignments(args.effect)
    if args.output != '-':
        _check_output(args.output)
    from aeropend_core.cli._checks import check_json_target
    check_json_target(args.json)
    from aeropend_core.sim.excitation import lhc_schedule       # scipy: imported once the arguments are known good
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import simulate
    parameters = PRESETS[args.preset]
    if args.model:
        from aeropend_core.control.model_source import load_model
        model = load_model(args.model)
        parameters, effects = model.parameters, {**model.effects, **effects}
        for doubt in model.doubts:
            print(f'aeropend simulate: warning: {doubt}', file=sys.stderr)
    if args.input:
        duty = input_duty(args.input)
        args.duration = duty.size * SAMPLE_TIME
    else:
        schedule = lhc_schedule(args.duration, duty_range=(0.0, args.max_duty), seed=args.seed,
                                duty_cap=args.max_duty)
        duty = schedule.duty(SAMPLE_TIME, args.duration)
    psnr = args.psnr if args.psnr else None             # 0: no noise
    noise = MeasurementNoise(psnr, args.quantise) if (psnr is not None or args.quantise) else None
    trajectory = simulate(duty, parameters=parameters, effects=effects, noise=noise, seed=args.seed)
    write_csv(args.output, trajectory.columns(with_truth=not args.no_truth))
    if args.output != '-' and not args.quiet:
        print(f'wrote {len(trajectory)} samples ({args.duration:g} s at {1 / SAMPLE_TIME:g} Hz) to {args.output}',
              file=sys.stderr)
    if args.json:
        from aeropend_core.present.json_output import write_json
        columns = trajectory.columns(with_truth=not args.no_truth)
        write_json(args.json, {
            'output': args.output, 'samples': len(trajectory), 'duration': args.duration,
            'sample_rate': round(1.0 / SAMPLE_TIME, 9), 'seed': args.seed, 'psnr_db': args.psnr or None,
            'quantise': args.quantise,
            'effects': {name: dict(values) for name, values in effects.items()}, 'preset': args.preset,
            'max_duty': args.max_duty, 'columns': list(columns),
            'units': {'t': 's', 'duty': '1', 'armature_voltage': 'V', 'armature_current': 'A', 'angle': 'rad'}})
    return 0


def input_duty(path: str):
    """The duty of a user's CSV at the rig's sample rate: column ``duty`` (fraction 0..1), held between the stamps
    of an optional ``t`` column [s] (else one value per sample)."""
    import csv
    import io

    import numpy as np

    from aeropend_core.io.inputs import read_input_text
    text = read_input_text(path, '--input', max_bytes=500_000_000)
    rows = list(csv.reader(io.StringIO(text)))
    if not rows or 'duty' not in [name.strip() for name in rows[0]]:
        raise AeropendError(f'--input {path}: no "duty" column in its header (write a CSV with a header line '
                            '"t,duty" or "duty", duty as a fraction 0..1)')
    header = [name.strip() for name in rows[0]]
    try:
        values = np.array([[float(row[header.index(name)]) for name in ('t', 'duty') if name in header]
                           for row in rows[1:] if row], dtype=float)
    except (ValueError, IndexError):
        raise AeropendError(f'--input {path}: every row needs a number in each of its columns') from None
    if values.size == 0:
        raise AeropendError(f'--input {path}: no rows after the header')
    duty = values[:, -1]
    if not np.all(np.isfinite(values)) or duty.min() < 0 or duty.max() > 1:
        raise AeropendError(f'--input {path}: duty must be finite fractions in [0, 1] (70 % is 0.7)')
    if 't' in header:
        stamps = values[:, 0]
        if np.any(np.diff(stamps) <= 0):
            raise AeropendError(f'--input {path}: t must increase from row to row')
        grid = stamps[0] + np.arange(int(np.floor((stamps[-1] - stamps[0]) / SAMPLE_TIME)) + 1) * SAMPLE_TIME
        duty = duty[np.searchsorted(stamps, grid + 1e-12, side='right') - 1]
    if duty.size < 2:
        raise AeropendError(f'--input {path}: it holds less than two samples at {1 / SAMPLE_TIME:g} Hz')
    return duty


def _check_output(path: str) -> None:
    """Refuse an --output that cannot be a new file before spending time on the simulation (a folder, a missing
    folder, a device, a named pipe, a symbolic link loop; see :mod:`aeropend_core.io.paths`)."""
    output_target(path, '--output', stdout_hint=True)


