"""serial_bridge_node: the live rig (Arduino Mega running firmware/aeropend) on the aeropend topics.

Reads the firmware's COBS/CRC-16 frames (:mod:`aeropend_core.rig.protocol`) from a serial port with pyserial,
converts raw ADC counts to SI units with calibration parameters, and publishes one ``sensor_msgs/JointState`` per
acquisition sample on ``aeropend/samples`` (SensorData QoS; topic names are relative to the
rig's namespace, see :mod:`aeropend_ros.topics`). Each sample is stamped with its *acquisition* time:
the device's sample counter x Ts anchored to the node clock with drift correction
(:class:`aeropend_core.rig.sample_clock.SampleClock`), never its arrival time.

**Nothing is written to the port until the device has spoken.** Opening the port resets an Arduino Mega (DTR
auto-reset); its stk500v2 bootloader then listens for ~1 s and, if any byte arrives in that time, stays in
programming mode and never starts the sketch. So after each (re)open the node only reads: the configuration (maximum
duty, watchdog, duty) goes out with the first valid frame that arrives at least ``boot_delay`` after opening (earlier
frames can only be left-overs from before the reset, buffered in the USB chip). Until then no heartbeat and no
duty command is sent either.

Duty commands from ``aeropend/duty_cmd`` (``std_msgs/Float64``, fraction 0..1) are forwarded to the device
(clamped to ``max_duty`` here and again by the firmware) and repeated every ``heartbeat_period`` so the firmware's
watchdog (``watchdog_timeout``) only cuts the motor when this node, or its link, dies.

Link health goes to ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``) every ``diagnostics_period``: samples
published and lost (sequence gaps), corrupt frames, device resets, reconnections, the device's own counters,
sample rate and clock drift. When the port disappears (USB unplugged) the node keeps running, retries every
``reconnect_period`` seconds, re-sends the configuration (maximum duty, watchdog, current duty) once the device is
back, and logs how many samples the outage cost.

Closed loop (``control_mode: closed_loop``; default ``open_loop`` is the behaviour above): the *firmware* runs the
controller law (protocol version 2, docs/rig-link.md section 5) on the angle it samples, the duty applying from the next
PWM period. The gains are parameters named as ros2_control's pid_controller (``p``, ``i``, ``d``,
``derivative_filter_time``, ``i_clamp_min``/``max``, ``u_clamp_min``/``max``, ``antiwindup``,
``tracking_time_constant``, ``feedforward_gain``, ``setpoint_weight``, ``angle_min``/``max``), as the sim node's,
changeable at run time: a change is checked together (:meth:`PidGains.problems`; refused with the reason, nothing
changed), then sent as 14 SET_CONTROL_COEFFICIENT commands whose ACKs the reader thread checks
(:class:`aeropend_core.rig.control_link.GainsUpload`; ``/diagnostics`` ``controller_gains`` says ``acknowledged``,
``sending`` or why the device refused). The gains, the angle calibration (``angle_zero``, ``angle_scale``) and, in
closed loop, the last reference and the mode are sent again whenever the device (re)starts. The reference comes from
``aeropend/reference`` (``std_msgs/Float64MultiArray``, ``data = [reference_rad, feedforward_duty]``; without the
feedforward the nominal model's static duty), forwarded as SET_REFERENCE (a new reference also releases a latched angle
trip). In closed loop duty commands are ignored and the heartbeat is REQUEST_STATUS (SET_DUTY would take the device back
to open loop); each CONTROL_SAMPLE is published on ``aeropend/samples`` as usual and on ``aeropend/control``
(``topics.CONTROL_NAMES``, the sample's stamp; ``duty`` the duty applied during the sample, ``unsaturated``,
``integral`` and ``tripped`` the law's state after answering its angle). Setting ``control_mode`` to open_loop sets the
duty to 0; setting closed_loop again restarts the law.

Run on the rig::

    ros2 run aeropend_ros serial_bridge_node --ros-args -p port:=/dev/ttyACM0 \\
        --params-file config/serial_bridge_node.yaml
"""
from __future__ import annotations

import math
import threading
import time

from aeropend_ros._node_util import (  # first: prepares the ROS environment  # isort: skip
    ParameterError,
    check_unknown_overrides,
    DutySourceGuard,
    checked_duty,
    declare,
    run_node,
)
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray

from aeropend_core.control.law import ANTIWINDUP, PidGains
from aeropend_core.rig import protocol as P
from aeropend_core.errors import AeropendError
from aeropend_core.rig.control_link import GainsUpload
from aeropend_core.model.parameters import DEFAULT_PARAMETERS
from aeropend_core.rig.link_checks import CheckedSample, FrameChecker
from aeropend_core.rig.sample_clock import SampleClock
from aeropend_ros import topics
from aeropend_ros.bridge_control import BridgeControl
from aeropend_ros.control_parameters import (CONTROL_MODES, DEFAULT_GAINS, GAIN_HELP, GAIN_NAMES, GAIN_RANGES,
                                            NUMERIC_GAIN_NAMES, gain_problems, gain_refusal, gains_of)

#: Parameters whose change rebuilds the counts -> SI conversion.
CALIBRATION_PARAMETERS = ('current_scale', 'current_offset', 'angle_zero', 'angle_scale', 'voltage_source',
                          'voltage_scale', 'voltage_offset', 'duty_voltage_k0', 'duty_voltage_k1',
                          'duty_voltage_k2', 'duty_voltage_k3')
#: Parameters whose change is sent to the device.
DEVICE_PARAMETERS = ('max_duty', 'watchdog_timeout')
#: Host time [s] a clock rate fault must last before samples are withheld (a backlog on a loaded host can look like
#: a rate error for a few seconds; a wrong clock stays wrong). Until then the samples go out with a WARN.
CLOCK_FAULT_PERSIST = 5.0
#: Reads observed before the first stamps of a (re)started clock are published (about 0.1 s of data).
PRIME_ARRIVALS = 8


class SerialBridgeNode(BridgeControl, Node):
    """Bridge between the rig's serial link and the aeropend topics (see module docstring)."""

    def __init__(self, node_name: str = 'serial_bridge_node', **kwargs) -> None:
        super().__init__(node_name, **kwargs)
        self.port = declare(self, 'port', '/dev/ttyACM0', 'serial port of the Arduino Mega (a stable name such as '
                            '/dev/serial/by-id/... survives replugging)', read_only=True)
        self.baud = declare(self, 'baud', 250000, 'serial baud rate (the firmware uses 250000)', read_only=True,
                            low=9600, high=2000000, integer=True)
        self.sample_period = declare(self, 'sample_period', P.SAMPLE_PERIOD, 'nominal device sampling period '
                                     'Ts [s] (Timer1: 64 * 510 / 16 MHz = 2.04 ms)', read_only=True,
                                     low=1e-5, high=1.0)
        declare(self, 'max_duty', 0.7, 'largest duty fraction sent to the device (the firmware clamps too)',
                low=0.0, high=1.0)
        declare(self, 'watchdog_timeout', 0.5, 'firmware watchdog [s]: the motor stops when no command arrives '
                'for this long', low=0.01, high=60.0)
        self.heartbeat_period = declare(self, 'heartbeat_period', 0.1, 'period [s] of repeating the duty '
                                        'command (must be shorter than watchdog_timeout)', read_only=True,
                                        low=0.005, high=10.0)
        self.reconnect_period = declare(self, 'reconnect_period', 2.0, 'retry period [s] when the port is '
                                        'missing or failed', read_only=True, low=0.05, high=60.0)
        declare(self, 'command_timeout', 1.0, 'set the duty to 0 when no duty command arrived for this long '
                '[s] (the controller died); 0 = hold the last command forever', low=0.0, high=3600.0)
        self.boot_delay = declare(self, 'boot_delay', 1.0, 'after opening the port, write nothing until a valid '
                                  'frame arrives at least this long [s] after the open (the Mega resets on open and '
                                  'its bootloader hangs if it receives bytes in its first second)', read_only=True,
                                  low=0.0, high=30.0)
        declare(self, 'current_scale', P.DEFAULT_CURRENT_SCALE, 'armature current per ADC count [A/count] '
                '(shield: 5 V/1024 * 2 A/3.3 V)', low=-1.0, high=1.0)
        declare(self, 'current_offset', 0.0, 'ADC counts at zero current (calibrate: aeropend calibrate zero)',
                low=-1023.0, high=2047.0)
        declare(self, 'angle_zero', P.DEFAULT_ANGLE_ZERO, 'angle ADC counts with the rod hanging at rest '
                '(calibrate: aeropend calibrate zero)', low=-1023.0, high=2047.0)
        declare(self, 'angle_scale', P.DEFAULT_ANGLE_SCALE, 'rod angle per ADC count [rad/count]; negative '
                'reverses the direction', low=-1.0, high=1.0)
        declare(self, 'voltage_source', 'duty', "armature voltage from 'duty' (eq 8, the paper's choice) or "
                "'adc' (divider on A3)", choices=('duty', 'adc'))
        declare(self, 'voltage_scale', P.ADC_VOLTS_PER_COUNT, 'armature voltage per ADC count of the divider '
                '[V/count]', low=-10.0, high=10.0)
        declare(self, 'voltage_offset', 0.0, 'divider ADC counts at 0 V', low=-1023.0, high=2047.0)
        for index in range(4):
            name = f'duty_voltage_k{index}'
            declare(self, name, float(getattr(DEFAULT_PARAMETERS, name)),
                    f'eq (8) coefficient k{index}: Va = k0 + k1 sqrt(k2 duty + k3)', low=-1e9, high=1e9)
        self.clock_latency = declare(self, 'clock_latency', 0.0, 'known minimum link latency [s] subtracted '
                                     'from the stamps', read_only=True, low=0.0, high=1.0)
        clock_max_drift = declare(self, 'clock_max_drift', SampleClock.DEFAULT_MAX_DRIFT, 'largest believable '
                                  "relative error of the device's clock (6e-3 = 0.6 %: the Mega 2560's ceramic "
                                  'resonator; 2e-4 for a crystal)', read_only=True, low=0.0, high=0.05)
        diagnostics_period = declare(self, 'diagnostics_period', 1.0, 'period [s] of /diagnostics', read_only=True,
                                     low=0.05, high=60.0)
        # The measurement chain's angle filter: not used by the bridge (the board filters before the ADC); kept in
        # its calibration file for `aeropend diagnose/identify --calibration` (aeropend calibrate angle-filter).
        declare(self, 'angle_filter_delay', 0.0141, "DC group delay [s] of the angle's RC low-pass on the board "
                '(3 R C; 0 = none); read by the diagnosis, not by the bridge', read_only=True, low=0.0, high=0.05)
        self._declare_control()
        check_unknown_overrides(self)
        if self.heartbeat_period >= self.get_parameter('watchdog_timeout').value:
            raise ParameterError(f'{self.get_name()}: heartbeat_period ({self.heartbeat_period:g} s) must be shorter '
                                 f'than watchdog_timeout ({self.get_parameter("watchdog_timeout").value:g} s), or '
                                 'the firmware stops the motor between two heartbeats; lower heartbeat_period or '
                                 'raise watchdog_timeout')
        try:
            self.calibration = self._calibration_from_parameters({})
        except AeropendError as error:
            raise ParameterError(f'{self.get_name()}: {error}') from None
        # A port that cannot be opened at start-up is a mistake (wrong name, not plugged in, no permission): say so
        # and exit. Once running, a port that disappears (USB unplugged) is retried every reconnect_period.
        self._first_link, error = self._open()
        if self._first_link is None:
            from pathlib import Path
            reason = 'does not exist' if not Path(self.port).exists() else f'cannot be opened ({error})'
            raise ParameterError(
                f'{self.get_name()}: parameter port: serial port {self.port} {reason}; plug in the Arduino and give '
                'its port with -p port:=... (ls /dev/ttyACM* /dev/serial/by-id/; permission: the dialout group)')

        self.clock_model = SampleClock(self.sample_period, max_drift=clock_max_drift, latency=self.clock_latency)
        self._epoch_ns = self.get_clock().now().nanoseconds
        self.decoder = P.FrameDecoder()
        self.checker = FrameChecker()
        self._withheld_reported = (0, 0)
        self._implausible_previous = 0
        self._clock_state = ('unverified', 0)      # (rate state, host steps) last logged
        self._rate_suspect_since: float | None = None
        self._priming: list[P.SampleFrame] = []
        self._serial = None
        self._serial_lock = threading.Lock()
        self._stop = threading.Event()
        self.duty = 0.0                    # commanded duty fraction (after the max_duty clamp)
        self._last_command_time = time.monotonic()
        self._config_sent_at = -math.inf
        self.status: P.StatusFrame | None = None
        self.stats = {'samples_published': 0, 'samples_lost': 0, 'device_resets': 0, 'reconnects': 0,
                      'outage_samples_lost': 0, 'last_outage_lost': 0, 'watchdog_trips': 0,
                      'clamped_commands': 0, 'samples_withheld_clock': 0}
        self._after_reconnect = False
        self._device_spoke = False         # a valid frame arrived >= boot_delay after the port opened
        self._opened_at = time.monotonic()
        self._silence_warned = False
        self._last_sequence: int | None = None
        self._last_flags = 0
        self._last_arrival = None
        self._disconnected_at: float | None = None
        self._diag_previous = (time.monotonic(), 0, 0, 0)
        self.connected = False
        self._message = JointState()

        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.publisher = self.create_publisher(JointState, topics.SAMPLES, topics.samples_qos())
        self.control_publisher = self.create_publisher(JointState, topics.CONTROL, topics.samples_qos())
        self._control_message = JointState()
        self._control_message.header.frame_id = topics.SAMPLE_FRAME_ID
        self._control_message.name = list(topics.CONTROL_NAMES)
        self.create_subscription(Float64MultiArray, topics.REFERENCE, self._on_reference, topics.command_qos())
        self.diagnostics_publisher = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS_TOPIC,
                                                           topics.diagnostics_qos())
        self.duty_guard = DutySourceGuard(self, topics.DUTY_COMMAND, self._refuse_duty)
        self.create_subscription(Float64, topics.DUTY_COMMAND, self._on_duty, topics.command_qos())
        self.create_timer(self.heartbeat_period, self._on_heartbeat)
        self.create_timer(diagnostics_period, self._publish_diagnostics)
        self._reader = threading.Thread(target=self._read_loop, name='serial_bridge_reader', daemon=True)
        self._reader.start()
        self.get_logger().info(f'bridging {self.port} at {self.baud} baud to {self.publisher.topic_name}')

    # ------------------------------------------------------------------------------------------------- parameters
    def _calibration_from_parameters(self, changed: dict) -> P.Calibration:
        def value(name):
            return changed[name] if name in changed else self.get_parameter(name).value
        try:
            return P.Calibration(
                current_scale=float(value('current_scale')), current_offset=float(value('current_offset')),
                angle_zero=float(value('angle_zero')), angle_scale=float(value('angle_scale')),
                voltage_source=str(value('voltage_source')), voltage_scale=float(value('voltage_scale')),
                voltage_offset=float(value('voltage_offset')),
                duty_voltage=tuple(float(value(f'duty_voltage_k{i}')) for i in range(4)))
        except P.ProtocolError as error:
            raise AeropendError(f'bad calibration parameter: {error}') from error

    def _validate_parameters(self, parameters) -> SetParametersResult:
        changed = {p.name: p.value for p in parameters}
        if any(name in CALIBRATION_PARAMETERS for name in changed):
            try:
                self._calibration_from_parameters(changed)
            except AeropendError as error:
                return SetParametersResult(successful=False, reason=str(error))
        if 'watchdog_timeout' in changed and changed['watchdog_timeout'] <= self.heartbeat_period:
            return SetParametersResult(successful=False, reason=f'watchdog_timeout must exceed heartbeat_period '
                                       f'({self.heartbeat_period} s)')
        refusal = gain_refusal(self.get_name(), self.gains, changed)
        return SetParametersResult(successful=refusal is None, reason=refusal or '')

    def _apply_parameters(self, parameters) -> None:
        names = {p.name for p in parameters}
        if names & set(CALIBRATION_PARAMETERS):
            self.calibration = self._calibration_from_parameters({})
            if names & {'angle_zero', 'angle_scale'}:
                if self.closed_loop:
                    self.get_logger().warning('angle calibration changed: the device takes it in open loop only '
                                              '(it is sent again when the device restarts or the loop is opened)')
                else:
                    self._write(self._calibration_command())
        if names & set(DEVICE_PARAMETERS):
            self.duty = min(self.duty, float(self.get_parameter('max_duty').value))
            self._send_configuration()
        if names & set(GAIN_NAMES):
            self.gains = gains_of(self)
            self.get_logger().info('controller gains changed: ' + ', '.join(
                f'{p.name} {p.value}' for p in parameters if p.name in GAIN_NAMES) + '; sending them to the device')
            self._start_upload()
        if 'control_mode' in names:
            closed = self.get_parameter('control_mode').value == 'closed_loop'
            self.closed_loop = closed
            if closed:
                self.get_logger().info('closed loop: the device runs the law once the gains are acknowledged')
                self._close_loop()
            else:
                self.duty = 0.0
                self.get_logger().info('open loop: duty 0 until a duty command arrives')
                self._write(P.encode_control_mode(P.MODE_OPEN_LOOP) + self._calibration_command())

    # ----------------------------------------------------------------------------------------------- closed loop
    def _declare_control(self) -> None:
        """The closed loop's parameters (as the sim node's): the mode and the gains."""
        mode = declare(self, 'control_mode', 'open_loop', "'open_loop' (duty commands) or 'closed_loop' (the "
                       "firmware's controller law on the measured angle); setting closed_loop again restarts the "
                       'law (and releases a trip)', choices=CONTROL_MODES)
        values = {}
        for name in NUMERIC_GAIN_NAMES:
            values[name] = declare(self, name, float(DEFAULT_GAINS[name]), GAIN_HELP[name],
                                   low=GAIN_RANGES[name][0], high=GAIN_RANGES[name][1])
        values['antiwindup'] = declare(self, 'antiwindup', str(DEFAULT_GAINS['antiwindup']), GAIN_HELP['antiwindup'],
                                       choices=tuple(ANTIWINDUP))
        problems = gain_problems(values)
        if problems:
            raise ParameterError(f'{self.get_name()}: controller gains: {"; ".join(problems)}; fix the -p values '
                                 'or the params file')
        self.gains = PidGains(**values)
        self.closed_loop = mode == 'closed_loop'
        self._control_lock = threading.Lock()
        self._upload: GainsUpload | None = None
        self.gains_state = 'not sent'          # 'sending', 'acknowledged' or why the device refused
        self.reference: tuple[float, float] | None = None
        self._device_closed = False            # the device's last frame had FLAG_CLOSED_LOOP
        self._trip_said = False
        self._duty_ignored_said = False
        self.control_stats = {'acks_refused': 0, 'law_trips': 0, 'control_published': 0}

    # ------------------------------------------------------------------------------------------------ serial link
    def _open(self):
        import serial
        try:
            link = serial.Serial(self.port, self.baud, timeout=0.05, write_timeout=0.5, exclusive=True)
        except (serial.SerialException, OSError, ValueError) as error:
            return None, error
        return link, None

    def _read_loop(self) -> None:
        import serial
        logger = self.get_logger()
        warned = False
        while not self._stop.is_set():
            link, error = (self._first_link, None) if self._first_link is not None else self._open()
            self._first_link = None
            if link is None:
                if not warned:
                    logger.warning(f'cannot open {self.port} ({error}); retrying every {self.reconnect_period:g} s')
                    warned = True
                self._stop.wait(self.reconnect_period)
                continue
            warned = False
            self.decoder.reset()
            with self._serial_lock:
                self._serial = link
                self._device_spoke = False
                self._opened_at = time.monotonic()
                self._silence_warned = False
            self.connected = True
            self._after_reconnect = True
            if self._disconnected_at is not None:
                self.stats['reconnects'] += 1
                logger.info(f'{self.port} is back after {time.monotonic() - self._disconnected_at:.1f} s; '
                            'the configuration follows once the device talks')
            else:
                logger.info(f'opened {self.port}; writing nothing until the device talks (an Arduino resets when '
                            'its port opens; its bootloader must not receive bytes for ~1 s)')
            try:
                # When the port was last found drained [s, monotonic]: every byte of a read arrived after it, so the
                # newest sample in a read waited on this host at most since then (the sample clock's delay bound).
                drained_at = time.monotonic()
                while not self._stop.is_set():
                    checked_at = time.monotonic()
                    waiting = link.in_waiting
                    data = link.read(max(1, min(waiting, 65536)))
                    if data:
                        self._handle_bytes(data, time.monotonic() - drained_at)
                    if waiting <= 65536:
                        drained_at = checked_at
            except (serial.SerialException, OSError, TypeError) as error:
                # TypeError: pyserial's read on a closed fd during shutdown.
                if not self._stop.is_set():
                    logger.warning(f'lost {self.port}: {error}; retrying every {self.reconnect_period:g} s')
            finally:
                with self._serial_lock:
                    self._serial = None
                self.connected = False
                self._disconnected_at = time.monotonic()
                try:
                    link.close()
                except Exception:  # noqa: BLE001, S110 - closing a dead port may fail in many ways
                    pass
            self._stop.wait(self.reconnect_period)

    def _write(self, data: bytes) -> bool:
        """Write to the device; refused (False) while not connected or the device has not spoken yet."""
        with self._serial_lock:
            link = self._serial
            if link is None or not self._device_spoke:
                return False
            try:
                link.write(data)
                return True
            except Exception as error:  # noqa: BLE001 - the reader thread handles the reconnection
                self.get_logger().warning(f'write to {self.port} failed: {error}', throttle_duration_sec=2.0)
                return False

    def _send_configuration(self) -> None:
        max_duty = float(self.get_parameter('max_duty').value)
        watchdog = float(self.get_parameter('watchdog_timeout').value)
        self._config_sent_at = time.monotonic()
        # (no SET_DUTY in closed loop: it would take the device back to open loop)
        duty = b'' if self.closed_loop else P.encode_command(P.SET_DUTY, min(self.duty, max_duty))
        self._write(P.encode_command(P.SET_MAX_DUTY, max_duty) + P.encode_command(P.SET_WATCHDOG, watchdog)
                    + duty + P.encode_command(P.REQUEST_STATUS))

    # ---------------------------------------------------------------------------------------------------- decoding
    def _device_talks(self, messages: list) -> None:
        """The first valid frame at least boot_delay after opening: the sketch runs, configure it."""
        since_open = time.monotonic() - self._opened_at
        if messages and since_open >= self.boot_delay:
            with self._serial_lock:
                self._device_spoke = True
            self.get_logger().info(f'device on {self.port} is talking ({since_open:.1f} s after opening): sending '
                                   'the configuration')
            self._send_configuration()
            self._configure_controller()

    def _warn_if_silent(self) -> None:
        """One warning when the open port stays silent well past the boot delay."""
        since_open = time.monotonic() - self._opened_at
        if self.connected and since_open > self.boot_delay + 5.0 and not self._silence_warned:
            self._silence_warned = True
            self.get_logger().warning(f'no valid frame from {self.port} in {since_open:.0f} s since opening (nothing '
                                      'was written to it): is firmware/aeropend uploaded, the baud rate '
                                      f'{self.baud}, the right port?')

    def _handle_bytes(self, data: bytes, delay_bound: float | None = None) -> None:
        """Decode a read; `delay_bound` [s]: the longest its newest byte can have waited on this host."""
        now_ns = self.get_clock().now().nanoseconds
        arrival = (now_ns - self._epoch_ns) * 1e-9
        messages = self.decoder.feed(data)
        if not self._device_spoke:
            self._device_talks(messages)
        samples = []
        for message in messages:
            if type(message) is P.SampleFrame or type(message) is P.ControlSampleFrame:
                samples.append(message)
            elif type(message) is P.AckFrame:
                self._on_ack(message)
            else:
                self._handle_status(message)
        # Range and sequence plausibility after the CRC (aeropend_core.rig.link_checks): what the stream
        # contradicts is withheld and counted, a sequence step is believed once the next sample confirms it.
        checked = self.checker.check(samples)
        self._report_withheld()
        run: list[P.SampleFrame] = []         # samples since the last device reset in this read
        for index, item in enumerate(checked):
            if self._check_sequence(item, arrival, checked, index):   # the device restarted: stamp the old run
                self._publish_run(run, arrival, delay_bound)
                self._flush_priming()
                run = []
                self.clock_model.reset()
            run.append(item.frame)
        self._publish_run(run, arrival, delay_bound)

    def _report_withheld(self) -> None:
        """Log newly withheld implausible frames (throttled); /diagnostics carries the counts."""
        counters = self.checker.counters
        now = (counters.implausible_range, counters.implausible_sequence)
        if now != self._withheld_reported and self.checker.last_withheld is not None:
            kind, sequence, expected = self.checker.last_withheld
            reason = ('an ADC count above 1023 or an unknown flag' if kind == 'range' else
                      f'sequence {sequence} where the stream continues from {expected}')
            self.get_logger().warning(f'withheld an implausible frame that passed the CRC ({reason}); so far '
                                      f'{now[0]} out of range, {now[1]} contradicted by the sequence',
                                      throttle_duration_sec=5.0)
            self._withheld_reported = now

    def _check_sequence(self, item: CheckedSample, arrival: float, checked: list, index: int) -> bool:
        """Update loss statistics with one accepted sample (``checked[index]`` of the read that arrived at
        `arrival`); True when it starts a new device run (a confirmed reset)."""
        frame = item.frame
        last = self._last_sequence
        reset = False
        if last is not None:
            if item.lost:
                gap = item.lost
                self.stats['samples_lost'] += gap
                if self._after_reconnect:
                    self.stats['last_outage_lost'] = gap
                    self.get_logger().warning(f'link restored: {gap} samples lost during the outage '
                                              f'(sequence {last} -> {frame.sequence})')
            elif item.reset:
                newest = frame.sequence
                for later in checked[index + 1:]:
                    if later.reset:
                        break
                    newest = later.frame.sequence
                self._device_reset(arrival, frame.sequence, newest)
                reset = True
        self._after_reconnect = False
        if frame.flags & P.FLAG_WATCHDOG_TRIPPED and not self._last_flags & P.FLAG_WATCHDOG_TRIPPED:
            self.stats['watchdog_trips'] += 1
            message = ('device watchdog tripped: motor stopped (no command within '
                       f'{self.get_parameter("watchdog_timeout").value:g} s)')
            if self.duty > 0.0 and not self._stop.is_set():
                self.get_logger().warning(message)
            else:   # commanded duty 0 anyway (e.g. while shutting down): nothing was cut
                self.get_logger().debug(message)
        if frame.flags & P.FLAG_LAW_TRIPPED and not self._last_flags & P.FLAG_LAW_TRIPPED:
            self.control_stats['law_trips'] += 1
            self.get_logger().error(f'safety trip on the device: angle outside [{self.gains.angle_min:g}, '
                                    f'{self.gains.angle_max:g}] rad, duty 0 until a new reference (or control_mode '
                                    'set again)')
        self._device_closed = bool(frame.flags & P.FLAG_CLOSED_LOOP)
        self._last_flags = frame.flags
        self._last_sequence = frame.sequence
        self._last_arrival = arrival
        return reset

    def _publish_run(self, run: list[P.SampleFrame], arrival: float, delay_bound: float | None = None) -> None:
        """Stamp samples that arrived together (acquisition times by sequence number) and publish them.

        After a (re)start of the clock the first ``PRIME_ARRIVALS`` reads are held back (~0.1 s) until the
        arrival envelope has seen several reads: the first stamps are then as good as the later ones.
        `delay_bound` [s]: the read's bound on its bytes' wait (:meth:`SampleClock.observe`).
        """
        if not run:
            return
        clock = self.clock_model
        if clock.observed < PRIME_ARRIVALS or self._priming:
            clock.observe(max(frame.sequence for frame in run), arrival, delay_bound)
            self._priming.extend(run)
            if clock.observed < PRIME_ARRIVALS:
                return
            run, self._priming = self._priming, []
            stamps = clock.place([frame.sequence for frame in run])
        else:
            stamps = clock.stamp_many([frame.sequence for frame in run], arrival, delay_bound)
        self._report_clock()
        if self._clock_withholds():
            # The device's clock is outside its tolerance: its stamps and its sample spacing are not what the data
            # claim. Withheld, and said on /diagnostics (ERROR) and in the log.
            self.stats['samples_withheld_clock'] += len(run)
            return
        to_si = self.calibration.to_si
        for frame, stamp in zip(run, stamps):
            angle, voltage, current, duty = to_si(frame)
            sample = topics.Sample(self._epoch_ns + round(stamp * 1e9), angle, voltage, current, duty,
                                   frame.sequence)
            self.publisher.publish(topics.sample_to_msg(sample, self._message))
            if type(frame) is P.ControlSampleFrame:
                self._publish_control(frame, self._message.header.stamp)
        self.stats['samples_published'] += len(run)

    def _rate_text(self) -> str:
        clock = self.clock_model
        error = clock.rate_error
        measured = clock.nominal_period * (1.0 + error)    # clock.period is the stamping slope, clamped to tolerance
        return (f'device clock {abs(error) * 100:.2f} % {"slow" if error > 0 else "fast"} (measured period '
                f'{measured * 1e3:.4f} ms ± {clock.rate_error_bound * 100:.2f} %, nominal '
                f'{clock.nominal_period * 1e3:.4f} ms, tolerance ±{clock.max_drift * 100:.2f} %)')

    def _clock_withholds(self) -> bool:
        """True when the clock's rate fault has lasted CLOCK_FAULT_PERSIST s: its samples are then withheld."""
        if not self.clock_model.rate_fault:
            self._rate_suspect_since = None
            return False
        now = time.monotonic()
        if self._rate_suspect_since is None:
            self._rate_suspect_since = now
        return now - self._rate_suspect_since >= CLOCK_FAULT_PERSIST

    def _report_clock(self) -> None:
        """Log a change of the clock's state: a rate fault raised or cleared, a host clock step."""
        clock = self.clock_model
        state = ('fault' if self._clock_withholds() else 'ok' if clock.rate_verified else 'unverified',
                 len(clock.host_steps))
        if state == self._clock_state:
            return
        previous, self._clock_state = self._clock_state, state
        logger = self.get_logger()
        if state[0] == 'fault' and previous[0] != 'fault':
            logger.error(f'{self._rate_text()}: samples withheld until it is back within tolerance (wrong '
                         'sample_period? a board whose clock is known to be off: raise clock_max_drift)')
        elif previous[0] == 'fault' and state[0] != 'fault':
            logger.warning(f'device clock back within tolerance ({clock.rate_error * 1e6:.0f} ppm): publishing again')
        if state[1] > previous[1]:
            logger.warning(f'host clock stepped by {clock.host_steps[-1]:+.3f} s (an NTP step?): the stamps continue '
                           f'on the device clock, now {-clock.host_offset:+.3f} s from the node clock')

    def _flush_priming(self) -> None:
        """Publish samples still held for priming (before the clock restarts)."""
        if self._priming:
            run, self._priming = self._priming, []
            if self._clock_withholds():
                self.stats['samples_withheld_clock'] += len(run)
                return
            stamps = self.clock_model.place([frame.sequence for frame in run])
            for frame, stamp in zip(run, stamps):
                angle, voltage, current, duty = self.calibration.to_si(frame)
                self.publisher.publish(topics.sample_to_msg(topics.Sample(
                    self._epoch_ns + round(stamp * 1e9), angle, voltage, current, duty, frame.sequence),
                    self._message))
                if type(frame) is P.ControlSampleFrame:
                    self._publish_control(frame, self._message.header.stamp)
            self.stats['samples_published'] += len(run)

    def _device_reset(self, arrival: float, first: int, newest: int) -> None:
        """The sequence went backwards: the device restarted (power cycle, DTR reset, brown-out).

        `first` is the new run's first sequence number received and `newest` the newest one in the same read, which
        arrived at `arrival` [s]. Samples lost: the new device's ``first`` samples before the first one received,
        plus the sample periods between the last old sample and the new device's sample 0 (acquired about
        ``newest`` periods before this read arrived). A read that brings a backlog of the new run is therefore not
        counted as lost; the reset and boot time itself is (its length is unknown): an upper estimate.

        The old run's end is its last sample on the device clock's envelope line (the least delay the link showed),
        not the arrival of the read that brought it: on a loaded host that read can come a fraction of a second late,
        which would shorten the gap and break the upper estimate. Any delay of the new run's read only lengthens it.
        """
        self.stats['device_resets'] += 1
        if self._last_arrival is not None:
            period = self.clock_model.period
            restart = arrival - newest * period
            old_end = self.clock_model.envelope_arrival(self._last_sequence)
            old_end = self._last_arrival if old_end is None else min(old_end, self._last_arrival)
            missing = first + max(0, round((restart - old_end) / period) - 1)
            self.stats['outage_samples_lost'] += missing
            self.stats['last_outage_lost'] = missing
            self.get_logger().warning(f'device reset detected; about {missing} samples lost (the new run starts at '
                                      f'sequence {first}); re-sending the configuration')
        self._send_configuration()
        self._configure_controller()

    def _handle_status(self, status) -> None:
        if not isinstance(status, P.StatusFrame):
            return
        self.status = status
        if status.protocol_version != P.PROTOCOL_VERSION:
            self.get_logger().error(f'device speaks protocol {status.protocol_version}, this node '
                                    f'{P.PROTOCOL_VERSION}: update the firmware', throttle_duration_sec=10.0)
        want_max = P.duty_to_q16(float(self.get_parameter('max_duty').value))
        want_watchdog = round(float(self.get_parameter('watchdog_timeout').value) * 1000)
        if (status.max_duty_q16 != want_max or status.watchdog_ms != want_watchdog) and \
                time.monotonic() - self._config_sent_at > 0.5:
            self._send_configuration()

    # ------------------------------------------------------------------------------------------------- commanding
    def _on_duty(self, msg: Float64, msg_info) -> None:
        if not self.duty_guard.accept(msg_info):
            return
        if self.closed_loop:
            if not self._duty_ignored_said:
                self._duty_ignored_said = True
                self.get_logger().warning('duty command ignored: the device runs the closed loop (set '
                                          'control_mode:=open_loop to command the duty)')
            return
        duty, clamped = checked_duty(self, float(msg.data), 'max_duty')
        self.stats['clamped_commands'] += clamped
        self.duty = duty
        self._last_command_time = time.monotonic()
        self._write(P.encode_command(P.SET_DUTY, duty))

    def _refuse_duty(self) -> None:
        """Two sources command this rig: duty 0 on the device now (DutySourceGuard); the heartbeat repeats it.
        (In closed loop duty commands are ignored anyway: the law keeps running.)"""
        self.duty = 0.0
        if not self.closed_loop:
            self._write(P.encode_command(P.SET_DUTY, 0.0))

    def _on_heartbeat(self) -> None:
        if not self._device_spoke:
            self._warn_if_silent()
        if self.closed_loop:
            self._write(P.encode_command(P.REQUEST_STATUS))    # feeds the watchdog without leaving closed loop
            return
        timeout = float(self.get_parameter('command_timeout').value)
        if timeout > 0.0 and self.duty > 0.0 and time.monotonic() - self._last_command_time > timeout:
            self.get_logger().warning(f'no duty command for {timeout:g} s: duty set to 0')
            self.duty = 0.0
        self._write(P.encode_command(P.SET_DUTY, self.duty))

    # ------------------------------------------------------------------------------------------------ diagnostics
    def diagnostics_values(self) -> tuple[dict[str, str], tuple[int, int, int]]:
        """The link-health numbers for /diagnostics as strings, and (samples, lost, corrupt) since the last call."""
        now = time.monotonic()
        counters = self.decoder.counters
        previous_time, previous_published, previous_lost, previous_corrupt = self._diag_previous
        published = self.stats['samples_published']
        elapsed = max(now - previous_time, 1e-9)
        values = {
            'port': self.port, 'connected': str(self.connected),
            'sample_rate_hz': f'{(published - previous_published) / elapsed:.1f}',
            'frames_corrupt': str(counters.corrupt), 'bytes_received': str(counters.bytes_received),
            'clock_drift_ppm': f'{self.clock_model.drift_ppm:.1f}', 'duty_command': f'{self.duty:.4f}',
            'last_sequence': str(self._last_sequence if self._last_sequence is not None else -1),
            'device_talking': str(self._device_spoke),
            'clock_rate_error_ppm': f'{self.clock_model.rate_error * 1e6:.1f}',
            'clock_rate_error_bound_ppm': f'{self.clock_model.rate_error_bound_ppm:.1f}',
            'clock_rate_verified': str(self.clock_model.rate_verified),
            'clock_max_drift_ppm': f'{self.clock_model.max_drift * 1e6:.0f}',
            'host_clock_steps': str(len(self.clock_model.host_steps)),
            'host_clock_offset_s': f'{self.clock_model.host_offset:.3f}',
            'frames_implausible_range': str(self.checker.counters.implausible_range),
            'frames_implausible_sequence': str(self.checker.counters.implausible_sequence),
            'sequence_wraps': str(self.checker.counters.wraps),
        }
        values.update({name: str(count) for name, count in self.stats.items()})
        values.update({'control_mode': 'closed_loop' if self.closed_loop else 'open_loop',
                       'controller_gains': self.gains_state, 'device_closed_loop': str(self._device_closed),
                       'law_tripped': str(bool(self._last_flags & P.FLAG_LAW_TRIPPED))})
        values.update({name: str(count) for name, count in self.control_stats.items()})
        if self.status is not None:
            values.update({
                'device_protocol_version': str(self.status.protocol_version),
                'device_pwm_mode': 'fast' if self.status.pwm_mode == P.PWM_FAST else 'phase-correct',
                'device_max_duty': f'{P.q16_to_duty(self.status.max_duty_q16):.4f}',
                'device_watchdog_ms': str(self.status.watchdog_ms),
                'device_rx_bad_frames': str(self.status.rx_bad_frames),
                'device_tx_dropped_frames': str(self.status.tx_dropped_frames),
                'device_watchdog_tripped': str(bool(self.status.flags & P.FLAG_WATCHDOG_TRIPPED)),
            })
        self._diag_previous = (now, published, self.stats['samples_lost'], counters.corrupt)
        return values, (published - previous_published, self.stats['samples_lost'] - previous_lost,
                        counters.corrupt - previous_corrupt)

    def _publish_diagnostics(self) -> None:
        values, (new_samples, new_lost, new_corrupt) = self.diagnostics_values()
        prefix = topics.status_prefix(self.get_namespace())       # the rig: /diagnostics is shared
        status = DiagnosticStatus(name=f'{prefix}{self.get_name()}: rig serial link', hardware_id=self.port)
        if not self.connected:
            status.level, status.message = DiagnosticStatus.ERROR, f'{self.port} not connected (retrying)'
        elif not self._device_spoke and time.monotonic() - self._opened_at < self.boot_delay + 5.0:
            status.level = DiagnosticStatus.WARN
            status.message = 'port open, waiting for the device to talk (booting); nothing written yet'
        elif self._clock_withholds():
            status.level = DiagnosticStatus.ERROR
            status.message = (f'{self._rate_text()}: samples withheld '
                              f'({self.stats["samples_withheld_clock"]} so far)')
        elif new_samples == 0:
            status.level, status.message = DiagnosticStatus.ERROR, 'connected but no samples'
        else:
            status.level, status.message = self._link_doubts(new_lost, new_corrupt)
        status.values = [KeyValue(key=key, value=value) for key, value in values.items()]
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [status]
        self.diagnostics_publisher.publish(array)

    def _link_doubts(self, new_lost: int, new_corrupt: int) -> tuple[int, str]:
        """(level, message) of a streaming link: WARN with every doubt on the published samples, else OK."""
        counters = self.checker.counters
        implausible = counters.implausible_range + counters.implausible_sequence
        new_implausible = implausible - self._implausible_previous
        self._implausible_previous = implausible
        clock = self.clock_model
        doubts = []
        if new_lost or new_corrupt:
            doubts.append(f'{new_lost} samples lost, {new_corrupt} corrupt frames')
        if new_implausible:
            doubts.append(f'{new_implausible} implausible frames withheld (passed the CRC; out of range or '
                          'contradicted by the sequence)')
        if self._last_flags & P.FLAG_WATCHDOG_TRIPPED:
            doubts.append('watchdog tripped')
        if clock.host_steps:
            doubts.append(f'host clock stepped {len(clock.host_steps)} time(s), last {clock.host_steps[-1]:+.3f} s: '
                          f'stamps stay on the device clock, {-clock.host_offset:+.3f} s from the node clock')
        if clock.rate_fault:
            doubts.append(f'{self._rate_text()}: checking (withheld if it lasts {CLOCK_FAULT_PERSIST:g} s)')
        elif not clock.rate_verified:
            doubts.append(f'device clock rate not verified yet ({clock.rate_error * 1e6:+.0f} ppm ± '
                          f'{clock.rate_error_bound_ppm:.0f} ppm so far; needs ~3 s)')
        elif not clock.rate_within:
            # not a fault, not shown within the tolerance either (a reader falling behind widens the bound)
            doubts.append(f'device clock rate not decided yet ({clock.rate_error * 1e6:+.0f} ppm ± '
                          f'{clock.rate_error_bound_ppm:.0f} ppm spans the edge of its '
                          f'±{clock.max_drift * 1e6:.0f} ppm tolerance)')
        doubts += self._command_doubts()
        if doubts:
            return DiagnosticStatus.WARN, '; '.join(doubts)
        return DiagnosticStatus.OK, 'streaming'

    def _command_doubts(self) -> list[str]:
        """Doubts about the commands: two duty sources (the guard's own status is ERROR); a closed loop asked for
        but not running on the device (its gains refused or not acknowledged yet); the device's safety trip."""
        doubts = []
        if self.duty_guard.contested:
            doubts.append(f'two duty command sources: {self.duty_guard.refused} commands refused, duty held at 0')
        if self.closed_loop and not self._device_closed:
            doubts.append(f'closed loop asked for, the device is not running it (controller gains: '
                          f'{self.gains_state})')
        if self._last_flags & P.FLAG_LAW_TRIPPED:
            doubts.append('safety trip on the device: angle outside [angle_min, angle_max], duty 0 until a new '
                          'reference')
        return doubts

    def destroy_node(self) -> None:
        """Stop the reader thread, set the duty to 0 on the device and close the port."""
        self._stop.set()
        self._write(P.encode_command(P.SET_DUTY, 0.0))
        with self._serial_lock:
            link = self._serial
        if link is not None:
            try:
                link.cancel_read()
            except Exception:  # noqa: BLE001, S110
                pass
        self._reader.join(timeout=2.0)
        super().destroy_node()


def main(args=None) -> int:
    """Run the serial bridge until Ctrl-C."""
    # SingleThreadedExecutor: with the pip wheels here rclpy.experimental.EventsExecutor never fired this node's
    # timers (the heartbeat), so the firmware watchdog tripped. The executor only carries the light callbacks; the
    # 490 Hz decoding and publishing run in the reader thread.
    return run_node(SerialBridgeNode, args, prefer_events=False)


if __name__ == '__main__':
    raise SystemExit(main())
