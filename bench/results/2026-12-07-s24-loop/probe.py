"""A refused seed's first-design model rebuilt as bench/closed_loop.py builds it, designed under each change.

    probe.py CASES.jsonl CASE SEED SEED_BASE MODES   (MODES: md,m1,td,t1,cross)

md: the model, its doubt; m1: the model, no doubt; td: the truth, the model's doubt; t1: the truth, no doubt;
cross: the truth's design (no doubt) and its gains run on the model and on the truth over six noise draws.
The model is cached in /tmp/loopdev24 (the open-loop identification takes about a minute).
"""
import json
import pickle
import sys
import time
import warnings

sys.path.insert(0, "bench")
import closed_loop as cl  # noqa: E402

from aeropend_core.control.design import TemplateNotMet, design  # noqa: E402
from aeropend_core.errors import AeropendError  # noqa: E402
from aeropend_core.model.parameters import DEFAULT_PARAMETERS  # noqa: E402
from aeropend_core.sim.noise import MeasurementNoise  # noqa: E402

warnings.simplefilter("ignore")
path, case, seed, base = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
modes = sys.argv[5].split(',')
rows = [json.loads(line) for line in open(path)]
r = [x for x in rows if x["case"] == case and x["seed"] == seed][0]
parameters = DEFAULT_PARAMETERS.scaled(**r["truth_scales"])
effects = r["truth_effects"]
cache = f"/tmp/loopdev24/model-{case}-{seed}.pkl"
try:
    model = pickle.load(open(cache, 'rb'))
except Exception:
    _, open_loop = cl.identify_open_loop(parameters, effects, base + 100 * seed + cl.CASES.index(case))
    model = cl.diagnosed_with(open_loop, tuple(r["first_added"]), True)
    pickle.dump(model, open(cache, 'wb'))
print("truth", effects, "model", model.effects, model.thrust_tolerance, model.psnr_db, flush=True)


def attempt(label, p, e, psnr, tol):
    t = time.perf_counter()
    try:
        res = design(cl.TEMPLATE, cl.AT, p, e, noise=MeasurementNoise(psnr_db=psnr, quantise=True),
                     thrust_tolerance=tol)
        steps = [(round(m.overshoot, 2), round(m.settling_time, 2)) for m in res.metrics]
        print(label, "DESIGNED", res.gains.as_dict(), steps, res.notes, res.summary().get("thrust_edge_misses"),
              f"{time.perf_counter() - t:.0f}s", flush=True)
        return res
    except (TemplateNotMet, AeropendError) as err:
        print(label, "REFUSED", str(err)[:200], None, f"{time.perf_counter() - t:.0f}s", flush=True)


for m in modes:
    if m == 'md':
        attempt("model, its doubt", model.parameters, model.effects, model.psnr_db, model.thrust_tolerance)
    if m == 'm1':
        attempt("model, no doubt", model.parameters, model.effects, model.psnr_db, (1.0, 1.0))
    if m == 'td':
        attempt("truth, model doubt", parameters, effects, 40.0, model.thrust_tolerance)
    if m == 't1':
        attempt("truth, no doubt", parameters, effects, 40.0, (1.0, 1.0))
if 'cross' in modes:
    from aeropend_core.control.loop import FeedforwardMap, simulate_loop
    from aeropend_core.control.metrics import schedule_metrics
    truth_design = attempt("truth, no doubt", parameters, effects, 40.0, (1.0, 1.0))
    g = truth_design.gains
    sched = truth_design.schedule
    ref = sched.reference(None, 1 / 490)
    for label, p, e, psnr in (("truth gains on model", model.parameters, model.effects, model.psnr_db),
                              ("truth gains on truth", parameters, effects, 40.0)):
        for s in range(6):
            run = simulate_loop(g, ref, FeedforwardMap(p, e), p, e, MeasurementNoise(psnr_db=psnr, quantise=True), s,
                                duty_limit=0.8)
            ms = schedule_metrics(run.time, run.angle, run.duty, sched)
            print(label, s, [(round(m.overshoot, 2), round(m.settling_time, 2), round(m.steady_state_error, 2))
                             for m in ms], flush=True)
