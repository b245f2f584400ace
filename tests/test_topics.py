"""The topic contract helpers: a sample survives sample_to_msg -> CDR -> msg_to_sample; channels are found by name."""
from __future__ import annotations

import pytest

from aeropend_ros._ros_env import ensure_ros_environment

ensure_ros_environment(local_only=True)

from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState

from aeropend_ros import topics


def test_sample_round_trip_through_cdr():
    sample = topics.Sample(1_763_700_000_123_456_789, 0.25, 1.5, 0.75, 0.4, 123456)
    msg = topics.sample_to_msg(sample)
    assert msg.header.frame_id == 'aeropend' and list(msg.name) == list(topics.SAMPLE_NAMES)
    assert len(msg.velocity) == 0 and len(msg.effort) == 0
    back = topics.msg_to_sample(deserialize_message(serialize_message(msg), JointState))
    assert back == sample
    assert back.time == pytest.approx(1_763_700_000.123456789)
    # reusing a message overwrites every field
    again = topics.sample_to_msg(topics.Sample(5, 0.0, 0.0, 0.0, 0.0, 1), msg)
    assert again is msg and msg.header.stamp.sec == 0 and msg.header.stamp.nanosec == 5


def test_channels_by_name_and_bad_messages():
    msg = JointState(name=['sequence', 'duty', 'angle', 'armature_current', 'armature_voltage'],
                     position=[7.0, 0.3, 0.1, 0.8, 1.2])
    sample = topics.msg_to_sample(msg)
    assert (sample.angle, sample.armature_voltage, sample.armature_current, sample.duty, sample.sequence) == \
        (0.1, 1.2, 0.8, 0.3, 7)
    with pytest.raises(ValueError, match='not an aeropend sample'):
        topics.msg_to_sample(JointState(name=['a', 'b'], position=[1.0, 2.0]))
    with pytest.raises(ValueError, match='positions'):
        topics.msg_to_sample(JointState(name=list(topics.SAMPLE_NAMES), position=[1.0]))
