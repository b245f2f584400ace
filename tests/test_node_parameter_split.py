"""The identification and recorder nodes validate a parameter set in one callback and apply it in another (issue
#44, as serial_bridge_node and the ROS demos do): a set that any check refuses changes nothing, an accepted one is
applied once, after every check."""
from __future__ import annotations

from tests.ros_helpers import private_domain_id


def test_identification_node_applies_effects_only_after_every_check():
    import rclpy
    from rclpy.parameter import Parameter

    from aeropend_ros.identification_node import IdentificationNode
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=private_domain_id())
    try:
        node = IdentificationNode(context=context, start_parameter_services=False, enable_rosout=False)
        try:
            assert node.effects == ()
            refused = node.set_parameters([Parameter('effects', value=['no_such_effect'])])[0]
            assert not refused.successful and 'no_such_effect' in refused.reason and 'unchanged' in refused.reason
            assert node.effects == ()                              # the validator changed nothing
            # a set where another check refuses a second parameter (NaN): the valid effects are not applied either
            refused = node.set_parameters_atomically([Parameter('effects', value=['coulomb_friction']),
                                                      Parameter('hop_s', value=float('nan'))])
            assert not refused.successful and node.effects == ()
            accepted = node.set_parameters([Parameter('effects', value=['coulomb_friction'])])[0]
            assert accepted.successful and node.effects == ('coulomb_friction',)
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


def test_recorder_node_applies_a_period_only_after_every_check(tmp_path):
    import rclpy
    from rclpy.parameter import Parameter

    from aeropend_ros.recorder_node import RecorderNode
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=private_domain_id())
    try:
        node = RecorderNode(context=context, start_parameter_services=False, enable_rosout=False,
                            cli_args=['--ros-args', '-p', f'output:={tmp_path / "bag"}'])
        try:
            before = node._poll_timer.timer_period_ns
            refused = node.set_parameters([Parameter('poll_period', value=5.0)])[0]       # above its range
            assert not refused.successful and node._poll_timer.timer_period_ns == before
            refused = node.set_parameters([Parameter('poll_period', value=float('nan'))])[0]
            assert not refused.successful and node._poll_timer.timer_period_ns == before
            accepted = node.set_parameters([Parameter('poll_period', value=0.05)])[0]
            assert accepted.successful and node._poll_timer.timer_period_ns == 50_000_000
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
