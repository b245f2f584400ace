"""Import a log written by another rig (its own columns, units and clock) through a log profile, write our CSV.

The profile (YAML, see docs/log-import.md; shipped ones in config/profiles/) maps each column to a quantity with
its unit or scale/offset (ADC counts, encoder counts, degrees, duty 0-255 or %, mA) and says how time is kept
(device rate, device stamps, or host date-time stamps, which are regularised from the sample order). The record
written carries the profile and the source file's SHA-256 in its first line (a comment our readers skip), and
`identify`/`diagnose` read its rate from there.

Examples:
  aeropend import rig_log.csv --profile config/profiles/arduino_logger.yaml -o run.csv
  aeropend diagnose run.csv
  aeropend identify rig_log.csv --profile config/profiles/arduino_logger.yaml    # without the intermediate file
"""
from __future__ import annotations

import argparse
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('log', metavar='LOG',
                        help='the log as it was recorded (CSV, or an MCAP bag with a bag profile)')
    parser.add_argument('--profile', required=True, metavar='PROFILE.yaml', help='the log profile (columns, units, '
                        'clock)')
    parser.add_argument('-o', '--output', required=True, metavar='RECORD.csv',
                        help="the recording to write (CSV; '-' for standard output)")
    parser.add_argument('--no-check', action='store_true', help='write without passing the data-quality gate')
    parser.add_argument('--quiet', action='store_true', help='no notes and no "wrote N samples" line on standard '
                        'error (the data-quality warnings are still printed)')


def main(args: argparse.Namespace) -> int:
    from aeropend_core.errors import AeropendError
    from aeropend_core.io.log_profile import import_log, load_profile, write_imported
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
