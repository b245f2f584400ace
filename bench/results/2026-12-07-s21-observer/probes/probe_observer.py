# ruff: noqa: E501, E702
"""Session 21 probe: the motor observer on second-rig seed 48047 with the angle at its own PSNR and Va, Ia at
`inputs_db` (the s20 split-noise case). Prints the observer's current error against the measured and the true
current, the noise estimate, and the thrust-voltage error of the observer and of the fallback Va - R Ia against the
true back-EMF. Run from the tree root: .venv/bin/python bench/results/2026-12-07-s21-observer/probes/probe_observer.py 48047 70"""
import sys
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[3]))
import numpy as np
import second_rig as sr
from aeropend_core.diagnosis.compare import prepare
from aeropend_core.io.recording import from_columns
from aeropend_core.signals import motor as M
from aeropend_core.signals.preprocess import noise_rms
from aeropend_core.testing import second_rig as g

seed = int(sys.argv[1])
rng = np.random.default_rng(seed)
rig = g.draw_rig(rng); chosen = g.draw_effects(rng, rig, sr.drawn_effects(seed)); psnr = float(rng.uniform(30, 60))
duty = g.excitation(40.0, g.duty_cap(rig), rng, g.SAMPLE_RATE, 'mixed')
true = g.integrate(duty, rig, chosen, g.SAMPLE_RATE)
e_true = rig.back_emf_constant * true['motor_speed']
print('seed', seed, 'angle psnr', round(psnr, 1), 'Ra', rig.armature_resistance, 'La/Ra', rig.armature_inductance / rig.armature_resistance)
orig = M.fit_motor
captured = {}
def spy(*a, **k):
    f = orig(*a, **k); captured['fit'] = f; captured['args'] = a; return f
import aeropend_core.diagnosis.compare as C
C.fit_motor = spy
for inputs_db in map(float, sys.argv[2:]):
    noisy = g.measure(true, chosen, psnr, np.random.default_rng(10_000))
    quiet = g.measure(true, chosen, inputs_db, np.random.default_rng(5))
    m = {'angle': noisy['angle'], 'armature_voltage': quiet['armature_voltage'], 'armature_current': quiet['armature_current']}
    prep = prepare(from_columns({'t': np.arange(duty.size) / g.SAMPLE_RATE, 'duty': duty, **m}, source='x'))
    f = captured['fit']; observed, current, steps, ts, switch = captured['args']
    keep = M._fitted_samples(f.kind, current.size, steps, ts) & M._fitted_samples('quasi_static', current.size, steps, ts)
    model_i, model_e = M._predict(f.kind, np.array(f.solution), observed, ts, f.switch)
    it = true['armature_current']
    print(f'inputs {inputs_db} dB: kept {prep.motor is not None} kind {f.kind} err {f.current_rms_error*1e3:.3f} mA noise {f.current_noise_rms*1e3:.3f} mA '
          f'(1.5x+0.1 = {1.5e3*f.current_noise_rms+0.1:.3f}); vs true current {np.sqrt(np.mean((model_i-it)[keep]**2))*1e3:.3f} mA; '
          f'meas-true {np.sqrt(np.mean((current-it)[keep]**2))*1e3:.3f} mA; noise_rms(true I) {noise_rms(it)*1e3:.3f}')
    print('   params', {k: round(v, 5) for k, v in f.parameters.items()}, 'true R', round(rig.armature_resistance, 5), 'tau_e', round(rig.armature_inductance/rig.armature_resistance, 5))
    va = quiet['armature_voltage']
    fallback = va - rig.armature_resistance * current
    seg = np.arange(current.size) >= 245
    for name, e in (('observer', model_e), ('fallback Va-Ra Ia (true Ra)', fallback)):
        d = (e - e_true)[seg]
        # slow part (what the pendulum sees): 0.1 s moving average
        w = 49; slow = np.convolve(d, np.ones(w) / w, 'same')
        print(f'   {name:28s} thrust-voltage error rms {np.sqrt(np.mean(d**2))*1e3:.2f} mV, slow part {np.sqrt(np.mean(slow**2))*1e3:.2f} mV, mean {d.mean()*1e3:+.2f} mV; e swing {np.ptp(e_true):.3f} V')
    # where the observer's current error sits: steps vs chirp, by time blocks of 2 s
    r = (model_i - current)
    blocks = [f'{np.sqrt(np.mean(r[a:a+980][keep[a:a+980]]**2))*1e3:.1f}' for a in range(0, r.size, 980)]
    print('   observer current error by 2 s block [mA]:', ' '.join(blocks))
    d = (model_i - it)
    print('   vs true by 2 s block [mA]:             ', ' '.join(f'{np.sqrt(np.mean(d[a:a+980][keep[a:a+980]]**2))*1e3:.1f}' for a in range(0, d.size, 980)))
    print('   duty std by block:', ' '.join(f'{np.std(np.diff(duty[a:a+980])!=0):.2f}' for a in range(0, d.size, 980)))
