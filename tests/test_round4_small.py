"""Issue 43, item 8: a calibration YAML without the bridge's section (empty, a lone .nan, another node's file) or
with a value that is not a number is refused, not taken silently as "no calibration"; the bridge's clock-fault
text says the measured period, not the tolerance bound the stamping slope is clamped to.
"""
from __future__ import annotations

from types import SimpleNamespace

import pytest

from aeropend_core.errors import AeropendError
from aeropend_core.rig import calibration as C


@pytest.mark.parametrize(('text', 'words'), [
    ('', 'empty'),
    ('.nan\n', 'no mapping'),
    ('other_node:\n  ros__parameters: {a: 1}\n', 'has no /**/serial_bridge_node section'),
    ('/**/serial_bridge_node:\n  ros__parameters:\n    angle_zero: .nan\n', 'angle_zero is nan'),
    ('/**/serial_bridge_node:\n  ros__parameters:\n    current_scale: .inf\n', 'current_scale is inf'),
])
def test_a_calibration_file_without_calibration_is_refused(tmp_path, text, words):
    path = tmp_path / 'calibration.yaml'
    path.write_text(text)
    with pytest.raises(AeropendError, match=words.replace('*', r'\*')) as caught:
        C.read_calibration_file(path)
    assert '\n' not in str(caught.value)


def test_a_calibration_file_with_its_section_is_read(tmp_path):
    path = tmp_path / 'calibration.yaml'
    path.write_text('serial_bridge_node:\n  ros__parameters:\n    angle_zero: 510\n')       # an old file: no /**/
    assert C.read_calibration_file(path) == {'angle_zero': 510}


def test_clock_fault_text_says_the_measured_period():
    from aeropend_ros.serial_bridge_node import SerialBridgeNode
    nominal = 1 / 490.196
    clock = SimpleNamespace(rate_error=0.015, nominal_period=nominal, period=nominal * 1.006,   # clamped to +0.6 %
                            rate_error_bound=0.001, max_drift=0.006)
    text = SerialBridgeNode._rate_text(SimpleNamespace(clock_model=clock))
    assert f'measured period {nominal * 1.015 * 1e3:.4f} ms' in text, text
    assert 'tolerance ±0.60 %' in text


def test_messages_arriving_after_a_failed_write_count_as_received(tmp_path):
    """After a full disk the recorder drops what arrives, and counts it as received: aeropend run waits for the
    in-flight samples to be received before it stops, and waited its whole 30 s drain deadline (measured: 31 s from
    'recording stopped' to the exit, now 1.3 s, with a 300 KiB tmpfs as the record folder)."""
    import rclpy

    from aeropend_ros.recorder_node import RecorderNode
    from aeropend_ros.testing import private_domain_id
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=private_domain_id(0.3))
    try:
        node = RecorderNode(context=context, start_parameter_services=False, enable_rosout=False,
                            cli_args=['--ros-args', '-p', f'output:={tmp_path / "bag"}'])
        try:
            node._failed.set()
            queued = len(node._queue)
            node._enqueue('/aeropend/samples', b'\x00\x01\x00\x00', {})
            assert node.received_counts.get('/aeropend/samples') == 1 and node._dropped == 1
            assert len(node._queue) == queued               # not queued for writing
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
