"""Compare the model with a recording, show where it fails and which physical effect is missing.

The recording (CSV from `aeropend simulate` or a rig log, or an MCAP bag) holds armature_voltage [V] (or the duty),
armature_current [A] and angle [rad]; only these are used. Without a current, or with one that is not the
period-average armature current (read inside the PWM pulse), the reduced model is used: the thrust from Va through
the motor's static map and lag, no armature resistance (docs/reduced-model.md). The model (nominal + the --add
effects) is fitted on the first 75 % and judged on the last 25 % by a free-run simulation of the angle (fit % as
MATLAB compare). Each catalog effect not yet in the model is tried as an augmentation and ranked.

Examples:
  aeropend diagnose bags/exercise.csv
  aeropend diagnose bags/exercise.csv --add coulomb_friction --report report.html
  aeropend diagnose run.csv --json
  aeropend diagnose monday.csv --validate tuesday.csv --report report.html   # the fitted model on a second record
  aeropend diagnose afternoon.mcap --start 600 --stop 1200      # ten minutes of a long record [s]
  aeropend diagnose run.csv --fix angle_filter=0.0141          # a known hardware value (the rig's RC filter)
  aeropend diagnose run.csv --calibration config/serial_bridge_node.yaml   # the same, from the calibration file
  aeropend diagnose run.csv --effects-module my_effects.py     # your own registered effects become candidates
  aeropend diagnose first.mcap experiment.mcap     # several records of one rig judged together (joint)
  aeropend diagnose run.csv --term 'thrust*angular_rate'       # a term the discovery stage proposed
  aeropend diagnose run.csv --motor-term 'sign(current)'       # a motor term it proposed (a brush drop)
"""
from __future__ import annotations

import argparse
import sys

from aeropend_core.errors import AeropendError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('data', metavar='RECORDING', nargs='+',
                        help='recording: .csv, .mcap or an MCAP bag folder; several recordings of the same rig are '
                             'diagnosed together (shared parameters, each record with its own initial states)')
    parser.add_argument('--add', action='append', default=[], metavar='EFFECT',
                        help='effect to include in the model (repeatable); see `aeropend effects`')
    from aeropend_core.cli._checks import add_calibration_argument, add_fix_argument
    add_fix_argument(parser)
    add_calibration_argument(parser)
    parser.add_argument('--no-drift', action='store_true', help='skip the per-segment drift test')
    parser.add_argument('--term', action='append', default=[], metavar='EXPRESSION',
                        help='a term outside the catalog to include in the model, dW/dt += c * EXPRESSION with c '
                             'fitted (repeatable; the expressions the discovery stage proposes, e.g. '
                             "'thrust*angular_rate'; docs/discovery.md lists them)")
    parser.add_argument('--motor-term', action='append', default=[], metavar='EXPRESSION',
                        help='a voltage term to include in the motor observer, La dIa/dt = Va - R Ia - e + c * '
                             "EXPRESSION with c fitted (one; the expressions of \"discovered_motor_terms\", e.g. "
                             "'sign(current)'; docs/discovery.md lists them); needs the armature current")
    parser.add_argument('--no-discovery', action='store_true',
                        help='skip the discovery stage (sparse regression for a term outside the catalog, run when '
                             'the catalog leaves error beyond the noise)')
    parser.add_argument('--only', action='append', default=None, metavar='EFFECT',
                        help='try only these candidate effects (repeatable; default: the whole catalog)')
    parser.add_argument('--effects-module', action='append', default=[], metavar='FILE.py',
                        help='a Python file that registers your own effects (register_effect)')
    parser.add_argument('--report', metavar='FILE.html', help='write a self-contained HTML report')
    parser.add_argument('--validate', metavar='FILE', default=None,
                        help='a second recording (.csv, .mcap or bag folder) of the same rig: the fitted model is '
                             'simulated on it unchanged (MATLAB compare with validation data); its fit %% and residual '
                             'statistics go to the summary, the JSON ("validation") and the report (default: none)')
    from aeropend_core.cli._checks import add_json_argument
    add_json_argument(parser, 'the diagnosis as one object (to standard output: instead of the text summary)')
    parser.add_argument('--quiet', action='store_true', help='no progress messages on standard error')
    parser.add_argument('--as-open-loop', action='store_true',
                        help='diagnose a closed-loop record as if its Va were an open-loop input (biased: the duty '
                             'carries fed-back noise; for comparison with the closed-loop diagnosis)')
    from aeropend_core.cli._checks import add_sample_rate_argument, add_time_range_arguments
    add_time_range_arguments(parser)
    add_sample_rate_argument(parser)


def main(args: argparse.Namespace) -> int:

    from aeropend_core.cli._checks import load_for_analysis, print_findings, time_window
    from aeropend_core.model.effects import check_effect_names
    from aeropend_core.model.effects import load_effects_module
    for path in args.effects_module:
        load_effects_module(path)
    if args.term:                   # a discovered term becomes a one-parameter effect named term_<slug>
        from aeropend_core.diagnosis.discovery import term_effect
        args.add = list(args.add) + [term_effect(text) for text in args.term]
    motor_term = None
    if args.motor_term:             # checked before minutes of fitting
        from aeropend_core.diagnosis.motor_discovery import motor_term_of
        if len(args.motor_term) > 1:
            raise AeropendError(f'--motor-term given {len(args.motor_term)} times; the motor observer carries one '
                                f'extra voltage: give one --motor-term')
        if len(args.data) > 1:
            raise AeropendError('--motor-term works on one record at a time; diagnose each record alone with it')
        motor_term = motor_term_of(args.motor_term[0])
    check_effect_names(args.add, '--add')
    check_effect_names(args.only or [], '--only')
    from aeropend_core.cli._checks import fixed_effects
    fixed = fixed_effects(args.fix, args.add)
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
    if len(args.data) == 1 and not args.as_open_loop:
        from aeropend_core.cli.control import closed_loop_record, diagnose_closed_loop
        data = closed_loop_record(args.data[0])
        if data is not None:                # a record of `aeropend run --controller`: judged in closed loop
            return diagnose_closed_loop(args, data)
    records = []
    for path in args.data:      # each through the data-quality gate (and --profile), each cut by --start/--stop
        records.append(time_window(load_for_analysis(args, 'diagnose', path=path), args.start, args.stop))
        print_findings('diagnose', records[-1].findings)    # first: before minutes of fitting, or a refusal
    recording = records[0]
    if len(records) > 1:
        from aeropend_core.diagnosis.joint import prepare_joint
        recording = prepare_joint(records)
    validation_recording = None
    if args.validate:                    # loaded (and refused if unusable) before minutes of fitting
        try:
            validation_recording = load_for_analysis(args, 'diagnose', path=args.validate)
        except AeropendError as error:
            raise AeropendError(f'--validate: {error}') from None
        from aeropend_core.diagnosis import MIN_DURATION
        times = validation_recording.time
        span = float(times[-1] - times[0]) if times.size else 0.0
        if span < MIN_DURATION:
            raise AeropendError(f'--validate {args.validate} lasts {span:.1f} s; a validation record needs at least '
                                f'{MIN_DURATION:g} s (give a longer recording of the same rig)')
        print_findings('diagnose --validate', validation_recording.findings)
    from aeropend_core.diagnosis.diagnose import diagnose      # scipy and numba: imported once the input is known good

    def progress(message: str) -> None:
        if not args.quiet:
            print(f'diagnose: {message}', file=sys.stderr, flush=True)

    if calibration_message:
        print(f'aeropend diagnose: {calibration_message}', file=sys.stderr, flush=True)
    if motor_term is not None:      # the observer refitted with the term; the pendulum sees its back-EMF
        from aeropend_core.diagnosis.compare import prepare
        from aeropend_core.diagnosis.motor_discovery import with_motor_term
        progress('preparing the data (input conditioning, motor observer)')
        recording = with_motor_term(prepare(recording), motor_term, progress)
    diagnosis = diagnose(recording, effects=args.add, candidates=args.only, progress=progress, fixed=fixed,
                         drift=not args.no_drift, fixed_from=fixed_from, discovery=not args.no_discovery)
    validation = None
    if validation_recording is not None:
        from aeropend_core.diagnosis.validation import validate
        progress(f'validating the fitted model on {args.validate}')
        try:
            validation = validate(diagnosis.current, diagnosis.prepared, validation_recording, source=args.validate)
        except AeropendError as error:
            raise AeropendError(f'--validate {args.validate}: {error}') from None
    if args.report:
        from aeropend_core.present.report import write_report
        written = write_report(diagnosis, args.report, source=' + '.join(args.data), validation=validation)
        progress(f'report written to {written}')
    time_range = None
    if args.start is not None or args.stop is not None:     # the numbers below are about this range only: say so
        time_range = {'start_s': args.start, 'stop_s': args.stop,
                      'samples_start_s': float(records[0].time[0]), 'samples_stop_s': float(records[0].time[-1])}
    if args.json:
        from aeropend_core.present.json_output import write_json
        out = diagnosis.to_dict()
        if time_range:
            out['time_range'] = time_range
        if validation is not None:
            out['validation'] = validation.to_dict()
        write_json(args.json, out)
    if args.json != '-':
        if time_range:
            print(f'time range: samples from {time_range["samples_start_s"]:g} s to {time_range["samples_stop_s"]:g} s '
                  f'of {" + ".join(args.data)} (--start/--stop)')
        print(diagnosis.as_text())
        if validation is not None:
            model = ' + '.join(('nominal', *validation.effects))
            print(f'validation on {args.validate} ({validation.duration:.1f} s, model {model}, unchanged): fit '
                  f'{validation.fit_percent:.2f} % (free run, as MATLAB compare); RMS error '
                  f'{validation.rms_error * 1e3:.2f} mrad against a noise of {validation.noise_rms * 1e3:.2f} mrad '
                  f'(beyond the noise {validation.excess_error * 1e3:.2f} mrad); residual mean '
                  f'{validation.residual_mean * 1e3:+.2f} mrad')
    return 0
