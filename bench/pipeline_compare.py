"""Compare two folders written by bench/pipeline_cases.sh: per case, whether the summary text and the JSON are
byte-identical (the elapsed time left out), the verdict, the catalog set, the error beyond the noise it leaves, the
proven motor term and the CPU seconds of each run.

Run:  python bench/pipeline_compare.py BEFORE AFTER [--json FILE]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _row(folder: Path, case: str) -> dict:
    data = json.loads((folder / f'{case}.json').read_text())
    cpu = sum(float(v) for v in (folder / f'{case}.time').read_text().split()[-2:])
    motor = [t['expression'] for t in data.get('discovered_motor_terms', [])]
    remaining = data.get('remaining_error_beyond_noise')
    return {'verdict': data['verdict'], 'set': [m['effect'] for m in data['missing_effects']],
            'beyond_noise_mrad': round(remaining * 1e3, 2) if remaining is not None else None,
            'noise_mrad': round(data['noise_rms'] * 1e3, 2), 'motor_terms': motor,
            'pendulum_terms': [t['expression'] for t in data.get('discovered_terms', [])], 'cpu_s': round(cpu, 2)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0], allow_abbrev=False)
    parser.add_argument('before')
    parser.add_argument('after')
    parser.add_argument('--json', help='write the rows to this file')
    args = parser.parse_args()
    before, after = Path(args.before), Path(args.after)
    rows = []
    for path in sorted(after.glob('*.json')):
        if path.name.endswith('.raw.json') or not (before / path.name).exists():
            continue
        case = path.stem
        same_json = (before / f'{case}.json').read_bytes() == path.read_bytes()
        same_text = (before / f'{case}.text').read_bytes() == (after / f'{case}.text').read_bytes()
        row = {'case': case, 'same_json': same_json, 'same_text': same_text,
               'before': _row(before, case), 'after': _row(after, case)}
        rows.append(row)
        b, a = row['before'], row['after']
        print(f"{case:12s} identical json={same_json!s:5s} text={same_text!s:5s}  {b['verdict']} {b['set']} "
              f"{b['beyond_noise_mrad']} mrad -> {a['verdict']} {a['set']} {a['beyond_noise_mrad']} mrad "
              f"(noise {a['noise_mrad']}; motor {a['motor_terms']}); CPU {b['cpu_s']} -> {a['cpu_s']} s")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
