"""Probe: a catalog effect beside an unmodelled remainder (temporary experiment)."""
import sys, time, json
from pathlib import Path
ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))
import numpy as np
from aeropend_core.io.recording import from_columns
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate
from aeropend_core.model.effects import CATALOG, load_effects_module
from aeropend_core.diagnosis.diagnose import diagnose

def rec(effects, seed, psnr=40.0):
    builtin = set(CATALOG)
    load_effects_module(str(ROOT / 'discovery_effects.py'))
    try:
        schedule = lhc_schedule(60.0, duty_range=(0.0, 0.7), duty_cap=0.7, seed=seed)
        tr = simulate(schedule.duty(duration=60.0), effects=effects, noise=MeasurementNoise(psnr_db=psnr, quantise=True), seed=seed + 1)
    finally:
        for extra in set(CATALOG) - builtin:
            CATALOG.pop(extra)
    return from_columns(tr.columns(with_truth=False), source='probe')

cases = json.loads(sys.argv[1])
seed = int(sys.argv[2]) if len(sys.argv) > 2 else 11
t = time.time()
d = diagnose(rec(cases, seed), discovery='--nodisc' not in sys.argv)
print('verdict', d.verdict, 'named', d.missing_effects, round(time.time() - t, 1), 's')
for c in d.candidates[:4]:
    print(f'  {c.effect:20s} sig={c.significant} dBIC={c.delta_bic:+.1f} t={c.t_statistic:.1f} dm={c.dm_statistic:+.2f} share={c.share_removed:.2f} params={ {k: round(v,4) for k,v in c.parameters.items()} } se={ {k: round(v,4) for k,v in c.standard_errors.items()} }')
print("found", [(f.effect, {k: round(v, 4) for k, v in f.parameters.items()}, {k: round(v, 4) for k, v in f.standard_errors.items()}) for f in d.found])
print('noise', d.noise_rms if hasattr(d, 'noise_rms') else None)
disc = d.discovery
if disc is not None:
    print('discovery proven', [(p.term.expression, p.status, getattr(p, 'excess_after', None)) for p in disc.proven], 'note', getattr(disc, 'note', ''))
from aeropend_core.present.summary import format_summary; print(format_summary(d))
