"""Mutation suite for bag reading and recovery: hundreds of damaged bags, judged by the ``mcap`` package.

For each case a small bag (``--samples`` JointState samples at 490 Hz plus duty commands, 16 KiB chunks) is
damaged by one operator of :data:`aeropend_core.testing.bag_mutations.OPERATORS` with its own seed, then:

- **judge**: the messages the ``mcap`` package decodes from the damaged file, chunk by chunk
  (:func:`~aeropend_core.testing.bag_mutations.judge_messages`, CRC-checked);
- **recover**: ``recover_bag`` writes a new file; its messages are read back with ``mcap``'s own
  ``StreamReader``. Pass: recovered ⊇ judged (no message the judge decodes is lost) and nothing that was never
  in the original appears (except in a file without CRCs, where a flip cannot be detected and the judge decodes
  the same changed message);
- **read**: ``read_samples`` with its damage list, and the findings ``identify``/``diagnose`` would show
  (:func:`aeropend_core.io.recording.bag_findings`). Pass: whenever fewer samples than the original's are read,
  or any value differs, there is at least one finding (never "clean" on a partial read).
- **independent reader** (issue 43): the ``rosbags`` reader (``AnyReader``) on the damaged file and on the
  recovered one, counting the samples it deserialises until its first error. Pass: samples read (plus those the
  reader skipped *and reported*: undecodable, or a stamp out of order) >= the independent count; the recovered file
  read by rosbags >= the damaged one; and ``load_recording`` (what identify/diagnose read, through the data-quality
  gate) never refuses a file in which the judge decodes >= 90 % of the samples.

Usage::

    nice -n 10 .venv/bin/python bench/bag_mutations.py --per-operator 40        # 20 operators: 800 bags

Prints one line per operator and a JSON summary; exit status 1 when any case fails.
"""
from __future__ import annotations

import argparse
import json
import random
import sys
import tempfile
import time
import warnings
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from aeropend_core.errors import AeropendError  # noqa: E402
from aeropend_core.io.bag import read_samples  # noqa: E402
from aeropend_core.io.bag_recover import recover_bag  # noqa: E402
from aeropend_core.io.recording import bag_findings, load_recording  # noqa: E402
from aeropend_core.testing.bag_mutations import (  # noqa: E402
    NEEDS,
    OPERATORS,
    judge_messages,
    layout,
    message_keys,
    write_sample_bag,
)


def stream_messages(path: Path) -> set:
    """Messages of a (recovered) file read by the ``mcap`` package's StreamReader with CRC checks."""
    from mcap.records import Message
    from mcap.stream_reader import StreamReader
    with open(path, 'rb') as stream:
        return message_keys(r for r in StreamReader(stream, validate_crcs=True).records if isinstance(r, Message))


def cdr_decodable(judged: set) -> set:
    """The judged messages whose bytes also decode as their type (``rosbags``): in a file without CRCs the judge
    takes a chunk whose bytes changed, and a message that no longer decodes must not be written by a recovery."""
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    out = set()
    for key in judged:
        try:
            store.deserialize_cdr(key[3], 'sensor_msgs/msg/JointState' if len(key[3]) > 16 else 'std_msgs/msg/Float64')
            out.add(key)
        except Exception:       # noqa: BLE001 - not decodable: a recovery leaves it out
            pass
    return out


def independent_samples(path: Path) -> int:
    """Samples the ``rosbags`` reader deserialises from a file before its first error (0 when it cannot open it)."""
    from rosbags.highlevel import AnyReader
    count = 0
    try:
        with AnyReader([path]) as reader:
            connections = [c for c in reader.connections if c.topic == '/aeropend/samples']
            for connection, _, raw in reader.messages(connections=connections):
                reader.deserialize(raw, connection.msgtype)
                count += 1
    except Exception:           # noqa: BLE001 - whatever stops the independent reader ends its count
        pass
    return count


def run_case(operator: str, seed: int, originals: dict, folder: Path) -> dict:
    need = NEEDS.get(operator, (True, 'zstd'))
    crcs = need[0]
    base, truth, n_samples, lay = originals[need]
    rng = random.Random(seed)
    damaged = OPERATORS[operator](base, lay, rng)
    path = folder / f'{operator}_{seed}.mcap'
    path.write_bytes(damaged)
    judged = judge_messages(damaged)
    if not crcs:
        judged = cdr_decodable(judged)
    judged_samples = sum(len(key[3]) > 16 for key in judged)          # JointState, not the 12-byte Float64
    result = {'operator': operator, 'seed': seed, 'judged': len(judged), 'judged_samples': judged_samples,
              'independent': independent_samples(path)}
    try:
        report = recover_bag(path)
        out = path.with_name(path.stem + '_recovered.mcap')
        result['independent_recovered'] = independent_samples(out if out.exists() else path)
        recovered = stream_messages(out) if out.exists() else stream_messages(path)
        result['recovered'] = len(recovered)
        result['missing'] = len(judged - recovered)
        if not crcs:    # a flip can garble a channel id: such a message has no schema and is left out, said so
            left_out = sum(c.messages or 0 for c in report.chunks if not c.kept and 'do not decode' in c.reason)
            result['left_out_reported'] = left_out
            result['missing'] = max(0, result['missing'] - left_out)
        result['invented'] = len(recovered - truth) if crcs else 0
        result['dropped_chunks'] = sum(not c.kept for c in report.chunks)
    except AeropendError as error:
        result['recover_error'] = str(error)
        result['missing'] = len(judged)
        result['invented'] = 0
    damage: list = []
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            samples = read_samples(path, damage=damage)
        findings = bag_findings(path, damage)
        partial = len(samples['sequence']) < n_samples
        result['read'] = len(samples['sequence'])
        result['skipped_reported'] = sum(d.damage.messages or 0 for d in damage
                                         if d.damage.kind in ('undecodable', 'stamp_out_of_order'))
        result['findings'] = len(findings)
        result['clean_on_partial'] = bool((partial or not crcs) and not findings)
    except AeropendError as error:          # refused (nothing readable): an error is not "clean"
        result['read_error'] = str(error)[:200]
        result['clean_on_partial'] = False
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            load_recording(path)
        result['refused'] = ''
    except AeropendError as error:
        result['refused'] = str(error)[:200]
    result['read_below_independent'] = result.get('read', 0) + result.get('skipped_reported', 0) \
        < result['independent']
    result['recovered_worse'] = result.get('independent_recovered', result['independent']) < result['independent']
    result['refused_decodable'] = bool(result['refused']) and judged_samples >= 0.9 * n_samples
    result['ok'] = (result['missing'] == 0 and result['invented'] == 0 and not result['clean_on_partial']
                    and 'recover_error' not in result or ('recover_error' in result and len(judged) == 0)) \
        and not result['read_below_independent'] and not result['recovered_worse'] and not result['refused_decodable']
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0], allow_abbrev=False)
    parser.add_argument('--per-operator', type=int, default=40, help='cases per operator')
    parser.add_argument('--samples', type=int, default=3000, help='samples in the original bag')
    parser.add_argument('--operators', nargs='*', default=sorted(OPERATORS), help='operators to run')
    parser.add_argument('--json', help='write the per-case results here')
    args = parser.parse_args(argv)
    started = time.perf_counter()
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        originals = {}
        from mcap.records import Message
        from mcap.stream_reader import StreamReader
        for need in {(True, 'zstd'), *NEEDS.values()}:
            crcs, compression = need
            path = write_sample_bag(folder / f'original_{crcs}_{compression}.mcap', args.samples, crcs=crcs,
                                    compression=compression)
            data = path.read_bytes()
            with open(path, 'rb') as stream:
                truth = message_keys(r for r in StreamReader(stream).records if isinstance(r, Message))
            originals[need] = (data, truth, args.samples, layout(data))
        first = originals[(True, 'zstd')]
        print(f'original: {len(first[3].chunks)} chunks, {len(first[1])} messages, {len(first[0])} bytes')
        for operator in args.operators:
            for seed in range(args.per_operator):
                case_dir = folder / f'{operator}_{seed}'
                case_dir.mkdir()
                results.append(run_case(operator, seed, originals, case_dir))
            mine = [r for r in results if r['operator'] == operator]
            print(f'{operator:>22}: {sum(r["ok"] for r in mine)}/{len(mine)} pass; judged '
                  f'{sum(r["judged"] for r in mine)} messages, recovered '
                  f'{sum(r.get("recovered", 0) for r in mine)}, missing {sum(r["missing"] for r in mine)}, '
                  f'clean on a partial read {sum(r["clean_on_partial"] for r in mine)}; samples read '
                  f'{sum(r.get("read", 0) for r in mine)} (+{sum(r.get("skipped_reported", 0) for r in mine)} '
                  f'skipped, reported) vs rosbags {sum(r["independent"] for r in mine)}, rosbags on the recovered '
                  f'{sum(r.get("independent_recovered", 0) for r in mine)}; refused '
                  f'{sum(bool(r["refused"]) for r in mine)} ({sum(r["refused_decodable"] for r in mine)} with '
                  '>= 90 % decodable)', flush=True)
    by_failure = defaultdict(list)
    for r in results:
        if not r['ok']:
            by_failure[r['operator']].append(r)
    summary = {'cases': len(results), 'operators': len(args.operators), 'passed': sum(r['ok'] for r in results),
               'missing_messages': sum(r['missing'] for r in results),
               'clean_on_partial_read': sum(r['clean_on_partial'] for r in results),
               'read_below_independent': sum(r['read_below_independent'] for r in results),
               'recovered_worse_for_rosbags': sum(r['recovered_worse'] for r in results),
               'refused_with_90_percent_decodable': sum(r['refused_decodable'] for r in results),
               'seconds': round(time.perf_counter() - started, 1),
               'failures': {k: v[:3] for k, v in by_failure.items()}}
    print(json.dumps(summary, indent=1, default=str))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=str))
    return 0 if summary['passed'] == summary['cases'] else 1


if __name__ == '__main__':
    sys.exit(main())
