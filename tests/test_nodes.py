"""Real nodes as separate processes over DDS (local discovery, private domain): sim, excitation, identification.

Every wait polls with ``wait_for`` (spinning the in-test listener) instead of sleeping fixed times.
"""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

from tests.ros_helpers import NodeProcess, private_domain_id, use_domain, wait_for

DOMAIN_ID = private_domain_id()
use_domain(DOMAIN_ID)

import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.parameter_client import AsyncParameterClient  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Bool, Float64  # noqa: E402

from aeropend_core.model import DEFAULT_PARAMETERS, SAMPLE_TIME  # noqa: E402
from aeropend_ros import topics  # noqa: E402

pytestmark = pytest.mark.timeout(180)

#: Discovery plus the first message can take a few seconds on a loaded machine (NOTES.md section 5).
DISCOVERY_TIMEOUT = 20.0


class Listener:
    """In-test node recording samples (with receive times), duty commands and the excitation's done flag."""

    def __init__(self, context) -> None:
        self.node = rclpy.create_node('test_listener', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.samples: list[topics.Sample] = []
        self.receive_times: list[float] = []
        self.duty_commands: list[float] = []
        self.done: list[bool] = []
        # Best effort like the contract, but a deep receive queue: a slow Python listener on a loaded machine
        # must not turn its own backlog into 'lost' samples of the publisher under test.
        deep = QoSProfile(depth=500, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.node.create_subscription(JointState, topics.SAMPLES_TOPIC, self._on_sample, deep)
        self.node.create_subscription(Float64, topics.DUTY_COMMAND_TOPIC,
                                      lambda msg: self.duty_commands.append(msg.data), topics.command_qos())
        from aeropend_ros.excitation_node import DONE_TOPIC, done_qos
        self.node.create_subscription(Bool, DONE_TOPIC, lambda msg: self.done.append(msg.data), done_qos())
        self.duty_publisher = self.node.create_publisher(Float64, topics.DUTY_COMMAND_TOPIC, topics.command_qos())

    def _on_sample(self, msg) -> None:
        self.receive_times.append(time.monotonic())
        self.samples.append(topics.msg_to_sample(msg))

    def wait_for(self, condition, timeout: float = DISCOVERY_TIMEOUT) -> bool:
        return wait_for(condition, timeout, executor=self.executor)

    def spin_for(self, seconds: float) -> None:
        """Keep receiving for `seconds` (a measurement window, not a synchronisation sleep)."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.01)

    def clear(self) -> None:
        self.samples.clear()
        self.receive_times.clear()


@pytest.fixture(scope='module')
def ros_context():
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    yield context
    rclpy.try_shutdown(context=context)


@pytest.fixture(scope='module')
def listener(ros_context):
    listener = Listener(ros_context)
    yield listener
    listener.executor.shutdown()
    listener.node.destroy_node()


@pytest.fixture(scope='module')
def sim(listener):
    """A real-time sim without noise (exact values for the duty checks)."""
    with NodeProcess('aeropend_ros.sim_node', ['-p', 'psnr_db:=0.0', '-p', 'quantise:=false',
                                               '-p', 'duty_limit:=0.7'], DOMAIN_ID) as process:
        assert listener.wait_for(lambda: len(listener.samples) > 10), process.output()
        yield process


def set_parameters(context, node_name: str, parameters: list[Parameter], timeout: float = DISCOVERY_TIMEOUT):
    """The ``ros2 param set`` equivalent: returns the list of SetParametersResult."""
    helper = rclpy.create_node('test_param_client', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(helper)
    try:
        client = AsyncParameterClient(helper, node_name)
        assert wait_for(client.services_are_ready, timeout, executor=executor), f'no parameter service {node_name}'
        future = client.set_parameters(parameters)
        executor.spin_until_future_complete(future, timeout_sec=timeout)
        assert future.done(), 'set_parameters timed out'
        return future.result().results
    finally:
        executor.shutdown()
        helper.destroy_node()


# --------------------------------------------------------------------------------------------------------------
def test_sim_rate_490hz_cross_process(sim, listener):
    """Receive rate and stamp spacing over a 5 s window: 490 Hz +- 1 %, stamps exactly k Ts apart."""
    listener.clear()
    window = 5.0
    listener.spin_for(window)
    samples, receive = listener.samples, np.array(listener.receive_times)
    count = len(samples)
    sequence = np.array([s.sequence for s in samples])
    stamps = np.array([s.stamp_ns for s in samples], dtype=np.int64)
    assert np.all(np.diff(sequence) >= 1), 'sequence numbers must increase'
    # Rate of the publisher: samples it produced (sequence span) per second of receive (wall) time.
    produced = sequence[-1] - sequence[0]
    rate = produced / (receive[-1] - receive[0])
    assert abs(rate - 490.0) <= 4.9, f'{produced} samples in {receive[-1] - receive[0]:.3f} s = {rate:.1f} Hz'
    # Receive count over the fixed window: also 490 Hz +- 1 %, i.e. nothing lost on the way.
    rate_by_count = count / window
    assert abs(rate_by_count - 490.0) <= 4.9, f'received {count} samples in {window} s = {rate_by_count:.1f} Hz'
    missing = int(np.sum(np.diff(sequence) - 1))
    assert missing <= 0.01 * count, f'{missing} samples lost of {count}'
    # Stamps are sample counter x Ts anchored at the start: exact to the rounding nanosecond.
    expected = (sequence - sequence[0]) * SAMPLE_TIME * 1e9
    assert np.max(np.abs((stamps - stamps[0]) - expected)) <= 1.0
    # Stamp time and receive (wall) time advance together: no drift of the acquisition clock.
    stamp_span = (stamps[-1] - stamps[0]) * 1e-9
    receive_span = receive[-1] - receive[0]
    assert abs(stamp_span / receive_span - 1.0) < 0.01, (stamp_span, receive_span)
    # Stamps are acquisition times on the ROS clock (system time), close to the receive wall time.
    assert abs(stamps[-1] * 1e-9 - time.time()) < 1.0


def test_sim_obeys_duty_command_with_cap(sim, listener):
    """A command applies from one sample on (Va = eq 8 of it), and a command over duty_limit is clamped."""
    assert listener.wait_for(lambda: listener.duty_publisher.get_subscription_count() > 0)
    for command, applied in ((0.45, 0.45), (0.95, 0.7), (0.0, 0.0)):
        listener.clear()
        listener.duty_publisher.publish(Float64(data=command))
        assert listener.wait_for(lambda: sum(1 for s in listener.samples if s.duty == applied) > 20, 5.0), \
            f'duty {applied} never seen after command {command}'
        duties = np.array([s.duty for s in listener.samples])
        first = int(np.argmax(duties == applied))
        assert np.all(duties[first:] == applied), 'duty must stay at the command from its first sample on'
        voltage = np.array([s.armature_voltage for s in listener.samples])[first:]
        assert np.allclose(voltage, DEFAULT_PARAMETERS.voltage_from_duty(applied))
    # The rig responds: current flows at duty 0.7 and the rod deflects (checked on the 0.7 plateau below).


def test_sim_rejects_out_of_range_parameter(sim, ros_context):
    results = set_parameters(ros_context, '/sim_node', [Parameter('duty_limit', value=1.5)])
    assert not results[0].successful and results[0].reason
    results = set_parameters(ros_context, '/sim_node', [Parameter('psnr_db', value=20.0)])
    assert not results[0].successful and 'read-only' in results[0].reason.lower()
    results = set_parameters(ros_context, '/sim_node', [Parameter('duty_limit', value=0.7)])
    assert results[0].successful


def test_sim_unknown_effect_exits_with_reason():
    with NodeProcess('aeropend_ros.sim_node', ['-p', "effects:=['no_such_effect=1']"], DOMAIN_ID) as process:
        process.process.wait(30)
        assert process.process.returncode == 2
        assert 'unknown effect' in process.output() and 'coulomb_friction' in process.output()


def test_excitation_plays_steps_with_cap_and_returns_to_zero(sim, listener):
    """Steps [0.3, 0.9 -> capped 0.6, 0.2] of 0.5 s each, timed by the sample stamps, then 0 and done."""
    listener.duty_commands.clear()
    listener.done.clear()
    listener.clear()
    steps = '[0.3, 0.5, 0.9, 0.5, 0.2, 0.5]'
    with NodeProcess('aeropend_ros.excitation_node',
                     ['-p', 'schedule:=steps', '-p', f'steps:={steps}', '-p', 'duty_cap:=0.6',
                      '-p', 'start_delay:=0.3', '-p', 'republish_period:=10.0'], DOMAIN_ID) as process:
        assert listener.wait_for(lambda: True in listener.done, 30.0), process.output()
        assert listener.wait_for(lambda: process.process.poll() is not None, 10.0), 'excitation did not exit'
        assert process.process.returncode == 0, process.output()
        assert 'clamped' in process.output()
    distinct = [d for i, d in enumerate(listener.duty_commands) if i == 0 or d != listener.duty_commands[i - 1]]
    assert distinct == [0.0, 0.3, 0.6, 0.2, 0.0]
    assert listener.wait_for(lambda: listener.samples and listener.samples[-1].duty == 0.0, 5.0)
    # Plateaus as applied by the sim: each step held 0.5 s of sample time (+- transport latency).
    duties = np.array([s.duty for s in listener.samples])
    times = np.array([s.stamp_ns for s in listener.samples]) * 1e-9
    for level in (0.3, 0.6, 0.2):
        held = times[duties == level]
        assert held.size and abs((held[-1] - held[0]) - 0.5) < 0.05, (level, held[-1] - held[0])
    rod = np.array([s.angle for s in listener.samples])[duties == 0.6]
    assert np.max(rod) > 0.05, 'the rod should swing up at duty 0.6'
    assert math.isfinite(rod[-1])
