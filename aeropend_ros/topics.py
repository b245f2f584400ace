"""The aeropend topic contract in one place: topic names, the sample message layout, QoS choices.

``/aeropend/samples`` carries ONE ``sensor_msgs/msg/JointState`` per acquisition sample (490 Hz):
``header.stamp`` = acquisition time (sample counter x Ts anchored to the clock, never arrival time),
``header.frame_id = 'aeropend'``, ``name = SAMPLE_NAMES`` and ``position`` = the values in that order
(angle rad, armature voltage V, armature current A, duty fraction 0..1, sample sequence number as a float);
``velocity`` and ``effort`` are empty. ``/aeropend/duty_cmd`` is a ``std_msgs/msg/Float64`` duty fraction 0..1.

Importing this module does not import rclpy; the QoS and message helpers import it when called.
"""
from __future__ import annotations

import math
from typing import NamedTuple

#: Topic of the acquisition samples (sensor_msgs/msg/JointState, SensorData QoS, 490 Hz).
SAMPLES_TOPIC = '/aeropend/samples'
#: Topic of the duty-cycle command (std_msgs/msg/Float64, fraction 0..1, reliable depth 10).
DUTY_COMMAND_TOPIC = '/aeropend/duty_cmd'
#: Standard diagnostics topic (diagnostic_msgs/msg/DiagnosticArray).
DIAGNOSTICS_TOPIC = '/diagnostics'

SAMPLES_TYPE = 'sensor_msgs/msg/JointState'
DUTY_COMMAND_TYPE = 'std_msgs/msg/Float64'
DIAGNOSTICS_TYPE = 'diagnostic_msgs/msg/DiagnosticArray'

#: ``header.frame_id`` of every sample message.
SAMPLE_FRAME_ID = 'aeropend'
#: ``JointState.name`` of every sample message; ``position[i]`` holds the value named ``SAMPLE_NAMES[i]``.
SAMPLE_NAMES: tuple[str, ...] = ('angle', 'armature_voltage', 'armature_current', 'duty', 'sequence')


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
