"""Small helpers shared by the aeropend nodes: parameter declaration with descriptors and the Jazzy ``main``.

Imports rclpy (call :func:`aeropend_ros._ros_env.ensure_ros_environment` first; the node modules do).
"""
from __future__ import annotations

import math
import sys
from collections.abc import Callable

from aeropend_ros._ros_env import ensure_ros_environment

ensure_ros_environment()

import rclpy  # noqa: E402
from rcl_interfaces.msg import (  # noqa: E402
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import ParameterException  # noqa: E402
from rclpy.executors import ExternalShutdownException  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from aeropend_core.errors import AeropendError  # noqa: E402


#: Names of the parameter types as a user writes them (messages).
_TYPE_WORDS = {
    'DOUBLE': 'a floating-point number', 'INTEGER': 'a whole number',
    'BOOL': 'true or false', 'STRING': 'a text', 'STRING_ARRAY': "a list of texts such as ['a', 'b']",
    'DOUBLE_ARRAY': 'a list of floating-point numbers such as [0.3, 1.5]',
    'INTEGER_ARRAY': 'a list of whole numbers', 'BOOL_ARRAY': 'a list of true/false', 'BYTE_ARRAY': 'bytes',
}
#: Prefix of ``ParameterDescriptor.additional_constraints`` for a parameter with a fixed set of text values.
CHOICES_PREFIX = 'one of: '


class ParameterError(AeropendError):
    """A node parameter with a bad value (start-up: the node prints this one line and exits with status 2)."""


def describe(description: str, *, read_only: bool = False, low: float | None = None, high: float | None = None,
             integer: bool = False, choices: tuple[str, ...] = ()) -> ParameterDescriptor:
    """A ``ParameterDescriptor`` with a description and, optionally, an inclusive range (enforced by rclpy) or a
    fixed set of text values (``additional_constraints = 'one of: a, b'``, enforced by :func:`declare`)."""
    descriptor = ParameterDescriptor(description=description, read_only=read_only)
    if low is not None and high is not None:
        if integer:
            descriptor.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=0)]
        else:
            descriptor.floating_point_range = [FloatingPointRange(from_value=float(low), to_value=float(high),
                                                                  step=0.0)]
    if choices:
        descriptor.additional_constraints = CHOICES_PREFIX + ', '.join(choices)
    return descriptor


def descriptor_choices(descriptor: ParameterDescriptor) -> tuple[str, ...]:
    """The allowed text values of a parameter declared with ``choices`` (empty when any text goes)."""
    text = descriptor.additional_constraints
    return tuple(text[len(CHOICES_PREFIX):].split(', ')) if text.startswith(CHOICES_PREFIX) else ()


def allowed_text(descriptor: ParameterDescriptor) -> str:
    """What a parameter accepts, in words: its type, and its range or its choices."""
    words = _TYPE_WORDS.get(Parameter.Type(descriptor.type).name, Parameter.Type(descriptor.type).name.lower())
    if descriptor.floating_point_range:
        r = descriptor.floating_point_range[0]
        return f'{words} in [{r.from_value:g}, {r.to_value:g}]'
    if descriptor.integer_range:
        r = descriptor.integer_range[0]
        return f'{words} in [{r.from_value}, {r.to_value}]'
    choices = descriptor_choices(descriptor)
    if choices:
        return 'one of ' + ', '.join(repr(c) for c in choices)
    return words


def value_problem(value, descriptor: ParameterDescriptor) -> str | None:
    """Why `value` is not acceptable for a parameter with this descriptor (type, range, NaN/inf, choices), or None."""
    expected = Parameter.Type(descriptor.type)
    try:
        given = Parameter.Type.from_parameter_value(value) if not isinstance(value, Parameter.Type) else value
    except (AttributeError, TypeError):
        given = None
    if given != expected:
        return 'has the wrong type'
    if expected == Parameter.Type.DOUBLE and not math.isfinite(value):
        return 'is not a finite number'
    if expected == Parameter.Type.DOUBLE_ARRAY and not all(math.isfinite(v) for v in value):
        return 'holds a value that is not a finite number'
    if descriptor.floating_point_range:
        r = descriptor.floating_point_range[0]
        if not r.from_value <= value <= r.to_value:
            return 'is out of range'
    if descriptor.integer_range:
        r = descriptor.integer_range[0]
        if not r.from_value <= value <= r.to_value:
            return 'is out of range'
    choices = descriptor_choices(descriptor)
    if choices and value not in choices:
        return 'is not an allowed value'
    return None


def parameter_message(node, name: str, value, problem: str, descriptor: ParameterDescriptor | None = None,
                      default=None) -> str:
    """One line naming the node, the parameter, its value, the problem, what it accepts and what to do."""
    text = f'{node.get_name()}: parameter {name} = {value!r} {problem}'
    if descriptor is not None:
        text += f'; it must be {allowed_text(descriptor)}'
        if problem == 'has the wrong type' and descriptor.type == Parameter.Type.DOUBLE.value \
                and isinstance(value, int) and not isinstance(value, bool):
            text += f' (write {float(value)!r}, not {value})'
        elif problem == 'has the wrong type' and descriptor.type == Parameter.Type.DOUBLE_ARRAY.value:
            text += ' (write 1.0, not 1)'
        if descriptor.description:
            text += f' ({descriptor.description})'
    if default is not None:
        text += f'; fix it on the command line (-p {name}:={_yaml(default)} is the default) or in the params file'
    return text


def _yaml(value) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return repr(value) if value else "''"
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(_yaml(v) for v in value) + ']'
    return repr(value)


def declare(node, name: str, default, description: str, **range_and_flags):
    """Declare one parameter with a descriptor and return its current value (default or from YAML/CLI).

    A value given at start-up (``-p`` or ``--params-file``) that has the wrong type, is out of range, is NaN/inf,
    or is not one of ``choices`` raises :class:`ParameterError` with one line saying so (``run_node`` prints it and
    exits with status 2); an empty list for a list of texts means none. The same checks apply to runtime changes
    (rclpy enforces the type, range and read-only flag; a callback added here rejects NaN and other choices).
    """
    descriptor = describe(description, **range_and_flags)
    descriptor.type = Parameter.Type.from_parameter_value(default).value
    overrides = getattr(node, '_parameter_overrides', {})
    override = overrides.get(name)
    if override is not None:
        value = override.value
        if override.type_ == Parameter.Type.NOT_SET:
            if descriptor.type != Parameter.Type.STRING_ARRAY.value:
                raise ParameterError(parameter_message(node, name, value, 'has no value (empty list or null)',
                                                       descriptor, default))
            overrides[name] = Parameter(name, value=[''])     # '[]' in YAML: no entries
        else:
            problem = value_problem(value, descriptor)
            if problem is not None:
                raise ParameterError(parameter_message(node, name, value, problem, descriptor, default))
    try:
        node.declare_parameter(name, default, descriptor)
    except ParameterException as error:                    # anything the checks above did not foresee
        raise ParameterError(f'{node.get_name()}: parameter {name}: {error}; it must be '
                             f'{allowed_text(descriptor)}') from None
    if not getattr(node, '_aeropend_checks_runtime', False):
        node._aeropend_checks_runtime = True
        node.add_on_set_parameters_callback(lambda parameters: _check_runtime_values(node, parameters))
    return node.get_parameter(name).value


def _check_runtime_values(node, parameters) -> SetParametersResult:
    """Runtime changes: reject NaN/inf and texts outside ``choices`` (rclpy has checked type, range, read-only)."""
    for parameter in parameters:
        if not node.has_parameter(parameter.name):
            continue
        descriptor = node.describe_parameter(parameter.name)
        problem = value_problem(parameter.value, descriptor)
        if problem is not None:
            return SetParametersResult(successful=False, reason=parameter_message(
                node, parameter.name, parameter.value, problem, descriptor) + '; the value is unchanged')
    return SetParametersResult(successful=True)


def check_unknown_overrides(node) -> None:
    """Raise :class:`ParameterError` for a start-up parameter the node does not have (a typo would be ignored)."""
    import difflib
    declared = set(node._parameters) if hasattr(node, '_parameters') else set()
    unknown = sorted(set(getattr(node, '_parameter_overrides', {})) - declared)
    if not unknown:
        return
    name = unknown[0]
    close = difflib.get_close_matches(name, sorted(declared), n=1)
    hint = f"did you mean '{close[0]}'? " if close else ''
    own = sorted(n for n in declared if n not in ('use_sim_time', 'start_type_description_service'))
    raise ParameterError(f'{node.get_name()} has no parameter {name!r} ({hint}its parameters: {", ".join(own)}); '
                         'remove or correct it in the command line or the params file')


def checked_duty(node, duty: float, limit_parameter: str) -> tuple[float, bool]:
    """A duty command made safe: not a number -> 0, outside [0, limit] -> clamped (both logged).

    Returns the duty to apply and whether it was clamped; `limit_parameter` names the node's cap parameter.
    """
    limit = float(node.get_parameter(limit_parameter).value)
    if not math.isfinite(duty):
        node.get_logger().warning(f'duty command {duty!r} is not a number: duty set to 0')
        duty = 0.0
    if 0.0 <= duty <= limit:
        return duty, False
    node.get_logger().warning(f'duty command {duty:.3f} outside [0, {limit:.3f}] ({limit_parameter}): clamped',
                              throttle_duration_sec=2.0)
    return min(max(duty, 0.0), limit), True


def make_executor(prefer_events: bool = True):
    """An executor for one node: ``rclpy.experimental.EventsExecutor`` (less CPU) when available."""
    if prefer_events:
        try:
            from rclpy.experimental import EventsExecutor
            return EventsExecutor()
        except ImportError:  # pragma: no cover - older rclpy
            pass
    from rclpy.executors import SingleThreadedExecutor
    return SingleThreadedExecutor()


def _raise_keyboard_interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def run_node(node_factory: Callable[[], object], args=None, prefer_events: bool = True,
             until: Callable[[object], bool] | None = None) -> int:
    """Jazzy-style ``main``: init, build the node, spin until Ctrl-C (or ``until(node)``), destroy, shut down.

    Ctrl-C (SIGINT) and SIGTERM end the spinning while the ROS context is still up, so that ``destroy_node`` can
    still publish (the excitation node sends duty 0 on the way out); rclpy's own signal handler would shut the
    context down first. While the node is being built they raise ``KeyboardInterrupt``; once it spins they only
    set a flag that the loop checks every 0.1 s (an exception raised inside a callback would be logged by the
    executor as a FATAL error). ``-h``/``--help`` before ``--ros-args`` prints the node's parameters and topics
    (:mod:`aeropend_ros.node_help`) and returns 0 without starting anything. A user mistake in the node's
    parameters (:class:`AeropendError` from the constructor, e.g. :class:`ParameterError`, or a parameter the node
    does not have) prints one line and returns 2 instead of a traceback.
    """
    import signal

    from aeropend_ros.node_help import print_node_help, wants_help
    if wants_help(args):            # the parameters and topics; nothing is started
        module = getattr(node_factory, '__module__', '')
        return print_node_help(module.rsplit('.', 1)[-1], module)
    from rclpy.signals import SignalHandlerOptions
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    previous_sigterm = signal.signal(signal.SIGTERM, _raise_keyboard_interrupt)
    node = None
    status = 0
    try:
        node = node_factory()
        check_unknown_overrides(node)
        executor = make_executor(prefer_events)
        executor.add_node(node)
        stop_signals: list[int] = []
        signal.signal(signal.SIGINT, lambda signum, frame: stop_signals.append(signum))
        signal.signal(signal.SIGTERM, lambda signum, frame: stop_signals.append(signum))
        # spin_once with a timeout returns to Python regularly, so the stop request is seen promptly.
        while rclpy.ok() and not stop_signals and not (until is not None and until(node)):
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except AeropendError as error:
        print(f'error: {error}', file=sys.stderr)
        status = 2
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)      # a second Ctrl-C must not cut the clean-up short
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        signal.signal(signal.SIGTERM, previous_sigterm)
        signal.signal(signal.SIGINT, signal.default_int_handler)
    return status


class DutySourceGuard:
    """Never two excitation sources for one rig: refuse duty commands while two publishers send them.

    rclpy (Jazzy) gives a subscription callback the message's ``publication_sequence_number`` but not the
    publisher's identity. One publisher's numbers only grow; numbers that do not grow while the graph shows two or
    more publishers on the duty topic mean two sources are sending (two graphs on one rig, a stray
    ``ros2 topic pub``): every duty command is then refused, the duty goes to 0, an ERROR goes to /diagnostics
    (status ``<rig>/<node>: duty command source``, with the publishing nodes) and to the log, until the numbers
    have grown for ``quiet`` s (one source left). A publisher that exists but sends nothing (a monitor, a test
    harness) changes nothing; a restarted publisher (numbers from 1 again, the old one gone from the graph) is no
    contest.

    Parameters
    ----------
    node : rclpy.node.Node
        The node that subscribes the duty topic (the sim or the serial bridge).
    topic : str
        The duty topic as the node resolves it.
    on_refuse : callable
        Called with no argument when a contest starts (set the duty to 0 and send it).
    quiet : float
        Seconds of growing numbers after which commands are accepted again [s] (default 2).
    """

    def __init__(self, node, topic: str, on_refuse: Callable[[], None], quiet: float = 2.0) -> None:
        import time as _time
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

        from aeropend_ros import topics
        self._time = _time.monotonic
        self._node = node
        self._topic = node.resolve_topic_name(topic)
        self._on_refuse = on_refuse
        self._quiet = float(quiet)
        self._last_number: int | None = None
        self._contested_until = -math.inf
        self.refused = 0
        self.contests = 0
        self._publishers: list[str] = []
        self._messages = (DiagnosticArray, DiagnosticStatus, KeyValue)
        self._status_name = f'{topics.status_prefix(node.get_namespace())}{node.get_name()}: duty command source'
        self._diagnostics = node.create_publisher(DiagnosticArray, topics.DIAGNOSTICS_TOPIC, topics.diagnostics_qos())
        node.create_timer(1.0, self._publish_status)

    @property
    def contested(self) -> bool:
        """Two sources were seen sending within the last ``quiet`` seconds."""
        return self._time() < self._contested_until

    def publishers(self) -> list[str]:
        """Full names of the nodes publishing on the duty topic, as the graph shows them now."""
        from aeropend_ros.topics import publisher_name
        return sorted(publisher_name(info) for info in self._node.get_publishers_info_by_topic(self._topic))

    def accept(self, msg_info) -> bool:
        """Whether the duty command that came with `msg_info` may be applied (False: refused, counted, said)."""
        number = msg_info.get('publication_sequence_number') if isinstance(msg_info, dict) else None
        previous, self._last_number = self._last_number, number
        if number is not None and previous is not None and number <= previous:
            publishers = self.publishers()
            if len(publishers) >= 2:
                if not self.contested:
                    self.contests += 1
                    self._publishers = publishers
                    self._node.get_logger().error(
                        f'{len(publishers)} publishers send duty commands on {self._topic} ({", ".join(publishers)}): '
                        'two excitation sources for one rig; every duty command refused and the duty set to 0 until '
                        'one is left (another graph on this rig? give each rig its own --rig NAME or ROS_DOMAIN_ID)')
                    self._on_refuse()
                self._contested_until = self._time() + self._quiet
        if self.contested:
            self.refused += 1
            return False
        return True

    def _publish_status(self) -> None:
        DiagnosticArray, DiagnosticStatus, KeyValue = self._messages
        status = DiagnosticStatus(name=self._status_name, hardware_id=self._topic)
        if self.contested:
            status.level = DiagnosticStatus.ERROR
            status.message = (f'two or more sources send duty commands ({", ".join(self._publishers)}): '
                              f'{self.refused} commands refused, duty held at 0')
        else:
            status.level = DiagnosticStatus.OK
            status.message = 'one duty command source' if self.contests == 0 else \
                f'one duty command source again ({self.contests} contest(s), {self.refused} commands refused)'
        status.values = [KeyValue(key='duty_commands_refused', value=str(self.refused)),
                         KeyValue(key='contests', value=str(self.contests)),
                         KeyValue(key='publishers', value=', '.join(self.publishers()))]
        array = DiagnosticArray()
        array.header.stamp = self._node.get_clock().now().to_msg()
        array.status = [status]
        self._diagnostics.publish(array)
