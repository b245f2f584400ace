"""The first design of a refused seed on this tree's code (bench/closed_loop.design_on, the model cached by probe.py),
run on the seed's truth and judged by control check as the benchmark does."""
import json
import pickle
import sys
import warnings

sys.path.insert(0, "bench")
import closed_loop as cl
from aeropend_core.model.parameters import DEFAULT_PARAMETERS
warnings.simplefilter("ignore")
path, case, seed, base = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
r = [x for x in map(json.loads, open(path)) if x["case"] == case and x["seed"] == seed][0]
parameters = DEFAULT_PARAMETERS.scaled(**r["truth_scales"])
effects = r["truth_effects"]
model = pickle.load(open(f"/tmp/loopdev24/model-{case}-{seed}.pkl", "rb"))
controller, outcome, items = cl.design_on(model, "open-loop diagnosis --add")
print(case, seed, outcome, items, flush=True)
if controller is not None:
    print("gains", {k: round(v, 4) for k, v in controller.gains.as_dict().items() if isinstance(v, float)})
    print("notes", controller.design.get("notes"))
    run = cl.run_on_truth(controller, controller.schedule, parameters, effects, seed)
    j = cl.judged(controller, controller.schedule, run, seed)
    print("on the truth:", {k: j[k] for k in j if k in ("met", "verdict")}, flush=True)
