"""The nominal model's design under a wide thrust doubt (the args: LOW:HIGH ...): does the doubt-weighted search
refuse where gains that meet on the model exist? (It did not: no test case from it.)"""
import math
import sys
import time
import warnings

from aeropend_core.control.design import TemplateNotMet, design
from aeropend_core.control.metrics import Template
from aeropend_core.sim.noise import MeasurementNoise

warnings.simplefilter('ignore')
for tol in [tuple(map(float, a.split(':'))) for a in sys.argv[1:]]:
    t = time.perf_counter()
    try:
        d = design(Template(), math.radians(40), noise=MeasurementNoise(psnr_db=50.0, quantise=True),
                   thrust_tolerance=tol)
        print(tol, 'DESIGNED', d.gains.p, d.gains.i, d.gains.d, d.misses(), d.notes[-1][:150],
              f'{time.perf_counter() - t:.0f}s', flush=True)
    except TemplateNotMet as e:
        print(tol, 'REFUSED', str(e)[:150], f'{time.perf_counter() - t:.0f}s', flush=True)
