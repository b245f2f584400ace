"""Is the joint diagnosis the loop's weak link? Offset bench seed 26002: the first record (duty 0.35-0.7, 40 dB) and a
record of the schedule the loop designed after it (its blocks as steps), diagnosed alone and jointly.

    nice -n 10 python bench/results/2026-11-27-s8-loop2/check_joint_vs_alone.py second|joint [GAP_SECONDS [no-observer]]
"""
import sys

import numpy as np

import aeropend_core.diagnosis.joint as joint
from aeropend_core.diagnosis.diagnose import diagnose
from aeropend_core.present.verdict_text import verdict_of
from aeropend_core.diagnosis.experiment_design import steps_to_duty
from aeropend_core.io.recording import from_columns
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import RigSimulator

truth = {'angle_offset': 0.01}
seed = 26002


def record(duty, noise_seed):
    simulator = RigSimulator(effects=truth, noise=MeasurementNoise(40.0, True), seed=noise_seed)
    return from_columns(simulator.run(duty).columns(with_truth=False))


first = record(lhc_schedule(40.0, duty_range=(0.35, 0.7), duty_cap=0.7, seed=seed).duty(duration=40.0), seed + 100)
second = record(steps_to_duty(np.array([[0, 1.0], [0.315, 4.9], [0, 10.6], [0.531, 6.9], [0.699, 6.8]])), seed + 200)
which = sys.argv[1]
if len(sys.argv) > 2:
    joint.GAP_SECONDS = float(sys.argv[2])
if len(sys.argv) > 3 and sys.argv[3] == 'no-observer':
    import functools

    import aeropend_core.diagnosis.compare as compare
    compare.prepare = functools.partial(compare.prepare, use_motor_observer=False)
result = diagnose(second, drift=False) if which == 'second' else joint.diagnose_joint([first, second], drift=False)
print(which, result.verdict, verdict_of(result)[:500], flush=True)
