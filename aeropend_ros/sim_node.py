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

Closed loop (``control_mode: closed_loop``; default ``open_loop`` is the behaviour above): the node runs the
controller law (:class:`aeropend_core.control.law.PidController`) with the rig's timing
(:class:`aeropend_core.control.loop.ClosedLoopSimulation`): the measured (noisy, quantised) angle of sample k goes
to the law, whose duty is applied from sample k+1, capped by ``duty_limit``; duty commands are then ignored. Gains
are parameters named as ros2_control's pid_controller (``p``, ``i``, ``d``, ``derivative_filter_time``,
``i_clamp_min``/``max``, ``u_clamp_min``/``max``, ``antiwindup``, ``tracking_time_constant``,
``feedforward_gain``, ``setpoint_weight``, ``angle_min``/``max``), changeable at run time (checked together by
:meth:`PidGains.problems`; a refused change says why and leaves every gain as it was). The reference comes from
``aeropend/reference`` (``std_msgs/Float64MultiArray``, ``data = [reference_rad, feedforward_duty]``; without the
feedforward the model's static duty) or from a schedule (``reference_file``, or :meth:`SimNode.play_schedule`)
played from the next sample; while a schedule plays the topic is ignored, after it the last step is held. The
feedforward model is that of ``controller_file`` (whose gains are then the defaults of the gain parameters), else
the nominal model. Every sample has its telemetry on ``aeropend/control`` (``topics.CONTROL_NAMES``, the sample's
stamp; the fields of :class:`aeropend_core.control.loop.ClosedLoopRecord`: ``duty`` is the duty applied during that
sample, ``unsaturated``/``integral``/``tripped`` the law's state after answering its angle), and the configuration
(gains, model, schedule, their sha256) on ``aeropend/controller`` (YAML, transient local). A measured angle outside
[``angle_min``, ``angle_max``] trips the law: duty 0, latched, until ``control_mode`` is set again or (as the
firmware) a reference is accepted from the topic.
"""
from __future__ import annotations

import math

import numpy as np

from aeropend_ros._node_util import (  # first: prepares the ROS environment  # isort: skip
    ParameterError,
    check_unknown_overrides,
    DutySourceGuard,
    checked_duty,
    declare,
    run_node,
)
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray, String

from aeropend_core.control.law import ANTIWINDUP, PidGains
from aeropend_core.model.effects import parse_effect_assignments
from aeropend_core.errors import AeropendError
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, SAMPLE_TIME
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import RigSimulator
from aeropend_ros import topics
from aeropend_ros.control_parameters import (CONTROL_MODES, DEFAULT_GAINS, GAIN_HELP, GAIN_NAMES, GAIN_RANGES,
                                            NUMERIC_GAIN_NAMES, checked_reference, gain_problems,
                                            gain_refusal, gains_of)

#: Samples simulated and published at most per timer tick when catching up (keeps the executor responsive).
CATCH_UP_LIMIT = 490
def reference_qos() -> QoSProfile:
    """QoS of ``aeropend/reference``: reliable, keep last 10, volatile (as the duty command)."""
    return topics.command_qos()


def controller_config_qos() -> QoSProfile:
    """QoS of ``aeropend/controller``: reliable, transient local, depth 1 (a late subscriber gets the last one)."""
    return QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


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
        self._declare_control()
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
        self._start_control()
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
        if self.closed_loop and not self._duty_ignored_said:
            self._duty_ignored_said = True
            self.get_logger().warning('closed loop: duty commands are ignored (the law sets the duty; '
                                      'control_mode:=open_loop to command it)')

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
        if self.closed_loop:
            self._publish_closed_loop(count)
            return
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

    # -- closed loop ---------------------------------------------------------------------------------------------
    def _declare_control(self) -> None:
        """The closed loop's parameters; gains default to the controller file's (when given), else PidGains()."""
        from aeropend_core.control.loop import FeedforwardMap
        mode = declare(self, 'control_mode', 'open_loop', "'open_loop' (duty commands) or 'closed_loop' (the "
                       'controller law on the measured angle); setting it again resets the law (and a trip)',
                       choices=CONTROL_MODES)
        controller_file = declare(self, 'controller_file', '', 'controller YAML (aeropend control design): its '
                                  'gains are the defaults of the gain parameters, its model gives the feedforward; '
                                  'empty: PidGains defaults, the nominal model', read_only=True)
        reference_file = declare(self, 'reference_file', '', 'reference schedule YAML played in closed loop from '
                                 'the first sample (steps: [{angle_deg: 20, hold: 5}, ...]); empty: the '
                                 'aeropend/reference topic', read_only=True)
        self.controller = None
        if controller_file:
            from aeropend_core.control.controller_file import Controller
            try:
                self.controller = Controller.load(controller_file)
            except AeropendError as error:
                raise ParameterError(f'{self.get_name()}: parameter controller_file: {error}') from None
        if self.controller is not None:         # the file's gains are the defaults (a -p value still wins)
            self.gain_defaults = self.controller.gains.as_dict()
        # (written so that `sim_node --help` reads the defaults without building the node: getattr, not an if)
        values = {}
        for name in NUMERIC_GAIN_NAMES:
            values[name] = declare(self, name, float(getattr(self, 'gain_defaults', DEFAULT_GAINS)[name]),
                                   GAIN_HELP[name], low=GAIN_RANGES[name][0], high=GAIN_RANGES[name][1])
        values['antiwindup'] = declare(self, 'antiwindup', str(getattr(self, 'gain_defaults', DEFAULT_GAINS)[
            'antiwindup']), GAIN_HELP['antiwindup'], choices=tuple(ANTIWINDUP))
        problems = gain_problems(values)
        if problems:
            raise ParameterError(f'{self.get_name()}: controller gains: {"; ".join(problems)}; fix the -p values, '
                                 'the params file or the controller file')
        self.gains = PidGains(**values)
        self.schedule = None
        if reference_file:
            from aeropend_core.control.record import read_schedule_file
            try:
                self.schedule = read_schedule_file(reference_file)
            except AeropendError as error:
                raise ParameterError(f'{self.get_name()}: parameter reference_file: {error}') from None
        model = self.controller if self.controller is not None else None
        self.feedforward_map = FeedforwardMap(model.parameters, model.effects) if model is not None else \
            FeedforwardMap()
        self.closed_loop = mode == 'closed_loop'
        self._duty_ignored_said = False
        self.add_on_set_parameters_callback(self._check_control_parameters)
        self.add_post_set_parameters_callback(self._apply_control_parameters)

    def _start_control(self) -> None:
        """Publishers, the reference subscription and the law (called once the simulator exists)."""
        from aeropend_core.control.loop import ClosedLoopSimulation
        self.control_publisher = self.create_publisher(JointState, topics.CONTROL, topics.samples_qos())
        # aeropend/controller is advertised when there is a configuration to say (closed loop, a schedule, new gains):
        # an open-loop run has none, and a recorder would otherwise report a topic it was not asked to record
        self.config_publisher = None
        self.create_subscription(Float64MultiArray, topics.REFERENCE, self._on_reference, reference_qos())
        self.loop = ClosedLoopSimulation(self.gains, self.feedforward_map, sample_time=self.sample_time)
        self.loop.simulator = self.simulator        # one simulated rig, whichever mode drives it
        self.reference = 0.0                         # [rad], from the topic
        self.topic_feedforward = None                # [duty] given with it; None: the model's
        self.schedule_start = 0                      # sequence of the schedule's first sample
        self._schedule_reference = np.empty(0)
        self._schedule_feedforward = np.empty(0)
        self.schedule_log: list = []                 # (first sequence, ClosedLoopRecord) while a schedule plays
        self._trip_said = False
        self._control_message = JointState()
        self._control_message.header.frame_id = topics.SAMPLE_FRAME_ID
        self._control_message.name = list(topics.CONTROL_NAMES)
        if self.schedule is not None:
            self.play_schedule(self.schedule)
        if self.closed_loop:
            self._enter_closed_loop()

    def play_schedule(self, schedule) -> None:
        """Play a :class:`~aeropend_core.control.reference.ReferenceSchedule` from the next sample (the first one
        when publishing has not started); the topic's references are ignored while it plays."""
        self.schedule = schedule
        self.schedule_start = self.sequence
        self._schedule_reference = schedule.reference(None, self.sample_time)
        self._schedule_feedforward = np.array([self.feedforward_map(value) for value in self._schedule_reference])
        self.schedule_log = []
        self._publish_config()

    @property
    def schedule_samples(self) -> int:
        """Length of the schedule being played [samples] (0: none)."""
        return int(self._schedule_reference.size) if self.schedule is not None else 0

    def schedule_done(self) -> bool:
        """A schedule was given and every one of its samples is published."""
        return self.schedule is not None and self.sequence - self.schedule_start >= self.schedule_samples

    def schedule_series(self):
        """(time from the schedule's start [s], angle [rad], duty applied [fraction]) of the schedule's samples
        published so far (the run's console judges its steps on them)."""
        parts = list(self.schedule_log)
        if not parts:
            return np.empty(0), np.empty(0), np.empty(0)
        first = parts[0][0] - self.schedule_start
        angle = np.concatenate([record.angle for _, record in parts])
        duty = np.concatenate([record.duty for _, record in parts])
        return (first + np.arange(angle.size)) * self.sample_time, angle, duty

    def _enter_closed_loop(self) -> None:
        self.loop.controller.reset()
        self.loop.next_duty = min(max(self.commanded_duty, 0.0), float(self.get_parameter('duty_limit').value))
        self._trip_said = False
        self.get_logger().info(f'closed loop: {self._reference_source()}, gains p {self.gains.p:g} i '
                               f'{self.gains.i:g} d {self.gains.d:g}')
        self._publish_config()

    def _reference_source(self) -> str:
        if self.schedule is not None:
            return f'reference schedule of {self.schedule.duration:g} s ({len(self.schedule.steps)} steps)'
        return f'reference from {self.resolve_topic_name(topics.REFERENCE)}'

    def _on_reference(self, msg: Float64MultiArray) -> None:
        checked = checked_reference(msg.data, self.gains, self.feedforward_map)
        if isinstance(checked, str):
            self.get_logger().warning(checked, throttle_duration_sec=2.0)
            return
        reference, feedforward = checked
        self.reference, self.topic_feedforward = reference, feedforward
        if self.closed_loop and self.schedule is None and self.loop.controller.tripped:
            self.loop.controller.reset()            # as the firmware: an accepted reference restarts a tripped law
            self._trip_said = False
            self.get_logger().info(f'new reference {reference:.3f} rad: the tripped law restarts')

    def _check_control_parameters(self, parameters) -> SetParametersResult:
        """Gains are checked together (PidGains.problems); a refused change names why and changes nothing."""
        refusal = gain_refusal(self.get_name(), self.gains, {p.name: p.value for p in parameters})
        return SetParametersResult(successful=refusal is None, reason=refusal or '')

    def _apply_control_parameters(self, parameters) -> None:
        """After a successful set: new gains from the next sample, or the new mode."""
        names = {p.name for p in parameters}
        if names & set(GAIN_NAMES):
            self.gains = gains_of(self)
            self.loop.controller.set_gains(self.gains)
            self.get_logger().info('controller gains changed: ' + ', '.join(
                f'{p.name} {p.value}' for p in parameters if p.name in GAIN_NAMES))
            self._publish_config()
        if 'duty_limit' in names and not names & set(GAIN_NAMES):
            self._publish_config()                  # the configuration names the cap after the law
        if 'control_mode' in names:
            self.closed_loop = self.get_parameter('control_mode').value == 'closed_loop'
            if self.closed_loop:
                self._enter_closed_loop()
            else:
                self.commanded_duty = 0.0           # open loop again: duty 0 until commanded
                self.get_logger().info('open loop: duty 0 until a duty command arrives')
                self._publish_config()

    def controller_config(self) -> dict:
        """What ``aeropend/controller`` carries (as YAML): mode, gains, model, schedule, their sha256."""
        import hashlib
        import json

        from aeropend_core.control.controller_file import Controller, model_hash
        from aeropend_core.model.parameters import DEFAULT_PARAMETERS
        gains = self.gains.as_dict()
        controller = self.controller
        model = {'source': controller.model_source, 'sha256': controller.model_sha256} if controller is not None \
            else {'source': 'nominal', 'sha256': model_hash(DEFAULT_PARAMETERS, {})}
        config = {'control_mode': 'closed_loop' if self.closed_loop else 'open_loop',
                  'gains': gains,
                  'gains_sha256': hashlib.sha256(json.dumps(self.gains.hashed_dict(),
                                                            sort_keys=True).encode()).hexdigest(),
                  'model': model,
                  'controller_sha256': Controller(self.gains, controller.parameters, controller.effects).sha256
                  if controller is not None else None,
                  'duty_limit': float(self.get_parameter('duty_limit').value),
                  'reference': 'schedule' if self.schedule is not None else topics.REFERENCE,
                  'schedule': self.schedule.as_dict() if self.schedule is not None else None,
                  'schedule_sha256': self.schedule.sha256 if self.schedule is not None else None,
                  'schedule_start_sequence': self.schedule_start if self.schedule is not None else None,
                  'applies_from_sequence': self.sequence}
        return config

    def _publish_config(self) -> None:
        import yaml
        if not hasattr(self, 'config_publisher'):
            return
        if self.config_publisher is None:
            self.config_publisher = self.create_publisher(String, topics.CONTROLLER_CONFIG, controller_config_qos())
        self.config_publisher.publish(String(data=yaml.safe_dump(self.controller_config(), sort_keys=False)))

    def _publish_closed_loop(self, count: int) -> None:
        """`count` samples under the law (the rig's timing: the angle of sample k sets the duty from k+1); each
        sample and its control telemetry published with the same stamp."""
        loop = self.loop
        loop.duty_limit = float(self.get_parameter('duty_limit').value)
        first = self.sequence
        if self.schedule is not None:
            index = np.minimum(np.arange(first, first + count) - self.schedule_start, self.schedule_samples - 1)
            index = np.maximum(index, 0)
            reference = self._schedule_reference[index]
            loop.feedforward = self.feedforward_map      # cached per reference value (computed by play_schedule)
        else:
            reference = np.full(count, self.reference)
            feedforward = self.topic_feedforward
            loop.feedforward = self.feedforward_map if feedforward is None else (lambda _reference: feedforward)
        try:
            record = loop.advance(reference)
        except (AeropendError, RuntimeError, ValueError) as error:
            self.get_logger().error(f'simulation failed: {error}; stopping')
            self.finished = True
            self.timer.cancel()
            return
        if self.schedule is not None and first - self.schedule_start < self.schedule_samples:
            self.schedule_log.append((first, record))
        if loop.controller.tripped and not self._trip_said:
            self._trip_said = True
            where = int(np.argmax(record.tripped > 0))
            self.get_logger().error(
                f'safety trip: measured angle {record.angle[where]:.3f} rad outside [{self.gains.angle_min:g}, '
                f'{self.gains.angle_max:g}] rad at sample {first + where}: duty 0 until control_mode is set again or '
                'a new reference arrives')
        msg, control = self._message, self._control_message
        angle, voltage, current = record.angle.tolist(), record.armature_voltage.tolist(), \
            record.armature_current.tolist()
        duty, unsaturated, integral, tripped = record.duty.tolist(), record.unsaturated.tolist(), \
            record.integral.tolist(), record.tripped.tolist()
        reference, feedforward = record.reference.tolist(), record.feedforward.tolist()
        for k in range(count):
            sequence = first + k
            stamp_ns = self.start_ns + round(sequence * self.sample_time * 1e9)
            sample = topics.Sample(stamp_ns, angle[k], voltage[k], current[k], duty[k], sequence)
            self.publisher.publish(topics.sample_to_msg(sample, msg))
            control.header.stamp = msg.header.stamp
            control.position = [reference[k], feedforward[k], duty[k], unsaturated[k], integral[k], tripped[k],
                                float(sequence)]
            self.control_publisher.publish(control)
        self.sequence += count




def main(args=None) -> int:
    """Run the sim node until Ctrl-C (or ``stop_after``)."""
    # EventsExecutor (a third of the CPU at 490 Hz): it cannot deliver message info, so the standalone node runs
    # without the duty-source guard (SimNode(guard_duty_sources=True) in `aeropend run` has it).
    return run_node(SimNode, args, until=lambda node: node.finished)


if __name__ == '__main__':
    raise SystemExit(main())
