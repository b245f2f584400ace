"""Compare the model with a recording, show where it fails and which physical effect is missing.

The recording (CSV from `aeropend simulate` or a rig log, or an MCAP bag) must hold armature_voltage [V],
armature_current [A] and angle [rad]; only these are used. The model (nominal + the --add effects) is fitted on the
first 75 % and judged on the last 25 % by a free-run simulation of the angle (fit % as MATLAB compare). Each
catalog effect not yet in the model is tried as an augmentation and ranked.

Examples:
  aeropend diagnose bags/exercise.csv
  aeropend diagnose bags/exercise.csv --add coulomb_friction --report report.html
  aeropend diagnose run.csv --json
  aeropend diagnose afternoon.mcap --start 600 --stop 1200      # ten minutes of a long record [s]
  aeropend diagnose run.csv --fix angle_filter=0.0141          # a known hardware value (the rig's RC filter)
  aeropend diagnose run.csv --calibration config/serial_bridge_node.yaml   # the same, from the calibration file
  aeropend diagnose run.csv --effects-module my_effects.py     # your own registered effects become candidates
"""
from __future__ import annotations

import argparse
import sys

from aeropend_core.errors import AeropendError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('data', help='recording: .csv, .mcap or an MCAP bag folder')
    parser.add_argument('--add', action='append', default=[], metavar='EFFECT',
                        help='effect to include in the model (repeatable); see `aeropend effects`')
    parser.add_argument('--fix', action='append', default=[], metavar='EFFECT=VALUE',
                        help='effect with a known hardware value, held in the model (repeatable), e.g. '
                             'angle_filter=0.0141 (the rig\'s RC filter delay [s]) or NAME.PARAMETER=VALUE')
    from aeropend_core.cli._checks import add_calibration_argument
    add_calibration_argument(parser)
    parser.add_argument('--no-drift', action='store_true', help='skip the per-segment drift test')
    parser.add_argument('--only', action='append', default=None, metavar='EFFECT',
                        help='try only these candidate effects (repeatable; default: the whole catalog)')
    parser.add_argument('--effects-module', action='append', default=[], metavar='FILE.py',
                        help='a Python file that registers your own effects (register_effect)')
    parser.add_argument('--report', metavar='FILE.html', help='write a self-contained HTML report')
    from aeropend_core.cli._checks import add_json_argument
    add_json_argument(parser, 'the diagnosis as one object (to standard output: instead of the text summary)')
    parser.add_argument('--quiet', action='store_true', help='no progress messages on standard error')
    from aeropend_core.cli._checks import add_sample_rate_argument, add_time_range_arguments
    add_time_range_arguments(parser)
    add_sample_rate_argument(parser)


def main(args: argparse.Namespace) -> int:

    from aeropend_core.cli._checks import load_for_analysis, print_findings, time_window
    from aeropend_core.model.effects import check_effect_names
    from aeropend_core.model.effects import load_effects_module
    for path in args.effects_module:
        load_effects_module(path)
    check_effect_names(args.add, '--add')
    check_effect_names(args.only or [], '--only')
    from aeropend_core.model.effects import parse_effect_assignments
    fixed = parse_effect_assignments(args.fix)
    both = sorted(set(fixed) & set(args.add))
    if both:
        raise AeropendError(f'{", ".join(both)} given with both --add and --fix; --fix already puts it in the model')
    from aeropend_core.cli._checks import calibration_fixed
    fixed, fixed_from, calibration_message = calibration_fixed(args.calibration, fixed)
    both = sorted(set(fixed) & set(args.add))
    if both:
        raise AeropendError(f'{", ".join(both)} given with --add and fixed by --calibration {args.calibration}; '
                            f'drop the --add (the calibration file already puts it in the model)')
    if args.report:                          # refuse now, not after minutes of diagnosis
        from aeropend_core.cli._checks import check_report_path
        check_report_path(args.report)    # a folder, device, FIFO, link loop or missing folder: refused
    from aeropend_core.cli._checks import check_json_target
    check_json_target(args.json)
    recording = load_for_analysis(args, 'diagnose')     # through the data-quality gate (and --profile)
    recording = time_window(recording, args.start, args.stop)     # --start/--stop: the same code path as identify
    print_findings('diagnose', recording.findings)          # first: before minutes of fitting, or a refusal
    from aeropend_core.diagnosis.diagnose import diagnose      # scipy and numba: imported once the input is known good

    def progress(message: str) -> None:
        if not args.quiet:
            print(f'diagnose: {message}', file=sys.stderr, flush=True)

    if calibration_message:
        print(f'aeropend diagnose: {calibration_message}', file=sys.stderr, flush=True)
    diagnosis = diagnose(recording, effects=args.add, candidates=args.only, progress=progress, fixed=fixed,
                         drift=not args.no_drift, fixed_from=fixed_from)
    if args.report:
        from aeropend_core.present.report import write_report
        written = write_report(diagnosis, args.report, source=args.data)
        progress(f'report written to {written}')
    time_range = None
    if args.start is not None or args.stop is not None:     # the numbers below are about this range only: say so
        time_range = {'start_s': args.start, 'stop_s': args.stop,
                      'samples_start_s': float(recording.time[0]), 'samples_stop_s': float(recording.time[-1])}
    if args.json:
        from aeropend_core.present.json_output import write_json
        out = diagnosis.to_dict()
        if time_range:
            out['time_range'] = time_range
        write_json(args.json, out)
    if args.json != '-':
        if time_range:
            print(f'time range: samples from {time_range["samples_start_s"]:g} s to {time_range["samples_stop_s"]:g} s '
                  f'of {args.data} (--start/--stop)')
        print(diagnosis.summary())
    return 0
