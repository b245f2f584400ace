import sys, numpy as np
from dataclasses import replace
sys.path.insert(0, '/work/wt-sigma/bench')
import sigma_coverage as sc
from aeropend_core.diagnosis.compare import compare, prepare
import aeropend_core.sim.simulate as sm
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.io.recording import from_columns
seed = int(sys.argv[1]); psnr = float(sys.argv[2])
cap = {}
orig = sm.simulate
def spy(duty, **k):
    cap['duty'] = duty; cap['k'] = dict(k); return orig(duty, **k)
sm.simulate = spy
rec, truth, row = sc.record(seed)
sm.simulate = orig
effects = () if row['effect'] == sc.CLEAN else (row['effect'],)
kk = dict(cap['k']); kk['noise'] = MeasurementNoise(psnr, False)
tr = orig(cap['duty'], **kk)
prep = prepare(from_columns(tr.columns(with_truth=False), source='x'))
n = len(prep.voltage)
emf = kk['parameters'].back_emf_constant * tr.truth['motor_speed'][:n]
err = prep.voltage - emf
print('observer', prep.motor.kind if prep.motor else None, 'emf err rms %.2e mean %.2e' % (np.sqrt(np.mean(err**2)), err.mean()))
# error right after steps vs elsewhere
st = prep.step_indices
near = np.zeros(n, bool)
for s in st: near[s:s+int(0.15/prep.sample_time)] = True
print(' err rms near steps %.2e elsewhere %.2e' % (np.sqrt(np.mean(err[near]**2)), np.sqrt(np.mean(err[~near]**2))))
# lag estimate: best shift of true emf matching the observer emf
for sh in (-3,-2,-1,0,1,2,3):
    a = prep.voltage[10:-10]; b = np.roll(emf, sh)[10:-10]
    print('  shift', sh, 'rms %.2e' % np.sqrt(np.mean((a-b)**2)))
f = compare(prep, effects).fit
print('fit', ' '.join(f'{k}: rel={(f.parameters[k]/truth[k]-1)*100:+.3f}% sig={f.standard_errors[k]/abs(truth[k])*100:.3f}%' for k in truth if k in f.standard_errors and k!='armature_resistance'))
