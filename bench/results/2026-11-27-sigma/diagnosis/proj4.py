import sys, numpy as np
from dataclasses import replace
sys.path.insert(0, '/work/wt-sigma/bench')
import sigma_coverage as sc
import aeropend_core.diagnosis.output_error as oe
from aeropend_core.diagnosis.compare import prepare, fit_model
import aeropend_core.sim.simulate as sm
from aeropend_core.diagnosis.evidence import input_covariance
seed = int(sys.argv[1])
cap = {}
orig = sm.simulate
def spy(*a, **k):
    global sm_k, sm_duty
    sm_k = dict(k); sm_duty = a[0]
    t = orig(*a, **k); cap['t'] = t; cap['p'] = k.get('parameters'); return t
sm.simulate = spy
rec, truth, row = sc.record(seed)
sm.simulate = orig
ns = int(sys.argv[2])
kk = dict(sm_k)
kk['seed'] = seed + 1 + 1000 * ns
from aeropend_core.io.recording import from_columns
cap['t'] = orig(sm_duty, **kk)
rec = from_columns(cap['t'].columns(with_truth=False), source='x')
effects = () if row['effect'] == sc.CLEAN else (row['effect'],)
prep = prepare(rec)
n = len(prep.voltage)
emf = cap['p'].back_emf_constant * cap['t'].truth['motor_speed'][:n]
err = emf - prep.voltage
import aeropend_core.signals.motor as mo
from aeropend_core.signals.preprocess import piecewise_constant
va_true = cap['t'].truth['armature_voltage'][:n]
st = prep.step_indices
bounds_ = np.concatenate(([0], st, [n]))
va_lv = np.empty(n)
for a_, b_ in zip(bounds_[:-1], bounds_[1:]): va_lv[a_:b_] = np.median(va_true[a_:b_])
x_hat = np.array(prep.motor.solution)
_, emf_truelevels = mo._predict(prep.motor.kind, x_hat, va_lv, prep.sample_time)
err_level = emf_truelevels - prep.voltage      # what correct Va levels would change (params held)
err_param = emf - emf_truelevels               # the rest: the observer's parameter error
print('va level err rms', np.sqrt(np.mean((prep.gate_voltage - va_lv)**2)))

captured = []
o2 = oe.input_covariance
def spy2(jac, changes):
    captured.append((jac, changes)); return o2(jac, changes)
oe.input_covariance = spy2
f = fit_model(prep, effects)
jac, changes = captured[-1]
data = prep.train
structure = f.structure
free = f.free_names
# residual change for the true error, params held at fit
from aeropend_core.diagnosis.output_error import _bounded
names = structure.parameter_names
rows = np.array([structure.row(f.parameters)])
ri = data.residual_index
base = data.simulate(structure, rows, f.initial_states[None])[0, ri]
moved = data.simulate(structure, rows, f.initial_states[None], data.voltage + err)[0, ri]
dr_true = (moved - base)
dr_level = data.simulate(structure, rows, f.initial_states[None], data.voltage + err_level)[0, ri] - base
dr_param = data.simulate(structure, rows, f.initial_states[None], data.voltage + err_param)[0, ri] - base
from aeropend_core.diagnosis.evidence import _jacobian_and_bread
J, _, B = _jacobian_and_bread(jac)
step_true = -(B @ (J.T @ dr_true))[:len(free)]
step_level = -(B @ (J.T @ dr_level))[:len(free)]
step_param = -(B @ (J.T @ dr_param))[:len(free)]
steps = -(B @ (J.T @ changes.T))[:len(free)]
scale = np.array([oe._default_scale(nm, f.parameters[nm]) for nm in free])
# note: the jac is in z-units (scaled)? compare in the same units anyway
# ensemble split, replicating back_emf_ensemble (seed 0)
from aeropend_core.signals.preprocess import noise_rms as _nr
fitm = prep.motor
xm = np.array(fitm.solution); kind = fitm.kind
Vobs = prep.gate_voltage
used = mo._fitted_samples(kind, n, st, prep.sample_time)
modelled, emf0 = mo._predict(kind, xm, Vobs, prep.sample_time)
residual = prep.armature_current - modelled
stp = 1e-6 * np.maximum(np.abs(xm), 1e-4)
jm = np.empty((int(used.sum()), xm.size)); je = np.empty((n, xm.size))
for i in range(xm.size):
    sh = xm.copy(); sh[i] += stp[i]
    c_, e_ = mo._predict(kind, sh, Vobs, prep.sample_time)
    jm[:, i] = (c_ - modelled)[used] / stp[i]; je[:, i] = (e_ - emf0) / stp[i]
inv = np.linalg.pinv(jm.T @ jm)
block = np.repeat(np.arange(len(bounds_) - 1), np.diff(bounds_))
lengths = np.maximum(np.diff(bounds_), 1)
lsig = 1.2533 * _nr(prep.armature_voltage) / np.sqrt(lengths)
rng = np.random.default_rng(0)
lv_parts, pa_parts = [], []
for k in range(16):
    signs = rng.choice((-1.0, 1.0), size=len(lengths))
    shifted = Vobs + (rng.standard_normal(len(lengths)) * lsig)[block]
    redrawn = modelled + signs[block] * residual
    mv, mem = mo._predict(kind, xm, shifted, prep.sample_time)
    ch = inv @ (jm.T @ (redrawn - mv)[used])
    lv_parts.append(mem - emf0); pa_parts.append(je @ ch)
def proj(e):
    dr = data.simulate(structure, rows, f.initial_states[None], data.voltage + e)[0, ri] - base
    return -(B @ (J.T @ dr))[:len(free)]
sl = np.array([proj(e) for e in lv_parts]); sp = np.array([proj(e) for e in pa_parts])
for i, nm in enumerate(free):
    print('SPLIT', ns, nm, 'true level/ens level sd %.2f  true param/ens param sd %.2f  (ens level sd %.3g param sd %.3g)' % (step_level[i]/np.sqrt(np.mean(sl[:,i]**2)), step_param[i]/np.sqrt(np.mean(sp[:,i]**2)), np.sqrt(np.mean(sl[:,i]**2)), np.sqrt(np.mean(sp[:,i]**2))), flush=True)
for i, nm in enumerate(free):
    sd = np.sqrt(np.mean(steps[i]**2))
    print('RATIO', ns, nm, '%.2f level %.2f param %.2f' % (step_true[i]/sd, step_level[i]/sd, step_param[i]/sd), flush=True)
print('err rms', np.sqrt(np.mean(err**2)), 'ens rms', np.sqrt(np.mean(prep.voltage_ensemble.astype(float)**2)))
# error structure vs level
lv = np.round(prep.gate_voltage, 3)
import collections
print('motor kind', prep.motor.kind, prep.motor.parameters, prep.motor.standard_errors)
print('corr(err, emf)', np.corrcoef(err, emf)[0,1], 'err mean', err.mean())
# fit err = a + b*emf + c*emf^2
A = np.c_[np.ones(n), emf, emf**2]
coef, *_ = np.linalg.lstsq(A, err, rcond=None)
print('err ~ a + b e + c e^2', coef, 'resid rms', np.sqrt(np.mean((err - A@coef)**2)))
for m in prep.voltage_ensemble[:4].astype(float):
    c2, *_ = np.linalg.lstsq(A, m, rcond=None); print('  member', c2, np.sqrt(np.mean((m-A@c2)**2)))
