import sys, numpy as np
sys.path.insert(0, '/work/wt-sigma/bench')
import sigma_coverage as sc
from aeropend_core.diagnosis.compare import compare, prepare
import aeropend_core.sim.simulate as sm
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.io.recording import from_columns
seed = int(sys.argv[1]); psnr = float(sys.argv[2]); up = int(sys.argv[3])
cap = {}
orig = sm.simulate
def spy(duty, **k):
    cap['duty'] = duty; cap['k'] = dict(k); return orig(duty, **k)
sm.simulate = spy
rec, truth, row = sc.record(seed)
sm.simulate = orig
effects = () if row['effect'] == sc.CLEAN else (row['effect'],)
kk = dict(cap['k']); kk['noise'] = MeasurementNoise(psnr, psnr < 60)
duty = np.repeat(cap['duty'], up)
if up > 1: kk['sample_time'] = (1/490) / up
tr = orig(duty, **kk)
f = compare(prepare(from_columns(tr.columns(with_truth=False), source='x')), effects).fit
print(seed, 'psnr', psnr, 'x', up, ' '.join(f'{k}: rel={(f.parameters[k]/truth[k]-1)*100:+.3f}% sig={f.standard_errors[k]/abs(truth[k])*100:.3f}%' for k in truth if k in f.standard_errors and k!='armature_resistance'), flush=True)
