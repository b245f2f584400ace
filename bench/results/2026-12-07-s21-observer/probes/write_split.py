# ruff: noqa: E501, E702
"""Session 21: write second-rig seed SEED's record with the angle at its own PSNR and Va, Ia at INPUTS_DB (the s20
split-noise case) as an aeropend CSV, and print its truth. Run from the root:
.venv/bin/python bench/results/2026-12-07-s21-observer/probes/write_split.py 48047 70 /tmp/split_48047_70.csv"""
import sys
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[3]))
import numpy as np
import second_rig as sr
from aeropend_core.testing import second_rig as g
seed, inputs_db, path = int(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
rng = np.random.default_rng(seed)
rig = g.draw_rig(rng); chosen = g.draw_effects(rng, rig, sr.drawn_effects(seed)); psnr = float(rng.uniform(30, 60))
duty = g.excitation(40.0, g.duty_cap(rig), rng, g.SAMPLE_RATE, 'mixed')
true = g.integrate(duty, rig, chosen, g.SAMPLE_RATE)
noisy = g.measure(true, chosen, psnr, np.random.default_rng(10_000))
quiet = g.measure(true, chosen, inputs_db, np.random.default_rng(5))
cols = {'t': np.arange(duty.size) / g.SAMPLE_RATE, 'duty': duty, 'armature_voltage': quiet['armature_voltage'],
        'armature_current': quiet['armature_current'], 'angle': noisy['angle']}
names = ('t', 'duty', 'armature_voltage', 'armature_current', 'angle')
np.savetxt(path, np.column_stack([cols[n] for n in names]), delimiter=',', header=','.join(names), comments='', fmt='%.9g')
print(f'{path}: angle {psnr:.1f} dB, Va and Ia {inputs_db:g} dB; truth', {k: round(v, 5) for k, v in rig.lumped(chosen).items()})
