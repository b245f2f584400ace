"""Reproduce predict_other for clean seeds of the s22 c23b980 run (model = open-loop identified nominal structure)."""

import json
import sys
import numpy as np

sys.path.insert(0, "bench")
from aeropend_core.control.law import PidGains
from aeropend_core.control.loop import FeedforwardMap, simulate_loop
from aeropend_core.control.metrics import schedule_metrics
from aeropend_core.control.model_source import model_from_dict
from aeropend_core.control.reference import ReferenceSchedule
from aeropend_core.model.parameters import DEFAULT_PARAMETERS
from aeropend_core.sim.noise import MeasurementNoise

CASES = "bench/results/2026-12-07-s22-suite/closed-loop-c23b980-cases.jsonl"
rows = [json.loads(line) for line in open(CASES)]
sched = ReferenceSchedule.steps_between([25, 50, 30], hold=5.0, start_hold=3.0)
out = {}
for r in rows:
    if r["case"] != "clean" or "predict" not in r or r["loop"].get("redesign") == "designed":
        continue
    seed = r["seed"]
    model = model_from_dict(r["identified"], "x")
    truth = DEFAULT_PARAMETERS.scaled(**r["truth_scales"])
    g = PidGains(**r["nominal_gains"]) if isinstance(r["nominal_gains"], dict) else None
    other = g.replace(p=0.7 * g.p, d=0.7 * g.d)
    ff = FeedforwardMap(model.parameters, model.effects)

    def run(params, effects, s, noise=True):
        n = MeasurementNoise(psnr_db=40.0, quantise=True) if noise else None
        return simulate_loop(other, sched.reference(), ff, params, effects, n, s, duty_limit=other.u_clamp_max)

    m = schedule_metrics(*(lambda x: (x.time, x.angle, x.duty))(run(truth, r["truth_effects"], seed + 900)), sched)
    p = schedule_metrics(
        *(lambda x: (x.time, x.angle, x.duty))(run(model.parameters, model.effects, seed + 901)), sched
    )
    print(
        "seed",
        seed,
        "recorded",
        [(round(s["settling_measured"], 3), round(s["settling_predicted"], 3)) for s in r["predict"]["steps"]],
    )
    print("        reproduced", [(round(a.settling_time, 3), round(b.settling_time, 3)) for a, b in zip(m, p)])
    # distribution over noise seeds
    ms, ps = [], []
    for k in range(12):
        ms.append(
            [
                x.settling_time
                for x in schedule_metrics(
                    *(lambda x: (x.time, x.angle, x.duty))(run(truth, r["truth_effects"], 5000 + k)), sched
                )
            ]
        )
        ps.append(
            [
                x.settling_time
                for x in schedule_metrics(
                    *(lambda x: (x.time, x.angle, x.duty))(run(model.parameters, model.effects, 7000 + k)), sched
                )
            ]
        )
    ms, ps = np.array(ms), np.array(ps)
    for j in range(3):
        print(f"   step{j} truth seeds: {np.round(np.sort(ms[:, j]), 2)}")
        print(f"   step{j} model seeds: {np.round(np.sort(ps[:, j]), 2)}")
    out[seed] = {"m": ms.tolist(), "p": ps.tolist()}
json.dump(out, open("probe_draws.json", "w"))
