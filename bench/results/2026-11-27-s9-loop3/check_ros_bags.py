"""Why did `aeropend run --until-decided` stay confounded where the core loop decided? (20 ms lag, 58 dB, 30 s design)

The first bag of the ROS run is diagnosed jointly with (a) the second bag, (b) the designed schedule replayed
in-process with the run's rests and noise seed SEED, (c) the same replayed 2.35 s late and cut at the bag's length
(as the graph played it: the excitation starts after discovery, the sim stops after a fixed number of samples).
Bags: a copy of the failed test's tmp folder in /tmp/loop3_ros (not kept: ~30 MB). Results: check_ros_bags.log.

    PYTHONPATH=. python bench/results/2026-11-27-s9-loop3/check_ros_bags.py bags|SEED [late]
"""
import glob
import json
import sys
import time

import numpy as np

from aeropend_core.diagnosis.experiment_design import read_schedule, steps_to_duty
from aeropend_core.diagnosis.experiment_loop import diagnose_records
from aeropend_core.io.recording import from_columns, load_recording
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import RigSimulator

FOLDER = '/tmp/loop3_ros/bags'
#: Samples the second bag started late (2.35 s) and its length.
LATE, LENGTH = 1152, 16170


def replayed(steps: np.ndarray, noise_seed: int, late: bool):
    lead = 490 + (LATE if late else 0)
    duty = np.concatenate([np.zeros(lead), steps_to_duty(steps), np.zeros(980)])
    duty = duty[:LENGTH] if late else duty
    run = RigSimulator(effects={'thrust_lag': 0.02}, noise=MeasurementNoise(58.0, True), seed=noise_seed).run(duty)
    return from_columns(run.columns(with_truth=False), source=f'replayed {noise_seed}')


def main() -> None:
    which, late = sys.argv[1], 'late' in sys.argv[2:]
    bags = sorted(glob.glob(f'{FOLDER}/aeropend_*'))
    steps, _ = read_schedule(glob.glob(f'{FOLDER}/experiment_round2_*.yaml')[0])
    first = load_recording(bags[0])
    second = load_recording(bags[1]) if which == 'bags' else replayed(steps, int(which), late)
    started = time.process_time()
    d = diagnose_records([first, second], {'drift': False})
    found = [[f.effect, f.confounded_with, f.parameters, f.standard_errors, f.dm_statistic] for f in d.found]
    print(json.dumps({'second': which, 'late': late, 'samples': [len(first.time), len(second.time)],
                      'verdict': d.verdict, 'found': found, 'cpu': time.process_time() - started}), flush=True)


if __name__ == '__main__':
    main()
