"""sim_node: the rig simulator standing in for the real rig on the same topics.

Publishes one ``sensor_msgs/JointState`` per acquisition sample on ``aeropend/samples`` (relative:
``/aeropend/samples`` in the default graph, ``/NAME/aeropend/samples`` in a rig's namespace ``/NAME``) at 490 Hz
(SensorData QoS) from :class:`aeropend_core.sim.simulate.RigSimulator`, with hidden effects and measurement noise
chosen by parameters, and obeys ``aeropend/duty_cmd`` (``std_msgs/Float64``, fraction 0..1; applied from the next
sample, clamped to ``duty_limit``).

Timing: sample k is stamped ``t0 + k·Ts`` with ``t0`` the node clock when publishing starts (never the time of
sending). A timer every ``publish_period`` seconds simulates and publishes every sample that is due since the
start (``floor(elapsed · realtime_factor / Ts)``), so the long-run rate is exact even when one tick is late: it
catches up by count. ``realtime_factor`` 1 is real time, 10 ten times faster (batch generation), 0 as fast as the
CPU allows (``max_block`` samples per tick; a best-effort subscriber may then drop samples).

Parameters (see ``config/sim_node.yaml``): ``effects`` (string array ``NAME=VALUE`` or ``NAME.PARAM=VALUE``),
``psnr_db`` (0 = no noise), ``quantise``, ``seed``, ``initial_angle`` [rad], ``duty_limit``, ``realtime_factor``,
``publish_period`` [s], ``max_block``, ``stop_after`` [s simulated, 0 = forever], ``wait_for_subscribers`` (start
publishing once that many subscribers of the samples are matched; for fast batch runs with a recorder).
"""
from __future__ import annotations

import math

from aeropend_ros._node_util import (  # first: prepares the ROS environment  # isort: skip
    ParameterError,
    check_unknown_overrides,
    DutySourceGuard,
    checked_duty,
    declare,
    run_node,
)
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from aeropend_core.model.effects import parse_effect_assignments
from aeropend_core.errors import AeropendError
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, SAMPLE_TIME
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import RigSimulator
from aeropend_ros import topics

#: Samples simulated and published at most per timer tick when catching up (keeps the executor responsive).
CATCH_UP_LIMIT = 490


class SimNode(Node):
    """Simulated rig: the model with hidden effects and noise, publishing samples and obeying duty commands.

    Parameters
    ----------
    node_name : str
        The node's name.
    guard_duty_sources : bool
        Refuse duty commands while two sources send them (:class:`aeropend_ros._node_util.DutySourceGuard`). Needs
        an executor that delivers message info (SingleThreadedExecutor, as in ``aeropend run``); rclpy's
        EventsExecutor does not, so the standalone node runs without it.
    **kwargs
        Passed to ``rclpy.node.Node``.
    """

    def __init__(self, node_name: str = 'sim_node', guard_duty_sources: bool = False, **kwargs) -> None:
        super().__init__(node_name, **kwargs)
        effect_texts = declare(self, 'effects', [''],
                               'hidden effects, NAME=VALUE or NAME.PARAM=VALUE (aeropend effects lists them)',
                               read_only=True)
        psnr_db = declare(self, 'psnr_db', 50.0, 'measurement noise PSNR [dB] on Va, Ia, angle; 0 = no noise',
                          read_only=True, low=0.0, high=200.0)
        quantise = declare(self, 'quantise', True, 'quantise angle (10 bit) and current like the rig ADC',
                           read_only=True)
        seed = declare(self, 'seed', 0, 'seed of the noise generator', read_only=True, low=0, high=2**31 - 1,
                       integer=True)
        initial_angle = declare(self, 'initial_angle', 0.0, 'initial rod angle [rad], at rest', read_only=True,
                                low=-math.pi, high=math.pi)
        declare(self, 'duty_limit', 0.7, 'safety cap on the commanded duty fraction', low=0.0, high=1.0)
        self.realtime_factor = declare(self, 'realtime_factor', 1.0,
                                       '1 = real time, >1 faster, 0 = as fast as possible', read_only=True,
                                       low=0.0, high=1000.0)
        publish_period = declare(self, 'publish_period', 0.004, 'timer period [s]; due samples are published '
                                 'at each tick', read_only=True, low=0.0005, high=0.1)
        self.max_block = declare(self, 'max_block', 49, 'samples per tick when realtime_factor = 0',
                                 read_only=True, low=1, high=4900, integer=True)
        self.stop_after = declare(self, 'stop_after', 0.0, 'stop publishing after this simulated time [s]; '
                                  '0 = run forever', read_only=True, low=0.0, high=1e6)

        self.wait_for_subscribers = declare(self, 'wait_for_subscribers', 0, 'start publishing only when this '
                                            'many subscribers of the samples are matched (batch runs with a '
                                            'recorder)', read_only=True, low=0, high=100, integer=True)
        check_unknown_overrides(self)
        try:
            effects = parse_effect_assignments([text for text in effect_texts if text.strip()])
        except AeropendError as error:
            raise ParameterError(f'{self.get_name()}: parameter effects: {error}; fix -p "effects:=[\'NAME=VALUE\']" '
                                 'or the params file') from None
        noise = MeasurementNoise(psnr_db=psnr_db if psnr_db > 0 else None, quantise=bool(quantise))
        self.simulator = RigSimulator(DEFAULT_PARAMETERS, effects, SAMPLE_TIME, noise, int(seed),
                                      float(initial_angle))
        self.sample_time = SAMPLE_TIME
        self.sequence = 0
        self.commanded_duty = 0.0
        self.finished = False
        self._message = JointState()

        self.publisher = self.create_publisher(JointState, topics.SAMPLES, topics.samples_qos())
        if guard_duty_sources:
            self.duty_guard = DutySourceGuard(self, topics.DUTY_COMMAND, self._refuse_duty)
            self.create_subscription(Float64, topics.DUTY_COMMAND, self._on_guarded_duty, topics.command_qos())
        else:
            self.duty_guard = None
            self.create_subscription(Float64, topics.DUTY_COMMAND, self._on_duty, topics.command_qos())
        self.start_ns = self.get_clock().now().nanoseconds
        self.started = self.wait_for_subscribers == 0
        self.timer = self.create_timer(publish_period, self._on_timer)
        hidden = ', '.join(f'{name} {values}' for name, values in effects.items()) or 'none'
        self.get_logger().debug(f'hidden effects: {hidden}')
        self.get_logger().info(
            f'simulating the rig at {1 / SAMPLE_TIME:.0f} Hz on {self.publisher.topic_name} '
            f'(realtime factor {self.realtime_factor:g}, noise {psnr_db:g} dB, {len(effects)} hidden effect(s))')

    # ------------------------------------------------------------------------------------------------------------
    def _on_duty(self, msg: Float64) -> None:
        self.commanded_duty, _ = checked_duty(self, float(msg.data), 'duty_limit')

    def _on_guarded_duty(self, msg: Float64, msg_info) -> None:
        if self.duty_guard.accept(msg_info):
            self._on_duty(msg)

    def _refuse_duty(self) -> None:
        """Two sources command this rig: hold the duty at 0 (DutySourceGuard)."""
        self.commanded_duty = 0.0

    def _samples_due(self) -> int:
        if self.realtime_factor <= 0.0:
            return self.sequence + int(self.max_block)
        elapsed = (self.get_clock().now().nanoseconds - self.start_ns) * 1e-9
        return int(elapsed * self.realtime_factor / self.sample_time) + 1

    def _on_timer(self) -> None:
        if self.finished:
            return
        if not self.started:
            if self.publisher.get_subscription_count() < self.wait_for_subscribers:
                return
            self.started = True
            self.start_ns = self.get_clock().now().nanoseconds     # the acquisition clock starts now
            self.get_logger().info(f'{self.wait_for_subscribers} subscriber(s) matched: publishing starts')
        due = self._samples_due()
        if self.stop_after > 0.0:
            due = min(due, int(round(self.stop_after / self.sample_time)))
        count = min(due - self.sequence, CATCH_UP_LIMIT)
        if count > 0:
            self.publish_block(count)
        if self.stop_after > 0.0 and self.sequence >= int(round(self.stop_after / self.sample_time)):
            self.finished = True
            self.timer.cancel()
            self.get_logger().info(f'stop_after reached: {self.sequence} samples published')

    def publish_block(self, count: int) -> None:
        """Simulate `count` samples at the commanded duty and publish them, stamped by their sample number."""
        duty = min(max(self.commanded_duty, 0.0), float(self.get_parameter('duty_limit').value))
        try:
            block = self.simulator.run([duty] * count)
        except (AeropendError, RuntimeError, ValueError) as error:
            self.get_logger().error(f'simulation failed: {error}; stopping')
            self.finished = True
            self.timer.cancel()
            return
        msg = self._message
        for k in range(count):
            sequence = self.sequence + k
            stamp_ns = self.start_ns + round(sequence * self.sample_time * 1e9)
            sample = topics.Sample(stamp_ns, float(block.angle[k]), float(block.armature_voltage[k]),
                                   float(block.armature_current[k]), float(block.duty[k]), sequence)
            self.publisher.publish(topics.sample_to_msg(sample, msg))
        self.sequence += count


def main(args=None) -> int:
    """Run the sim node until Ctrl-C (or ``stop_after``)."""
    # EventsExecutor (a third of the CPU at 490 Hz): it cannot deliver message info, so the standalone node runs
    # without the duty-source guard (SimNode(guard_duty_sources=True) in `aeropend run` has it).
    return run_node(SimNode, args, until=lambda node: node.finished)


if __name__ == '__main__':
    raise SystemExit(main())
