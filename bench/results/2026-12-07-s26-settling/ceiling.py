"""Ceiling of the settling point prediction when the model IS the truth: one draw vs the median of 20 draws."""
import sys, math, json
import numpy as np
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))      # bench/
from closed_loop import truth_of, CASES, TEMPLATE, AT, PSNR, predict_other
from aeropend_core.control.design import design, TemplateNotMet
from aeropend_core.control.controller_file import Controller
from aeropend_core.control.loop import noise_draws
from aeropend_core.control.loop import FeedforwardMap, simulate_loop
from aeropend_core.control.metrics import schedule_metrics
from aeropend_core.control.reference import ReferenceSchedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.errors import AeropendError

base = int(sys.argv[1]); n = int(sys.argv[2])
one_ok = med_ok = total = 0
for seed in range(base, base + n):
    case = CASES[seed % len(CASES)]
    params, effects = truth_of(case, np.random.default_rng(seed))
    try:
        res = design(TEMPLATE, AT, params, effects, noise=MeasurementNoise(psnr_db=PSNR, quantise=True))
    except (TemplateNotMet, AeropendError) as e:
        print(seed, case, 'refused'); continue
    gains = res.gains.replace(p=0.7 * res.gains.p, d=0.7 * res.gains.d)
    schedule = ReferenceSchedule.steps_between([25, 50, 30], hold=5.0, start_hold=3.0)
    ff = FeedforwardMap(params, effects)
    noise = MeasurementNoise(psnr_db=PSNR, quantise=True)
    measured = simulate_loop(gains, schedule.reference(), ff, params, effects, noise, seed + 900, duty_limit=gains.u_clamp_max)
    m = schedule_metrics(measured.time, measured.angle, measured.duty, schedule)
    from aeropend_core.control.loop import feedforward_per_sample
    ref = schedule.reference()
    runs = noise_draws(gains, ref, feedforward_per_sample(ff, ref), params, effects, noise, range(seed + 901, seed + 921), schedule,
                       duty_limit=gains.u_clamp_max)
    for k, a in enumerate(m):
        draws = [metrics[k].settling_time for _r, metrics in runs]
        one = draws[0]; med = float(np.median(draws))
        ok1 = abs(one - a.settling_time) <= 0.2 * a.settling_time
        okm = abs(med - a.settling_time) <= 0.2 * a.settling_time
        one_ok += ok1; med_ok += okm; total += 1
        print(seed, case, k, f'measured {a.settling_time:.3f} one {one:.3f} median {med:.3f} spread {np.min(draws):.3f}-{np.max(draws):.3f}', ok1, okm, flush=True)
print(f'one draw within 20%: {one_ok}/{total}; median of 20 within 20%: {med_ok}/{total}')
