"""In-process emulation of ``aeropend run --until-decided --experiment first.yaml`` on the simulator.

Each played schedule gets the run's framing: 1 s at duty 0 before it, 2 s at duty 0 after it; the simulator's noise
seed is SEED + round - 1 (as the run now does); 2 runs, 30 s designs of 10 + 5 schedules (--design-candidates 10).

Each argument is EFFECT:SIZE:SEED:FIRST_S:DESIGN_S:TAIL_DUTY:PSNR:LOWEST_DUTY: the first schedule is a Latin
hypercube of FIRST_S seconds over duty LOWEST_DUTY-0.7 followed by 3 s at TAIL_DUTY. Results: check_run_framing.log.

    PYTHONPATH=. nice -n 5 python bench/results/2026-11-27-s9-loop3/check_run_framing.py \\
        cable_torque:30:26000:37:30:0.2:40:0.35 thrust_lag:0.02:26000:37:30:0:58:0
"""
import json
import sys
import time

import numpy as np

from aeropend_core.diagnosis.experiment_loop import LoopBudget, Played, until_decided
from aeropend_core.io.recording import from_columns
from aeropend_core.model.parameters import SAMPLE_TIME
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import RigSimulator


def framed(duty: np.ndarray) -> np.ndarray:
    """The run's framing: 1 s at duty 0 before, 2 s at duty 0 after."""
    return np.concatenate([np.zeros(int(round(1 / SAMPLE_TIME))), duty, np.zeros(int(round(2 / SAMPLE_TIME)))])


def case(spec: str) -> dict:
    effect, size, seed, seconds, design_s, tail, psnr, lowest = spec.split(':')
    size, seed, seconds, design_s = float(size), int(seed), float(seconds), float(design_s)
    tail, psnr, lowest = float(tail), float(psnr), float(lowest)
    started = time.process_time()
    played = []

    def play(design, schedule):
        if design is None:
            first = lhc_schedule(seconds, duty_range=(lowest, 0.7), duty_cap=0.7, seed=seed).duty(duration=seconds)
            duty = np.concatenate([first, np.full(int(round(3 / SAMPLE_TIME)), tail)])
        else:
            duty = design.schedule.duty()
        run = RigSimulator(effects={effect: size}, noise=MeasurementNoise(psnr, True), seed=seed + len(played))
        played.append(1)
        duty = framed(duty)
        return Played(from_columns(run.run(duty).columns(with_truth=False)), 'sim', 'x', len(duty) * SAMPLE_TIME)

    outcome = until_decided(play, LoopBudget(max_runs=2, design_seconds=design_s, overhead_seconds=3.0),
                            {'drift': False}, seed=seed, design_options=dict(candidates=10, refinements=5))
    found = [[[f.effect, f.confounded_with, f.parameters, f.standard_errors] for f in r.diagnosis.found]
             for r in outcome.rounds]
    return {'spec': spec, 'verdicts': [r.diagnosis.verdict for r in outcome.rounds], 'found': found,
            'cpu': time.process_time() - started}


if __name__ == '__main__':
    for argument in sys.argv[1:]:
        print(json.dumps(case(argument)), flush=True)
