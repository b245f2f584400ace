"""The diagnosis's answers with exact sensitivities (the default) and with forward-difference Jacobians (the method
before, ``AEROPEND_JACOBIAN=differences``) on the same records (issue 41: nothing about the answer changes).

Each record is simulated here (60 s, LHC duty steps, 40 dB PSNR, 10-bit quantisation, one hidden effect or none) and
diagnosed end to end by ``aeropend diagnose --json`` twice. Compared: the verdict and the effects named (must be
equal), every parameter of the final model and of each candidate (difference in units of the differenced fit's
1 sigma) and every 1 sigma (relative difference). Tolerances: a parameter within 0.01 sigma, a sigma within 1 %.

Run:  .venv/bin/python bench/jacobian_answers.py [--out FOLDER] [--json PATH]   (~1 min per record, idle)
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from _common import add_json_argument, figure, write_json

RECORDS = [('coulomb_friction=4', 1), ('thrust_lag=0.15', 2), ('dead_zone=0.6', 3), (None, 4), ('cable_torque=20', 5)]
CLI = 'import sys; from aeropend_core.cli import main; sys.exit(main())'
PARAMETER_TOLERANCE = 0.01      # [sigma]
SIGMA_TOLERANCE = 0.01          # [-] relative


def diagnose(path: Path, method: str) -> dict:
    env = {**os.environ, 'AEROPEND_JACOBIAN': method}
    out = path.with_suffix(f'.{method}.json')
    subprocess.run([sys.executable, '-c', CLI, 'diagnose', str(path), '--quiet', '--json', str(out)],
                   env=env, check=False, capture_output=True)
    return json.loads(out.read_text())


def fits(answer: dict) -> dict:
    """{label: (parameters, standard errors)} of the final model and of each candidate."""
    found = {'final': (answer.get('parameters', {}), answer.get('standard_errors', {}))}
    for candidate in answer.get('candidates', []):
        found[f"candidate {candidate.get('effect', candidate.get('name', '?'))}"] = (
            candidate.get('parameters', {}), candidate.get('standard_errors', {}))
    for effect in answer.get('missing_effects', []):
        found[f"missing {effect.get('effect', effect.get('name', '?'))}"] = (
            effect.get('parameters', {}), effect.get('standard_errors', {}))
    return found


def compare(exact: dict, differenced: dict) -> dict:
    worst_z, worst_sigma, where = 0.0, 0.0, {}
    a, b = fits(exact), fits(differenced)
    for label in b:
        if label not in a:
            continue
        values_a, sigmas_a = a[label]
        values_b, sigmas_b = b[label]
        for name, value in values_b.items():
            sigma = sigmas_b.get(name, math.nan)
            if name not in values_a or not (isinstance(sigma, float) and math.isfinite(sigma) and sigma > 0):
                continue
            z = abs(values_a[name] - value) / sigma
            if z > worst_z:
                worst_z, where['parameter'] = z, f'{label}: {name}'
            other = sigmas_a.get(name, math.nan)
            rel = abs(other - sigma) / sigma if isinstance(other, float) and math.isfinite(other) else math.inf
            if rel > worst_sigma:
                worst_sigma, where['sigma'] = rel, f'{label}: {name}'
    return {'verdict_same': exact.get('verdict') == differenced.get('verdict'),
            'named_same': exact.get('add') == differenced.get('add'),
            'worst_parameter_z': worst_z, 'worst_sigma_relative': worst_sigma, 'where': where,
            'verdict': exact.get('verdict'), 'add': exact.get('add'),
            'seconds': (exact.get('seconds'), differenced.get('seconds'))}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--out', type=Path, default=None, help='folder for the records and JSON (default: temp)')
    add_json_argument(parser)
    args = parser.parse_args()
    folder = args.out or Path(tempfile.mkdtemp(prefix='jacobian-answers-'))
    folder.mkdir(parents=True, exist_ok=True)
    rows, ok = [], True
    print('| hidden effect | seed | verdict (same?) | named (same?) | worst parameter move [sigma] | worst sigma change'
          ' | seconds exact / differences |')
    print('| --- | --- | --- | --- | --- | --- | --- |')
    for effect, seed in RECORDS:
        path = folder / f'record_{seed}.csv'
        command = [sys.executable, '-c', CLI, 'simulate', '--duration', '60', '--seed', str(seed),
                   '--psnr', '40', '--quantise', '--no-truth', '-o', str(path)]
        if effect:
            command += ['--effect', effect]
        subprocess.run(command, check=True, capture_output=True)
        result = compare(diagnose(path, 'exact'), diagnose(path, 'differences'))
        result.update(effect=effect or 'none', seed=seed)
        rows.append(result)
        good = (result['verdict_same'] and result['named_same'] and result['worst_parameter_z'] <= PARAMETER_TOLERANCE
                and result['worst_sigma_relative'] <= SIGMA_TOLERANCE)
        ok &= good
        print(f"| {result['effect']} | {seed} | {result['verdict']} ({result['verdict_same']}) | {result['add']} "
              f"({result['named_same']}) | {result['worst_parameter_z']:.2g} ({result['where'].get('parameter', '')}) "
              f"| {result['worst_sigma_relative']:.2g} ({result['where'].get('sigma', '')}) | "
              f"{result['seconds'][0]} / {result['seconds'][1]} |", flush=True)
    print(f'all within tolerance (parameters {PARAMETER_TOLERANCE} sigma, sigmas {SIGMA_TOLERANCE:.0%}): {ok}')
    worst_z = max(row['worst_parameter_z'] for row in rows)
    worst_sigma = max(row['worst_sigma_relative'] for row in rows)
    write_json(args.json, 'jacobian_answers', [
        figure('worst parameter move, exact vs differenced Jacobian', worst_z, 'sigma', target='<= 0.01',
               met=worst_z <= PARAMETER_TOLERANCE),
        figure('worst sigma change, exact vs differenced Jacobian', worst_sigma, '-', target='<= 0.01',
               met=worst_sigma <= SIGMA_TOLERANCE)], rows=rows, ok=ok)
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
