import sys, numpy as np
sys.path.insert(0, '/work/wt-sigma/bench')
import sigma_coverage as sc
import aeropend_core.sim.simulate as sm
from aeropend_core.io.recording import from_columns
from aeropend_core.diagnosis.compare import prepare
from aeropend_core.signals.preprocess import noise_rms
seed = int(sys.argv[1])
cap = {}
orig = sm.simulate
def spy(duty, **k):
    cap['duty'] = duty; cap['k'] = dict(k); return orig(duty, **k)
sm.simulate = spy
sc.record(seed)
sm.simulate = orig
zv, ze, zeb = [], [], []
for ns in range(int(sys.argv[2])):
    kk = dict(cap['k']); kk['seed'] = seed + 1 + 1000 * ns
    tr = orig(cap['duty'], **kk)
    prep = prepare(from_columns(tr.columns(with_truth=False), source='x'))
    n = len(prep.voltage)
    st = prep.step_indices
    bounds = np.concatenate(([0], st, [n]))
    va_true = tr.truth['armature_voltage'][:n]
    emf_true = kk['parameters'].back_emf_constant * tr.truth['motor_speed'][:n]
    sig = noise_rms(prep.armature_voltage)
    ens = prep.voltage_ensemble.astype(float)
    for a, b in zip(bounds[:-1], bounds[1:]):
        if b - a < 200: continue
        ls = 1.2533 * sig / np.sqrt(b - a)
        zv.append((prep.gate_voltage[a] - np.median(va_true[a:b])) / ls)
        m = slice(a + (b - a)//2, b)   # second half: near steady state
        e_err = np.mean(prep.voltage[m] - emf_true[m])
        e_sd = np.sqrt(np.mean(np.mean(ens[:, m], axis=1)**2))
        ze.append(e_err / e_sd)
print('Va level z: n', len(zv), 'sd %.2f mean %.2f' % (np.std(zv), np.mean(zv)))
print('emf level err / ensemble sd: n', len(ze), 'rms %.2f mean %.2f' % (np.sqrt(np.mean(np.square(ze))), np.mean(ze)))
