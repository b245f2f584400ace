import sys, numpy as np, json
from dataclasses import replace
sys.path.insert(0, '/work/wt-sigma/bench')
import sigma_coverage as sc
from aeropend_core.diagnosis.compare import compare, prepare
import aeropend_core.sim.simulate as sm
from aeropend_core.io.recording import from_columns
seed = int(sys.argv[1]); count = int(sys.argv[2])
cap = {}
orig = sm.simulate
def spy(duty, **k):
    cap['duty'] = duty; cap['k'] = dict(k)
    return orig(duty, **k)
sm.simulate = spy
rec, truth, row = sc.record(seed)
sm.simulate = orig
effects = () if row['effect'] == sc.CLEAN else (row['effect'],)
k = cap['k']
for noise_seed in range(count):
    kk = dict(k); kk['seed'] = seed + 1 + 1000 * noise_seed
    tr = orig(cap['duty'], **kk)
    prep = prepare(from_columns(tr.columns(with_truth=False), source='x'))
    n = len(prep.voltage)
    emf_true = kk['parameters'].back_emf_constant * tr.truth['motor_speed'][:n]
    out = {'seed': seed, 'noise_seed': noise_seed}
    for label, p in (('obs', prep), ('true', replace(prep, voltage=emf_true.copy(), voltage_ensemble=None))):
        f = compare(p, effects).fit
        out[label] = {k2: [(f.parameters[k2]-truth[k2])/f.standard_errors[k2], f.parameters[k2]/truth[k2]-1, f.standard_errors[k2]/truth[k2]] for k2 in truth if k2 in f.standard_errors and k2 != 'armature_resistance'}
    print(json.dumps(out), flush=True)
