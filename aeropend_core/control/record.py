"""A closed-loop record: what ``aeropend run --controller FILE --reference FILE`` writes, read back into arrays.

The run's bag holds, beside the samples (``/aeropend/samples``), the law's telemetry on ``/aeropend/control``
(``sensor_msgs/JointState``, one per sample, the sample's stamp; ``name`` = reference, feedforward, duty,
unsaturated, integral, tripped, sequence: the fields of :class:`aeropend_core.control.loop.ClosedLoopRecord`), the
controller's configuration on ``/aeropend/controller`` (``std_msgs/String``, YAML: gains, model, schedule and
their sha256; one message at the start and one per change), and in ``metadata.yaml``'s ``custom_data``
(:func:`closed_loop_metadata`):

=====================================  ====================================================================
``aeropend.control_mode``              ``closed_loop``
``aeropend.controller``                the controller file (absolute path)
``aeropend.controller_yaml``           its content, as read
``aeropend.controller_file_sha256``    sha256 of its bytes
``aeropend.controller_sha256``         :attr:`Controller.sha256` (gains + model)
``aeropend.reference``                 the schedule file (absolute path), or ``default: ...``
``aeropend.reference_yaml``            its content (the default schedule: as YAML)
``aeropend.reference_file_sha256``     sha256 of the file's bytes (a file only)
``aeropend.reference_sha256``          :attr:`ReferenceSchedule.sha256` (its content)
``aeropend.duty_limit``               the rig's duty cap after the law (``--duty-cap``) [fraction]
``aeropend.schedule_*``                where the schedule starts and whether it was played whole (as ``--experiment``)
=====================================  ====================================================================

:func:`load_closed_loop` reads it back (the samples with the bag reader of :mod:`aeropend_core.io.bag`, the
telemetry decoded the same way, vectorised).
"""
from __future__ import annotations

import functools
import hashlib
import math
import os
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from aeropend_core.control.controller_file import Controller
from aeropend_core.control.reference import ReferenceSchedule
from aeropend_core.errors import AeropendError
from aeropend_core.io.inputs import load_yaml_text
from aeropend_core.model.parameters import SAMPLE_TIME

#: Topic names in the default graph (a bag of rig NAME holds ``/NAME/aeropend/...``; one rig per bag).
CONTROL_TOPIC = '/aeropend/control'
CONTROLLER_CONFIG_TOPIC = '/aeropend/controller'
#: ``JointState.name`` of the control telemetry (as aeropend_ros.topics.CONTROL_NAMES; no ROS import here).
CONTROL_NAMES = ('reference', 'feedforward', 'duty', 'unsaturated', 'integral', 'tripped', 'sequence')
#: The schedule played when ``aeropend run --controller`` is given no ``--reference``: 20, 40, 60, 30 deg, 5 s each,
#: after 2 s at rest.
DEFAULT_STEPS_DEG = (20.0, 40.0, 60.0, 30.0)
DEFAULT_HOLD_S = 5.0
DEFAULT_START_HOLD_S = 2.0


def default_schedule() -> ReferenceSchedule:
    """The default reference schedule (:data:`DEFAULT_STEPS_DEG`, each held :data:`DEFAULT_HOLD_S`)."""
    return ReferenceSchedule.steps_between(list(DEFAULT_STEPS_DEG), hold=DEFAULT_HOLD_S,
                                           start_hold=DEFAULT_START_HOLD_S)


def default_schedule_text() -> str:
    """The default schedule in words (console, metadata)."""
    return (f'default: {", ".join(f"{angle:g}" for angle in DEFAULT_STEPS_DEG)} deg, {DEFAULT_HOLD_S:g} s each after '
            f'{DEFAULT_START_HOLD_S:g} s at rest')


def read_schedule_file(path: str | os.PathLike) -> ReferenceSchedule:
    """A reference schedule file (YAML, :mod:`aeropend_core.control.reference`); a clear AeropendError for every
    problem (not a file, not YAML, wrong layout)."""
    import yaml

    from aeropend_core.io.inputs import load_yaml
    try:
        data = load_yaml(path, 'reference schedule')
    except yaml.YAMLError as error:
        raise AeropendError(f'reference schedule {path}: not valid YAML ({" ".join(str(error).split())})') from None
    return ReferenceSchedule.from_mapping(data, f'reference schedule {path}')


def closed_loop_metadata(controller_path: str | os.PathLike, schedule: ReferenceSchedule,
                         schedule_path: str | os.PathLike | None = None,
                         duty_limit: float | None = None, schedule_text: str | None = None) -> dict[str, str]:
    """The bag's ``custom_data`` of a closed-loop run (module docstring): the controller file and the schedule,
    their content and sha256, the duty cap [fraction]. `schedule_path` None: the default schedule."""
    import yaml
    controller_path = Path(controller_path)
    controller_bytes = controller_path.read_bytes()
    controller = Controller.from_dict(yaml.safe_load(controller_bytes.decode('utf-8')), str(controller_path))
    data = {'aeropend.control_mode': 'closed_loop',
            'aeropend.controller': str(controller_path.resolve()),
            'aeropend.controller_yaml': controller_bytes.decode('utf-8'),
            'aeropend.controller_file_sha256': hashlib.sha256(controller_bytes).hexdigest(),
            'aeropend.controller_sha256': controller.sha256,
            'aeropend.reference_sha256': schedule.sha256}
    if duty_limit is not None:
        data['aeropend.duty_limit'] = repr(float(duty_limit))
    if schedule_path is None:
        data['aeropend.reference'] = schedule_text or default_schedule_text()
        data['aeropend.reference_yaml'] = yaml.safe_dump(schedule.as_dict(), sort_keys=False)
    else:
        schedule_bytes = Path(schedule_path).read_bytes()
        data['aeropend.reference'] = str(Path(schedule_path).resolve())
        data['aeropend.reference_yaml'] = schedule_bytes.decode('utf-8')
        data['aeropend.reference_file_sha256'] = hashlib.sha256(schedule_bytes).hexdigest()
    data['aeropend.experiment'] = (f'closed loop: controller {data["aeropend.controller"]}, reference '
                                   f'{data["aeropend.reference"]}')
    return data


@dataclass
class ClosedLoopData:
    """A closed-loop record; arrays of shape (n,), one entry per sample that has its control telemetry, in order.

    time [s from the schedule's start (its first sample); from the first sample when no schedule is known],
    angle [rad, measured], duty [fraction, applied during the sample], reference [rad], feedforward [fraction],
    integral [fraction], unsaturated [fraction, the law's output before the clamps], tripped [bool],
    armature_voltage [V], armature_current [A], sequence [the acquisition counter].
    """

    time: np.ndarray
    angle: np.ndarray
    duty: np.ndarray
    reference: np.ndarray
    feedforward: np.ndarray
    integral: np.ndarray
    unsaturated: np.ndarray
    tripped: np.ndarray
    armature_voltage: np.ndarray
    armature_current: np.ndarray
    sequence: np.ndarray
    controller: Controller | None
    schedule: ReferenceSchedule | None
    complete: bool
    source: str = ''
    #: the rig's duty cap after the law [fraction] (``--duty-cap``; NaN when the record does not say)
    duty_limit: float = math.nan
    #: the controller configurations published while recording (:meth:`SimNode.controller_config`), each with
    #: ``time`` [s, same clock as `time`]; more than one: the gains changed during the run
    configs: list[dict] = field(default_factory=list)
    #: samples recorded without their control telemetry (lost on the way, or before the loop was closed)
    samples_without_control: int = 0
    metadata: dict[str, str] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.time.size)

    @property
    def sample_time(self) -> float:
        """Ts [s]: the median spacing of the samples per sequence step (the rig's 1/490 s when too short)."""
        if self.time.size < 2:
            return SAMPLE_TIME
        steps = np.diff(self.sequence)
        spacing = np.diff(self.time)[steps > 0] / steps[steps > 0]
        return float(np.median(spacing)) if spacing.size else SAMPLE_TIME


def load_closed_loop(path: str | os.PathLike) -> ClosedLoopData:
    """Read a closed-loop bag (folder or ``.mcap``): the samples joined with their control telemetry by sequence
    number, the controller and schedule from the metadata (else from the last configuration message).

    Raises
    ------
    AeropendError
        Not a bag, no samples, or no control telemetry (the bag holds no closed loop).
    """
    from aeropend_core.io.bag import bag_files, bag_topics, read_samples
    path = Path(path)
    from aeropend_core.io.bag import bag_information
    info = bag_information(path)
    listed = [path / Path(name).name for name in info.get('relative_file_paths') or []]
    # one file (the usual bag): read it directly, so that the bag readers do not parse metadata.yaml again each
    files = listed if listed and all(file.is_file() for file in listed) else bag_files(path)
    target = files[0] if len(files) == 1 else path
    topics = {str(entry['topic_metadata']['name']): str(entry['topic_metadata']['type'])
              for entry in info.get('topics_with_message_count') or []
              if isinstance(entry, dict) and isinstance(entry.get('topic_metadata'), dict)} or bag_topics(target)
    control_topic = _one_topic(topics, CONTROL_TOPIC, path)
    if control_topic is None:
        raise AeropendError(f'{path} holds no closed loop: no {CONTROL_TOPIC} messages (it holds '
                            f'{", ".join(sorted(topics)) or "no topic"}); record one with `aeropend run --controller '
                            'gains.yaml --reference steps.yaml`')
    config_topic = _one_topic(topics, CONTROLLER_CONFIG_TOPIC, path)
    samples_topic = control_topic[:-len('control')] + 'samples'
    # one pass over the file: the samples, and the control telemetry and configuration messages beside them
    control_datas: list[bytes] = []
    config_texts: list[bytes] = []
    others = {control_topic: control_datas, **({config_topic: config_texts} if config_topic else {})}
    samples = read_samples(target, samples_topic, others=others)
    if not control_datas:
        raise AeropendError(f'{path} holds no closed loop: {control_topic} has no message')
    control_stamps, control = _decode_joint_states(control_datas, CONTROL_NAMES, f'{control_topic} in {path}')
    control_sequence = control[:, CONTROL_NAMES.index('sequence')].astype(np.int64)
    order = np.argsort(control_sequence, kind='stable')
    control_sequence, control, control_stamps = control_sequence[order], control[order], control_stamps[order]
    keep = np.ones(control_sequence.size, dtype=bool)
    keep[1:] = np.diff(control_sequence) != 0                                  # a duplicate: the first one
    control_sequence, control, control_stamps = control_sequence[keep], control[keep], control_stamps[keep]
    sequence = samples['sequence']
    common, in_samples, in_control = np.intersect1d(sequence, control_sequence, assume_unique=False,
                                                    return_indices=True)
    if common.size == 0:
        raise AeropendError(f'{path}: no sample matches a control message by sequence number (samples '
                            f'{sequence.min()}..{sequence.max()}, control {control_sequence.min()}..'
                            f'{control_sequence.max()}): not one closed loop')
    custom = info.get('custom_data') or {}
    metadata = {str(key): str(value) for key, value in custom.items()} if isinstance(custom, dict) else {}
    configs = [_config(text) for text in config_texts]
    configs = [config for config in configs if config is not None]
    controller = _controller(metadata, configs, path)
    schedule = _schedule(metadata, configs, path)
    stamps = samples['stamp_ns'][in_samples]
    start_ns = _schedule_start_ns(metadata, configs, samples, stamps)
    time = (stamps - start_ns) * 1e-9
    values = control[in_control]
    column = {name: values[:, index] for index, name in enumerate(CONTROL_NAMES)}
    complete = _complete(metadata, schedule, time)
    first_sequence, first_stamp = int(samples['sequence'][0]), int(samples['stamp_ns'][0])
    for config in configs:            # where each applies: its first sample, on the samples' clock
        applies = config.get('applies_from_sequence')
        config['time'] = ((first_stamp + round((applies - first_sequence) * SAMPLE_TIME * 1e9) - start_ns) * 1e-9
                          if isinstance(applies, int) else math.nan)
    return ClosedLoopData(time=time, angle=samples['angle'][in_samples], duty=samples['duty'][in_samples],
                          reference=column['reference'], feedforward=column['feedforward'],
                          integral=column['integral'], unsaturated=column['unsaturated'],
                          tripped=column['tripped'] > 0.5,
                          armature_voltage=samples['armature_voltage'][in_samples],
                          armature_current=samples['armature_current'][in_samples], sequence=common,
                          controller=controller, schedule=schedule, complete=complete, source=str(path),
                          duty_limit=_duty_limit(metadata, configs),
                          configs=configs, samples_without_control=int(sequence.size - common.size),
                          metadata=metadata)


def _one_topic(topics: dict[str, str], name: str, path: Path) -> str | None:
    """`name` (default graph) or the one rig's ``/NAME`` + `name` in the bag; None when absent."""
    if name in topics:
        return name
    found = sorted(topic for topic in topics if topic.endswith(name))
    if len(found) > 1:
        raise AeropendError(f'{path} holds several rigs\' {name} ({", ".join(found)}); one rig per bag')
    return found[0] if found else None


def _config(data: bytes) -> dict | None:
    """A configuration message (std_msgs/String CDR: 4 bytes header, u32 length, text with its NUL) as a dict."""
    import yaml
    try:
        (length,) = struct.unpack_from('<I', data, 4)
        text = data[8:8 + length].rstrip(b'\x00').decode('utf-8')
        config = load_yaml_text(text, 'a controller configuration message')
    except (struct.error, UnicodeDecodeError, yaml.YAMLError, AeropendError):
        return None
    return config if isinstance(config, dict) else None


def _controller(metadata: dict[str, str], configs: list[dict], path: Path) -> Controller | None:
    import yaml
    text = metadata.get('aeropend.controller_yaml')
    if text:
        try:
            return Controller.from_dict(load_yaml_text(text, f'the controller in {path}'), f'the controller in {path}')
        except (yaml.YAMLError, AeropendError):
            pass
    for config in reversed(configs):                # the gains alone (no model): the last configuration's
        gains = config.get('gains')
        if isinstance(gains, dict):
            try:
                from aeropend_core.control.law import PidGains
                return Controller(PidGains.from_mapping(gains), model_source=str(
                    (config.get('model') or {}).get('source', 'nominal')))
            except AeropendError:
                continue
    return None


def _schedule(metadata: dict[str, str], configs: list[dict], path: Path) -> ReferenceSchedule | None:
    import yaml
    text = metadata.get('aeropend.reference_yaml')
    if text:
        try:
            return ReferenceSchedule.from_mapping(load_yaml_text(text, f'the schedule in {path}'),
                                                  f'the reference schedule in {path}')
        except (yaml.YAMLError, AeropendError):
            pass
    for config in reversed(configs):
        if isinstance(config.get('schedule'), dict):
            try:
                return ReferenceSchedule.from_mapping(config['schedule'], f'the reference schedule in {path}')
            except AeropendError:
                continue
    return None


def _schedule_start_ns(metadata: dict[str, str], configs: list[dict], samples: dict, stamps: np.ndarray) -> int:
    """The stamp [ns] of the schedule's first sample: the metadata's, else the configuration's start sequence
    placed on the samples' clock, else the first sample with telemetry."""
    stated = metadata.get('aeropend.schedule_start_stamp_ns')
    if stated is not None:
        try:
            return int(stated)
        except ValueError:
            pass
    for config in configs:
        start = config.get('schedule_start_sequence')
        if isinstance(start, int) and samples['sequence'].size:
            first = int(samples['sequence'][0])
            return int(samples['stamp_ns'][0] + round((start - first) * SAMPLE_TIME * 1e9))
    return int(stamps[0])


def _duty_limit(metadata: dict[str, str], configs: list[dict]) -> float:
    try:
        return float(metadata['aeropend.duty_limit'])
    except (KeyError, ValueError):
        pass
    for config in reversed(configs):
        if isinstance(config.get('duty_limit'), (int, float)):
            return float(config['duty_limit'])
    return math.nan


def _complete(metadata: dict[str, str], schedule: ReferenceSchedule | None, time: np.ndarray) -> bool:
    stated = metadata.get('aeropend.schedule_complete')
    if stated is not None:
        return stated == 'true'
    if schedule is None or time.size == 0:
        return False
    return bool(time[-1] >= schedule.duration - 1.5 * SAMPLE_TIME)


def _joint_state_layout(data: bytes) -> tuple[list[str], int, int] | None:
    """(names, byte offset of ``position[0]``, len(position)) of a little-endian CDR ``sensor_msgs/JointState``, or
    None when it is laid out otherwise (big endian, truncated)."""
    if len(data) < 16 or data[0] != 0 or data[1] != 1:
        return None

    def align(offset: int, size: int) -> int:          # CDR alignment counts from after the 4-byte header
        return offset + (-(offset - 4) % size)

    try:
        offset = 12                                     # header, then stamp (sec, nanosec)
        (length,) = struct.unpack_from('<I', data, offset)
        offset = align(offset + 4 + length, 4)          # frame_id
        (count,) = struct.unpack_from('<I', data, offset)
        offset += 4
        names = []
        for _ in range(count):
            offset = align(offset, 4)
            (length,) = struct.unpack_from('<I', data, offset)
            names.append(data[offset + 4:offset + 4 + length].rstrip(b'\x00').decode('utf-8'))
            offset += 4 + length
        offset = align(offset, 4)
        (positions,) = struct.unpack_from('<I', data, offset)
        offset = align(offset + 4, 8)
    except (struct.error, UnicodeDecodeError):
        return None
    return (names, offset, positions) if offset + 8 * positions <= len(data) else None


@functools.lru_cache(maxsize=1)
def _joint_state_decoder():
    """The rosbags CDR deserialiser of JointState (for messages the vectorised path does not take)."""
    from aeropend_core.io.bag import joint_state_store
    store = joint_state_store()
    return lambda data: store.deserialize_cdr(data, 'sensor_msgs/msg/JointState')


def _decode_joint_states(datas: list[bytes], names: tuple[str, ...], where: str) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (int64 ns) and the `names` values (n, len(names)) of JointState CDR messages: every message laid out
    as the first one (one publisher: same length, same bytes outside the stamp and the values) at once with numpy,
    any other through the rosbags deserialiser."""
    n = len(datas)
    stamps = np.empty(n, dtype=np.int64)
    table = np.empty((n, len(names)))
    done = np.zeros(n, dtype=bool)

    def index_of(message_names) -> list[int]:
        message_names = list(message_names)
        missing = [name for name in names if name not in message_names]
        if missing:
            raise AeropendError(f'{where}: JointState lacks {missing} (names {message_names}): not the closed '
                                'loop\'s telemetry')
        return [message_names.index(name) for name in names]

    first = datas[0]
    layout = _joint_state_layout(first)
    if layout is not None:
        message_names, offset, count = layout
        index = index_of(message_names)
        length = len(first)
        end = offset + 8 * count
        if count >= len(message_names):
            rows = np.flatnonzero(np.fromiter((len(d) == length for d in datas), dtype=bool, count=n))
            block = np.frombuffer(b''.join(datas[k] for k in rows), dtype=np.uint8).reshape(len(rows), length)
            alike = np.all(block[:, 12:offset] == block[0, 12:offset], axis=1) & \
                np.all(block[:, end:] == block[0, end:], axis=1)
            block, rows = block[alike], rows[alike]
            values = np.ascontiguousarray(block[:, offset:end]).view('<f8')
            sec = np.ascontiguousarray(block[:, 4:8]).view('<i4')[:, 0].astype(np.int64)
            nsec = np.ascontiguousarray(block[:, 8:12]).view('<u4')[:, 0].astype(np.int64)
            stamps[rows] = sec * 1_000_000_000 + nsec
            table[rows] = values[:, index]
            done[rows] = True
    for k in np.flatnonzero(~done):
        try:
            message = _joint_state_decoder()(datas[k])
        except Exception as error:  # noqa: BLE001 - rosbags raises its own types
            raise AeropendError(f'a message in {where} is not valid CDR for JointState: {error}') from None
        index = index_of(message.name)
        if len(message.position) < len(message.name):
            raise AeropendError(f'{where}: a JointState has fewer positions than names')
        stamps[k] = int(message.header.stamp.sec) * 1_000_000_000 + int(message.header.stamp.nanosec)
        table[k] = [message.position[i] for i in index]
    return stamps, table


__all__ = ['CONTROL_NAMES', 'ClosedLoopData', 'closed_loop_metadata', 'default_schedule', 'default_schedule_text',
           'load_closed_loop', 'read_schedule_file']
