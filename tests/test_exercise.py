"""The shipped exercise recording: the CSV and the MCAP bag hold the same measured samples and nothing else."""
from pathlib import Path

import numpy as np

from aeropend_core.io.recording import load_recording

BAGS = Path(__file__).resolve().parents[1] / 'bags'


def test_exercise_csv_and_bag_agree_and_carry_no_truth():
    csv = load_recording(BAGS / 'exercise.csv')
    bag = load_recording(BAGS / 'exercise')
    assert not [name for name in csv.signals if name.startswith('true_')]
    assert len(csv) == len(bag) == 29400
    for name in ('armature_voltage', 'armature_current', 'angle', 'duty'):
        assert np.allclose(csv.signals[name], bag.signals[name], atol=1e-8)
    assert np.allclose(np.diff(bag.time), 1 / 490, atol=1e-6)


def test_exercise_bag_opens_with_the_independent_rosbags_reader():
    from rosbags.highlevel import AnyReader
    with AnyReader([BAGS / 'exercise']) as reader:
        connections = [c for c in reader.connections if c.topic == '/aeropend/samples']
        first = next(reader.messages(connections=connections))
        message = reader.deserialize(first[2], first[0].msgtype)
    assert list(message.name) == ['angle', 'armature_voltage', 'armature_current', 'duty', 'sequence']
    assert message.header.frame_id == 'aeropend'
