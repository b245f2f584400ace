"""Coverage of the second-rig rows split by what the record carries and by its noise level (session 20).

Run: .venv/bin/python bench/results/2026-12-07-s20-second-rig/split.py ROWS.jsonl [...]
"""
from __future__ import annotations

import json
import sys
from pathlib import Path


def share(rows: list[dict], name: str) -> str:
    zs = [r['z'][name] for r in rows if name in r.get('z', {})]
    if not zs:
        return '-'
    finite = [abs(v) for v in zs if v is not None]
    one = sum(v <= 1 for v in finite) / len(zs)
    two = sum(v <= 2 for v in finite) / len(zs)
    return f'{100 * one:.0f} % / {100 * two:.0f} % ({len(zs)})'


def main() -> None:
    rows = [json.loads(line) for path in sys.argv[1:] for line in Path(path).read_text().splitlines() if line]
    rows = [r for r in rows if not r.get('refused')]
    groups = {
        'effect-free': [r for r in rows if not r['true_effects']],
        'lag and filter both': [r for r in rows if {'thrust_lag', 'angle_filter'} <= set(r['true_effects'])],
        'dry friction': [r for r in rows if 'coulomb_friction' in r['true_effects']],
        'other effects': [r for r in rows if r['true_effects'] and 'coulomb_friction' not in r['true_effects']
                          and not {'thrust_lag', 'angle_filter'} <= set(r['true_effects'])],
        'PSNR < 40 dB': [r for r in rows if r['psnr_db'] < 40],
        'PSNR 40-50 dB': [r for r in rows if 40 <= r['psnr_db'] < 50],
        'PSNR >= 50 dB': [r for r in rows if r['psnr_db'] >= 50],
    }
    names = sorted({name for r in rows for name in r['z']})
    print('| parameter | ' + ' | '.join(f'{g} ({len(v)})' for g, v in groups.items()) + ' |')
    print('| --- ' * (len(groups) + 1) + '|')
    for name in names:
        print(f'| {name} | ' + ' | '.join(share(v, name) for v in groups.values()) + ' |')
    print()
    print('misses (abs z > 2): seed, PSNR, true effects, z')
    for r in rows:
        bad = {k: round(v, 1) for k, v in r['z'].items() if v is not None and abs(v) > 2}
        if bad:
            print(f'  {r["seed"]} {r["psnr_db"]} dB {",".join(r["true_effects"]) or "-"}: {bad}')


if __name__ == '__main__':
    main()
