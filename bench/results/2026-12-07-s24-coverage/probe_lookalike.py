"""Probe: which assess() decisions differ between trees on test_discovery's encoder-harmonic look-alike record."""
import json
import sys

import numpy as np

from aeropend_core.diagnosis import candidates as cand_mod
from aeropend_core.diagnosis import discovery as disc_mod  # noqa: F401 (loaded before assess is patched)
from aeropend_core.diagnosis.diagnose import diagnose
from aeropend_core.io.recording import from_columns
from aeropend_core.model.effects import MEASUREMENT, EffectParameter, catalog_scope, register_effect
from aeropend_core.present.verdict_text import verdict_of
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate

log = []
original = cand_mod.assess


def logged(prep, base, augmented, name, *args, **kwargs):
    c = original(prep, base, augmented, name, *args, **kwargs)
    log.append({'base': list(base.effects), 'augmented': list(augmented.effects), 'name': name,
                't': round(c.t_statistic, 2), 'dbic': round(c.delta_bic, 1), 'dm': round(c.dm_statistic, 2),
                'significant': c.significant,
                'values': {k: float('%.4g' % v) for k, v in c.parameters.items()},
                'sigmas': {k: float('%.3g' % v) for k, v in c.standard_errors.items()}})
    return c


for module in list(sys.modules.values()):
    if getattr(module, 'assess', None) is original:
        module.assess = logged
with catalog_scope():
    register_effect('test_encoder_harmonic', 'encoder second-harmonic nonlinearity', kind=MEASUREMENT, replace=True,
                    parameters=[EffectParameter('test_encoder_amplitude', 'rad', 'amplitude', 0.04, -1.0, 1.0)])(
        lambda angle, test_encoder_amplitude: angle + test_encoder_amplitude * np.sin(2.0 * angle))
    schedule = lhc_schedule(60.0, duty_range=(0.0, 0.7), duty_cap=0.7, seed=11)
    trajectory = simulate(schedule.duty(duration=60.0), effects={'test_encoder_harmonic': 0.04},
                          noise=MeasurementNoise(psnr_db=40.0, quantise=True), seed=12)
found = diagnose(from_columns(trajectory.columns(with_truth=False)), drift=False)
json.dump({'verdict': found.verdict, 'text': verdict_of(found), 'assess': log}, open(sys.argv[1], 'w'), indent=1)
print(found.verdict)
