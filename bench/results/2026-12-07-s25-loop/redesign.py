"""The benchmark's loop step on a rebuilt seed (rebuild.py's pickle), as bench/closed_loop.py runs it after a first
design missed: the closed-loop diagnosis with the first model's effects added, the redesign on its model (the
open-loop record's rests as thrust doubt), the new gains run on the truth (seed + 500) and judged by control check.

    nice -n 10 .venv/bin/python bench/results/2026-12-07-s25-loop/redesign.py dead_zone 0
"""
import math
import pickle
import sys
import warnings

sys.path.insert(0, "bench")
import closed_loop as cl  # noqa: E402
from aeropend_core.control.controller_file import Controller  # noqa: E402
from aeropend_core.control.design import TemplateNotMet, design  # noqa: E402
from aeropend_core.control.hold_doubt import hold_doubt  # noqa: E402
from aeropend_core.control.model_source import model_from_dict  # noqa: E402
from aeropend_core.sim.noise import MeasurementNoise  # noqa: E402

warnings.simplefilter("ignore")
case, seed = sys.argv[1], int(sys.argv[2])
data = pickle.load(open(f"/tmp/loopdev25/run-{case}-{seed}.pkl", "rb"))
controller, run, (truth, truth_effects), open_loop = data["controller"], data["run"], data["truth"], data["open_loop"]
had = tuple(controller.effects)
diagnosis = cl.loop_diagnosis(controller, run, had)
print("closed-loop diagnosis:", diagnosis["verdict"], diagnosis["missing_effect"], diagnosis["parameters"], flush=True)
base = model_from_dict({**diagnosis, "parameters": {**diagnosis["parameters"]}}, "loop diagnosis")
base = base.with_hold_doubt(hold_doubt(open_loop["t"], open_loop["angle"], open_loop["duty"], base.parameters,
                                       base.effects))
noise_db = min(80.0, 20 * math.log10((math.pi / 2) / max(diagnosis["noise_rms"], 1e-9)))
print("redesign on", base.effects, "thrust doubt", base.thrust_tolerance, "noise dB", round(noise_db, 2), flush=True)
try:
    redesign = design(cl.TEMPLATE, cl.AT, base.parameters, base.effects,
                      noise=MeasurementNoise(psnr_db=noise_db, quantise=True), thrust_tolerance=base.thrust_tolerance)
except TemplateNotMet as refusal:
    print("refused:", refusal)
    raise SystemExit(0)
again_controller = Controller(redesign.gains, base.parameters, base.effects, cl.TEMPLATE, "loop diagnosis",
                              redesign.summary())
print("gains", {k: round(v, 4) for k, v in redesign.gains.as_dict().items() if isinstance(v, float)}, flush=True)
again = cl.run_on_truth(again_controller, again_controller.schedule, truth, truth_effects, seed + 500)
judged = cl.judged(again_controller, again_controller.schedule, again, seed + 500)
print("on the truth:", judged["met"], judged["verdict"], judged["measured_misses"], judged["overshoot"],
      judged["settling"], flush=True)
