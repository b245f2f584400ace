"""A window that comes due while the identification worker is busy is never skipped silently: it is counted and
reported on /diagnostics (WARN) with its time span and the reason (received by a real subscriber over DDS)."""
from __future__ import annotations

from concurrent.futures import Future

from tests.ros_helpers import private_domain_id, wait_for


def _sample_bytes(sequence: int, stamp_ns: int) -> bytes:
    from rclpy.serialization import serialize_message

    from aeropend_ros import topics
    return serialize_message(topics.sample_to_msg(topics.Sample(stamp_ns, 0.1, 1.0, 0.2, 0.3, sequence)))


def test_a_skipped_window_is_reported_with_its_reason():
    domain_id = private_domain_id()
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from rclpy.parameter import Parameter

    from aeropend_core.model.parameters import SAMPLE_TIME
    from aeropend_ros import topics
    from aeropend_ros.identification_node import IdentificationNode
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = IdentificationNode(context=context, parameter_overrides=[Parameter('window_s', value=4.0),
                                                                    Parameter('hop_s', value=1.0)])
    listener = rclpy.create_node('skip_listener', context=context)
    from rclpy.executors import SingleThreadedExecutor
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(listener)
    received: list = []
    listener.create_subscription(DiagnosticArray, topics.DIAGNOSTICS_TOPIC,
                                 lambda msg: received.extend(s for s in msg.status if 'skipped' in s.message),
                                 topics.diagnostics_qos())
    start_ns = 1_000_000_000_000
    sequence = 0

    def feed(seconds: float) -> None:
        nonlocal sequence
        for _ in range(int(round(seconds / SAMPLE_TIME))):
            node._on_sample(_sample_bytes(sequence, start_ns + round(sequence * SAMPLE_TIME * 1e9)))
            sequence += 1

    try:
        # the listener must be matched before the reports: wait for discovery, not a fixed time
        assert wait_for(lambda: node.diagnostics_publisher.get_subscription_count() > 0, 30.0, executor=executor)
        node.pending = Future()          # the worker busy starting (nothing submitted yet): never done
        feed(4.5)                        # the first window (0-4 s) comes due
        assert node.windows_skipped == 1 and node.windows_submitted == 0
        assert wait_for(lambda: len(received) >= 1, 30.0, executor=executor), 'no /diagnostics report of the skip'
        first = received[0]
        values = {kv.key: kv.value for kv in first.values}
        assert first.level == DiagnosticStatus.WARN
        assert 'window 0.0-4.0 s skipped' in first.message and 'still starting' in first.message, first.message
        assert values['windows_skipped'] == '1' and 'still starting' in values['skip_reason']
        assert abs(float(values['skipped_window_stop_s']) - 4.0) < 0.01
        node.windows_submitted = 1       # a window in the worker now: the next skip names that reason
        feed(1.0)
        assert node.windows_skipped == 2
        assert wait_for(lambda: len(received) >= 2, 30.0, executor=executor), 'the second skip was not reported'
        assert 'previous window is still being computed' in received[1].message, received[1].message
        assert {kv.key: kv.value for kv in received[1].values}['windows_skipped'] == '2'
    finally:
        executor.shutdown()
        listener.destroy_node()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
