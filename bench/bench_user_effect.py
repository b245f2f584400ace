"""A user's effect module diagnoses as fast as the same built-in term (target: within 2x of ``--term``).

docs/discovery.md's worked example, as a user runs it (each command a fresh process: import, numba cache load and
the user function's compilation included): a 60 s record with a propeller-inflow loss that is not in the catalog,
diagnosed with the discovered term given as ``--term 'thrust*angular_rate'`` (the baseline, measured in the same
run) and as the module ``aeropend effects --write-discovered`` writes, ``--effects-module kept.py --add
discovered_thrust_rate``. Times are the child's CPU (user + system; the wall time on a shared machine is also
printed) and the two diagnoses' numbers must be the same.

Also the output-error kernel alone: the built-in quadratic_drag against the same law written as a user's effect
(called through a function pointer, not inlined).

Run:  .venv/bin/python bench/bench_user_effect.py [--duration 60] [--json PATH]   (~1 min of CPU)
"""
import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import add_json_argument, figure, write_json

MODULE = '''from aeropend_core.model.effects import EffectParameter, register_effect
loss = EffectParameter('inflow_loss', 's/rad', 'thrust lost per unit rod rate', 0.05, 0.0, 1.0)
@register_effect('inflow', 'thrust falls as the rod moves through the propeller inflow', parameters=[loss])
def inflow(angle, angular_rate, inflow_loss, thrust): return -inflow_loss * thrust * angular_rate
'''


def aeropend(*argv: str, cwd: Path) -> tuple[str, float, float]:
    """Run ``aeropend ARGV`` in a fresh process: (standard output, CPU seconds, wall seconds)."""
    code = 'import sys; from aeropend_core.cli import main; sys.exit(main())'
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run([sys.executable, '-c', code, *argv], cwd=cwd, capture_output=True, text=True,
                          env={**os.environ, 'PYTHONPATH': str(Path(__file__).resolve().parents[1])}, check=False)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f'aeropend {" ".join(argv)} failed: {done.stderr.strip()}')
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return done.stdout, cpu, wall


def kernel_times(repeats: int = 7) -> tuple[float, float]:
    """Process CPU [s] of one output-error simulation (best of `repeats`; 16 parameter rows x 30,000 samples in 10
    segments) with the built-in quadratic_drag and with the same law written as a user's effect."""
    import numpy as np

    from aeropend_core.diagnosis import output_error
    from aeropend_core.model.effects import EffectParameter, register_effect

    @register_effect('bench_user_drag', 'drag written by a user', replace=True,
                     parameters=[EffectParameter('bench_user_drag_coefficient', '1/rad', 'Cd', 4.0, 0.0, 100.0)])
    def drag(angle, angular_rate, bench_user_drag_coefficient):
        return -bench_user_drag_coefficient * angular_rate * np.abs(angular_rate)

    rng = np.random.default_rng(1)
    n = 30000
    voltage = np.repeat(rng.uniform(0.5, 2.0, n // 300), 300)
    data = output_error.SegmentedData(voltage, 0.2 * voltage, np.zeros(n), [(i, i + 3000) for i in range(0, n, 3000)],
                                      1 / 490)
    nominal = {'gravity_stiffness': 130.0, 'damping': 1.5, 'thrust_gain': 20.0, 'armature_resistance': 1.0}
    times = []
    for effect, parameter in (('quadratic_drag', 'drag_coefficient'),
                              ('bench_user_drag', 'bench_user_drag_coefficient')):
        structure = output_error.Structure((effect,))
        rows = np.array([structure.row({**nominal, parameter: 4.0}) * (1 + 0.001 * k) for k in range(16)])
        initial = np.zeros((16, 10, 2))
        data.simulate(structure, rows, initial)                 # compile / load the cache
        best = float('inf')
        for _ in range(repeats):
            start = time.process_time()
            data.simulate(structure, rows, initial)
            best = min(best, time.process_time() - start)
        times.append(best)
    return times[0], times[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--duration', type=float, default=60.0)
    add_json_argument(parser)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        cwd = Path(folder)
        (cwd / 'outside.py').write_text(MODULE)
        aeropend('simulate', '-o', 'inflow.csv', '--duration', f'{args.duration:g}', '--seed', '11', '--psnr', '40',
                 '--quantise', '--effects-module', 'outside.py', '--effect', 'inflow=0.05', '--no-truth', '--quiet',
                 cwd=cwd)
        aeropend('effects', '--write-discovered', 'kept.py', '--term', 'thrust*angular_rate', cwd=cwd)
        common = ('diagnose', 'inflow.csv', '--no-drift', '--quiet')
        term, term_cpu, term_wall = aeropend(*common, '--term', 'thrust*angular_rate', cwd=cwd)
        module, module_cpu, module_wall = aeropend(*common, '--effects-module', 'kept.py', '--add',
                                                   'discovered_thrust_rate', cwd=cwd)

    def numbers(text):      # the summary's lines with numbers, the model's name aside
        return [line for line in text.splitlines() if 'mrad' in line and not line.startswith('Model')]
    same = numbers(term) == numbers(module)
    ratio = module_cpu / term_cpu
    print(f'{args.duration:g} s record, diagnose with the discovered term:')
    print(f"  --term 'thrust*angular_rate' (baseline)           {term_cpu:6.1f} s CPU ({term_wall:.1f} s wall)")
    print(f'  --effects-module kept.py --add discovered_...     {module_cpu:6.1f} s CPU ({module_wall:.1f} s wall)')
    print(f'  ratio {ratio:.2f} (target <= 2: {"met" if ratio <= 2 else "NOT met"}); same numbers: {same}')
    builtin, user = kernel_times()
    print(f'kernel, 16 rows x 30000 samples: built-in quadratic_drag {builtin:.4f} s, the same law as a user effect '
          f'{user:.4f} s CPU (ratio {user / builtin:.2f})')
    write_json(args.json, 'bench_user_effect', [
        figure('output-error simulation CPU time, drag as a user effect', user, 's', baseline=builtin,
               baseline_name='the built-in quadratic_drag, same rows and data', ratio_meaning='user / built-in'),
        figure(f'diagnosis CPU time with a written effect module, {args.duration:g} s record', module_cpu, 's',
               baseline=term_cpu, baseline_name="the same term as --term 'thrust*angular_rate'", ratio=ratio,
               ratio_meaning='module / --term', target='ratio <= 2', met=ratio <= 2),
    ], duration_s=args.duration, same_numbers=same, wall_term_s=term_wall, wall_module_s=module_wall)


if __name__ == '__main__':
    main()
