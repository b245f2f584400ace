"""Calibrate the rig through its serial port (talks to the firmware directly; stop serial_bridge_node first).

Steps, in this order (each prints the YAML lines for config/serial_bridge_node.yaml; --write FILE updates them):

  aeropend calibrate zero --port /dev/ttyACM0
      rod hanging still, motor off: angle_zero and current_offset [ADC counts]
  aeropend calibrate angle-scale --port /dev/ttyACM0 --reference-deg 90
      rod held at a known angle (90 = horizontal, towards positive thrust): angle_scale [rad/count]
  aeropend calibrate locked-rotor --port /dev/ttyACM0 --duties 0.1,0.15,0.2,0.25
      propeller held so the rotor cannot turn: Ra [ohm] from Va = Ra Ia over the duty steps
  aeropend calibrate back-emf --port /dev/ttyACM0 --duty 0.4,0.6 --motor-speed-rpm 8100,11900 --resistance 1.08
      motor running freely, shaft speed read with a tachometer at each duty: Kw [V s/rad]
  aeropend calibrate angle-filter --filter-resistance 4700 --filter-capacitance 1e-6 --write config/...yaml
      the angle's 2nd-order RC ladder on the board (R1 = R2, C1 = C2; read off the components, no port needed):
      angle_filter_delay = 3 R C [s], which `aeropend diagnose/identify --calibration FILE` holds fixed

Raw counts are converted with the calibration in --config (default: the bridge's defaults); Va comes from the
duty by eq (8) unless the config says voltage_source: adc. The motor is driven with the firmware's watchdog armed
(0.5 s) and set to 0 at the end, on Ctrl-C and on any error.

The firmware reads the current at the pulse centre, where the PWM ripple (La/Ra ~ one period) puts it above the
period average that Va = Ra Ia + e needs. locked-rotor and back-emf subtract the first-order estimate of that
ripple (armature inductance --inductance, default 2.2 mH) and print it; --no-ripple-correction keeps the raw
readings.

The port is opened and then left alone until the device sends its first frame (opening resets an Arduino Mega; its
bootloader must not receive bytes in its first second).
"""
from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from aeropend_core.rig import calibration as C
from aeropend_core.rig import protocol as P
from aeropend_core.errors import AeropendError
from aeropend_core.model.parameters import DEFAULT_PARAMETERS

STEPS = ('zero', 'angle-scale', 'locked-rotor', 'back-emf', 'angle-filter')
NODE_KEY = C.NODE_KEY     # the shipped file's key: the node in any namespace
#: Least extra wall time [s] :meth:`RigLink.record` waits for the samples it asked for (a busy host reads late;
#: the device keeps counting), beyond the recording time itself.
RECORD_MARGIN_S = 10.0


def _fractions(text: str) -> list[float]:
    try:
        values = [float(part) for part in text.split(',') if part.strip()]
    except ValueError as error:
        raise argparse.ArgumentTypeError(f'expected comma-separated numbers, got {text!r}') from error
    return values


def add_arguments(parser) -> None:
    parser.add_argument('step', choices=STEPS, help='what to calibrate (see above)')
    parser.add_argument('--port', help='serial port of the Arduino (e.g. /dev/ttyACM0); every step but '
                        'angle-filter needs it')
    parser.add_argument('--baud', type=int, default=250000, help='baud rate (firmware default 250000)')
    parser.add_argument('--config', type=Path, help='serial_bridge_node YAML with the current calibration')
    parser.add_argument('--write', type=Path, metavar='FILE', help='update the printed keys in this YAML file')
    parser.add_argument('--seconds', type=float, default=2.0, help='recording time for zero / angle-scale [s]')
    parser.add_argument('--reference-deg', type=float, default=90.0, help='angle of the rod for angle-scale [deg]')
    parser.add_argument('--duties', type=_fractions, default=[0.1, 0.15, 0.2, 0.25],
                        help='duty steps for locked-rotor (fractions, comma-separated)')
    parser.add_argument('--dwell', type=float, default=1.0, help='seconds per duty step (second half averaged)')
    parser.add_argument('--duty', type=_fractions, default=[0.5], help='duty(ies) for back-emf')
    parser.add_argument('--motor-speed-rpm', type=_fractions, help='measured motor-shaft speed(s) for back-emf, '
                        'one per --duty [rpm]')
    parser.add_argument('--resistance', type=float, help='Ra [ohm] for back-emf (from locked-rotor)')
    parser.add_argument('--max-duty', type=float, default=0.7, help='safety cap sent to the firmware')
    parser.add_argument('--inductance', type=float, default=DEFAULT_PARAMETERS.armature_inductance,
                        help='armature inductance La [H] for the PWM-ripple correction of the current (default '
                        f'{DEFAULT_PARAMETERS.armature_inductance:g}, the paper\'s)')
    from aeropend_core.cli._checks import add_json_argument
    add_json_argument(parser, 'the calibrated values with units and the measurements behind them')
    parser.add_argument('--filter-resistance', type=float, default=4.7e3,
                        help='angle-filter: R1 = R2 of the RC ladder [ohm] (default 4700, the rig\'s board)')
    parser.add_argument('--filter-capacitance', type=float, default=1e-6,
                        help='angle-filter: C1 = C2 of the RC ladder [F] (default 1e-6, the rig\'s board)')
    parser.add_argument('--no-ripple-correction', action='store_true',
                        help='use the current as read at the pulse centre, without the ripple correction')


class RigLink:
    """The firmware over pyserial: configure, drive a duty while recording samples, always stop the motor."""

    def __init__(self, port: str, baud: int, max_duty: float) -> None:
        import serial
        try:
            self.link = serial.Serial(port, baud, timeout=0.02)
        except (serial.SerialException, OSError) as error:
            raise AeropendError(f'cannot open {port}: {error} (is the Arduino plugged in? is serial_bridge_node '
                                'still running on it?)') from error
        self.decoder = P.FrameDecoder()
        self.max_duty = max_duty
        self.phase_correct = True          # the shipped firmware; a STATUS says otherwise
        # The Mega resets when the port opens: write nothing until its frames come (bootloader ~1 s).
        deadline = time.monotonic() + 6.0
        while True:
            messages = self.decoder.feed(self.link.read(4096))
            for message in messages:
                if isinstance(message, P.StatusFrame):
                    self.phase_correct = message.pwm_mode == P.PWM_PHASE_CORRECT
            if any(isinstance(m, P.SampleFrame) for m in messages):
                break
            if time.monotonic() > deadline:
                self.link.close()
                raise AeropendError(f'no aeropend frames from {port} in 6 s: is firmware/aeropend uploaded, and '
                                    f'the baud rate {baud}?')
        self.link.write(P.encode_command(P.SET_MAX_DUTY, max_duty) + P.encode_command(P.SET_WATCHDOG, 0.5))

    def record(self, duty: float, seconds: float) -> list[P.SampleFrame]:
        """Hold `duty` until the samples cover `seconds` of the device's own time and return them.

        The device's time is its sequence counter x the sample period: a host too busy to read for a while still
        gets the `seconds` it asked for (the firmware keeps counting; the bytes wait in the serial buffer). The
        command is repeated every 0.1 s for the firmware's watchdog. The wait gives up only after `seconds` +
        ``max(RECORD_MARGIN_S, seconds)`` of wall time [s], saying what arrived.

        Parameters
        ----------
        duty : float
            Duty cycle to hold, fraction in [0, max_duty] [-].
        seconds : float
            Device time to record [s].

        Raises
        ------
        AeropendError
            No samples, samples lost on the link, or too few samples for the time waited (naming which).
        """
        if not 0.0 <= duty <= self.max_duty:
            raise AeropendError(f'duty {duty} outside [0, {self.max_duty}] (--max-duty)')
        samples: list[P.SampleFrame] = []
        command = P.encode_command(P.SET_DUTY, duty)
        needed = max(1, int(round(seconds / P.SAMPLE_PERIOD)))      # samples of device time asked for
        started = time.monotonic()
        give_up = started + seconds + max(RECORD_MARGIN_S, seconds)
        next_command = 0.0
        self.link.reset_input_buffer()
        self.decoder.reset()
        while not samples or samples[-1].sequence - samples[0].sequence + 1 < needed:
            now = time.monotonic()
            if now > give_up:
                break
            if now >= next_command:
                self.link.write(command)
                next_command = now + 0.1
            samples += [m for m in self.decoder.feed(self.link.read(max(1, self.link.in_waiting)))
                        if isinstance(m, P.SampleFrame)]
        waited = time.monotonic() - started
        if not samples:
            raise AeropendError(f'no samples in {waited:.1f} s (waiting for {seconds:g} s of samples): is the '
                                'device still streaming?')
        # Lost on the way (sequence gaps) is a bad link; few but contiguous is a slow device (or a starved host).
        span = samples[-1].sequence - samples[0].sequence + 1
        if len(samples) < 0.9 * span:
            raise AeropendError(f'only {len(samples)} of {span} samples arrived in {waited:.1f} s: the serial link '
                                'is losing data')
        if span < needed:
            raise AeropendError(f'only {len(samples)} samples ({span * P.SAMPLE_PERIOD:.2f} s of device time) in '
                                f'{waited:.1f} s of waiting for {seconds:g} s (the firmware sends '
                                f'{1 / P.SAMPLE_PERIOD:.0f} per second): is the right firmware running?')
        return samples

    def close(self) -> None:
        try:
            self.link.write(P.encode_command(P.SET_DUTY, 0.0))
            self.link.flush()
        finally:
            self.link.close()


def load_calibration(path: Path | None) -> tuple[P.Calibration, dict]:
    """The bridge's calibration from a serial_bridge_node YAML file (defaults for missing keys)."""
    if path is None:
        return P.Calibration(), {}
    values = C.read_calibration_file(path)
    default = P.Calibration()
    try:
        calibration = P.Calibration(
            current_scale=float(values.get('current_scale', default.current_scale)),
            current_offset=float(values.get('current_offset', default.current_offset)),
            angle_zero=float(values.get('angle_zero', default.angle_zero)),
            angle_scale=float(values.get('angle_scale', default.angle_scale)),
            voltage_source=str(values.get('voltage_source', default.voltage_source)),
            voltage_scale=float(values.get('voltage_scale', default.voltage_scale)),
            voltage_offset=float(values.get('voltage_offset', default.voltage_offset)),
            duty_voltage=tuple(float(values.get(f'duty_voltage_k{i}', default.duty_voltage[i])) for i in range(4)))
    except (P.ProtocolError, TypeError, ValueError) as error:
        raise AeropendError(f'bad calibration in {path}: {error}') from error
    return calibration, values


def write_values(path: Path, updates: dict[str, float]) -> None:
    """Set `updates` under the bridge node's ``ros__parameters`` in the YAML file `path` (created when missing).

    A round-trip YAML edit (ruamel.yaml): other node sections, comments and key order are kept; a key is written
    under ``/**/serial_bridge_node`` (or an old file's ``serial_bridge_node``) only, whatever other sections hold
    a key of the same name; a missing section or key is added there.

    Raises
    ------
    AeropendError
        The file is not YAML, or is not a mapping of node sections (nothing is written).
    """
    from ruamel.yaml import YAML, YAMLError
    from ruamel.yaml.comments import CommentedMap

    from aeropend_core.io.inputs import YAML_MAX_BYTES
    from aeropend_core.io.paths import output_target, write_atomically
    output_target(path, '--write')              # a device or a FIFO is refused before reading it (it could block)
    yaml = YAML()                               # round trip: comments, order and quoting kept
    yaml.width = 4096                           # never fold a long comment line
    yaml.indent(mapping=2, sequence=4, offset=2)
    yaml.preserve_quotes = True
    from aeropend_core.io.inputs import check_yaml_text, read_input_text
    try:
        text = read_input_text(path, '--write', YAML_MAX_BYTES) if path.exists() else None
        if text is not None:
            check_yaml_text(text, f'--write {path}')        # depth, size, aliases: refused before ruamel reads it
        document = yaml.load(text) if text is not None else None
    except (OSError, UnicodeDecodeError, YAMLError) as error:
        raise AeropendError(f'cannot read {path} to update it: {error}; give another --write FILE') from None
    if document is None:
        document = CommentedMap()
    if not isinstance(document, dict):
        raise AeropendError(f'{path} is not a parameter file (a YAML mapping of node sections, e.g. {NODE_KEY}: '
                            f'ros__parameters: ...); nothing was written')
    key = next((k for k in (NODE_KEY, NODE_KEY.removeprefix('/**/')) if k in document), NODE_KEY)
    section = document.setdefault(key, CommentedMap())
    if not isinstance(section, dict):
        raise AeropendError(f'{path}: {key} is not a mapping; nothing was written')
    parameters = section.get('ros__parameters')
    if parameters is None:
        parameters = section['ros__parameters'] = CommentedMap()
    if not isinstance(parameters, dict):
        raise AeropendError(f'{path}: {key}.ros__parameters is not a mapping; nothing was written')
    for name, value in updates.items():
        parameters[name] = float(value)
    write_atomically(path, lambda handle: yaml.dump(document, handle), '--write', 'the calibration')


def _to_si(calibration: P.Calibration, samples: list[P.SampleFrame]) -> np.ndarray:
    """Array (n, 4): angle rad, Va V, Ia A, duty."""
    return np.array([calibration.to_si(s) for s in samples])


def ripple_correction(args, rig: RigLink, duty: float, voltage: float, resistance: float) -> float:
    """Estimated excess [A] of the current read at the pulse centre over the period average (0 when disabled)."""
    if args.no_ripple_correction:
        return 0.0
    hold = C.hold_after_pulse_start(duty, P.SAMPLE_PERIOD, rig.phase_correct)
    return float(C.held_current_offset(duty, voltage, resistance, args.inductance, P.SAMPLE_PERIOD, hold))


def check_arguments(args) -> None:
    """Refuse out-of-range settings before the port is opened and the motor driven (AeropendError)."""
    def positive(option: str, value: float, unit: str) -> None:
        if not 0 < value < math.inf:
            raise AeropendError(f'{option} must be a positive number{unit}, got {value}')

    if args.step == 'angle-filter':
        C.rc_ladder_delay(args.filter_resistance, args.filter_capacitance)     # refuses bad values
        return
    if not args.port:
        raise AeropendError(f'calibrate {args.step} talks to the rig: give --port (e.g. /dev/ttyACM0)')
    if not 0 < args.max_duty <= 1:
        raise AeropendError(f'--max-duty must be a fraction in (0, 1], got {args.max_duty}')
    positive('--baud', args.baud, '')
    positive('--seconds', args.seconds, ' of seconds')
    positive('--dwell', args.dwell, ' of seconds')
    positive('--inductance', args.inductance, ' of henries (e.g. 0.0022)')
    if not 10 <= abs(args.reference_deg) <= 180:
        raise AeropendError(f'--reference-deg must be a rod angle of 10 to 180 degrees (e.g. 90, the rod '
                            f'horizontal), got {args.reference_deg}')
    duties = list(args.duties) if args.step == 'locked-rotor' else list(args.duty) if args.step == 'back-emf' \
        else []
    if args.step in ('locked-rotor', 'back-emf') and not duties:
        raise AeropendError(f'{args.step} needs at least one duty')
    for duty in duties:
        if not 0 < duty <= args.max_duty:
            raise AeropendError(f'duty {duty:g} is outside (0, {args.max_duty:g}] (--max-duty); duties are '
                                'fractions, e.g. 0.25 for 25 %')
    if args.step == 'locked-rotor' and len(duties) < 3:
        raise AeropendError('locked-rotor needs at least three --duties to fit Ra (e.g. 0.1,0.15,0.2,0.25)')
    if args.step == 'back-emf':
        if not args.motor_speed_rpm or len(args.motor_speed_rpm) != len(args.duty):
            raise AeropendError('back-emf needs --motor-speed-rpm with one measured speed per --duty')
        for speed in args.motor_speed_rpm:
            positive('--motor-speed-rpm', speed, ' of rpm')
        if args.resistance is None:
            raise AeropendError('back-emf needs --resistance (Ra in ohm, from `aeropend calibrate locked-rotor`)')
        positive('--resistance', args.resistance, ' of ohms')


def main(args) -> int:
    check_arguments(args)
    from aeropend_core.cli._checks import check_json_target, text_aside_from_json
    check_json_target(args.json)
    with text_aside_from_json(args.json):       # --json -: standard output carries the JSON only
        result = _calibrate(args)
    if args.json:
        from aeropend_core.present.json_output import write_json
        write_json(args.json, result)
    return 0


#: SI unit of each key the calibration prints (ADC counts for the bridge's zeros).
UNITS = {'angle_zero': 'count', 'current_offset': 'count', 'angle_scale': 'rad/count', 'armature_resistance': 'ohm',
         'back_emf_constant': 'V s/rad', C.ANGLE_FILTER_KEY: 's'}


def _calibrate(args) -> dict:
    """Run the step; returns the JSON object of ``--json`` (the same numbers as the printed lines)."""
    if args.step == 'angle-filter':
        return _angle_filter(args)
    calibration, _ = load_calibration(args.config)
    rig = RigLink(args.port, args.baud, args.max_duty)
    updates: dict[str, float] = {}
    details: dict[str, object] = {}
    try:
        if args.step == 'zero':
            samples = rig.record(0.0, args.seconds)
            zero = C.zero_offsets([s.angle_counts for s in samples], [s.current_counts for s in samples])
            print(f'# {zero.samples} samples, rod still: angle scatter {zero.angle_std:.2f} counts, current '
                  f'scatter {zero.current_std:.2f} counts')
            updates = {'angle_zero': round(zero.angle_zero, 2), 'current_offset': round(zero.current_offset, 2)}
            details = {'samples': zero.samples, 'angle_scatter_counts': zero.angle_std,
                       'current_scatter_counts': zero.current_std}
        elif args.step == 'angle-scale':
            samples = rig.record(0.0, args.seconds)
            scale = C.angle_scale_from_reference([s.angle_counts for s in samples], calibration.angle_zero,
                                                 math.radians(args.reference_deg))
            print(f'# rod at {args.reference_deg:g} deg reads {np.mean([s.angle_counts for s in samples]):.1f} '
                  f'counts (zero {calibration.angle_zero:g}); nominal 2 pi/1024 = {P.DEFAULT_ANGLE_SCALE:.6g}')
            updates = {'angle_scale': float(f'{scale:.8g}')}
            details = {'reference_angle': math.radians(args.reference_deg), 'samples': len(samples)}
        elif args.step == 'locked-rotor':
            voltages, currents, applied = [], [], []
            for duty in args.duties:
                values = _to_si(calibration, rig.record(duty, args.dwell))
                voltages.append(C.steady_mean(values[:, 1]))
                currents.append(C.steady_mean(values[:, 2]))
                applied.append(C.steady_mean(values[:, 3]))
                print(f'# duty {duty:.3f}: Va {voltages[-1]:.4f} V, Ia {currents[-1]:.4f} A (read at the pulse centre)')
            rig.record(0.0, 0.2)
            fit = C.locked_rotor_resistance(voltages, currents)
            if not args.no_ripple_correction:
                for _ in range(3):      # the ripple depends on Ra: a few fixed-point passes
                    excess = [ripple_correction(args, rig, d, v, fit.value) for d, v in zip(applied, voltages)]
                    fit = C.locked_rotor_resistance(voltages, np.subtract(currents, excess))
                print(f'# PWM ripple: the current at the pulse centre exceeds the period average by '
                      f'{min(excess) * 1e3:.1f}-{max(excess) * 1e3:.1f} mA at these duties (La = '
                      f'{args.inductance:g} H, first-order estimate); subtracted (--no-ripple-correction keeps the '
                      'raw readings)')
            print(f'# Ra = {fit.value:.4f} +- {fit.sigma:.4f} ohm (drop {fit.intercept:+.4f} V, {fit.points} steps)')
            updates = {'armature_resistance': round(fit.value, 5)}
            details = {'armature_resistance_sigma': fit.sigma, 'voltage_drop': fit.intercept, 'steps': fit.points,
                       'armature_voltage': voltages, 'armature_current': currents,
                       'ripple_corrected': not args.no_ripple_correction}
        else:  # back-emf
            voltages, currents = [], []
            for duty in args.duty:
                values = _to_si(calibration, rig.record(duty, max(args.dwell, 2.0)))
                voltages.append(C.steady_mean(values[:, 1]))
                read = C.steady_mean(values[:, 2])
                excess = ripple_correction(args, rig, C.steady_mean(values[:, 3]), voltages[-1], args.resistance)
                currents.append(read - excess)
                note = (f', {excess * 1e3:.1f} mA of PWM ripple subtracted (La = {args.inductance:g} H)'
                        if not args.no_ripple_correction else ' (raw, read at the pulse centre)')
                print(f'# duty {duty:.3f}: Va {voltages[-1]:.4f} V, Ia {currents[-1]:.4f} A{note}')
            speeds = np.array(args.motor_speed_rpm) * 2 * math.pi / 60
            fit = C.back_emf_constant(voltages, currents, speeds, args.resistance)
            sigma = '' if math.isnan(fit.sigma) else f' +- {fit.sigma:.3g}'
            print(f'# Kw = {fit.value:.5g}{sigma} V s/rad ({fit.points} point(s))')
            updates = {'back_emf_constant': float(f'{fit.value:.6g}')}
            details = {'back_emf_constant_sigma': fit.sigma, 'points': fit.points, 'armature_voltage': voltages,
                       'armature_current': currents, 'motor_speed': speeds.tolist(),
                       'ripple_corrected': not args.no_ripple_correction}
    finally:
        rig.close()
    bridge_keys = {'angle_zero', 'current_offset', 'angle_scale'}
    for key, value in updates.items():
        where = 'config/serial_bridge_node.yaml' if key in bridge_keys else 'model parameter (RigParameters)'
        print(f'{key}: {value!r}    # {where}')
    written: list[str] = []
    if args.write is not None:
        bridge_updates = {k: v for k, v in updates.items() if k in bridge_keys}
        if bridge_updates:
            write_values(args.write, bridge_updates)
            written = list(bridge_updates)
            print(f'# wrote {", ".join(bridge_updates)} to {args.write}')
        else:
            print(f'# {", ".join(updates)} is a model parameter, not a bridge setting: {args.write} unchanged')
    return {'step': args.step, 'port': args.port,
            'values': {key: {'value': value, 'unit': UNITS.get(key, ''),
                             'where': 'config/serial_bridge_node.yaml' if key in bridge_keys else 'model parameter'}
                       for key, value in updates.items()},
            'details': details, 'written_to': str(args.write) if written else None, 'written_keys': written}


def _angle_filter(args) -> dict:
    """The angle filter's delay from the board's component values (no port): print it, --write it; returns the
    JSON object of ``--json``."""
    delay = C.rc_ladder_delay(args.filter_resistance, args.filter_capacitance)
    print(f'# 2nd-order RC ladder R1 = R2 = {args.filter_resistance:g} ohm, C1 = C2 = {args.filter_capacitance:g} F: '
          f'DC group delay 3RC = {delay * 1e3:.2f} ms, cut-off {0.1787 / delay:.1f} Hz')
    print(f'{C.ANGLE_FILTER_KEY}: {delay!r}    # measurement chain (aeropend diagnose/identify --calibration)')
    written: list[str] = []
    if args.write is not None:
        write_values(args.write, {C.ANGLE_FILTER_KEY: float(f'{delay:.6g}')})
        written = [C.ANGLE_FILTER_KEY]
        print(f'# wrote {C.ANGLE_FILTER_KEY} to {args.write}')
    return {'step': args.step, 'port': None,
            'values': {C.ANGLE_FILTER_KEY: {'value': delay, 'unit': 's', 'where': 'config/serial_bridge_node.yaml'}},
            'details': {'filter_resistance': args.filter_resistance, 'filter_capacitance': args.filter_capacitance,
                        'cut_off_frequency': 0.1787 / delay},
            'written_to': str(args.write) if written else None, 'written_keys': written}
