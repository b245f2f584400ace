# ruff: noqa: E501, E702
"""Development probe of session 20 (bench/results/2026-12-07-s20-second-rig/README.md); run from the tree root."""
import sys
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[3]))
import numpy as np
import second_rig as sr
from aeropend_core.diagnosis.compare import prepare
from aeropend_core.io.recording import from_columns
from aeropend_core.testing import second_rig as g
seed = int(sys.argv[1])
rng = np.random.default_rng(seed)
rig = g.draw_rig(rng); chosen = g.draw_effects(rng, rig, sr.drawn_effects(seed)); psnr = float(rng.uniform(30, 60))
duty = g.excitation(40.0, g.duty_cap(rig), rng, g.SAMPLE_RATE, 'mixed')
true = g.integrate(duty, rig, chosen, g.SAMPLE_RATE)
for inputs_db in map(float, sys.argv[2:]):
    noisy = g.measure(true, chosen, psnr, np.random.default_rng(10_000))
    quiet = g.measure(true, chosen, inputs_db, np.random.default_rng(5))
    m = {'angle': noisy['angle'], 'armature_voltage': quiet['armature_voltage'], 'armature_current': quiet['armature_current']}
    prep = prepare(from_columns({'t': np.arange(duty.size) / g.SAMPLE_RATE, 'duty': duty, **m}, source='x'))
    print(inputs_db, 'motor observer:', prep.motor is not None, 'reduced', prep.reduced,
          {k: getattr(prep, k) for k in ('thrust_source',) if hasattr(prep, k)}, flush=True)
    if prep.motor is not None:
        print('   ', {k: v for k, v in vars(prep.motor).items() if isinstance(v, (int, float, str, bool))})
