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


def test_parameter_estimate_round_trip_through_cdr():
    """/aeropend/parameters/<name>: value, band (value -+ sigma), sigma, flags by fixed field names; estimator, unit
    and the data flag in frame_id; a NaN sigma (unknown) gives a NaN band, never a made-up one."""
    estimate = topics.ParameterEstimate('thrust_gain', 1_763_700_000_123_456_789, 140.5, 1.25, 'output_error',
                                        'rad/s^2/V^2', 'flagged:lost_samples,angle_jump', -0.15, True)
    msg = topics.parameter_to_msg(estimate)
    assert list(msg.name) == list(topics.PARAMETER_FIELDS)
    assert list(msg.position) == [140.5, 139.25, 141.75, 1.25, 1.0, -0.15, 1.0]
    assert msg.header.frame_id == 'estimator=output_error;unit=rad/s^2/V^2;data=flagged:lost_samples,angle_jump'
    back = topics.msg_to_parameter(deserialize_message(serialize_message(msg), JointState), 'thrust_gain')
    assert back == estimate
    unknown = topics.parameter_to_msg(topics.ParameterEstimate('armature_resistance', 5, 1.08, float('nan'),
                                                               'motor_observer', 'ohm'))
    assert unknown.position[0] == 1.08 and all(v != v for v in unknown.position[1:4])       # NaN band and sigma
    assert unknown.position[4] == 0.0 and unknown.header.frame_id.endswith('data=clean')
    assert topics.parameter_topic('damping') == '/aeropend/parameters/damping'
    assert topics.parameter_topic('damping', 'weak_sindy') == '/aeropend/parameters/weak_sindy/damping'
    assert topics.parameter_topic('damping', 'motor_observer') == '/aeropend/parameters/damping'
    with pytest.raises(ValueError, match='not an aeropend parameter'):
        topics.msg_to_parameter(JointState(name=['a'], position=[1.0]))
