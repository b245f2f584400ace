"""The verbs' outputs before and after a refactoring, byte for byte (issue #44): ``aeropend diagnose`` (text and
``--json``) and ``aeropend identify`` (text and ``--json``) on small sample records, run from a given tree.

Usage (a tree other than the installed one is run with the venv's editable finder removed, so its own code runs):

    python bench/outputs_identical.py write FOLDER [--tree PATH] [--case NAME]   # each command's standard output
    python bench/outputs_identical.py compare EXPECTED ACTUAL          # byte comparison, one line per output

The one thing that changes between runs is masked on both sides before comparing: the diagnosis's wall-clock time
(the text's last line ``(12.3 s)`` and the JSON's ``"seconds"``); :func:`masked` says how.
"""
from __future__ import annotations

import argparse
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: name -> the verb's arguments (paths relative to the repository); the records are the repository's samples
CASES = {
    'diagnose_rig_log.txt': ['diagnose', 'samples/rig_log.csv', '--profile',
                             'config/profiles/arduino_logger.yaml', '--quiet'],
    'diagnose_rig_log.json': ['diagnose', 'samples/rig_log.csv', '--profile',
                             'config/profiles/arduino_logger.yaml', '--quiet', '--json', '-'],
    'diagnose_semicolon.txt': ['diagnose', 'samples/rig_log_semicolon.csv', '--profile',
                               'samples/rig_log_semicolon.yaml', '--quiet'],
    'diagnose_semicolon.json': ['diagnose', 'samples/rig_log_semicolon.csv', '--profile',
                                'samples/rig_log_semicolon.yaml', '--quiet', '--json', '-'],
    'diagnose_exercise.txt': ['diagnose', 'bags/exercise.csv', '--stop', '40', '--quiet'],
    'diagnose_exercise.json': ['diagnose', 'bags/exercise.csv', '--stop', '40', '--quiet', '--json', '-'],
    'identify_rig_log.txt': ['identify', 'samples/rig_log.csv', '--profile',
                             'config/profiles/arduino_logger.yaml', '--quiet'],
    'identify_rig_log.json': ['identify', 'samples/rig_log.csv', '--profile',
                             'config/profiles/arduino_logger.yaml', '--quiet', '--json', '-'],
    'identify_semicolon.txt': ['identify', 'samples/rig_log_semicolon.csv', '--profile',
                               'samples/rig_log_semicolon.yaml', '--quiet'],
    'identify_semicolon.json': ['identify', 'samples/rig_log_semicolon.csv', '--profile',
                                'samples/rig_log_semicolon.yaml', '--quiet', '--json', '-'],
    'identify_sample_sim.txt': ['identify', 'bags/sample_sim', '--quiet'],
    'identify_sample_sim.json': ['identify', 'bags/sample_sim', '--quiet', '--json', '-'],
    'identify_exercise.json': ['identify', 'bags/exercise.csv', '--quiet', '--json', '-'],
}

RUNNER = '''import sys
tree = sys.argv.pop(1)
sys.meta_path = [f for f in sys.meta_path if 'editable' not in repr(f).lower()]
sys.path.insert(0, tree)
import aeropend_core
assert aeropend_core.__file__.startswith(tree), aeropend_core.__file__
from aeropend_core.cli import main
sys.exit(main(sys.argv[1:]))
'''


def masked(text: str) -> str:
    """`text` with the diagnosis's wall-clock time [s] replaced by ``<seconds>``: the text's ``(12.3 s)`` line and
    the JSON's ``"seconds": 12.34``."""
    text = re.sub(r'^\(\d+(\.\d+)? s\)$', '(<seconds> s)', text, flags=re.M)
    return re.sub(r'"seconds": [0-9.eE+-]+', '"seconds": "<seconds>"', text)


def write(folder: Path, tree: Path, names: list[str]) -> int:
    folder.mkdir(parents=True, exist_ok=True)
    for name, args in CASES.items():
        if names and name not in names:
            continue
        started = time.perf_counter()
        result = subprocess.run([sys.executable, '-c', RUNNER, str(tree), *args], cwd=tree, capture_output=True,
                                text=True)
        (folder / name).write_text(masked(result.stdout), encoding='utf-8')
        print(f'{name}: exit {result.returncode}, {len(result.stdout)} characters, '
              f'{time.perf_counter() - started:.1f} s', flush=True)
        if result.returncode:
            print(result.stderr[-2000:], file=sys.stderr)
    return 0


def compare(expected: Path, actual: Path) -> int:
    different = 0
    for name in CASES:
        want, got = (expected / name).read_bytes(), (actual / name).read_bytes()
        same = want == got
        different += not same
        print(f'{name}: {"identical" if same else "DIFFERENT"} ({len(got)} bytes)')
    print(f'{len(CASES) - different} of {len(CASES)} identical')
    return 1 if different else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest='command', required=True)
    w = sub.add_parser('write')
    w.add_argument('folder', type=Path)
    w.add_argument('--tree', type=Path, default=ROOT)
    w.add_argument('--case', action='append', default=[], choices=sorted(CASES), help='only these (default: all)')
    c = sub.add_parser('compare')
    c.add_argument('expected', type=Path)
    c.add_argument('actual', type=Path)
    args = parser.parse_args()
    if args.command == 'write':
        return write(args.folder.resolve(), args.tree.resolve(), args.case)
    return compare(args.expected, args.actual)


if __name__ == '__main__':
    sys.exit(main())
