"""Design a controller on a model, check a closed-loop record against its template, linearise the model.

Examples:
  aeropend control design --template settling=2,overshoot=10,error=5,duty=0.8 --at 40deg -o gains.yaml
  aeropend control design --model diagnosis.json --at 40deg -o gains.yaml   # on an identified model
  aeropend control check bags/aeropend_20261206_190000 --json check.json   # the controller stored in the bag
  aeropend control check bags/aeropend_20261206_190000 --design gains.yaml
  aeropend control linearise diagnosis.json --at 40deg --json lin.json      # state space, transfer function

The law, the metrics and the rig's safety: docs/control.md.
"""
from __future__ import annotations

import argparse
import math
import sys

from aeropend_core.errors import AeropendError


def _angle(text: str) -> float:
    """'40deg', '40 deg', '0.7rad' or '0.7' (rad) -> rad."""
    value = text.strip().lower().replace(' ', '')
    try:
        if value.endswith(('deg', '°')):
            return math.radians(float(value.rstrip('deg°')))
        return float(value[:-3] if value.endswith('rad') else value)
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r} is not an angle (write 40deg or 0.7rad)') from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from aeropend_core.cli import VerbParser
    sub = parser.add_subparsers(dest='action', metavar='ACTION', parser_class=VerbParser)
    design = sub.add_parser('design', help='gains for a template on the nominal or an identified model')
    design.add_argument('--model', metavar='DIAGNOSIS.json', default=None,
                        help='design on the model of an `aeropend diagnose/identify --json` file (default: nominal)')
    design.add_argument('--record', metavar='OPEN_LOOP', default=None,
                        help='the open-loop record (bag or CSV) the --model was identified on: the duty that held '
                             'the rod still at its rests sets the thrust doubt the design tolerates (docs/control.md'
                             '#the-thrust-doubt-of-an-identified-model)')
    design.add_argument('--template', default='settling=2,overshoot=10,error=5,duty=0.8',
                        help='items: settling [s], overshoot [%%], error [%% of the step], duty [fraction]')
    design.add_argument('--at', type=_angle, default=math.radians(40), metavar='ANGLE',
                        help='operating angle, e.g. 40deg (default 40deg); design steps go 10 deg either side')
    design.add_argument('--reference', metavar='STEPS.yaml', default=None,
                        help='design on this schedule of steps instead (aeropend run --reference format)')
    design.add_argument('--psnr', type=float, default=None, metavar='DB',
                        help='angle noise the loop must live with [dB PSNR on 90 deg] (default: the noise the '
                             '--model diagnosis measured, else 50)')
    design.add_argument('-o', '--output', default='gains.yaml', help='controller file to write (default gains.yaml)')
    design.add_argument('--json', nargs='?', const='-', default=None, metavar='FILE',
                        help='the design as JSON (to FILE, or standard output)')
    check = sub.add_parser('check', help='measured vs predicted transients of a closed-loop record')
    check.add_argument('record', help='bag folder (or .mcap) of `aeropend run --controller`')
    check.add_argument('--design', metavar='GAINS.yaml', default=None,
                       help='judge against this controller file (default: the one stored in the bag)')
    check.add_argument('--json', nargs='?', const='-', default=None, metavar='FILE', help='the check as JSON')
    check.add_argument('--report', metavar='FILE.html', default=None,
                       help='measured and predicted transients overlaid, step by step (one self-contained page)')
    check.add_argument('--draws', type=int, default=19, metavar='N',
                       help='more noise draws of the model for the predicted settling\'s range (default 19; 0: none; '
                            'docs/control.md#the-predicted-settling-is-a-range)')
    linear = sub.add_parser('linearise', help='the model linearised at an angle: state space, transfer function')
    linear.add_argument('model', nargs='?', default=None, metavar='MODEL.json',
                        help='an `aeropend diagnose --json` file (default: the nominal model)')
    linear.add_argument('--at', type=_angle, default=math.radians(40), metavar='ANGLE', help='e.g. 40deg')
    linear.add_argument('--json', nargs='?', const='-', default=None, metavar='FILE', help='as JSON')
    linear.add_argument('--report', metavar='FILE.html', default=None,
                        help='step response and Bode plot of the linear model (one self-contained page)')


def main(args: argparse.Namespace) -> int:
    if not getattr(args, 'action', None):
        raise AeropendError('say what to do: aeropend control design | check | linearise (aeropend control --help)')
    return {'design': _design, 'check': _check, 'linearise': _linearise}[args.action](args)


def _write_json(target: str | None, data: dict) -> None:
    if target:
        from aeropend_core.present.json_output import write_json
        write_json(target, data)


def _design(args) -> int:
    from aeropend_core.control.metrics import Template
    template = Template.parse(args.template)
    if args.psnr is not None and not 0 < args.psnr <= 200:
        raise AeropendError(f'--psnr must be in (0, 200] dB, got {args.psnr}')
    from aeropend_core.cli._checks import check_json_target
    from aeropend_core.io.paths import output_target
    output_target(args.output, '--output')
    check_json_target(args.json)
    from aeropend_core.control.model_source import load_model
    from aeropend_core.control.reference import ReferenceSchedule, design_schedule
    model = load_model(args.model)
    if args.record:
        if args.model is None:
            raise AeropendError('--record checks an identified model\'s feedforward: give the --model it was '
                                'identified as (aeropend diagnose RECORD --json model.json)')
        from aeropend_core.control.hold_doubt import hold_doubt
        from aeropend_core.io.recording import load_recording
        recording = load_recording(args.record)
        model = model.with_hold_doubt(hold_doubt(recording.time, recording.signal('angle'),
                                                 recording.signal('duty'), model.parameters, model.effects))
    if args.reference:
        from aeropend_core.io.inputs import load_yaml
        schedule = ReferenceSchedule.from_mapping(load_yaml(args.reference, 'reference schedule'), args.reference)
    else:                       # built (and an angle out of range refused) before the design stack is imported
        schedule = design_schedule(args.at)
    from aeropend_core.control.controller_file import Controller
    from aeropend_core.control.design import TemplateNotMet, design
    from aeropend_core.sim.noise import MeasurementNoise
    for doubt in model.doubts:
        print(f'aeropend control design: warning: {doubt}', file=sys.stderr)
    psnr = args.psnr if args.psnr is not None else model.psnr_db
    try:
        result = design(template, args.at, model.parameters, model.effects, schedule,
                        MeasurementNoise(psnr_db=psnr, quantise=True), thrust_tolerance=model.thrust_tolerance)
    except TemplateNotMet as refusal:
        _print_design(refusal.design, model, predicted_only=True)
        raise
    controller = Controller(result.gains, model.parameters, model.effects, template, model.source,
                            {**result.summary(), 'doubts': list(model.doubts)})
    controller.write(args.output)
    _print_design(result, model)
    print(f'wrote {args.output} (controller sha256 {controller.sha256[:12]}); run it: aeropend run --controller '
          f'{args.output}')
    _write_json(args.json, {'schema': 'aeropend.control_design/1', 'output': args.output,
                            'controller_sha256': controller.sha256, 'model': model.source,
                            'model_effects': {k: dict(v) for k, v in model.effects.items()},
                            'doubts': list(model.doubts), 'template': template.as_dict(), **result.summary()})
    return 0


def _print_design(result, model, predicted_only: bool = False) -> None:
    gains = result.gains
    effects = ', '.join(f'{name} (' + ', '.join(f'{key} = {value:.4g}' for key, value in values.items()) + ')'
                        for name, values in model.effects.items()) or 'none'
    print(f'Model: {model.source} (effects: {effects})')
    print(f'Operating point: {math.degrees(result.linearisation.angle):.1f} deg at duty '
          f'{result.linearisation.duty:.3f}; loop margins {result.gain_margin_db:.1f} dB, '
          f'{result.phase_margin_deg:.1f} deg (linearised)')
    print(f'{"Closest gains" if predicted_only else "Gains"}: {gains.text()}')
    print(f'Predicted steps (nonlinear model, discrete law, duty clamp, 10-bit angle with noise) against '
          f'{result.template.text()}:')
    for index, m in enumerate(result.metrics, start=1):
        misses = m.misses(result.template)
        verdict = 'meets the template' if not misses else 'misses ' + ', '.join(misses)
        settling = f'{m.settling_time:.2f} s' if m.settled else 'not settled'
        print(f'  step {index}: {math.degrees(m.initial):5.1f} -> {math.degrees(m.target):5.1f} deg: overshoot '
              f'{m.overshoot:4.1f} %, settling {settling}, rise {m.rise_time:.2f} s, error '
              f'{m.steady_state_error:+.1f} %, peak duty {m.peak_duty:.2f}: {verdict}')
    for note in result.notes:
        print(f'Note: {note}')


def _check_page(path: str | None) -> None:
    """Refuse a --report that cannot be an HTML page before any work (as diagnose's --report)."""
    if path:
        from aeropend_core.cli._checks import check_report_path
        check_report_path(path)


def _check(args) -> int:
    from aeropend_core.cli._checks import check_json_target
    check_json_target(args.json)
    _check_page(args.report)
    if not 0 <= args.draws <= 1000:
        raise AeropendError(f'--draws must be 0..1000 noise draws, got {args.draws}')
    from aeropend_core.control.controller_file import Controller
    from aeropend_core.control.record import load_closed_loop
    data = load_closed_loop(args.record)
    controller = Controller.load(args.design) if args.design else data.controller
    if controller is None:
        raise AeropendError(f'{args.record} holds no controller file; give the one it ran with: --design gains.yaml')
    if data.schedule is None:
        raise AeropendError(f'{args.record} holds no reference schedule: it is not a record of `aeropend run '
                            '--controller`')
    cap = getattr(data, 'duty_limit', math.nan)
    from aeropend_core.control.check import check_record         # numba: once the record is read
    result = check_record(data.time, data.angle, data.duty, controller, data.schedule,
                          duty_limit=min(cap, controller.gains.u_clamp_max) if math.isfinite(cap) else None,
                          draws=args.draws)
    if not getattr(data, 'complete', True):
        result.notes.insert(0, 'the run was cut short: its schedule did not play to the end')
    print(result.as_text())
    _write_json(args.json, {'record': str(args.record), 'controller_sha256': controller.sha256, **result.to_dict()})
    if args.report:
        from aeropend_core.control.report import check_report
        _write_page(args.report, check_report(result, data.time, data.angle, data.duty, data.reference,
                                              str(args.record)))
    return 0


def _linearise(args) -> int:
    from aeropend_core.cli._checks import check_json_target
    check_json_target(args.json)
    _check_page(args.report)
    import numpy as np

    from aeropend_core.control.linear import linearise
    from aeropend_core.control.model_source import load_model
    model = load_model(args.model)
    lin = linearise(args.at, model.parameters, model.effects)
    data = lin.to_dict()
    print(f'Model: {model.source}; linearised at {math.degrees(lin.angle):.1f} deg (duty {lin.duty:.4f}, '
          f'{lin.voltage_slope:.3f} V per unit duty)')
    print('States: ' + ', '.join(f'{s["name"]} [{s["unit"]}]' for s in data['states'])
          + '; input duty [1]; output measured angle [rad]')
    with np.printoptions(precision=4, suppress=False, linewidth=110):
        print(f'A =\n{lin.A}\nB =\n{lin.B.ravel()}\nC = {lin.C.ravel()}')
    tf = data['transfer_function']
    print(f'Transfer function duty -> angle: numerator {np.round(tf["numerator"], 6).tolist()}, denominator '
          f'{np.round(tf["denominator"], 6).tolist()} (in s)')
    print(f'DC gain {lin.dc_gain:.4f} rad per unit duty; poles ' + ', '.join(
        f'{p["real"]:.2f}{p["imag"]:+.2f}j' for p in data['poles']))
    for name, why in lin.left_out.items():
        print(f'Note: {name} left out: {why}')
    for doubt in model.doubts:
        print(f'Note: {doubt}')
    _write_json(args.json, {'schema': 'aeropend.linearisation/1', 'model': model.source,
                            'doubts': list(model.doubts), **data})
    if args.report:
        from aeropend_core.control.report import linearisation_report
        _write_page(args.report, linearisation_report(lin, model.source))
    return 0


def _write_page(path: str, page: str) -> None:
    from aeropend_core.io.atomic import atomic_write
    atomic_write(path, lambda handle: handle.write(page))
    print(f'wrote {path}', file=sys.stderr)


def closed_loop_record(path: str):
    """The closed-loop data of a bag of `aeropend run --controller`, or None for any other input."""
    from pathlib import Path
    target = Path(path)
    if not (target.is_dir() or target.suffix == '.mcap'):
        return None
    if target.is_dir():
        from aeropend_core.io.recording import check_bag_folder
        check_bag_folder(target)            # a folder of bags (`diagnose bags/`): refused with a lead
    from aeropend_core.control.record import load_closed_loop
    try:
        return load_closed_loop(target)
    except AeropendError as error:
        if 'holds no closed loop' in str(error):
            return None
        raise


def _duty_cap(data) -> tuple[float, str]:
    """The duty cap the loop ran under: the controller's u_clamp_max, or the rig's lower cap seen in the data
    (the logged duty held flat below what the law asked)."""
    gains = data.controller.gains
    recorded = getattr(data, 'duty_limit', math.nan)
    if not math.isfinite(recorded):
        recorded = None
    if recorded and recorded < gains.u_clamp_max - 1e-9:
        return float(recorded), (f'the rig capped the duty at {recorded:g} (below the controller\'s '
                                 f'{gains.u_clamp_max:g})')
    if recorded:
        return gains.u_clamp_max, ''
    import numpy as np
    logged_max = float(np.max(data.duty)) if data.duty.size else gains.u_clamp_max
    asked = data.unsaturated[:-1] if data.unsaturated.size > 1 else data.unsaturated
    if logged_max < gains.u_clamp_max - 1e-6 and np.any(asked > logged_max + 1e-6):
        return logged_max, f'the rig capped the duty at {logged_max:.3g} (below the controller\'s ' \
                           f'{gains.u_clamp_max:g}; read from the data)'
    return gains.u_clamp_max, ''


def diagnose_closed_loop(args, data) -> int:
    """`aeropend diagnose BAG` on a closed-loop record: the models judged in closed loop (docs/control.md)."""
    from aeropend_core.control.loop_diagnosis import diagnose_loop
    if data.controller is None:
        raise AeropendError(f'{args.data[0]} is a closed-loop record without its controller file: the closed-loop '
                            'diagnosis needs the gains that ran (record with `aeropend run --controller`), or use '
                            '--as-open-loop (biased)')
    import numpy as np
    cap, cap_note = _duty_cap(data)
    if not args.quiet:
        print(f'aeropend diagnose: {args.data[0]} is a closed-loop record (controller '
              f'{data.controller.sha256[:12]}); judging models in closed loop', file=sys.stderr)
    keep = ~data.tripped
    if not keep.all():
        cut = int(np.argmax(data.tripped))
        print(f'aeropend diagnose: warning: the safety trip held the duty at 0 from t = {data.time[cut]:.2f} s; '
              'only the record before it is judged', file=sys.stderr)
        keep = np.arange(len(data)) < cut
    result = diagnose_loop(data.time[keep], data.angle[keep], data.duty[keep], data.reference[keep],
                           data.feedforward[keep], data.controller.gains, cap, data.controller.parameters,
                           add=tuple(args.add), model_effects=data.controller.effects)
    if cap_note:
        result.notes.append(cap_note)
    if not data.complete:
        result.notes.append('the run was cut short: its schedule did not play to the end')
    if data.samples_without_control:
        result.notes.append(f'{data.samples_without_control} sample(s) without their control telemetry were left '
                            'out')
    print(f'Diagnosis of {len(data)} closed-loop samples ({data.time[-1] - data.time[0]:.1f} s) from {args.data[0]}:')
    print(result.as_text())
    if args.json:
        from aeropend_core.present.json_output import write_json
        payload = result.to_dict()
        payload['source'] = str(args.data[0])
        payload['controller_sha256'] = data.controller.sha256
        payload['design_model'] = {'parameters': data.controller.parameters.as_dict(),
                                   'effects': {k: dict(v) for k, v in data.controller.effects.items()}}
        write_json(args.json, payload)
    if args.report:
        print('aeropend diagnose: note: the HTML report covers open-loop diagnoses; the closed-loop diagnosis is '
              'in the text and --json', file=sys.stderr)
    return 0
