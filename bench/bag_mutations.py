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

Usage::

    nice -n 10 .venv/bin/python bench/bag_mutations.py --per-operator 40        # 14 operators: 560 bags

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
from aeropend_core.io.recording import bag_findings  # noqa: E402
from aeropend_core.testing.bag_mutations import (  # noqa: E402
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


def run_case(operator: str, seed: int, originals: dict, folder: Path) -> dict:
    crcs = operator != 'no_crc_flip'
    base, truth, n_samples, lay = originals[crcs]
    rng = random.Random(seed)
    damaged = OPERATORS[operator](base, lay, rng)
    path = folder / f'{operator}_{seed}.mcap'
    path.write_bytes(damaged)
    judged = judge_messages(damaged)
    result = {'operator': operator, 'seed': seed, 'judged': len(judged)}
    try:
        report = recover_bag(path)
        out = path.with_name(path.stem + '_recovered.mcap')
        recovered = stream_messages(out) if out.exists() else stream_messages(path)
        result['recovered'] = len(recovered)
        result['missing'] = len(judged - recovered)
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
        result['findings'] = len(findings)
        result['clean_on_partial'] = bool((partial or not crcs) and not findings)
    except AeropendError as error:          # refused (nothing readable): an error is not "clean"
        result['read_error'] = str(error)[:200]
        result['clean_on_partial'] = False
    result['ok'] = result['missing'] == 0 and result['invented'] == 0 and not result['clean_on_partial'] \
        and 'recover_error' not in result or ('recover_error' in result and len(judged) == 0)
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
        for crcs in (True, False):
            path = write_sample_bag(folder / f'original_{crcs}.mcap', args.samples, crcs=crcs)
            data = path.read_bytes()
            with open(path, 'rb') as stream:
                truth = message_keys(r for r in StreamReader(stream).records if isinstance(r, Message))
            originals[crcs] = (data, truth, args.samples, layout(data))
        print(f'original: {len(originals[True][3].chunks)} chunks, {len(originals[True][1])} messages, '
              f'{len(originals[True][0])} bytes')
        for operator in args.operators:
            for seed in range(args.per_operator):
                case_dir = folder / f'{operator}_{seed}'
                case_dir.mkdir()
                results.append(run_case(operator, seed, originals, case_dir))
            mine = [r for r in results if r['operator'] == operator]
            print(f'{operator:>20}: {sum(r["ok"] for r in mine)}/{len(mine)} pass; judged '
                  f'{sum(r["judged"] for r in mine)} messages, recovered '
                  f'{sum(r.get("recovered", 0) for r in mine)}, missing {sum(r["missing"] for r in mine)}, '
                  f'clean on a partial read {sum(r["clean_on_partial"] for r in mine)}', flush=True)
    by_failure = defaultdict(list)
    for r in results:
        if not r['ok']:
            by_failure[r['operator']].append(r)
    summary = {'cases': len(results), 'operators': len(args.operators), 'passed': sum(r['ok'] for r in results),
               'missing_messages': sum(r['missing'] for r in results),
               'clean_on_partial_read': sum(r['clean_on_partial'] for r in results),
               'seconds': round(time.perf_counter() - started, 1),
               'failures': {k: v[:3] for k, v in by_failure.items()}}
    print(json.dumps(summary, indent=1, default=str))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=str))
    return 0 if summary['passed'] == summary['cases'] else 1


if __name__ == '__main__':
    sys.exit(main())
