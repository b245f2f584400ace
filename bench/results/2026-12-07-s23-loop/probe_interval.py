"""Coverage of two settling-interval forms on s22's reconstructable clean seeds (model = the open-loop identified
nominal structure, controller = the other one, truth = the seed's rig)."""

import json
import sys
import numpy as np
from aeropend_core.control.law import PidGains
from aeropend_core.control.loop import FeedforwardMap, simulate_loop
from aeropend_core.control.metrics import schedule_metrics, moving_mean, SMOOTHING_TIME
from aeropend_core.control.model_source import model_from_dict
from aeropend_core.control.reference import ReferenceSchedule
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, SAMPLE_TIME
from aeropend_core.sim.noise import MeasurementNoise


def settle_at(x, m, band):
    ins = (x.time >= m.start - 1e-9) & (x.time < m.start + m.hold - 1e-9)
    t = x.time[ins] - m.start
    y = moving_mean(x.angle[ins], int(round(SMOOTHING_TIME / SAMPLE_TIME)), ends="shrink")
    out = np.flatnonzero(np.abs(y - m.final) > band)
    if out.size == 0:
        return 0.0
    if out[-1] == y.size - 1:
        return m.hold
    return float(t[out[-1] + 1])


def tail_sd(x, m):
    ins = (x.time >= m.start + 0.8 * m.hold) & (x.time < m.start + m.hold - 1e-9)
    y = moving_mean(x.angle[ins], 24, ends="shrink")
    return float(np.std(y - m.final))


CASES = "bench/results/2026-12-07-s22-suite/closed-loop-c23b980-cases.jsonl"
rows = [json.loads(line) for line in open(CASES)]
sched = ReferenceSchedule.steps_between([25, 50, 30], hold=5.0, start_hold=3.0)
K = int(sys.argv[1]) if len(sys.argv) > 1 else 12
A_in = B_in = P_ok = total = 0
for r in rows:
    if r["case"] != "clean" or "predict" not in r or r["loop"].get("redesign") == "designed":
        continue
    model = model_from_dict(r["identified"], "x")
    truth = DEFAULT_PARAMETERS.scaled(**r["truth_scales"])
    g = PidGains(**r["nominal_gains"])
    other = g.replace(p=0.7 * g.p, d=0.7 * g.d)
    ff = FeedforwardMap(model.parameters, model.effects)
    def run(params, s, other=other, ff=ff):
        return simulate_loop(
            other, sched.reference(), ff, params, {}, MeasurementNoise(40.0, True), s, duty_limit=other.u_clamp_max
        )

    model_runs = [run(model.parameters, 7000 + k) for k in range(K)]
    model_metrics = [schedule_metrics(x.time, x.angle, x.duty, sched) for x in model_runs]
    for k in range(12):
        xt = run(truth, 5000 + k)
        mt = schedule_metrics(xt.time, xt.angle, xt.duty, sched)
        for j in range(3):
            total += 1
            measured = mt[j].settling_time
            # A: band +- 2 sd on the first model draw
            x0, m0 = model_runs[0], model_metrics[0][j]
            s = tail_sd(x0, m0)
            lo, hi = settle_at(x0, m0, m0.band + 2 * s), settle_at(x0, m0, max(m0.band - 2 * s, 0))
            A_in += lo - 1e-9 <= measured <= hi + 1e-9
            vals = [mm[j].settling_time for mm in model_metrics]
            B_in += min(vals) - 1e-9 <= measured <= max(vals) + 1e-9
            P_ok += abs(measured - m0.settling_time) <= 0.2 * measured
            if k == 0:
                print(
                    r["seed"],
                    j,
                    f"A [{lo:.2f}, {hi:.2f}] sd {1000 * s:.1f} mrad",
                    f"B [{min(vals):.2f}, {max(vals):.2f}] measured {measured:.2f}",
                )
print(f"total {total}: A covers {A_in}, B (range of {K} draws) covers {B_in}, point within 20 %: {P_ok}")
