"""Generate bags/exercise.csv and the same samples as an MCAP bag, bags/exercise/: a 60 s rig-like recording
with hidden physics for the diagnosis walkthrough.

SPOILER: the hidden truth is written here and nowhere else. Run `aeropend diagnose bags/exercise.csv` first.

Run from the repository root:  .venv/bin/python bags/make_exercise.py
"""
import os
import shutil
import sys
from pathlib import Path

import numpy as np

from aeropend_core.io.bag_writer import BagWriter
from aeropend_core.io.mcap_format import msg_file_loader, msg_type_hash, offered_qos, ros2msg_definition
from aeropend_core.io.recording import write_csv
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.model.parameters import DEFAULT_PARAMETERS
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate

DURATION = 60.0          # s
SEED = 2026
# The hidden truth: two effects, so the loop needs two rounds; nominal parameters moved away from the defaults.
HIDDEN_EFFECTS = {'thrust_lag': {'time_constant': 0.12}, 'coulomb_friction': {'friction_acceleration': 3.0}}
PARAMETERS = DEFAULT_PARAMETERS.scaled(damping=1.15, thrust_coefficient=0.9, armature_resistance=1.1)


def main() -> None:
    duty = lhc_schedule(DURATION, seed=SEED).duty(duration=DURATION)
    trajectory = simulate(duty, parameters=PARAMETERS, effects=HIDDEN_EFFECTS,
                          noise=MeasurementNoise(psnr_db=40.0, quantise=True), seed=SEED)
    target = Path(__file__).with_name('exercise.csv')
    write_csv(str(target), trajectory.columns(with_truth=False))
    print(f'wrote {target} ({len(trajectory)} samples)')
    write_bag(Path(__file__).with_name('exercise'), trajectory)


def write_bag(folder: Path, trajectory) -> None:
    """The samples as /aeropend/samples JointState messages (the topic contract), CDR by rosbags' serializer."""
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    joint_state = store.types['sensor_msgs/msg/JointState']
    header, stamp = store.types['std_msgs/msg/Header'], store.types['builtin_interfaces/msg/Time']
    prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p] + [sys.prefix]
    type_name = 'sensor_msgs/msg/JointState'
    if folder.exists():
        shutil.rmtree(folder)
    start_ns = 1_700_000_000 * 10 ** 9          # a fixed epoch, so the file is reproducible
    empty = np.zeros(0)
    with BagWriter(folder) as bag:
        bag.add_topic('/aeropend/samples', type_name, ros2msg_definition(type_name, msg_file_loader(prefixes)),
                      [offered_qos('best_effort', depth=5)], msg_type_hash(type_name, prefixes))
        for k in range(len(trajectory)):
            stamp_ns = start_ns + round(trajectory.time[k] * 1e9)
            message = joint_state(
                header=header(stamp=stamp(sec=stamp_ns // 10 ** 9, nanosec=stamp_ns % 10 ** 9), frame_id='aeropend'),
                name=['angle', 'armature_voltage', 'armature_current', 'duty', 'sequence'],
                position=np.array([trajectory.angle[k], trajectory.armature_voltage[k],
                                   trajectory.armature_current[k], trajectory.duty[k], float(k)]),
                velocity=empty, effort=empty)
            bag.write('/aeropend/samples', store.serialize_cdr(message, type_name), stamp_ns, stamp_ns)
    print(f'wrote {folder}/ (rosbag2 MCAP bag folder)')


if __name__ == '__main__':
    main()
