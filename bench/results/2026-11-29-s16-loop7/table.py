"""Markdown table of the loop runs in this folder: python bench/results/2026-11-29-s16-loop7/table.py"""
import json
import math
from pathlib import Path

HERE = Path(__file__).resolve().parent
print('| truth | PSNR dB | budget | seed | first record | loop result | runs | s played | estimate +- sigma | '
      '(estimate - truth) / sigma | CPU s |')
print('|---|---|---|---|---|---|---|---|---|---|---|')
for path in sorted(HERE.glob('loop_*.json')):
    data = json.loads(path.read_text())
    psnr = f"{data['settings']['psnr']:g}" + (' (no ADC)' if data['settings'].get('no_quantise') else '')
    budget = f"{data['settings']['max_runs']} runs, {data['settings']['max_seconds']:g} s"
    for row in data['rows']:
        truth = row['truth']
        name, size = next(iter(truth.items())) if truth else ('clean', math.nan)
        sizes = row['rounds'][-1].get('sizes', {}) if row['rounds'] else {}
        estimate = ''
        z = ''
        for effect, parameters in sizes.items():
            for parameter, (value, sigma) in parameters.items():
                estimate += f'{effect} {value * 1e3:.2f} +- {sigma * 1e3:.2f} ms ' if parameter in (
                    'time_constant', 'filter_delay') else f'{effect} {parameter} {value:.4g} +- {sigma:.2g} '
                if effect == name and sigma > 0:
                    z = f'{(value - size) / sigma:+.2f}'
        label = ('clean' if not truth else f'{name} {size * 1e3:.0f} ms' if name in ('thrust_lag', 'angle_filter')
                 else f'{name} {size:g}')
        result = 'missed' if row['result'] == 'wrong' and row['final_verdict'] == 'nothing_missing' else row['result']
        print(f'| {label} | {psnr} | {budget} | {row["seed"]} | {row["first_verdict"]} | {result} | '
              f'{row["runs"]} | '
              f'{row["excitation_seconds"]:.0f} | {estimate.strip() or "-"} | {z or "-"} | {row["cpu_seconds"]:.0f} |')
