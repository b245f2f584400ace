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

from aeropend_core.cli._checks import add_sample_rate_argument, add_time_range_arguments
from aeropend_core.cli._checks import time_window as _window     # the range code path shared with diagnose
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
    chain = None
    if args.calibration:
        from aeropend_core.rig.calibration import read_measurement_chain
        chain = read_measurement_chain(args.calibration)
    # the fitting stack (scipy, numba) is imported once the input is known good: bad input is refused at once
    from aeropend_core.identify.record import identify_record

    def note(message: str, warning: bool) -> None:
        if warning or not args.quiet:
            print(f'aeropend identify: {message}', file=sys.stderr, flush=True)

    result = identify_record(recording, model=args.model, effects=args.add, calibration=chain,
                             calibration_source=args.calibration or '', weak_only=args.weak_only, source=args.data,
                             note=note)
    if args.json:
        from aeropend_core.present.json_output import write_json
        write_json(args.json, result.to_dict())
    if args.json != '-':
        print(result.as_text())
    return 0
