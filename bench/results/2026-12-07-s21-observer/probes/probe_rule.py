# ruff: noqa: E501, E702
"""Session 21 probe: the data-only comparison of the observer's and the fallback's thrust-voltage errors
(observer: R x its current error beyond the noise; fallback: La dIa/dt = Va - R Ia - e in the observer's own
model, and R x the current's noise) on (1) second-rig 48047 with Va, Ia at several PSNRs and the angle at 44.8 dB,
(2) the own rig with a brush drop of `size` V at 40 dB (an observer that cannot write the motor). Run from the root."""
import sys
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[3]))
import numpy as np
import aeropend_core.diagnosis.compare as C
from aeropend_core.diagnosis.compare import prepare
from aeropend_core.io.recording import from_columns
from aeropend_core.signals import motor as M
captured = {}
orig = M.fit_motor
def spy(*a, **k):
    f = orig(*a, **k); captured['fit'] = f; captured['args'] = a; return f
C.fit_motor = spy

def stats(rec, label):
    prep = prepare(rec)
    f = captured['fit']; observed, current, steps, ts, switch = captured['args']
    x = np.array(f.solution)
    i_m, e_m = M._predict(f.kind, x, observed, ts, f.switch)
    r = f.parameters['motor_resistance']
    d = (observed - r * i_m - e_m)[2:]
    excess = np.sqrt(max(f.current_rms_error ** 2 - f.current_noise_rms ** 2, 0.0))
    print(f'{label}: kept {prep.motor is not None} kind {f.kind} err {f.current_rms_error*1e3:.2f} mA noise {f.current_noise_rms*1e3:.2f} mA | '
          f'observer R*excess {r*excess*1e3:.2f} mV, fallback La dI/dt {np.sqrt(np.mean(d**2))*1e3:.2f} mV, R*noise {r*f.current_noise_rms*1e3:.2f} mV', flush=True)

if sys.argv[1] == 'second':
    import second_rig as sr
    from aeropend_core.testing import second_rig as g
    seed = int(sys.argv[2])
    rng = np.random.default_rng(seed)
    rig = g.draw_rig(rng); chosen = g.draw_effects(rng, rig, sr.drawn_effects(seed)); psnr = float(rng.uniform(30, 60))
    duty = g.excitation(40.0, g.duty_cap(rig), rng, g.SAMPLE_RATE, 'mixed')
    true = g.integrate(duty, rig, chosen, g.SAMPLE_RATE)
    for db in map(float, sys.argv[3:]):
        noisy = g.measure(true, chosen, psnr, np.random.default_rng(10_000))
        quiet = g.measure(true, chosen, db, np.random.default_rng(5))
        m = {'angle': noisy['angle'], 'armature_voltage': quiet['armature_voltage'], 'armature_current': quiet['armature_current']}
        stats(from_columns({'t': np.arange(duty.size) / g.SAMPLE_RATE, 'duty': duty, **m}, source='x'), f'{seed} inputs {db} dB')
else:
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import simulate
    from aeropend_core.testing.motor_rigs import simulate_motor_effect
    effect, size, db = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
    duty = lhc_schedule(60.0, duty_range=(0.0, 0.7), duty_cap=0.7, seed=11).duty(duration=60.0)
    noise = MeasurementNoise(psnr_db=db, quantise=True)
    tr = simulate(duty, noise=noise, seed=12) if effect == 'none' else simulate_motor_effect(duty, effect, size, noise=noise, seed=12)
    stats(from_columns(tr.columns(with_truth=False), source='own'), f'own rig {effect} {size} at {db} dB')
