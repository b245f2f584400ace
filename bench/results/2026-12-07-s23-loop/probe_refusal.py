import json
import sys
import warnings
import time

sys.path.insert(0, "bench")
import closed_loop as cl
from aeropend_core.control.design import TemplateNotMet, design
from aeropend_core.errors import AeropendError
from aeropend_core.model.parameters import DEFAULT_PARAMETERS
from aeropend_core.sim.noise import MeasurementNoise

warnings.simplefilter("ignore")
path, case, seed, base = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
rows = [json.loads(line) for line in open(path)]
r = [row for row in rows if row["case"] == case and row["seed"] == seed][0]
parameters = DEFAULT_PARAMETERS.scaled(**r["truth_scales"])
effects = r["truth_effects"]
_, open_loop = cl.identify_open_loop(parameters, effects, base + 100 * seed + cl.CASES.index(case))
model = cl.diagnosed_with(open_loop, tuple(r["first_added"]), True)
print("truth", effects, "model effects", model.effects, "tol", model.thrust_tolerance, flush=True)
for name in ("gravity_stiffness", "damping", "lever_per_inertia", "armature_resistance", "motor_inertia"):
    print(f"  {name}: model {getattr(model.parameters, name):.4g} truth {getattr(parameters, name):.4g}")


def attempt(label, p, e, psnr, tol):
    t = time.perf_counter()
    try:
        res = design(
            cl.TEMPLATE, cl.AT, p, e, noise=MeasurementNoise(psnr_db=psnr, quantise=True), thrust_tolerance=tol
        )
        worst = max(m.overshoot for m in res.metrics)
        print(
            label,
            "DESIGNED",
            res.gains.p,
            res.gains.i,
            res.gains.d,
            "worst overshoot",
            round(worst, 2),
            "edges",
            res.summary().get("thrust_edge_misses"),
            f"{time.perf_counter() - t:.0f}s",
            flush=True,
        )
    except (TemplateNotMet, AeropendError) as err:
        print(label, "REFUSED", str(err)[:200], f"{time.perf_counter() - t:.0f}s", flush=True)


attempt("model, its doubt", model.parameters, model.effects, model.psnr_db, model.thrust_tolerance)
attempt("model, no doubt", model.parameters, model.effects, model.psnr_db, (1.0, 1.0))
attempt("truth, model doubt", parameters, effects, 40.0, model.thrust_tolerance)
attempt("truth, no doubt 40dB", parameters, effects, 40.0, (1.0, 1.0))
attempt("model, doubt, 40 dB", model.parameters, model.effects, 40.0, model.thrust_tolerance)
