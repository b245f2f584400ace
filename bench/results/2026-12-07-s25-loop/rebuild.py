"""Rebuild a benchmark seed's first-design closed-loop run from its row (bench/closed_loop.py's steps: the open-loop
record, `diagnose --add` its named effect, the row's first-design gains on that model, the run on the truth) and
pickle what the closed-loop diagnosis reads: /tmp/loopdev25/run-CASE-SEED.pkl.

    nice -n 10 .venv/bin/python bench/results/2026-12-07-s25-loop/rebuild.py ROWS.jsonl dead_zone 0 45000
"""
import json
import pickle
import sys
import warnings

sys.path.insert(0, "bench")
import closed_loop as cl  # noqa: E402
from aeropend_core.control.controller_file import Controller  # noqa: E402
from aeropend_core.control.law import PidGains  # noqa: E402
from aeropend_core.model.parameters import DEFAULT_PARAMETERS  # noqa: E402

warnings.simplefilter("ignore")
path, case, seed, base = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
row = [x for x in map(json.loads, open(path)) if x["case"] == case and x["seed"] == seed][0]
parameters = DEFAULT_PARAMETERS.scaled(**row["truth_scales"])
effects = row["truth_effects"]
# identify_open_loop's record without its diagnosis (the row holds its numbers): the same columns
import math  # noqa: E402
import numpy as np  # noqa: E402
from aeropend_core.sim.excitation import lhc_schedule  # noqa: E402
from aeropend_core.sim.noise import MeasurementNoise, apply_measurement_noise  # noqa: E402
from aeropend_core.sim.simulate import simulate  # noqa: E402
record_seed = base + 100 * seed + cl.CASES.index(case)
max_duty = row["identified"]["max_duty"]
duty = lhc_schedule(60.0, duty_range=(0.0, max_duty), duty_cap=max_duty, seed=record_seed).duty(cl.SAMPLE_TIME, 60.0)
trajectory = simulate(duty, parameters, effects or None, seed=record_seed)
clean = {"armature_voltage": trajectory.armature_voltage, "armature_current": trajectory.armature_current,
         "angle": trajectory.angle}
noisy = apply_measurement_noise(clean, MeasurementNoise(cl.PSNR, True), np.random.default_rng(record_seed + 17))
trajectory.armature_voltage, trajectory.armature_current, trajectory.angle = (
    noisy["armature_voltage"], noisy["armature_current"], noisy["angle"])
open_loop = trajectory.columns(with_truth=False)
assert math.isclose(float(np.max(open_loop["angle"])), float(np.max(open_loop["angle"])))
model = cl.diagnosed_with(open_loop, tuple(row["first_added"]), True)
print("first model", model.effects, model.thrust_tolerance, "row:", row["first_model"], flush=True)
controller, outcome, _ = cl.design_on(model, "open-loop diagnosis --add")
gains = PidGains(**row["nominal_gains"])
print("design", outcome, "gains as the row's:", controller.gains == gains, flush=True)
print("predicted", [(round(m["overshoot"], 3), round(m["settling_time"], 3), round(m["steady_state_error"], 3))
                    for m in controller.design["predicted_steps"]], "notes", controller.design["notes"], flush=True)
controller = Controller(gains, model.parameters, model.effects, cl.TEMPLATE, "open-loop diagnosis --add",
                        controller.design)
run = cl.run_on_truth(controller, controller.schedule, parameters, effects, seed)
judged = cl.judged(controller, controller.schedule, run, seed)
print("judged", judged["met"], judged["measured_misses"], "row:", row["nominal"]["measured_misses"], flush=True)
with open(f"/tmp/loopdev25/run-{case}-{seed}.pkl", "wb") as stream:
    pickle.dump({"controller": controller, "run": run, "truth": (parameters, effects), "row": row,
                 "open_loop": open_loop}, stream)
