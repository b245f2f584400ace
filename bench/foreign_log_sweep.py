"""Sweep of random foreign logs through `aeropend import`, `identify` and `diagnose` (issue #21 item 6).

Each variant (aeropend_core.testing.foreign_logs.random_spec: 20-49 Hz, current read inside the PWM pulse, the
period average, or none; encoder counts, degrees or radians; duty register or %; host date-time stamps with
buffering, device millis() or no time column; one hidden effect or none) is written as a log with its profile,
imported, then identified and diagnosed (in-process CLI calls, so exits and messages are what a user sees).

Counted per step: exit 0, a refusal (exit 2, one line), an internal error (exit 1: a bug; must be 0), and an
impossible number shown plain: a parameter outside its physical range (gravity_stiffness <= 0 or > 1e4 1/s^2,
damping < 0, thrust_gain <= 0, armature_resistance <= 0 or > 100 ohm) printed with no warning line on the same
output that names it; one printed under a general warning about every number only (identify's low-rate warning)
is counted apart. Results (counts and each variant's outcome) go to --out as JSON.

Usage (two halves, one per core):
  nice -n 10 python bench/foreign_log_sweep.py --variants 100 --first 0 \
      --out bench/results/2026-11-27-rates/foreign_logs_0.json   (and --first 100 ... foreign_logs_1.json)
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

import yaml

from aeropend_core.cli import main as cli
from aeropend_core.testing.foreign_logs import generate, random_spec

#: Candidates the diagnosis tries (two of the catalog: the sweep is about completing honestly, not about ranking).
DIAGNOSE_CANDIDATES = ['--only', 'coulomb_friction', '--only', 'angle_offset']
#: parameter -> (lowest, highest) physically possible value [SI]
PHYSICAL_RANGE = {'gravity_stiffness': (0.0, 1e4), 'damping': (0.0, 1e3), 'thrust_gain': (0.0, 1e5),
                  'armature_resistance': (0.0, 100.0)}


def run(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            status = cli(argv)
        except SystemExit as stop:          # argparse
            status = int(stop.code or 0)
    return status, out.getvalue(), err.getvalue()


def impossible_plain(parameters: dict, text: str) -> list[str]:
    """Parameters outside PHYSICAL_RANGE with no line of `text` that names them next to a warning word (a general
    warning about every number, e.g. identify's low-rate one, is counted apart: :func:`general_warning`)."""
    bad = []
    for name, (low, high) in PHYSICAL_RANGE.items():
        value = parameters.get(name)
        if value is None or not isinstance(value, (int, float)):
            continue
        if not (low < value <= high):
            warned = any(name in line and any(w in line.lower() for w in ('warning', 'impossible', 'outside',
                                                                          'not physical', 'does not fit'))
                         for line in text.splitlines())
            if not warned:
                bad.append(f'{name}={value:.4g}')
    return bad


def general_warning(text: str) -> bool:
    """True when `text` carries a warning about every number it shows (identify's low-rate warning)."""
    return 'Warning (about every number above)' in text


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--variants', type=int, default=200)
    parser.add_argument('--first', type=int, default=0)
    parser.add_argument('--out', default='-')
    options = parser.parse_args()
    outcomes = []
    counts = {step: {'ok': 0, 'refused': 0, 'internal_error': 0, 'impossible_plain': 0,
                     'impossible_under_general_warning_only': 0}
              for step in ('import', 'identify', 'diagnose')}
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as folder:
        for seed in range(options.first, options.first + options.variants):
            spec = random_spec(seed, duration=(21.0, 27.0))     # diagnose needs 20 s
            log = generate(spec)
            log_path, profile_path, record = (Path(folder) / f'{seed}.log.csv', Path(folder) / f'{seed}.yaml',
                                              Path(folder) / f'{seed}.csv')
            log_path.write_text(log.text)
            profile_path.write_text(yaml.safe_dump(log.profile))
            outcome = {'seed': seed, 'rate_hz': round(spec.rate, 3), 'current': spec.current, 'angle': spec.angle,
                       'stamps': spec.stamps, 'effects': spec.effects}
            status, _, err = run(['import', str(log_path), '--profile', str(profile_path), '-o', str(record)])
            steps = [('import', status, err, {})]
            if status == 0:
                for verb, extra in (('identify', []), ('diagnose', ['--no-drift', '--quiet', *DIAGNOSE_CANDIDATES])):
                    json_path = Path(folder) / f'{seed}.{verb}.json'
                    status, text, err = run([verb, str(record), '--json', str(json_path), *extra])
                    try:
                        parameters = json.loads(json_path.read_text()).get('parameters', {}) if status == 0 else {}
                    except (OSError, json.JSONDecodeError):
                        parameters = {}
                    steps.append((verb, status, err + text, parameters))
            for verb, status, text, parameters in steps:
                kind = {0: 'ok', 2: 'refused'}.get(status, 'internal_error')
                counts[verb][kind] += 1
                plain = impossible_plain(parameters, text) if status == 0 else []
                general = bool(plain) and general_warning(text)
                counts[verb]['impossible_plain'] += bool(plain) and not general
                counts[verb]['impossible_under_general_warning_only'] += general
                outcome[verb] = {'exit': status, 'impossible_plain': plain, 'general_warning': general,
                                 'message': text.strip().splitlines()[-1][:300] if status and text.strip() else ''}
            outcomes.append(outcome)
            if options.out != '-':         # written after every variant: a stopped sweep keeps what it did
                Path(options.out).parent.mkdir(parents=True, exist_ok=True)
                Path(options.out).write_text(json.dumps({'variants_done': len(outcomes), 'counts': counts,
                                                         'outcomes': outcomes}, indent=1, default=str))
            print(f'{seed}: ' + ' '.join(f'{v}={outcome.get(v, {}).get("exit", "-")}' for v in
                                         ('import', 'identify', 'diagnose')), file=sys.stderr, flush=True)
    result = {'variants': options.variants, 'seconds': round(time.perf_counter() - started, 1), 'counts': counts,
              'outcomes': outcomes}
    text = json.dumps(result, indent=1, default=str)
    if options.out == '-':
        print(text)
    else:
        Path(options.out).parent.mkdir(parents=True, exist_ok=True)
        Path(options.out).write_text(text)
    print(json.dumps(counts), file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
