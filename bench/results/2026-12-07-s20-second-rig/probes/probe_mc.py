# ruff: noqa: E501, E702
"""Development probe of session 20 (bench/results/2026-12-07-s20-second-rig/README.md); run from the tree root."""
import sys
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[3]))
import numpy as np
import second_rig as sr
from threadpoolctl import threadpool_limits
from aeropend_core.diagnosis.compare import compare, prepare
from aeropend_core.io.recording import from_columns
from aeropend_core.testing import second_rig as g
kinds = sr._effects_of_kind()
seed, K = int(sys.argv[1]), int(sys.argv[2])
rng = np.random.default_rng(seed)
rig = g.draw_rig(rng); chosen = g.draw_effects(rng, rig, sr.drawn_effects(seed)); psnr = float(rng.uniform(30, 60))
duty = g.excitation(40.0, g.duty_cap(rig), rng, g.SAMPLE_RATE, 'mixed')
true = g.integrate(duty, rig, chosen, g.SAMPLE_RATE)
lumped = rig.lumped(chosen)
truth = {kinds[k][1]: v for k, v in lumped.items() if k in kinds}
truth.update({k: v for k, v in lumped.items() if k in sr.NOMINAL and k != 'armature_resistance'})
effects = sorted({kinds[k][0] for k in lumped if k in kinds})
print(seed, effects, f'{psnr:.1f} dB', flush=True)
est = {n: [] for n in truth}; sig = {n: [] for n in truth}
for r in range(K):
    measured = g.measure(true, chosen, psnr, np.random.default_rng(10_000 + r))
    rec = from_columns({'t': np.arange(duty.size) / g.SAMPLE_RATE, 'duty': duty, **measured}, source='mc')
    with threadpool_limits(1):
        f = compare(prepare(rec), effects).fit
    for n in truth:
        est[n].append(f.parameters[n]); sig[n].append(f.standard_errors[n])
    print(r, ' '.join(f'{n}={(f.parameters[n]-truth[n])/f.standard_errors[n]:+.1f}' for n in truth), flush=True)
for n in truth:
    e, s = np.array(est[n]), np.array(sig[n])
    print(f'{n:22s} truth {truth[n]:.5g} mean est {e.mean():.5g} (bias/median sd {(e.mean()-truth[n])/np.median(s):+.2f}) '
          f'spread sd {e.std(ddof=1):.3g} median reported sd {np.median(s):.3g} ratio {e.std(ddof=1)/np.median(s):.2f}')
