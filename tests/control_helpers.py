"""A device's closed-loop commands over its serial port, for the firmware (simavr) and emulator tests."""
from __future__ import annotations

import time

from aeropend_core.rig import protocol as P


class Device:
    """A device (firmware in simavr or the pty emulator) over a pyserial port: commands, ACKs, every message kept."""

    def __init__(self, link) -> None:
        self.link = link
        self.decoder = P.FrameDecoder()
        self.messages: list = []

    def read(self, seconds: float, until=None) -> list:
        """Messages read for up to `seconds`, stopping early when `until(new messages)` is true."""
        start = len(self.messages)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.messages += self.decoder.feed(self.link.read(max(1, self.link.in_waiting)))
            if until is not None and until(self.messages[start:]):
                break
        return self.messages[start:]

    def ack(self, command: bytes, timeout: float = 5.0) -> P.AckFrame:
        """Send one acknowledged command and return its ACK."""
        self.link.write(command)
        new = self.read(timeout, until=lambda ms: any(isinstance(m, P.AckFrame) for m in ms))
        acks = [m for m in new if isinstance(m, P.AckFrame)]
        assert len(acks) == 1, new[-5:]
        return acks[0]

    def samples(self, count: int, kind=P.ControlSampleFrame, timeout: float = 10.0) -> list:
        """The next `count` (or more) messages of `kind`."""
        new = self.read(timeout, until=lambda ms: sum(isinstance(m, kind) for m in ms) >= count)
        found = [m for m in new if isinstance(m, kind)]
        assert len(found) >= count, new[-5:]
        return found

    def status(self, timeout: float = 5.0) -> P.StatusFrame:
        """A fresh STATUS (REQUEST_STATUS)."""
        self.link.write(P.encode_command(P.REQUEST_STATUS))
        new = self.read(timeout, until=lambda ms: any(isinstance(m, P.StatusFrame) for m in ms))
        return [m for m in new if isinstance(m, P.StatusFrame)][-1]


def check_refusals_before_gains(device: Device) -> None:
    """Each refusal code a device gives before its coefficients are set (firmware and emulator alike)."""
    import math

    from aeropend_core.control import law
    ack = device.ack(P.encode_control_mode(P.MODE_CLOSED_LOOP))
    assert (ack.command, ack.result, ack.value) == (P.SET_CONTROL_MODE, P.ACK_REFUSED, 0.0)   # coefficients unset
    ack = device.ack(P.encode_control_mode(2))
    assert (ack.result, ack.value) == (P.ACK_OUT_OF_RANGE, 0.0)
    ack = device.ack(P.encode_coefficient(law.N_COEFFICIENTS, 1.0))                 # 14: no such coefficient
    assert (ack.command, ack.index, ack.result, ack.value) == (P.SET_CONTROL_COEFFICIENT, law.N_COEFFICIENTS,
                                                                P.ACK_UNKNOWN_INDEX, 0.0)
    for index, value in [(law.P, math.nan), (law.P, math.inf), (law.P, -1.0), (law.D_POLE, 1.0),
                         (law.U_MAX, 1.5), (law.U_MIN, -0.1), (law.AW_CODE, 3.0), (law.AW_CODE, 1.5),
                         (law.ANGLE_MIN, 3.5), (law.ANGLE_MAX, -3.5), (law.I_TS, -math.inf),
                         (law.SETPOINT_WEIGHT, 1.5), (law.SETPOINT_WEIGHT, -0.1), (law.SETPOINT_WEIGHT, math.nan)]:
        ack = device.ack(P.encode_coefficient(index, value))
        assert (ack.index, ack.result) == (index, P.ACK_OUT_OF_RANGE), (index, value, ack)
        if index == law.SETPOINT_WEIGHT:
            assert ack.value == 1.0                                        # b stays at its boot value, the plain PID
    for zero, scale in [(512.0, 0.0), (math.nan, 0.006), (512.0, math.inf)]:
        ack = device.ack(P.encode_angle_calibration(zero, scale))
        assert (ack.command, ack.result, ack.value) == (P.SET_ANGLE_CALIBRATION, P.ACK_OUT_OF_RANGE, 0.0)


def check_thirteen_coefficients_close_the_loop(device: Device, gains) -> None:
    """A host that knows only the 13 coefficients before the setpoint weight (as before it existed) may close the
    loop: the device's b stays at its boot value 1 (the plain PID). Then back to open loop (duty 0). For a device
    at boot, in open loop, with `gains` inside the boot limits."""
    from aeropend_core.control import law
    from aeropend_core.rig.control_link import GainsUpload
    upload = GainsUpload(gains)
    for index in range(law.SETPOINT_WEIGHT):
        ack = device.ack(upload.command(index))
        assert (ack.index, ack.result) == (index, P.ACK_OK), ack
    ack = device.ack(P.encode_control_mode(P.MODE_CLOSED_LOOP))
    assert (ack.result, ack.value) == (P.ACK_OK, 1.0)
    ack = device.ack(P.encode_coefficient(law.SETPOINT_WEIGHT, 2.0))          # refused: what it holds is 1
    assert (ack.index, ack.result, ack.value) == (law.SETPOINT_WEIGHT, P.ACK_OUT_OF_RANGE, 1.0)
    ack = device.ack(P.encode_control_mode(P.MODE_OPEN_LOOP))
    assert (ack.result, ack.value) == (P.ACK_OK, 0.0)


def check_refusals_after_gains(device: Device) -> None:
    """Limits refused against their stored partner, and references outside the window (gains of the tests: u in
    [0, 0.6], i in [-0.2, 0.2], angle in [-0.35, 1.75]; no reference stored yet)."""
    import math

    import numpy as np

    from aeropend_core.control import law
    ack = device.ack(P.encode_coefficient(law.ANGLE_MIN, 1.75))
    assert (ack.result, ack.value) == (P.ACK_OUT_OF_RANGE, np.float32(-0.35))      # angle_min >= angle_max
    ack = device.ack(P.encode_coefficient(law.I_MAX, -0.3))
    assert (ack.result, ack.value) == (P.ACK_OUT_OF_RANGE, np.float32(0.2))
    ack = device.ack(P.encode_coefficient(law.U_MIN, 0.7))
    assert ack.result == P.ACK_OUT_OF_RANGE
    for reference, feedforward in [(2.0, 0.2), (-0.5, 0.2), (0.5, 1.5), (0.5, -0.1), (math.nan, 0.2)]:
        ack = device.ack(P.encode_reference(reference, feedforward))
        assert (ack.command, ack.result, ack.value) == (P.SET_REFERENCE, P.ACK_OUT_OF_RANGE, 0.0)


class Watcher:
    """In-test node: samples and control telemetry by sequence number; publishes references, sets parameters."""

    def __init__(self, context) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.parameter_client import AsyncParameterClient
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray

        from aeropend_ros import topics
        self.topics = topics
        self.node = rclpy.create_node('bridge_closed_loop_watcher', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.samples: dict = {}
        self.control: dict[int, list[float]] = {}
        deep = QoSProfile(depth=2000, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.node.create_subscription(JointState, topics.SAMPLES_TOPIC, self._on_sample, deep)
        self.node.create_subscription(JointState, topics.CONTROL_TOPIC, self._on_control, deep)
        self.reference = self.node.create_publisher(Float64MultiArray, topics.REFERENCE_TOPIC, topics.command_qos())
        self.Float64MultiArray = Float64MultiArray
        self.parameters = AsyncParameterClient(self.node, '/serial_bridge_node')

    def _on_sample(self, msg) -> None:
        sample = self.topics.msg_to_sample(msg)
        self.samples[sample.sequence] = sample

    def _on_control(self, msg) -> None:
        assert list(msg.name) == list(self.topics.CONTROL_NAMES)
        self.control[int(msg.position[-1])] = list(msg.position)

    def wait_for(self, condition, timeout: float = 30.0) -> bool:
        """Poll `condition` until true or `timeout` [s], handling every message that arrived between two polls (one
        callback per poll fell behind ~1,000 telemetry messages/s on a loaded machine: the watcher's view then lagged
        the device by seconds and its best-effort subscriptions dropped samples)."""
        from tests.ros_helpers import wait_for

        def drained() -> bool:
            for _ in range(500):
                self.executor.spin_once(timeout_sec=0.0)
            return condition()
        return condition() or wait_for(drained, timeout, executor=self.executor)

    def set(self, **values):
        """``ros2 param set`` on the bridge (one request): the SetParametersResult list."""
        from rclpy.parameter import Parameter
        assert self.wait_for(self.parameters.services_are_ready, 120.0), 'no parameter service'
        future = self.parameters.set_parameters([Parameter(name, value=value) for name, value in values.items()])
        self.executor.spin_until_future_complete(future, timeout_sec=30.0)
        assert future.done(), 'set_parameters timed out'
        return future.result().results

    def publish_reference(self, *data: float) -> None:
        self.reference.publish(self.Float64MultiArray(data=[float(value) for value in data]))

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
