"""Repair an MCAP bag whose recorder was killed (SIGKILL, power loss, full disk).

A killed recording keeps every chunk that reached the disk, but its files end without a summary and footer and
its metadata.yaml may be stale, so `ros2 bag`, rosbags and some viewers refuse it. This command rewrites each cut
.mcap file with everything up to its last complete chunk (messages after it were never written and are lost),
adds the summary, footer and rosbag2 metadata record, and regenerates metadata.yaml. Intact files are untouched.

A bag that is still being recorded (its folder holds recording.lock naming a running process) is refused with
exit status 2: stop the recorder instead (Ctrl-C finalises the bag). The lock of a process that no longer runs
(killed) is stale: the bag is repaired and the lock removed.

Example:
  aeropend bag-recover bags/run_2026_11_21
"""
from __future__ import annotations

import argparse

from aeropend_core.io.bag_recover import recover_bag


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bag', metavar='BAG',
                        help='bag folder (with *.mcap and metadata.yaml) or one of its .mcap files')
    parser.add_argument('--keep-original', action='store_true',
                        help='keep each cut file as <file>.orig next to the repaired one')
    from aeropend_core.cli._checks import add_json_argument
    add_json_argument(parser, 'what was repaired (files repaired and intact, messages, notes)')


def main(args: argparse.Namespace) -> int:
    from aeropend_core.cli._checks import check_json_target, text_aside_from_json
    check_json_target(args.json)
    with text_aside_from_json(args.json):       # --json -: standard output carries the JSON only
        report = _recover(args)
    if args.json:
        from aeropend_core.present.json_output import write_json
        write_json(args.json, {'bag': args.bag, 'repaired': [str(p) for p in report.repaired],
                               'intact': [str(p) for p in report.intact], 'notes': list(report.notes),
                               'message_count': report.message_count, 'removed_lock': report.removed_lock or None,
                               'metadata_yaml': str(report.metadata_yaml) if report.metadata_yaml else None})
    return 0


def _recover(args: argparse.Namespace):
    report = recover_bag(args.bag, keep_original=args.keep_original)
    for note in report.notes:
        print(f'repaired {note}')
    if report.removed_lock:
        print(f'{args.bag}: {report.removed_lock}')
    files = len(report.repaired) + len(report.intact)
    if not report.repaired:
        print(f'{args.bag}: all {files} file(s) intact' + ('; metadata.yaml regenerated' if report.metadata_yaml
                                                           else ''))
    print(f'{args.bag}: {report.message_count} messages in {files} file(s)')
    return report
