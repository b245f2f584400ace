"""The sim node in closed loop, a real process over DDS (private domain, local discovery): the law's timing on the
measured angle, gains changed at run time, invalid gains refused with the reason, the latched angle trip.

Every wait polls with ``wait_for`` (spinning the in-test node) instead of sleeping fixed times.
"""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from tests.ros_helpers import NodeProcess, own_context, private_domain_id, use_domain, wait_for

DOMAIN_ID = private_domain_id()
use_domain(DOMAIN_ID)

import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.parameter_client import AsyncParameterClient  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64MultiArray, String  # noqa: E402

from aeropend_ros import topics  # noqa: E402
from aeropend_ros.sim_node import controller_config_qos, reference_qos  # noqa: E402

pytestmark = pytest.mark.timeout(300)

#: A node process's start (Python and numba imports, then discovery) on a loaded machine; waits end at once when
#: their condition holds.
START_TIMEOUT = 180.0
WAIT = 60.0
#: callbacks handled between two polls of a wait's condition (a quarter second of telemetry at 2x real time)
DRAIN = 500


class Watcher:
    """In-test node: samples and control telemetry by sequence number, the controller configurations; publishes
    references and sets the sim's parameters."""

    def __init__(self, context) -> None:
        self.node = rclpy.create_node('closed_loop_watcher', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.samples: dict[int, topics.Sample] = {}
        self.control: dict[int, tuple[int, list[float]]] = {}
        self.configs: list[dict] = []
        self._last = -1
        deep = QoSProfile(depth=2000, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.node.create_subscription(JointState, topics.SAMPLES_TOPIC, self._on_sample, deep)
        self.node.create_subscription(JointState, topics.CONTROL_TOPIC, self._on_control, deep)
        self.node.create_subscription(String, topics.CONTROLLER_CONFIG_TOPIC,
                                      lambda msg: self.configs.append(yaml.safe_load(msg.data)),
                                      controller_config_qos())
        self.reference = self.node.create_publisher(Float64MultiArray, topics.REFERENCE_TOPIC, reference_qos())
        self.parameters = AsyncParameterClient(self.node, '/sim_node')

    def _on_sample(self, msg) -> None:
        sample = topics.msg_to_sample(msg)
        self.samples[sample.sequence] = sample

    def _on_control(self, msg) -> None:
        assert list(msg.name) == list(topics.CONTROL_NAMES)
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        sequence = int(msg.position[-1])
        self.control[sequence] = (stamp, list(msg.position))
        self._last = max(self._last, sequence)

    def wait_for(self, condition, timeout: float = WAIT) -> bool:
        """Poll `condition` until true or `timeout` [s], draining every message that has arrived between two polls.

        The sim at 2x real time sends ~2,000 messages/s; one callback per poll (``spin_once``) fell behind on a
        loaded machine and the best-effort subscriptions then dropped most samples (73 of 490 kept at load 15).
        """
        def drained() -> bool:
            for _ in range(DRAIN):
                self.executor.spin_once(timeout_sec=0.0)
            return condition()
        return condition() or wait_for(drained, timeout, executor=self.executor)

    def last(self) -> int:
        """The newest control telemetry's sample sequence number (-1 before the first)."""
        return self._last

    def received_after(self, sequence: int) -> list[int]:
        """Sequence numbers after `sequence` whose sample arrived, in order."""
        return sorted(k for k in self.samples if k > sequence)

    def wait_received(self, sequence: int, count: int) -> list[int]:
        """Until `count` samples after `sequence` have arrived (a best-effort subscription may drop some under
        load, so a count, not a span of sequence numbers); their sequence numbers."""
        assert self.wait_for(lambda: len(self.received_after(sequence)) >= count), \
            f'fewer than {count} samples after {sequence} arrived'
        return self.received_after(sequence)

    def set(self, **values):
        """``ros2 param set`` for each value (one request): the SetParametersResult list."""
        assert self.wait_for(self.parameters.services_are_ready, START_TIMEOUT), 'no parameter service /sim_node'
        future = self.parameters.set_parameters([Parameter(name, value=value) for name, value in values.items()])
        self.executor.spin_until_future_complete(future, timeout_sec=WAIT)
        assert future.done(), 'set_parameters timed out'
        return future.result().results

    def get(self, name: str):
        future = self.parameters.get_parameters([name])
        self.executor.spin_until_future_complete(future, timeout_sec=WAIT)
        assert future.done(), 'get_parameters timed out'
        from rclpy.parameter import parameter_value_to_python
        return parameter_value_to_python(future.result().values[0])

    def hold(self, seconds: float) -> int:
        """Until the sim has answered `seconds` [s] of samples more (its own clock); the last sequence then."""
        target = self.last() + round(seconds * 490)
        assert self.wait_for(lambda: self.last() >= target), 'the control telemetry stopped'
        return self.last()


@pytest.fixture(scope='module')
def watcher():
    with own_context(DOMAIN_ID) as context:
        watcher = Watcher(context)
        yield watcher
        watcher.executor.shutdown()
        watcher.node.destroy_node()


@pytest.fixture(scope='module')
def sim(watcher):
    """A closed-loop sim at 2x real time with the rig's noise and quantisation, duty cap 0.7."""
    with NodeProcess('aeropend_ros.sim_node', ['-p', 'control_mode:=closed_loop', '-p', 'realtime_factor:=2.0',
                                               '-p', 'psnr_db:=50.0', '-p', 'duty_limit:=0.7'],
                     DOMAIN_ID) as process:
        assert watcher.wait_for(lambda: len(watcher.control) > 50 or process.process.poll() is not None,
                                START_TIMEOUT) and len(watcher.control) > 50, process.output()
        yield process


def _tracking(watcher, reference: float):
    watcher.reference.publish(Float64MultiArray(data=[reference]))
    assert watcher.wait_for(lambda: watcher.control[watcher.last()][1][0] == reference), 'reference not taken'
    end = watcher.hold(3.0)                          # settled (sim time)
    received = watcher.wait_received(end, 300)
    return np.array([watcher.samples[k].angle for k in received[:490]])


def test_closed_loop_tracks_with_one_sample_of_latency(sim, watcher):
    """The rod follows a reference from the topic; each sample's telemetry carries its stamp; the duty applied at
    sample k+1 is the law's clamped answer to sample k (one sample of latency, the rig's timing)."""
    angles = _tracking(watcher, 0.5)
    assert angles.size >= 300 and abs(np.mean(angles) - 0.5) < 0.03, np.mean(angles)
    config = watcher.configs[-1]
    assert config['control_mode'] == 'closed_loop' and config['gains']['p'] == 0.5 and len(config['gains_sha256']) == 64
    assert watcher.wait_for(lambda: len(set(watcher.samples) & set(watcher.control)) > 1100)
    both = sorted(set(watcher.samples) & set(watcher.control))
    names = topics.CONTROL_NAMES
    checked = 0
    for k in both:
        stamp, values = watcher.control[k]
        sample = watcher.samples[k]
        assert stamp == sample.stamp_ns
        assert values[names.index('duty')] == sample.duty          # the duty applied during the sample
        if k + 1 in watcher.samples and k > both[0] + 10:
            law = min(max(values[names.index('unsaturated')], 0.0), 0.8)      # u_clamp_min/max
            assert watcher.samples[k + 1].duty == pytest.approx(min(law, 0.7), abs=1e-12)   # then duty_limit
            checked += 1
    assert checked > 1000


def test_gains_changed_at_run_time_take_effect(sim, watcher):
    """u_clamp_max 0.2 at run time: from the sample after the change on (that one still applies the answer to the
    sample before, computed with the old gains), no duty above 0.2, and the rod sinks (to about 0.3 rad, where 0.2
    holds it); the configuration is published again (it names the first sample it applies to); then back."""
    _tracking(watcher, 0.5)
    before = len(watcher.configs)
    results = watcher.set(u_clamp_max=0.2)
    assert results[0].successful, results[0].reason
    assert watcher.wait_for(lambda: len(watcher.configs) > before)
    config = watcher.configs[-1]
    assert config['gains']['u_clamp_max'] == 0.2
    applies = config['applies_from_sequence']
    end = watcher.hold(3.0)
    watcher.wait_received(applies, 600)
    after = [watcher.samples[k].duty for k in watcher.received_after(applies)]
    assert len(after) > 500 and max(after) <= 0.2 + 1e-12, max(after)
    sunk = watcher.wait_received(end, 200)
    assert np.mean([watcher.samples[k].angle for k in sunk]) < 0.4
    assert watcher.set(u_clamp_max=0.8)[0].successful


def test_invalid_gains_are_refused_with_the_reason(sim, watcher):
    results = watcher.set(u_clamp_min=0.9)          # above u_clamp_max 0.8
    assert not results[0].successful
    assert 'u_clamp_min' in results[0].reason and 'unchanged' in results[0].reason, results[0].reason
    assert watcher.get('u_clamp_min') == 0.0
    results = watcher.set(i_clamp_max=-1.0)         # below i_clamp_min -0.3
    assert not results[0].successful and 'i_clamp_min' in results[0].reason, results[0].reason
    results = watcher.set(antiwindup='sometimes')
    assert not results[0].successful and 'back_calculation' in results[0].reason, results[0].reason
    results = watcher.set(p=-1.0)                   # outside the parameter's declared range: rclpy says so
    assert not results[0].successful and 'p out of range' in results[0].reason, results[0].reason
    assert watcher.configs[-1]['gains']['p'] == 0.5
    results = watcher.set(setpoint_weight=1.5)      # b outside [0, 1]
    assert not results[0].successful and 'setpoint_weight out of range' in results[0].reason, results[0].reason
    assert watcher.get('setpoint_weight') == 1.0
    assert watcher.set(setpoint_weight=0.5)[0].successful          # accepted, applied, published
    assert watcher.wait_for(lambda: watcher.configs[-1]['gains']['setpoint_weight'] == 0.5)
    assert watcher.set(setpoint_weight=1.0)[0].successful


def test_angle_trip_latches_duty_zero_until_reset(sim, watcher):
    """angle_max below the rod's angle: the next sample trips the law, duty 0 and tripped from then on (latched,
    even after the limit is raised again) until a new reference arrives (as the firmware) or control_mode is set
    again."""
    tripped_index = topics.CONTROL_NAMES.index('tripped')

    def trip() -> int:
        _tracking(watcher, 0.5)
        before = watcher.last()
        assert watcher.control[before][1][tripped_index] == 0.0
        assert watcher.set(angle_max=0.4)[0].successful
        assert watcher.wait_for(lambda: watcher.control[watcher.last()][1][tripped_index] == 1.0)
        first = min(k for k, (_, values) in watcher.control.items() if values[tripped_index] == 1.0 and k > before)
        assert watcher.set(angle_max=1.75)[0].successful
        end = watcher.hold(2.0)
        after = watcher.wait_received(first, 400)
        assert len(after) > 300 and all(watcher.samples[k].duty == 0.0 for k in after)
        assert all(watcher.control[k][1][tripped_index] == 1.0 for k in after if k in watcher.control)
        return end

    def running() -> bool:
        last = watcher.last()
        return watcher.control[last][1][tripped_index] == 0.0 and last in watcher.samples and \
            watcher.samples[last].duty > 0.0

    trip()
    watcher.reference.publish(Float64MultiArray(data=[0.45]))       # a new reference restarts the law
    assert watcher.wait_for(running)
    trip()
    assert watcher.set(control_mode='closed_loop')[0].successful    # so does setting the mode
    assert watcher.wait_for(running)
    assert sim.process.poll() is None
    assert 'safety trip: measured angle' in sim.output()


def test_bad_gains_at_start_up_exit_2_with_one_line():
    with NodeProcess('aeropend_ros.sim_node', ['-p', 'control_mode:=closed_loop', '-p', 'u_clamp_min:=0.9',
                                               '-p', 'u_clamp_max:=0.5'], DOMAIN_ID) as process:
        process.process.wait(START_TIMEOUT)
        output = process.output()
        assert process.process.returncode == 2, output
        assert 'controller gains' in output and 'u_clamp_min' in output and 'Traceback' not in output, output


def test_controller_file_gains_are_the_defaults_and_a_parameter_wins(tmp_path):
    """controller_file: its gains are the parameters' defaults (`-p` still wins); its model gives the feedforward;
    reference_file: a schedule played from the first sample (the node built in this process, not spun)."""
    from aeropend_core.control.controller_file import Controller
    from aeropend_core.control.law import PidGains
    from aeropend_core.model.effects import resolve_effects
    from aeropend_ros.sim_node import SimNode
    path = tmp_path / 'gains.yaml'
    Controller(PidGains(p=1.25, i=0.2, antiwindup='none'), effects=resolve_effects({'angle_offset': 0.05})).write(path)
    (tmp_path / 'steps.yaml').write_text('steps:\n  - {angle_deg: 30, hold: 2}\n')
    with own_context(private_domain_id()) as context:
        node = SimNode(context=context, parameter_overrides=[
            Parameter('controller_file', value=str(path)), Parameter('i', value=0.3),
            Parameter('reference_file', value=str(tmp_path / 'steps.yaml'))])
        try:
            assert node.get_parameter('p').value == 1.25 and node.get_parameter('antiwindup').value == 'none'
            assert node.get_parameter('i').value == 0.3 and node.gains.i == 0.3 and node.gains.p == 1.25
            assert node.feedforward_map.effects == {'angle_offset': {'angle_offset': 0.05}}
            assert node.schedule.duration == 4.0 and node.schedule_samples == 1960
            config = node.controller_config()
            assert config['model']['sha256'] == Controller.load(path).model_sha256
            assert config['schedule_sha256'] == node.schedule.sha256 and config['gains']['i'] == 0.3
        finally:
            node.destroy_node()
