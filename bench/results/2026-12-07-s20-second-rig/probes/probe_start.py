# ruff: noqa: E501, E702
"""Development probe of session 20 (bench/results/2026-12-07-s20-second-rig/README.md); run from the tree root."""
import sys
import math
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[3]))
import second_rig as sr
from threadpoolctl import threadpool_limits
from aeropend_core.diagnosis.compare import compare, prepare
kinds = sr._effects_of_kind()
for seed in map(int, sys.argv[1:]):
    rec, rig = sr.record(seed)
    effects = sorted({kinds[k][0] for k in rig.truth if k in kinds})
    truth = {kinds[k][1]: v for k, v in rig.truth.items() if k in kinds}
    truth.update({k: v for k, v in rig.truth.items() if k in sr.NOMINAL and k != 'armature_resistance'})
    with threadpool_limits(1):
        prep = prepare(rec)
        a = compare(prep, effects).fit
        b = compare(prep, effects, start=truth).fit
    d = a.effective_samples * math.log(b.residual_rms ** 2 / a.residual_rms ** 2)
    print(seed, f'default rms {a.residual_rms:.5e}  from-truth rms {b.residual_rms:.5e}  dchi2(b-a) {d:+.2f}')
    for n, v in truth.items():
        print(f'   {n:22s} truth {v:.5g} default {a.parameters[n]:.5g} z {(a.parameters[n]-v)/a.standard_errors[n]:+.1f}'
              f' | from truth {b.parameters[n]:.5g} z {(b.parameters[n]-v)/b.standard_errors[n]:+.1f}', flush=True)
