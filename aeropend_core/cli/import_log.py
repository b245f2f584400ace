"""Import a log written by another rig (its own columns, units and clock) through a log profile, write our CSV.

The profile (YAML, see docs/log-import.md; shipped ones in config/profiles/) maps each column to a quantity with
its unit or scale/offset (ADC counts, encoder counts, degrees, duty 0-255 or %, mA) and says how time is kept
(device rate, device stamps, or host date-time stamps, which are regularised from the sample order). The record
written carries the profile and the source file's SHA-256 in its first line (a comment our readers skip), and
`identify`/`diagnose` read its rate from there.

A log in another format than ours is recognised as such by `identify` and `diagnose`, which then name this verb:
--guess-profile writes a profile guessed from the log's header (delimiter, time column and format, which column
is which quantity) for you to check.

Examples:
  aeropend import samples/rig_log.csv --profile config/profiles/arduino_logger.yaml -o run.csv
  aeropend import samples/rig_log_semicolon.csv --guess-profile my_logger.yaml     # a start for your own profile
  aeropend diagnose run.csv
  aeropend identify samples/rig_log.csv --profile config/profiles/arduino_logger.yaml    # no intermediate file
"""
from __future__ import annotations

import argparse
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('log', metavar='LOG',
                        help='the log as it was recorded (CSV, or an MCAP bag with a bag profile)')
    parser.add_argument('--profile', metavar='PROFILE.yaml', help='the log profile (columns, units, clock); needed '
                        'with -o')
    parser.add_argument('-o', '--output', metavar='RECORD.csv',
                        help="the recording to write (CSV; '-' for standard output); needed with --profile")
    parser.add_argument('--guess-profile', metavar='PROFILE.yaml', default=None,
                        help="write a profile guessed from the log's header and first rows (delimiter, time column "
                             "and format, columns; '-' for standard output), each guess said in a comment, for you "
                             'to check; nothing is imported')
    parser.add_argument('--no-check', action='store_true', help='write without passing the data-quality gate')
    parser.add_argument('--quiet', action='store_true', help='no notes and no "wrote N samples" line on standard '
                        'error (the data-quality warnings are still printed)')


def main(args: argparse.Namespace) -> int:
    from aeropend_core.errors import AeropendError
    from aeropend_core.io.log_profile import import_log, load_profile, write_imported
    if args.guess_profile:
        return _guess(args)
    if not args.profile or not args.output:
        raise AeropendError('give --profile PROFILE.yaml and -o RECORD.csv (or --guess-profile PROFILE.yaml to write '
                            'a profile guessed from the log\'s header first)')
    if not args.output.lower().endswith('.csv') and args.output != '-':
        raise AeropendError(f'-o {args.output}: the imported record is written as CSV; give a name ending in .csv')
    if args.output != '-':
        from aeropend_core.io.paths import output_target
        output_target(args.output, '--output')
    profile = load_profile(args.profile)
    columns, metadata = import_log(args.log, profile, args.profile)
    for note in metadata['notes'] if not args.quiet else []:
        print(f'aeropend import: {note}', file=sys.stderr)
    if not args.no_check:
        from aeropend_core.io.recording import Recording
        from aeropend_core.signals.quality import check_recording
        rate = metadata['sample_rate_hz']
        recording = Recording(columns['t'], {k: v for k, v in columns.items() if k != 't'}, args.log)
        report = check_recording(recording, sample_time=None if rate is None else 1.0 / rate)
        for finding in report.findings:
            print(f'aeropend import: warning: {finding.message} [{finding.code}, {finding.severity}]', file=sys.stderr)
    write_imported(args.output, columns, metadata)
    n = len(columns['t'])
    rate = metadata['sample_rate_hz']
    if not args.quiet:                                   # progress on standard error, as every verb
        target = 'standard output' if args.output == '-' else args.output
        print(f'wrote {n} samples ({columns["t"][-1]:.3g} s at {rate:.6g} Hz; columns '
              f'{", ".join(k for k in columns if k != "t")}) to {target}; source SHA-256 {metadata["source_sha256"]}',
              file=sys.stderr)
    return 0


def _guess(args: argparse.Namespace) -> int:
    """--guess-profile: write the guessed profile (checked as any profile), say what was guessed."""
    from aeropend_core.errors import AeropendError
    from aeropend_core.io.inputs import check_input
    from aeropend_core.io.log_profile import check_profile
    from aeropend_core.io.profile_guess import guess_profile, profile_yaml
    if args.profile or args.output:
        raise AeropendError('--guess-profile writes a profile and imports nothing; give it without --profile and -o')
    check_input(args.log, 'the log')
    profile, guesses = guess_profile(args.log)
    check_profile(profile, f'the profile guessed from {args.log}')
    text = profile_yaml(profile, guesses, args.log)
    if args.guess_profile == '-':
        sys.stdout.write(text)
        return 0
    from aeropend_core.io.paths import output_target, write_atomically
    output_target(args.guess_profile, '--guess-profile')
    write_atomically(args.guess_profile, lambda handle: handle.write(text), '--guess-profile', 'the profile')
    if not args.quiet:
        for guess in guesses:
            print(f'aeropend import: guessed {guess}', file=sys.stderr)
        print(f'wrote {args.guess_profile}; check it, then: aeropend diagnose {args.log} --profile '
              f'{args.guess_profile}', file=sys.stderr)
    return 0
