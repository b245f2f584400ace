"""The s21 redesigns that ended "settling +None" (and clean 5), run on their truth (bench/closed_loop.py's seeds
97000+) with the truth's own feedforward scaled as a model whose thrust is 0.85-1.15 x the rig's; three noise
seeds each; settling time [s] of each step of the design schedule (None: never settled in the hold).

    python bench/results/2026-12-07-s22-loop/redesign_edges.py
"""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))

from closed_loop import CASES, truth_of  # noqa: E402

from aeropend_core.control.law import PidGains  # noqa: E402
from aeropend_core.control.loop import FeedforwardMap, simulate_loop  # noqa: E402
from aeropend_core.control.metrics import schedule_metrics  # noqa: E402
from aeropend_core.control.reference import design_schedule  # noqa: E402
from aeropend_core.sim.noise import MeasurementNoise  # noqa: E402

records = [json.loads(line) for line in (HERE.parent / '2026-12-07-s21-closed-loop' / 'cases.jsonl').open()]
schedule = design_schedule(math.radians(40))
for case, seed in (('thrust_lag', 1), ('angle_offset', 1), ('clean', 5)):
    record = next(r for r in records if r['case'] == case and r['seed'] == seed)
    parameters, effects = truth_of(case, np.random.default_rng(97000 + 1000 * CASES.index(case) + seed))
    gains = PidGains(**record['loop']['gains'])
    for factor in (0.85, 0.95, 1.05, 1.15):
        feedforward = FeedforwardMap(parameters.scaled(lever_per_inertia=factor), effects)
        runs = []
        for noise_seed in range(3):
            run = simulate_loop(gains, schedule.reference(), feedforward, parameters, effects,
                                MeasurementNoise(40.0, True), 97500 + noise_seed, duty_limit=0.8)
            runs.append(' '.join(f'{m.settling_time:.2f}' if m.settled else 'None'
                                 for m in schedule_metrics(run.time, run.angle, run.duty, schedule)))
        print(f'{case} {seed}: model thrust x {factor:g} | settling per step, 3 noise seeds: {" / ".join(runs)}')
