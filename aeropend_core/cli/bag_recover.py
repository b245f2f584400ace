"""Recover what is still readable from a damaged or cut MCAP bag (recorder killed, power loss, full disk, bit rot).

Every chunk whose data pass their CRC is kept: a damaged chunk is dropped and the chunks after it are kept; a file
cut by a kill keeps every complete chunk. The kept messages are written to a new, complete bag (index, summary,
footer, rosbag2 metadata record, regenerated metadata.yaml), streamed one chunk at a time. Each dropped chunk is
listed with its time span and message count when the file still says them.

By default the original is not touched: bags/run1 is recovered into bags/run1_recovered (intact files copied), a
lone x.mcap into x_recovered.mcap. --in-place replaces the damaged files of the bag itself (--keep-original keeps
each replaced file as <file>.orig).

A bag that is being recorded (a recorder holds the lock on its recording.lock) is refused with exit status 2: stop
the recorder instead (Ctrl-C finalises the bag). The repair holds that lock itself until it is done, so a recorder
starting on the folder waits for it, and nothing is replaced once the lock is not held by the repair.

Example:
  aeropend bag-recover bags/run_2026_11_21
"""
from __future__ import annotations

import argparse

from aeropend_core.io.bag_recover import recover_bag


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bag', metavar='BAG',
                        help='bag folder (with *.mcap and metadata.yaml) or one of its .mcap files')
    parser.add_argument('--output', metavar='PATH',
                        help='where the recovered bag goes (default: <bag>_recovered beside it)')
    parser.add_argument('--in-place', action='store_true',
                        help='replace the damaged files of the bag itself instead of writing a new bag')
    parser.add_argument('--keep-original', action='store_true',
                        help='with --in-place: keep each replaced file as <file>.orig')
    from aeropend_core.cli._checks import add_json_argument
    add_json_argument(parser, 'what was recovered (files written and intact, per chunk kept or dropped, notes)')


def main(args: argparse.Namespace) -> int:
    from aeropend_core.cli._checks import check_json_target, text_aside_from_json
    check_json_target(args.json)
    if args.keep_original and not args.in_place:
        from aeropend_core.errors import AeropendError
        raise AeropendError('--keep-original only applies with --in-place (without it the original is not touched)')
    with text_aside_from_json(args.json):       # --json -: standard output carries the JSON only
        report = _recover(args)
    if args.json:
        from aeropend_core.present.json_output import write_json
        write_json(args.json, {'bag': args.bag, 'output': str(report.folder), 'in_place': report.in_place,
                               'repaired': [str(p) for p in report.repaired],
                               'intact': [str(p) for p in report.intact], 'notes': list(report.notes),
                               'chunks': [c.to_dict() for c in report.chunks],
                               'message_count': report.message_count, 'removed_lock': report.removed_lock or None,
                               'metadata_yaml': str(report.metadata_yaml) if report.metadata_yaml else None})
    return 0


def _recover(args: argparse.Namespace):
    report = recover_bag(args.bag, keep_original=args.keep_original, in_place=args.in_place, output=args.output)
    for note in report.notes:
        print(f'repaired {note}')
    for chunk in report.chunks:
        if not chunk.kept:
            span = '' if chunk.start_ns is None else f', log time {chunk.start_ns} to {chunk.end_ns} ns'
            lost = 'an unknown number of' if chunk.messages is None else str(chunk.messages)
            print(f'dropped {chunk.file} byte {chunk.offset}{span}: {lost} messages ({chunk.reason})')
    if report.removed_lock:
        print(f'{args.bag}: {report.removed_lock}')
    files = len(report.repaired) + len(report.intact)
    if not report.repaired:
        print(f'{args.bag}: all {files} file(s) intact; nothing written')
    elif report.in_place:
        print(f'{args.bag}: {len(report.repaired)} file(s) replaced in place')
    else:
        print(f'{args.bag}: recovered into {report.folder} (the original is unchanged)')
    print(f'{report.folder}: {report.message_count} messages in {files} file(s)')
    return report
