"""Start-up imports only what a verb uses: `aeropend --help` and the refusal of a bad argument by any verb import
none of scipy, numba, rclpy or the diagnosis stack (issue 41: they cost seconds before a one-line answer).

Checked by which modules a fresh interpreter holds after the command (no wall-clock assertion: the time is measured
in bench/bench_speed.py). Each command runs in its own process, as a user's would.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Packages whose import a refusal must not pay for (scipy.signal alone took ~1.5 s, numba ~0.3 s, rclpy ~1 s).
HEAVY = ('scipy', 'numba', 'rclpy', 'aeropend_core.diagnosis.compare', 'aeropend_core.diagnosis.output_error',
         'aeropend_core.diagnosis.diagnose')

DRIVER = '''
import json, sys
from aeropend_core.cli import main
try:
    status = main(sys.argv[1:])
except SystemExit as exit_:
    status = exit_.code
heavy = sorted(m for m in sys.modules if any(m == h or m.startswith(h + '.') for h in %r))
print(json.dumps({'status': status, 'heavy': heavy}), file=sys.stderr)
''' % (HEAVY,)

#: (command line, a word of the answer that shows it was refused for that reason; None: help, exit 0)
COMMANDS = [
    (['--help'], None),
    (['diagnose', 'run.csv', '--efect', 'thrust_lag'], 'unrecognized option --efect'),
    (['diagnose', 'missing.csv'], 'no such file'),
    (['diagnose', 'missing.csv', '--add', 'no_such_effect'], "unknown effect 'no_such_effect'"),
    (['simulate', '--duration', '-1', '-o', 'never.csv'], '--duration'),
    (['identify', 'missing.csv'], 'no such file'),
    (['run', '--effect', 'no_such_effect=1'], "unknown effect 'no_such_effect'"),
    (['run', '--duration', '5'], 'too short'),
    (['run', '--controller', 'missing.yaml'], 'missing.yaml'),
    (['control', 'design', '--at', '400deg', '-o', 'never.yaml'], '410 deg'),
    (['control', 'check', 'missing'], 'missing'),
]


@pytest.mark.parametrize('argv, refusal', COMMANDS, ids=[' '.join(c) for c, _ in COMMANDS])
def test_help_and_refusals_import_no_heavy_stack(argv, refusal, tmp_path):
    # as a user's shell: no thread-count variables (the tests' conftest sets them; aeropend_core.blas then does less)
    env = {k: v for k, v in os.environ.items() if k not in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS',
                                                            'MKL_NUM_THREADS', 'BLIS_NUM_THREADS')}
    result = subprocess.run([sys.executable, '-c', DRIVER, *argv], capture_output=True, text=True, cwd=tmp_path,
                            env=env, timeout=120, check=False)
    report = json.loads(result.stderr.strip().splitlines()[-1])
    if refusal is None:
        assert report['status'] in (0, None), result.stderr
    else:
        assert report['status'] == 2, result.stderr
        assert refusal in result.stderr, result.stderr
    assert report['heavy'] == [], f'{" ".join(argv)} imported {report["heavy"]}'
