"""The aeropend topic contract in one place: topic names, the sample message layout, QoS choices.

Names are relative: every node subscribes and publishes ``aeropend/samples``, ``aeropend/duty_cmd``, ... which ROS
resolves in the node's namespace. The default graph runs in the root namespace, so its topics are
``/aeropend/samples``, ``/aeropend/duty_cmd`` (the names of every bag, layout and document so far); a rig NAME runs
its nodes in the namespace ``/NAME`` (``aeropend run --rig NAME``, ``ros2 launch ... namespace:=NAME``, or
``--ros-args -r __ns:=/NAME``), so its topics are ``/NAME/aeropend/samples``, ... Two rigs' topics never share a
prefix: whatever records "everything under ``<namespace>/aeropend/``" records one rig. ``/diagnostics`` stays
global (what diagnostic_aggregator reads); each status name starts with the rig's namespace (``NAME/``, nothing in
the root namespace), as ROS 1's diagnostic_updater named them (``ns/node: task``).

``/aeropend/samples`` carries ONE ``sensor_msgs/msg/JointState`` per acquisition sample (490 Hz):
``header.stamp`` = acquisition time (sample counter x Ts anchored to the clock, never arrival time),
``header.frame_id = 'aeropend'``, ``name = SAMPLE_NAMES`` and ``position`` = the values in that order
(angle rad, armature voltage V, armature current A, duty fraction 0..1, sample sequence number as a float);
``velocity`` and ``effort`` are empty. ``/aeropend/duty_cmd`` is a ``std_msgs/msg/Float64`` duty fraction 0..1.

Importing this module does not import rclpy; the QoS and message helpers import it when called.
"""
from __future__ import annotations

import math
import re
from typing import NamedTuple

from aeropend_core.errors import AeropendError

#: Topic of the acquisition samples relative to the rig's namespace (sensor_msgs/msg/JointState, SensorData QoS,
#: 490 Hz).
SAMPLES = 'aeropend/samples'
#: Topic of the duty-cycle command relative to the rig's namespace (std_msgs/msg/Float64, fraction 0..1, reliable
#: depth 10).
DUTY_COMMAND = 'aeropend/duty_cmd'
#: Full names of those topics in the default graph (root namespace): the names in bags and layouts.
SAMPLES_TOPIC = '/' + SAMPLES
DUTY_COMMAND_TOPIC = '/' + DUTY_COMMAND
#: Standard diagnostics topic (diagnostic_msgs/msg/DiagnosticArray).
DIAGNOSTICS_TOPIC = '/diagnostics'

#: Prefix of the per-parameter topics: ``/aeropend/parameters/<name>`` (the refined model's value of each identified
#: parameter, by name) and ``/aeropend/parameters/weak_sindy/<name>`` (weak SINDy's value of the same quantity);
#: sensor_msgs/msg/JointState with ``name = PARAMETER_FIELDS`` (see :func:`parameter_to_msg`), one per window.
PARAMETERS_TOPIC_PREFIX = '/aeropend/parameters'

#: Topic of the closed loop's per-sample telemetry relative to the rig's namespace (sensor_msgs/msg/JointState,
#: SensorData QoS, one per sample while a controller runs; ``name = CONTROL_NAMES``). Absent in open loop.
CONTROL = 'aeropend/control'
CONTROL_TOPIC = '/' + CONTROL
#: ``JointState.name`` of every control message: reference angle [rad], the model's feedforward duty [fraction],
#: the duty the law applied [fraction], its unsaturated output [fraction], its integral term [fraction], whether the
#: safety trip holds the duty at 0 (1/0), and the acquisition sequence number of the sample it answered.
CONTROL_NAMES: tuple[str, ...] = ('reference', 'feedforward', 'duty', 'unsaturated', 'integral', 'tripped',
                                  'sequence')
#: Topic of the controller's configuration (std_msgs/msg/String, a YAML document: gains, schedule, hashes;
#: transient-local, reliable), published once when a controller starts and again at each change.
CONTROLLER_CONFIG = 'aeropend/controller'
CONTROLLER_CONFIG_TOPIC = '/' + CONTROLLER_CONFIG
CONTROLLER_CONFIG_TYPE = 'std_msgs/msg/String'
#: Topic of the closed loop's reference relative to the rig's namespace (std_msgs/msg/Float64MultiArray, reliable
#: depth 10): ``data = [reference_rad, feedforward_duty]`` (the feedforward may be left out: the controller's model
#: then gives it). A schedule played by the controller itself takes precedence while it plays.
REFERENCE = 'aeropend/reference'
REFERENCE_TOPIC = '/' + REFERENCE
REFERENCE_TYPE = 'std_msgs/msg/Float64MultiArray'
CONTROL_TYPE = 'sensor_msgs/msg/JointState'
SAMPLES_TYPE = 'sensor_msgs/msg/JointState'
DUTY_COMMAND_TYPE = 'std_msgs/msg/Float64'
DIAGNOSTICS_TYPE = 'diagnostic_msgs/msg/DiagnosticArray'

#: ``header.frame_id`` of every sample message.
SAMPLE_FRAME_ID = 'aeropend'
#: ``JointState.name`` of every sample message; ``position[i]`` holds the value named ``SAMPLE_NAMES[i]``.
SAMPLE_NAMES: tuple[str, ...] = ('angle', 'armature_voltage', 'armature_current', 'duty', 'sequence')


#: ``JointState.name`` of every per-parameter message; ``position[i]`` holds ``PARAMETER_FIELDS[i]``: the value, the
#: ±1σ band's lower and upper ends (value ∓ σ; NaN when σ is unknown), σ (the 1σ standard error; NaN: unknown),
#: ``data_flagged`` (1 when the window's data were repaired, filled or warned about: see /diagnostics
#: ``data_quality``; else 0), ``trend_change`` (the straight-line trend over the windows that do not overlap, as a
#: fraction of the mean; NaN until 4 such windows) and ``drifting`` (1 when that trend is a drift: p < 0.001 and
#: more than 5 %). All in the parameter's SI unit, except the fractions and flags.
PARAMETER_FIELDS: tuple[str, ...] = ('value', 'lower', 'upper', 'sigma', 'data_flagged', 'trend_change', 'drifting')


class ParameterEstimate(NamedTuple):
    """One parameter of one window as carried by ``/aeropend/parameters/<name>``.

    ``header.frame_id`` of the message is not a coordinate frame: it carries ``estimator=<e>;unit=<u>;data=<d>``
    (``e`` one of ``weak_sindy``, ``output_error``, ``motor_observer``; ``u`` the SI unit; ``d`` ``clean`` or the
    data-quality findings, e.g. ``flagged:lost_samples``).

    Attributes
    ----------
    name : str
        Parameter name (aeropend_core.model.names; effect parameters by their catalog name).
    stamp_ns : int
        End of the window, acquisition time [ns].
    value : float
        The estimate, SI unit `unit`.
    sigma : float
        Its 1σ standard error, same unit (NaN: unknown).
    estimator : str
        ``weak_sindy``, ``output_error`` or ``motor_observer``.
    unit : str
        SI unit of `value` and `sigma`.
    data : str
        ``clean``, ``flagged:<codes>`` when the window's data were repaired or warned about, or ``failed_check``
        when the value fails a physical check (sign, range: the model does not fit the window; the text is in
        ``/diagnostics``, key ``parameter_warnings``) [-].
    trend_change : float
        Trend over the windows that do not overlap, fraction of the mean [-] (NaN: not tested yet).
    drifting : bool
        The trend is a drift (p < 0.001 and larger than 5 %).
    """

    name: str
    stamp_ns: int
    value: float
    sigma: float
    estimator: str
    unit: str
    data: str = 'clean'
    trend_change: float = float('nan')
    drifting: bool = False

    @property
    def lower(self) -> float:
        """value − σ (NaN when σ is unknown), SI unit."""
        return self.value - self.sigma

    @property
    def upper(self) -> float:
        """value + σ (NaN when σ is unknown), SI unit."""
        return self.value + self.sigma


def parameter_topic(name: str, estimator: str | None = None) -> str:
    """Topic of one parameter: ``/aeropend/parameters/<name>``, or ``.../weak_sindy/<name>`` for weak SINDy's value.

    Parameters
    ----------
    name : str
        Parameter name [-].
    estimator : str or None
        ``'weak_sindy'`` for the weak-form value; None (or any other estimator) for the refined model's value.
    """
    if estimator == 'weak_sindy':
        return f'{PARAMETERS_TOPIC_PREFIX}/weak_sindy/{name}'
    return f'{PARAMETERS_TOPIC_PREFIX}/{name}'


def parameter_to_msg(estimate: ParameterEstimate):
    """A ``sensor_msgs.msg.JointState`` carrying one :class:`ParameterEstimate` (see :data:`PARAMETER_FIELDS`)."""
    from sensor_msgs.msg import JointState
    msg = JointState()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(estimate.stamp_ns), 1_000_000_000)
    msg.header.frame_id = f'estimator={estimate.estimator};unit={estimate.unit};data={estimate.data}'
    msg.name = list(PARAMETER_FIELDS)
    msg.position = [float(estimate.value), float(estimate.lower), float(estimate.upper), float(estimate.sigma),
                    1.0 if estimate.data != 'clean' else 0.0, float(estimate.trend_change),
                    1.0 if estimate.drifting else 0.0]
    return msg


def msg_to_parameter(msg, name: str = '') -> ParameterEstimate:
    """Parse a per-parameter JointState (the inverse of :func:`parameter_to_msg`).

    Parameters
    ----------
    msg : sensor_msgs.msg.JointState
        The message.
    name : str
        The parameter's name (the last part of the topic) [-].

    Raises
    ------
    ValueError
        When ``name`` or ``position`` do not hold :data:`PARAMETER_FIELDS`.
    """
    names, position = list(msg.name), list(msg.position)
    if names[:len(PARAMETER_FIELDS)] != list(PARAMETER_FIELDS) or len(position) < len(PARAMETER_FIELDS):
        raise ValueError(f'JointState is not an aeropend parameter (names {names}, expected '
                         f'{list(PARAMETER_FIELDS)})')
    values = dict(zip(PARAMETER_FIELDS, position))
    meta = dict(part.split('=', 1) for part in str(msg.header.frame_id).split(';') if '=' in part)
    stamp_ns = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
    return ParameterEstimate(name, stamp_ns, values['value'], values['sigma'], meta.get('estimator', ''),
                             meta.get('unit', ''), meta.get('data', ''), values['trend_change'],
                             bool(values['drifting']))


#: The rig name of the default graph (nodes in the root namespace); not available to ``--rig``.
DEFAULT_RIG = 'aeropend'
_RIG_NAME = re.compile(r'[A-Za-z][A-Za-z0-9_]*')


def rig_namespace(rig: str | None) -> str:
    """The ROS namespace of a rig: ``'/'`` for the default graph (None or ''), ``'/NAME'`` for rig NAME.

    Parameters
    ----------
    rig : str or None [-]
        The rig's name (``aeropend run --rig NAME``), or None / '' for the default graph.

    Raises
    ------
    AeropendError
        When `rig` is not a ROS name token (a letter, then letters, digits, underscores) or is ``aeropend`` (its
        topics ``/aeropend/aeropend/...`` would lie under the default graph's ``/aeropend/``).
    """
    if not rig:
        return '/'
    if not _RIG_NAME.fullmatch(rig):
        raise AeropendError(f'rig name {rig!r} is not a ROS name: use a letter, then letters, digits or underscores '
                            '(e.g. rig1, bench_a)')
    if rig == DEFAULT_RIG:
        raise AeropendError(f'rig name {DEFAULT_RIG!r} is the default graph (no --rig); choose another name '
                            '(e.g. rig1)')
    return '/' + rig


def rig_name(namespace: str) -> str:
    """The rig of a node namespace: ``aeropend`` for the root namespace, ``NAME`` for ``/NAME`` (``/a/b``: ``a/b``).

    Parameters
    ----------
    namespace : str [-]
        A node's namespace (``Node.get_namespace()``).
    """
    return namespace.strip('/') or DEFAULT_RIG


def status_prefix(namespace: str) -> str:
    """What each of a rig's DiagnosticStatus names starts with: ``''`` in the root namespace, ``'NAME/'`` in
    ``/NAME`` (ROS 1 diagnostic_updater's ``ns/node: task``; /diagnostics is shared by every rig).

    Parameters
    ----------
    namespace : str [-]
        A node's namespace (``Node.get_namespace()``).
    """
    inner = namespace.strip('/')
    return f'{inner}/' if inner else ''


def status_namespace(name: str) -> str:
    """The namespace a DiagnosticStatus name belongs to (inverse of :func:`status_prefix`): the part before the
    first ``': '`` is the node path, its leading segments the namespace (``'rig1/recorder_node: bag'`` ->
    ``'/rig1'``; ``'recorder_node: bag'`` -> ``'/'``).

    Parameters
    ----------
    name : str [-]
        ``DiagnosticStatus.name``.
    """
    path = name.split(': ', 1)[0]
    return '/' + path.rsplit('/', 1)[0] if '/' in path else '/'


def relative_topic(topic: str, namespace: str) -> str:
    """`topic` (a full name) relative to `namespace` (``'/rig1/aeropend/samples'`` in ``'/rig1'`` ->
    ``'aeropend/samples'``); a topic outside the namespace is returned as it is (with its leading ``/``).

    Parameters
    ----------
    topic : str [-]
        A fully qualified topic name.
    namespace : str [-]
        A node's namespace.
    """
    prefix = namespace.rstrip('/') + '/'
    return topic[len(prefix):] if topic.startswith(prefix) else topic


#: How a publisher is named while discovery has shown its endpoint but not yet its node's name.
UNNAMED_NODE = 'a node whose name discovery has not told yet'


def publisher_name(info) -> str:
    """The fully qualified node name of a publisher's endpoint (``rclpy.topic_endpoint_info.TopicEndpointInfo``):
    ``'/rig1/sim_node'``, ``'/sim_node'`` in the root namespace; UNNAMED_NODE while discovery has not told it (rmw
    reports ``_NODE_NAME_UNKNOWN_`` / ``_NODE_NAMESPACE_UNKNOWN_`` until the participant's node info arrives)."""
    if '_UNKNOWN_' in info.node_name or '_UNKNOWN_' in info.node_namespace:
        return UNNAMED_NODE
    return f'{info.node_namespace.rstrip("/")}/{info.node_name}'


class Sample(NamedTuple):
    """One acquisition sample as carried by ``/aeropend/samples``.

    Attributes
    ----------
    stamp_ns : int
        Acquisition time, integer nanoseconds since the epoch of the publishing clock.
    angle : float
        Rod angle, rad.
    armature_voltage : float
        Motor armature voltage Va, V.
    armature_current : float
        Motor armature current Ia, A.
    duty : float
        PWM duty fraction applied during this sample, 0..1.
    sequence : int
        Acquisition sample counter (consecutive; a gap means lost samples).
    """

    stamp_ns: int
    angle: float
    armature_voltage: float
    armature_current: float
    duty: float
    sequence: int

    @property
    def time(self) -> float:
        """Acquisition time in seconds (float)."""
        return self.stamp_ns * 1e-9


def samples_qos():
    """QoS of ``/aeropend/samples``: ``rclpy.qos.qos_profile_sensor_data`` (best effort, keep last 5)."""
    from rclpy.qos import qos_profile_sensor_data
    return qos_profile_sensor_data


def command_qos():
    """QoS of ``/aeropend/duty_cmd``: reliable, keep last 10, volatile."""
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)


def diagnostics_qos():
    """QoS of ``/diagnostics``: reliable, keep last 10 (what diagnostic_updater uses)."""
    return command_qos()


def sample_to_msg(sample: Sample, msg=None):
    """Fill a ``sensor_msgs.msg.JointState`` from a :class:`Sample`.

    Parameters
    ----------
    sample
        The sample; ``stamp_ns`` becomes ``header.stamp``.
    msg
        A JointState to reuse (its fields are overwritten), or None for a new one.
    """
    if msg is None:
        from sensor_msgs.msg import JointState
        msg = JointState()
    stamp_ns = int(sample.stamp_ns)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    msg.header.frame_id = SAMPLE_FRAME_ID
    msg.name = list(SAMPLE_NAMES)
    msg.position = [float(sample.angle), float(sample.armature_voltage), float(sample.armature_current),
                    float(sample.duty), float(sample.sequence)]
    msg.velocity = []
    msg.effort = []
    return msg


def msg_to_sample(msg) -> Sample:
    """Parse a ``sensor_msgs.msg.JointState`` sample message into a :class:`Sample`.

    Channels are looked up by name, so a publisher that orders ``name`` differently still parses.

    Raises
    ------
    ValueError
        When a name of :data:`SAMPLE_NAMES` is missing, ``position`` is shorter than ``name`` or the sequence number
        is not a whole number (NaN/inf). Other values may be NaN/inf; the consumer decides (identification_node
        rejects such samples).
    """
    names = list(msg.name)
    position = list(msg.position)
    if len(position) < len(names):
        raise ValueError(f'JointState has {len(names)} names but {len(position)} positions')
    try:
        values = {key: position[names.index(key)] for key in SAMPLE_NAMES}
    except ValueError as error:
        raise ValueError(f'JointState is not an aeropend sample (names {names}, expected {list(SAMPLE_NAMES)})') \
            from error
    stamp_ns = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
    return Sample(stamp_ns, values['angle'], values['armature_voltage'], values['armature_current'],
                  values['duty'], sequence_number(values['sequence']))


def sequence_number(value: float) -> int:
    """The sample counter carried as a float in ``position``, as an int.

    Raises
    ------
    ValueError
        When it is NaN/inf or not a whole non-negative number (the sample cannot be placed).
    """
    if not (math.isfinite(value) and value >= 0 and value == round(value)):
        raise ValueError(f'sample sequence number {value!r} is not a whole non-negative number')
    return int(value)
