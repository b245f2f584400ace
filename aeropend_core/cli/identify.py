"""Identify the rig equations with weak SINDy from a recording (CSV now; MCAP bags through aeropend_core.io.bag).

The CSV has columns t [s], duty [1], armature_voltage [V], armature_current [A], angle [rad] (what the rig
measures), optionally simulator truth columns (true_motor_speed [rad/s], true_angular_rate [rad/s], ...).

Models:
  pendulum    (default) the live-rig fit from Va, Ia and angle only:
              d²y/dt² = −(mgd/J) sin y − (c/J) dy/dt + θ1 Va² + θ2 Va Ia + θ3 Ia²
  (reduced)   a record without a period-average armature current (duty or Va and the angle only, or a
              current read inside the PWM pulse): the pendulum with the thrust from Va through the motor's
              static map and lag, T de/dt = Va - e - q e|e|, fitted by output error (docs/reduced-model.md)
  full-state  the four first-order equations of the paper "Data-Driven System Identification of an
              Aeropendulum" from [Va, Ia, ω1, y, Ω] (needs motor_speed and angular_rate columns, i.e. a
              simulation)

Examples:
  aeropend simulate -o run.csv --duration 60 --psnr 50 --quantise
  aeropend identify run.csv
  aeropend identify run.csv --json
  aeropend identify run.csv --calibration config/serial_bridge_node.yaml   # undo the angle filter's delay
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from aeropend_core.cli._checks import add_sample_rate_argument, add_time_range_arguments
from aeropend_core.cli._checks import time_window as _window     # the range code path shared with diagnose
from aeropend_core.present.json_output import finite_json
from aeropend_core.errors import AeropendError
from aeropend_core.model.effects import CATALOG


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('data', metavar='RECORDING', help='recording: .csv, .mcap or an MCAP bag folder')
    from aeropend_core.cli._checks import add_json_argument
    add_json_argument(parser, '{coefficients, standard_errors, parameters, ...} (to standard output: instead of '
                              'the text)')
    parser.add_argument('--model', choices=('pendulum', 'full-state'), default='pendulum',
                        help='which equations to identify (default: pendulum, the live-rig case)')
    parser.add_argument('--add', action='append', default=[], metavar='EFFECT',
                        help='pendulum model: add a catalog effect as a candidate term (repeatable; the same flag as '
                             '`aeropend diagnose --add`; those with a weak form: '
                             f'{", ".join(n for n, e in CATALOG.items() if e.weak_form)})')
    # the old spelling, kept working for scripts: hidden from the help, one deprecation line when used
    parser.add_argument('--effect', dest='deprecated_effect', action='append', default=[], help=argparse.SUPPRESS)
    parser.add_argument('--quiet', action='store_true', help='no notes on standard error (warnings about the data '
                                                             'still print)')
    add_time_range_arguments(parser)
    parser.add_argument('--calibration', metavar='FILE.yaml',
                        help="the rig's calibration file (config/serial_bridge_node.yaml): the angle is advanced by "
                             'its angle_filter_delay [s] before the fit (pendulum model; the first-order inverse '
                             'of the RC low-pass), and the output says so')
    add_sample_rate_argument(parser)
    parser.add_argument('--weak-only', action='store_true',
                        help='pendulum model: skip the held-out free-run score and the cross-check against the '
                             'output-error fit (by default both are run: a few seconds more per minute of record)')


def _pieces_between_gaps(time: np.ndarray, shortest: float = 1.0) -> list[tuple[int, int]]:
    """Sample ranges between gaps (a step over 1.5 median steps) at least `shortest` [s] long (all: no gap)."""
    if time.size < 3:
        return [(0, time.size)]
    steps = np.diff(time)
    step = float(np.median(steps))
    cuts = np.flatnonzero(steps > 1.5 * step) + 1
    if cuts.size == 0 or not step > 0:
        return [(0, time.size)]
    bounds = np.concatenate(([0], cuts, [time.size]))
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if (b - a) * step >= shortest]


def _short_pieces(time: np.ndarray, shortest: float = 1.0) -> list[tuple[int, int, float, float]]:
    """(first, stop, t first, t last) of each piece between gaps that :func:`_pieces_between_gaps` leaves out."""
    if time.size < 3:
        return []
    kept = set(_pieces_between_gaps(time, shortest))
    steps = np.diff(time)
    bounds = np.concatenate(([0], np.flatnonzero(steps > 1.5 * float(np.median(steps))) + 1, [time.size]))
    return [(int(a), int(b), float(time[a]), float(time[b - 1])) for a, b in zip(bounds[:-1], bounds[1:])
            if (int(a), int(b)) not in kept]


def main(args: argparse.Namespace) -> int:
    from aeropend_core.cli._checks import load_for_analysis, print_findings
    from aeropend_core.model.effects import check_effect_names
    if args.deprecated_effect:
        print('aeropend identify: warning: --effect is deprecated; write --add (the same flag as diagnose and run)',
              file=sys.stderr)
        args.add = [*args.add, *args.deprecated_effect]
    check_effect_names(args.add, '--add')
    from aeropend_core.cli._checks import check_json_target
    check_json_target(args.json)
    recording = load_for_analysis(args, 'identify')     # through the data-quality gate (and --profile)
    recording = _window(recording, args.start, args.stop)
    print_findings('identify', recording.findings)          # first, before any number
    # the fitting stack (scipy, numba) is imported once the input is known good: bad input is refused at once
    from aeropend_core.identify.pendulum import identify_full_state, identify_pendulum, parameter_unit_of
    from aeropend_core.signals.quality import findings_to_json, quality_lines
    pieces = _pieces_between_gaps(np.asarray(recording.time, dtype=float))
    chain = None
    if args.calibration:
        from aeropend_core.rig.calibration import read_measurement_chain
        chain = read_measurement_chain(args.calibration)
        if args.model != 'pendulum':
            raise AeropendError('--calibration applies to the pendulum model (the full-state model uses simulator '
                                'truth columns, which have no sensor filter)')
    filter_note = None
    if args.model == 'pendulum' and 'armature_current' not in recording.signals:
        if chain is not None:
            raise AeropendError('--calibration is not supported by the reduced model (no armature current); use '
                                'aeropend diagnose --calibration, which holds the angle filter in the model')
        return _identify_reduced(args, recording)
    if args.model == 'pendulum':
        names = ('armature_voltage', 'armature_current', 'angle')
        columns = [np.asarray(recording.signal(name), dtype=float) for name in names]
        duty = recording.signals.get('duty')
        if chain is not None and chain.angle_filter_delay:
            from aeropend_core.signals.measurement_chain import advance_angle
            time_all = np.asarray(recording.time, dtype=float)
            advanced = np.full(time_all.size, np.nan)
            for a, b in pieces:       # within each piece between gaps (never across a gap)
                keep, values = advance_angle(time_all[a:b], columns[2][a:b], chain.angle_filter_delay)
                advanced[a:b][keep] = values
            columns[2] = advanced
            trimmed = [(a, b - int(np.count_nonzero(np.isnan(advanced[a:b])))) for a, b in pieces]
            pieces = trimmed
            filter_note = {'delay': chain.angle_filter_delay, 'from': f'calibration file {args.calibration}',
                           'correction': 'angle advanced by the delay (first-order inverse of the RC low-pass)'}
            if not args.quiet:
                print(f'aeropend identify: angle advanced by the angle filter delay '
                      f'{chain.angle_filter_delay * 1e3:.2f} ms fixed from calibration file {args.calibration}',
                      file=sys.stderr)
        elif chain is not None:
            filter_note = {'delay': chain.angle_filter_delay, 'from': f'calibration file {args.calibration}',
                           'correction': 'none (no filter stated)' if chain.angle_filter_delay is None else
                           'none (no filter on the angle)'}
        if not pieces:
            raise AeropendError(f'{args.data}: no piece between its gaps of lost samples lasts 1 s or more; nothing '
                                'to fit')
        whole = pieces == [(0, len(recording.time))]
        if not whole or filter_note and filter_note['delay']:
            # lost samples: the weak form is fitted on the pieces between the gaps, together (also the single
            # piece trimmed by the filter's delay, or the one piece left when a short one after a gap is dropped)
            cut = [[c[a:b] for a, b in pieces] for c in [np.asarray(recording.time, dtype=float), *columns]]
            fit = identify_pendulum(*cut, duty=None if duty is None else [duty[a:b] for a, b in pieces],
                                    effects=args.add)
            if len(pieces) > 1 and not args.quiet:
                print(f'aeropend identify: {len(pieces) - 1} gap(s) of lost samples in the time stamps: fitted on '
                      f'the {len(pieces)} pieces between them together', file=sys.stderr)
            dropped = _short_pieces(np.asarray(recording.time, dtype=float))
            if dropped and not args.quiet:
                print('aeropend identify: ' + '; '.join(f'{b - a} sample(s) from t = {t0:.3f} to {t1:.3f} s'
                                                        for a, b, t0, t1 in dropped) +
                      ' between gaps of lost samples: shorter than 1 s, not fitted', file=sys.stderr)
        else:
            fit = identify_pendulum(recording.time, *columns, duty=duty, effects=args.add)
    else:
        fit = identify_full_state(recording)
    check, check_note = None, None
    if args.model == 'pendulum' and not args.weak_only:
        # one answer per record: the weak form scored as diagnose scores, and compared with the output-error fit
        from aeropend_core.diagnosis.agreement import cross_check
        fixed = {'angle_filter': chain.angle_filter_delay} if chain is not None and chain.angle_filter_delay else {}
        try:
            check = cross_check(recording, fit, tuple(args.add) + tuple(fixed), args.data, fixed)
        except AeropendError as error:       # too short or too flat for the output-error fit: say so, keep the fit
            check_note = f'no held-out score or output-error cross-check: {error}'
        except (ValueError, FloatingPointError, np.linalg.LinAlgError) as error:      # the fit failed numerically
            check_note = (f'no held-out score or output-error cross-check: the output-error fit failed '
                          f'({type(error).__name__}: {error}); run aeropend diagnose {args.data} to see why')
    from aeropend_core.identify.plausibility import check_parameters, free_oscillation, verdict_line
    independent = free_oscillation(recording.time, recording.signal('angle'), recording.signal('armature_voltage'))
    fitted = set(fit.parameters) - {'armature_resistance_from_current_square'}
    warnings = check_parameters(fit.parameters, fit.standard_errors, independent, fitted)
    rate_warning = _rate_warning(recording)
    if rate_warning:
        print(f'aeropend identify: warning: {rate_warning}', file=sys.stderr)
    if args.json:
        out = {
            'model': args.model,
            'coefficients': fit.result.coefficients,
            'standard_errors': fit.result.standard_errors,
            'parameters': finite_json(fit.parameters),
            'parameter_standard_errors': finite_json(fit.standard_errors),
            'units': {k: parameter_unit_of(k) for k in fit.parameters},
            'estimator': 'weak_sindy',
            'gaps': {'count': len(pieces) - 1, 'pieces': len(pieces)},
            'angle_filter': filter_note,
            'samples': len(recording),
            'test_function_half_width': {eq.name: eq.half_width for eq in fit.result.equations},
            'warnings': findings_to_json(recording.findings),
            'cross_check': finite_json(check.to_dict()) if check is not None else check_note,
            'parameter_warnings': warnings,
            'verdict': 'model_does_not_fit' if warnings else 'parameters_plausible',
            'free_oscillation': independent.to_dict(),
        }
        if rate_warning:
            out['warnings'].append({'code': 'low_sample_rate', 'severity': 'warning', 'message': rate_warning})
            out['parameters_doubt'] = rate_warning
        from aeropend_core.present.json_output import write_json
        write_json(args.json, out)
    if args.json != '-':
        duration = len(recording) * float(np.median(np.diff(recording.time))) if len(recording) > 1 else 0.0
        print(f'{args.data}: {len(recording)} samples ({duration:.3g} s), model {args.model}')
        print(quality_lines(recording.findings))
        if filter_note is not None:
            print(f'Angle filter: delay {filter_note["delay"]} s, fixed from {filter_note["from"]}; '
                  f'{filter_note["correction"]}')
        if rate_warning:
            print(f'Warning: {rate_warning}')
        print(_flag_lines(fit.format(), warnings))
        if rate_warning:
            print(f'Warning (about every number above): {rate_warning}')
        for line in check.lines() if check is not None else [check_note] if check_note else []:
            print(line)
        print(independent.describe())
        if warnings:
            print('Verdict: ' + verdict_line(warnings))
    return 0


def _flag_lines(text: str, warnings: dict[str, str]) -> str:
    """`text` with each failing parameter's warning at the end of its line (``  name = value ...``)."""
    lines = []
    for line in text.splitlines():
        name = line.strip().split(' = ')[0] if ' = ' in line and line.startswith('  ') else ''
        lines.append(line + (f'   !! {warnings[name]}' if name in warnings else ''))
    return '\n'.join(lines)


def _identify_reduced(args: argparse.Namespace, recording) -> int:
    """The pendulum model without a period-average current: the reduced model (docs/reduced-model.md)."""
    from aeropend_core.diagnosis.reduced_fit import identify_reduced
    from aeropend_core.identify.plausibility import check_parameters, free_oscillation, verdict_line
    from aeropend_core.signals.quality import findings_to_json, quality_lines
    from aeropend_core.signals.reduced import IDENTIFIABLE, MAP_PARAMETERS, NOT_IDENTIFIABLE, REDUCED_MODEL
    print('aeropend identify: no period-average armature current in the record: fitting the reduced model (thrust '
          'from Va through the motor map; output error, about a minute)', file=sys.stderr)
    fit = identify_reduced(recording, args.add)
    prep = fit.prepared
    independent = free_oscillation(recording.time, recording.signal('angle'), recording.signal('armature_voltage'),
                                   None if prep is None else prep.step_indices)
    warnings = check_parameters(fit.parameters, fit.standard_errors, independent)
    if args.json:
        from aeropend_core.model.effects import parameter_unit
        from aeropend_core.present.json_output import write_json
        write_json(args.json, {
            'model': REDUCED_MODEL, 'parameters': finite_json(fit.parameters),
            'parameter_standard_errors': finite_json(fit.standard_errors),
            'units': {k: MAP_PARAMETERS.get(k) or parameter_unit(k) for k in fit.parameters},
            'estimator': 'output_error', 'fit_percent': fit.comparison.fit_percent,
            'rms_error': fit.comparison.rms_error, 'noise_rms': fit.comparison.noise_rms,
            'identifiable': IDENTIFIABLE, 'not_identifiable': NOT_IDENTIFIABLE,
            'samples': len(recording), 'warnings': findings_to_json(recording.findings),
            'parameter_warnings': warnings,
            'verdict': 'model_does_not_fit' if warnings else 'parameters_plausible',
            'free_oscillation': independent.to_dict()})
    if args.json != '-':
        duration = len(recording) * float(np.median(np.diff(recording.time))) if len(recording) > 1 else 0.0
        print(f'{args.data}: {len(recording)} samples ({duration:.3g} s), model {REDUCED_MODEL}')
        print(quality_lines(recording.findings))
        print(fit.format(warnings))
        print(independent.describe())
        if warnings:
            print('Verdict: ' + verdict_line(warnings))
    return 0


#: Sample time [s] above which the weak-form fit is said to be biased (measured in bench/rate_sweep.py: at 245 Hz
#: gravity_stiffness ~9 % low, at 122 Hz ~30 %, at 24.5 Hz a thrust gain of the wrong sign).
WEAK_FORM_LOW_RATE_TIME = 1.5 / 490.0
#: The weak form's largest measured relative error of (gravity_stiffness, damping, thrust_gain) per rate [Hz] over
#: seeds 11-14 (bench/lowrate_weak_form.py, 40 dB, 10-bit; bench/results/2026-11-27-lowrate/weak_form.json).
WEAK_FORM_RATE_BIAS = ((245.0, (-0.141, -0.086, -0.191)), (98.0, (-0.444, -0.368, -0.530)),
                       (49.0, (-0.577, -0.435, -0.706)), (24.5, (-0.684, -0.487, -0.860)))


def _rate_warning(recording) -> str:
    """The doubt a low sample rate casts on the weak-form numbers, with the bias measured near that rate (empty at
    the rig's rate)."""
    if len(recording) < 3:
        return ''
    step = float(np.median(np.diff(np.asarray(recording.time, dtype=float))))
    if not step > WEAK_FORM_LOW_RATE_TIME:
        return ''
    rate = 1.0 / step
    at, (gravity, damping, gain) = next((entry for entry in WEAK_FORM_RATE_BIAS if entry[0] <= rate * 1.02),
                                        WEAK_FORM_RATE_BIAS[-1])
    slower = f'; {rate:.4g} Hz is slower than any rate measured' if rate < 0.98 * WEAK_FORM_RATE_BIAS[-1][0] else ''
    return (f'at {rate:.4g} Hz ({step * 1e3:.3g} ms per sample) the weak-form fit is biased low. Measured at {at:g} '
            f'Hz on four seeded simulations, as far off as gravity_stiffness {gravity * 100:+.0f} %, damping '
            f'{damping * 100:+.0f} %, thrust_gain {gain * 100:+.0f} %{slower} (bench/lowrate_weak_form.py); these '
            'parameters are not trustworthy. '
            'Use `aeropend diagnose` (output error with a motor observer): at 24.5-98 Hz its parameters were within '
            'the tolerances of docs/log-import.md')
