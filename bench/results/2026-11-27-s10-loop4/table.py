"""The README's tables from the loop JSON files of this folder (bench/experiment_decide.py --part loop --measure).

    python bench/results/2026-11-27-s10-loop4/table.py
"""
from __future__ import annotations

import json
import math
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main() -> None:
    print('| truth | PSNR | seed | first record | loop verdict | result | runs | s played | need stated [s] '
          '| noise that decides [mrad] | predicted sep. (cautious / fitted) | measured noise-free | truth fits '
          'better | CPU s |')
    print('|' + '---|' * 14)
    for path in sorted(HERE.glob('loop_*.json')):
        data = json.loads(path.read_text())
        psnr = data['settings']['psnr']
        for row in data['rows']:
            truth = ', '.join(f'{k} {v * 1e3:g} ms' for k, v in row['truth'].items()) or 'clean'
            designed = [r for r in row['rounds'] if 'predicted_separation' in r]
            predicted = (f'{designed[0]["predicted_separation"]:.4f} / {designed[0]["predicted_separation_fitted"]:.4f}'
                         if designed else '')
            measured, better = '', ''
            for r in row['rounds']:
                m = r.get('measured_separation_unplayed') or r.get('measured_separation')
                if m:
                    free = m['noise_free']
                    measured = f'{free["separation"]:.4f}'
                    fitted = m['models'][free['better']]
                    better = 'yes' if set(fitted) == set(row['truth']) else 'no'
            need = row.get('needed_seconds')
            need = '' if row.get('loop_verdict') != 'cannot_decide_within_budget' else (
                'none (below floor)' if need is None or not math.isfinite(need) else f'{need:.0f}')
            noise = row.get('needed_noise_rms_rad')
            noise = f'{noise * 1e3:.2f}' if noise is not None and row.get('loop_verdict') == \
                'cannot_decide_within_budget' else ''
            print(f'| {truth} | {psnr:g} | {row["seed"]} | {row["first_verdict"]} | {row.get("loop_verdict")} | '
                  f'{row["result"]} | {row["runs"]} | {row["excitation_seconds"]:.0f} | {need} | {noise} | '
                  f'{predicted} | {measured} | {better} | {row["cpu_seconds"]:.0f} |')


if __name__ == '__main__':
    main()
