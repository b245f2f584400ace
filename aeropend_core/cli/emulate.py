"""Start the fake rig (device emulator) on a pseudo-terminal and print its port; runs until Ctrl-C.

The fake device speaks the firmware's protocol at 490.196 Hz with the simulator's physics behind it, so the serial
bridge, `aeropend run --port` and `aeropend calibrate` can be tried without hardware:

  aeropend emulate                                   # prints e.g. /tmp/aeropend-emu-x1y2/ttyAEROPEND0
  aeropend calibrate zero --port /tmp/aeropend-emu-x1y2/ttyAEROPEND0       # in another terminal
  aeropend emulate --effect coulomb_friction=4 --clock-error 0.5 --angle-zero 530 --link /tmp/ttyRIG

Like an Arduino Mega it resets when a program opens the port and stays silent ~1 s in its bootloader; a program
that writes during that second leaves it stuck there (--no-auto-reset: a board without auto-reset). Its analog
front end is the rig's: the angle through the RC filter (4.7 kOhm, 1 uF) with the encoder's wrap at 0/1023, the
current read at the pulse centre of the PWM-resolved armature current, ADC noise (--ideal-chain: exact counts).
The first line on standard output is the port; then one status line every --status-period seconds.
"""
from __future__ import annotations

import argparse
import math
import signal
import sys
import time
from pathlib import Path

from aeropend_core.errors import AeropendError

CLOCK_ERROR_LIMIT = 5.0      # % (a ceramic resonator is within ~0.5 %)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--link', type=Path, help='make this path a symlink to the port (a stable name, like '
                        '/dev/serial/by-id/...); default: a name in a new temporary folder')
    parser.add_argument('--effect', action='append', default=[], metavar='NAME=VALUE',
                        help='hidden physical effect (repeatable), e.g. coulomb_friction=4; `aeropend effects`')
    parser.add_argument('--seed', type=int, default=0, help='seed of the noise and the faults (default 0)')
    parser.add_argument('--initial-angle', type=float, default=0.0, help='rod angle at start [rad]')
    parser.add_argument('--clock-error', type=float, default=0.0, metavar='PERCENT',
                        help='error of the device clock, + = samples slower (a Mega\'s resonator: up to ~0.5)')
    chain = parser.add_argument_group('measurement chain')
    chain.add_argument('--ideal-chain', action='store_true',
                       help='exact counts of the simulated values (no filter, no wrap, no ripple, no noise)')
    chain.add_argument('--adc-noise', type=float, default=0.5, metavar='COUNTS',
                       help='ADC noise, standard deviation per conversion (default 0.5)')
    chain.add_argument('--no-angle-filter', action='store_true', help='leave out the angle RC filter')
    chain.add_argument('--no-pwm-current', action='store_true',
                       help='send the period-average current instead of the reading at the pulse centre')
    chain.add_argument('--angle-zero', type=float, default=512.0, metavar='COUNTS',
                       help='encoder counts with the rod hanging (default 512; near 0 or 1023 shows the wrap)')
    chain.add_argument('--current-offset', type=float, default=0.0, metavar='COUNTS',
                       help='current sense counts at zero current (default 0)')
    faults = parser.add_argument_group('faults')
    faults.add_argument('--no-auto-reset', action='store_true',
                        help='a board whose DTR auto-reset is disabled: streams at once, whoever opens the port')
    faults.add_argument('--boot-delay', type=float, default=1.0, help='bootloader silence after a reset [s]')
    faults.add_argument('--garbage-rate', type=float, default=0.0, metavar='BYTES_PER_S',
                        help='random bytes injected between frames per second')
    faults.add_argument('--corrupt-rate', type=float, default=0.0, metavar='FRAMES_PER_S',
                        help='frames with a flipped bit per second')
    faults.add_argument('--locked-rotor', action='store_true',
                        help='the propeller is held (for `aeropend calibrate locked-rotor`)')
    parser.add_argument('--duration', type=float, default=0.0,
                        help='stop after this many seconds (default 0: run until Ctrl-C)')
    parser.add_argument('--status-period', type=float, default=10.0, help='seconds between status lines')
    from aeropend_core.cli._checks import add_json_argument
    add_json_argument(parser, 'the port and the settings, once the port is open (one line; the status lines then '
                              'go to standard error with -)')


def check_arguments(args: argparse.Namespace) -> None:
    """Refuse bad options before anything starts (AeropendError, exit 2)."""
    def within(option: str, value: float, low: float, high: float, unit: str = '') -> None:
        if not (math.isfinite(value) and low <= value <= high):
            raise AeropendError(f'{option} must be in [{low:g}, {high:g}]{unit}, got {value:g}')

    within('--clock-error', args.clock_error, -CLOCK_ERROR_LIMIT, CLOCK_ERROR_LIMIT, ' %')
    within('--adc-noise', args.adc_noise, 0.0, 50.0, ' counts')
    within('--angle-zero', args.angle_zero, 0.0, 1023.0, ' counts')
    within('--current-offset', args.current_offset, 0.0, 1023.0, ' counts')
    within('--boot-delay', args.boot_delay, 0.0, 10.0, ' s')
    within('--garbage-rate', args.garbage_rate, 0.0, 1e6, ' bytes/s')
    within('--corrupt-rate', args.corrupt_rate, 0.0, 490.0, ' frames/s')
    within('--initial-angle', args.initial_angle, -math.pi, math.pi, ' rad')
    within('--duration', args.duration, 0.0, 1e7, ' s')
    within('--status-period', args.status_period, 0.1, 3600.0, ' s')
    if args.seed < 0:
        raise AeropendError(f'--seed must be a whole number >= 0, got {args.seed}')
    if args.link is not None:
        if args.link.is_dir():
            raise AeropendError(f'--link {args.link} is a folder; give the name of the port to create in it')
        if not args.link.parent.is_dir():
            raise AeropendError(f'--link: folder {args.link.parent} does not exist; create it or choose another')
        if args.link.exists() and not args.link.is_symlink():
            raise AeropendError(f'--link {args.link} exists and is not a symlink; choose another name')


def main(args: argparse.Namespace) -> int:
    check_arguments(args)
    from aeropend_core.cli._checks import check_json_target
    check_json_target(args.json)
    if args.json == '-':       # standard output carries the JSON line only; the text goes to standard error
        import contextlib
        stdout = sys.stdout
        with contextlib.redirect_stdout(sys.stderr):
            return _emulate(args, stdout)
    return _emulate(args, sys.stdout)


def _emulate(args: argparse.Namespace, stdout) -> int:
    from aeropend_core.model.effects import parse_effect_assignments
    effects = parse_effect_assignments([e for e in args.effect if e != 'none'])
    from aeropend_core.rig import protocol as P
    from aeropend_core.sim.simulate import RigSimulator
    from aeropend_core.testing.device_emulator import DeviceEmulator, EmulatorConfig
    from aeropend_core.testing.measurement_chain import MeasurementChain

    chain = None if args.ideal_chain else MeasurementChain(
        angle_filter=not args.no_angle_filter, pwm_current=not args.no_pwm_current, adc_noise_counts=args.adc_noise)
    calibration = P.Calibration(angle_zero=args.angle_zero, current_offset=args.current_offset)
    simulator = RigSimulator(effects=effects, sample_time=P.SAMPLE_PERIOD, seed=args.seed,
                             initial_angle=args.initial_angle)
    emulator = DeviceEmulator(link=args.link, simulator=simulator, calibration=calibration,
                              config=EmulatorConfig(boot_delay=args.boot_delay), seed=args.seed,
                              clock_ppm=args.clock_error * 1e4, auto_reset=not args.no_auto_reset, chain=chain,
                              keep_log=False)

    def on_sigterm(_signum, _frame):
        raise KeyboardInterrupt
    previous = signal.signal(signal.SIGTERM, on_sigterm)
    # Ctrl-C stops it even when started from a shell that ignores SIGINT for background jobs.
    previous_int = signal.signal(signal.SIGINT, signal.default_int_handler)
    emulator.locked_rotor = args.locked_rotor
    start = last_status = last_fault = time.monotonic()
    try:
        emulator.start()
        print(emulator.port, flush=True)
        describe(args, effects, chain)
        if args.json:
            import os
            from aeropend_core.present.json_output import json_text, write_json
            info = {'port': emulator.port, 'link': str(args.link) if args.link else None, 'pid': os.getpid(),
                    'effects': {name: dict(values) for name, values in effects.items()}, 'seed': args.seed,
                    'chain': None if chain is None else {'angle_filter': chain.angle_filter,
                                                         'pwm_current': chain.pwm_current,
                                                         'adc_noise_counts': chain.adc_noise_counts},
                    'auto_reset': not args.no_auto_reset, 'boot_delay': args.boot_delay,
                    'duration': args.duration or None}
            if args.json == '-':
                stdout.write(json_text(info, indent=None) + '\n')
                stdout.flush()
            else:
                write_json(args.json, info)
        while not args.duration or time.monotonic() - start < args.duration:
            time.sleep(0.05)
            now = time.monotonic()
            if args.garbage_rate or args.corrupt_rate:
                elapsed, last_fault = now - last_fault, now
                if args.garbage_rate:
                    emulator.inject_garbage(int(emulator.rng.random() + args.garbage_rate * elapsed))
                if args.corrupt_rate:
                    emulator.corrupt_frames(int(emulator.rng.random() + args.corrupt_rate * elapsed))
            if now - last_status >= args.status_period:
                last_status = now
                print(status_line(emulator, now - start), flush=True)
    except KeyboardInterrupt:
        print(f'# stopped after {time.monotonic() - start:.1f} s ({emulator.samples_sent()} samples sent)',
              flush=True)
        return 130
    finally:
        emulator.stop()
        signal.signal(signal.SIGTERM, previous)
        signal.signal(signal.SIGINT, previous_int)
    print(status_line(emulator, time.monotonic() - start), flush=True)
    return 0


def describe(args: argparse.Namespace, effects: dict, chain) -> None:
    """The '#' lines after the port: what this fake rig does."""
    reset = ('off (streams at once)' if args.no_auto_reset else
             f'on: opening the port resets it; silent {args.boot_delay:g} s in the bootloader, stuck there if '
             'bytes arrive meanwhile')
    front = 'ideal counts' if chain is None else (
        ('angle RC filter 4.7 kOhm / 1 uF (delay 14.1 ms), ' if chain.angle_filter else 'no angle filter, ')
        + 'encoder wrap at 0/1023, '
        + ('current read at the pulse centre (PWM ripple), ' if chain.pwm_current else 'period-average current, ')
        + f'ADC noise {chain.adc_noise_counts:g} counts')
    hidden = ', '.join(f'{name}({", ".join(f"{k}={v:g}" for k, v in values.items())})'
                       for name, values in effects.items()) or 'none'
    lines = [f'auto-reset {reset}',
             f'clock error {args.clock_error:+g} % (stamps must follow it), 490.196 Hz nominal',
             f'measurement chain: {front}; hanging rod at {args.angle_zero:g} counts, current offset '
             f'{args.current_offset:g} counts',
             f'hidden effects: {hidden}' + ('; propeller held (locked rotor)' if args.locked_rotor else ''),
             'faults: ' + (f'{args.garbage_rate:g} garbage bytes/s, {args.corrupt_rate:g} corrupt frames/s'
                           if args.garbage_rate or args.corrupt_rate else 'none'),
             'give the port to serial_bridge_node (-p port:=...), aeropend run --port or aeropend calibrate --port; '
             'Ctrl-C stops']
    for line in lines:
        print(f'# {line}')
    sys.stdout.flush()


def status_line(emulator, elapsed: float) -> str:
    from aeropend_core.rig import protocol as P
    port = 'port open' if emulator.host_open else 'no program has the port open'
    return (f'# t = {elapsed:.0f} s: {emulator.state}, {port}, {emulator.samples_sent()} samples sent, duty '
            f'{P.q16_to_duty(emulator.applied_q16):.3f}, {len(emulator.commands)} commands received, '
            f'{len(emulator.host_opens)} port opens, {emulator.bootloader_bytes} bytes swallowed by the bootloader')
