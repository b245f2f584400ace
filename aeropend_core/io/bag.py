"""ROS-free rosbag2-compatible MCAP bags: writing, reading into arrays, and repairing a killed recording.

A *bag* is a folder ``<name>/`` holding ``<name>_0.mcap`` (then ``<name>_1.mcap``, ... when split by size or
time) and ``metadata.yaml`` in rosbag2's format (version 9), so that ``ros2 bag info``, the ``rosbags`` library
(``AnyReader([Path(folder)])``), ``mcap_ros2`` and Foxglove open it. Inside each file the conventions of
rosbag2's MCAP storage plugin are followed:

- header profile ``ros2``; chunked, zstd-compressed (or lz4, or none) with CRCs, message and chunk indexes;
- one schema per message type: name ``pkg/msg/Type``, encoding ``ros2msg``, text = the ``.msg`` file followed,
  for each dependency, by a line of 80 ``=``, a line ``MSG: pkg/Type`` and that definition
  (:func:`ros2msg_definition` builds it);
- one channel per topic: message encoding ``cdr``, metadata ``offered_qos_profiles`` (YAML) and
  ``topic_type_hash`` (``RIHS01_...``);
- messages hold the exact CDR bytes as received; ``log_time`` = receive time, ``publish_time`` = send time,
  integer nanoseconds since the Unix epoch (or since the start of a simulation clock, as the recorder's clock
  says);
- a metadata record ``rosbag2`` with ``ROS_DISTRO`` at the start and ``serialized_metadata`` (the bag's
  metadata YAML) before each file's summary.

Crash behaviour: a chunk is written to the OS as soon as it is full, so a recording killed with SIGKILL leaves a
file readable up to its last complete chunk (no summary, no footer). :func:`read_messages` and
:func:`read_samples` read such a file up to that point (with a warning); :func:`recover_bag` (CLI ``aeropend
bag-recover``) rewrites the killed files with a summary and footer and regenerates ``metadata.yaml``.

Nothing here imports ROS: message definitions are given as text, and ``sensor_msgs/msg/JointState`` samples are
decoded with the ``rosbags`` CDR deserialiser.
"""
from __future__ import annotations

import os
import re
import struct
import warnings
import zlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Self

import numpy as np
import yaml

from aeropend_core.errors import AeropendError, StorageError
from aeropend_core.io import bag_lock
from aeropend_core.io.paths import path_problem, storage_error

__all__ = [
    'SAMPLE_CHANNELS',
    'BagMessage',
    'BagWriter',
    'RecoveryReport',
    'TopicInfo',
    'bag_files',
    'bag_topics',
    'msg_file_loader',
    'msg_type_hash',
    'offered_qos',
    'read_messages',
    'read_samples',
    'recover_bag',
    'ros2msg_definition',
]

MCAP_MAGIC = b'\x89MCAP0\r\n'
ROS2_PROFILE = 'ros2'
SCHEMA_ENCODING = 'ros2msg'
MESSAGE_ENCODING = 'cdr'
DEFINITION_SEPARATOR = '=' * 80
METADATA_VERSION = 9
NS_PER_S = 1_000_000_000
# rosbag2 writes an "infinite" duration as this sec/nsec pair.
_INFINITE_TIME = {'sec': 9223372036, 'nsec': 854775807}
#: The values carried by each ``/aeropend/samples`` JointState, in ``position`` order.
SAMPLE_CHANNELS = ('angle', 'armature_voltage', 'armature_current', 'duty', 'sequence')
_SAMPLES_TOPIC = '/aeropend/samples'
_JOINT_STATE = 'sensor_msgs/msg/JointState'

_BUILTIN_TYPES = frozenset({
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16', 'int32', 'uint32',
    'int64', 'uint64', 'string', 'wstring'})
_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
_OP_METADATA, _OP_DATA_END = 0x0C, 0x0F


# --------------------------------------------------------------------------------------------------------------
# Schema text and QoS description
# --------------------------------------------------------------------------------------------------------------
def _split_type(type_name: str) -> tuple[str, str]:
    """``'pkg/msg/Type'`` or ``'pkg/Type'`` -> ``('pkg', 'Type')``."""
    parts = type_name.split('/')
    if len(parts) == 3 and parts[1] == 'msg':
        return parts[0], parts[2]
    if len(parts) == 2:
        return parts[0], parts[1]
    raise AeropendError(f'message type {type_name!r} is not of the form pkg/msg/Type')


def _msg_dependencies(text: str, package: str) -> list[str]:
    """Non-builtin field types of a ``.msg`` text, as ``pkg/Type``, in order of appearance."""
    found: list[str] = []
    for raw_line in text.splitlines():
        line = raw_line.split('#', 1)[0].strip()
        if not line:
            continue
        field_type = line.split()[0]                    # constants and defaults only exist for builtin types
        base = re.sub(r'\[.*\]$', '', field_type)      # arrays: T[], T[3], T[<=3]
        base = re.sub(r'<=\d+$', '', base)              # bounded strings: string<=10
        if base in _BUILTIN_TYPES:
            continue
        if base == 'Header':
            dep = 'std_msgs/Header'
        elif '/' in base:
            pkg, name = _split_type(base)
            dep = f'{pkg}/{name}'
        else:
            dep = f'{package}/{base}'
        if dep not in found:
            found.append(dep)
    return found


def ros2msg_definition(type_name: str, load_msg: Callable[[str], str]) -> str:
    """The schema text rosbag2 stores for a message type (encoding ``ros2msg``).

    Parameters
    ----------
    type_name
        ``pkg/msg/Type``, e.g. ``'sensor_msgs/msg/JointState'``.
    load_msg
        Returns the ``.msg`` text of a ``pkg/msg/Type``; see :func:`msg_file_loader`.

    Returns
    -------
    str
        The type's ``.msg`` text, then for every (transitive) dependency, depth first and each once: a line of 80
        ``=``, a line ``MSG: pkg/Type`` and the dependency's ``.msg`` text.
    """
    package, name = _split_type(type_name)
    parts: list[str] = []
    seen: set[str] = set()

    def append(pkg: str, type_: str, top: bool) -> None:
        key = f'{pkg}/{type_}'
        seen.add(key)
        text = load_msg(f'{pkg}/msg/{type_}')
        if not top:
            parts.append(f'{DEFINITION_SEPARATOR}\nMSG: {key}\n')
        parts.append(text if text.endswith('\n') else text + '\n')
        for dep in _msg_dependencies(text, pkg):
            if dep not in seen:
                append(*dep.split('/'), top=False)

    append(package, name, top=True)
    return ''.join(parts)


def msg_file_loader(prefixes: Iterable[str | os.PathLike]) -> Callable[[str], str]:
    """A ``load_msg`` for :func:`ros2msg_definition` reading ``<prefix>/share/<pkg>/msg/<Type>.msg``.

    Parameters
    ----------
    prefixes
        Install prefixes to search in order (e.g. the entries of ``AMENT_PREFIX_PATH``).
    """
    roots = [Path(p) for p in prefixes]

    def load(type_name: str) -> str:
        pkg, name = _split_type(type_name)
        for root in roots:
            path = root / 'share' / pkg / 'msg' / f'{name}.msg'
            if path.is_file():
                return path.read_text(encoding='utf-8')
        raise AeropendError(f'no definition of {type_name} under {[str(r) for r in roots]}: install the '
                            f'message package ({pkg}) or add its prefix to AMENT_PREFIX_PATH')
    return load


def msg_type_hash(type_name: str, prefixes: Iterable[str | os.PathLike]) -> str:
    """The type description hash (``RIHS01_...``) of ``pkg/msg/Type`` from ``share/<pkg>/msg/<Type>.json``.

    Returns an empty string when no installed package provides the description (older distributions).
    """
    import json
    pkg, name = _split_type(type_name)
    full = f'{pkg}/msg/{name}'
    for root in prefixes:
        path = Path(root) / 'share' / pkg / 'msg' / f'{name}.json'
        if path.is_file():
            try:
                hashes = json.loads(path.read_text(encoding='utf-8')).get('type_hashes', [])
            except ValueError:
                continue
            for entry in hashes:
                if entry.get('type_name') == full:
                    return str(entry.get('hash_string', ''))
    return ''


def offered_qos(reliability: str = 'reliable', durability: str = 'volatile', history: str = 'keep_last',
                depth: int = 10, liveliness: str = 'automatic') -> dict[str, Any]:
    """One offered QoS profile in rosbag2's metadata form (version 9: policy names, infinite times).

    Parameters are rclpy policy names in lower case, e.g. ``reliability='best_effort'``.
    """
    return {'history': history, 'depth': int(depth), 'reliability': reliability, 'durability': durability,
            'deadline': dict(_INFINITE_TIME), 'lifespan': dict(_INFINITE_TIME), 'liveliness': liveliness,
            'liveliness_lease_duration': dict(_INFINITE_TIME), 'avoid_ros_namespace_conventions': False}


# --------------------------------------------------------------------------------------------------------------
# Writer
# --------------------------------------------------------------------------------------------------------------
class _DirectFile:
    """Unbuffered binary file for the mcap writer: each write goes to the OS at once (kill-safe chunks).

    A write the system refuses part-way (disk full, file size limit) is undone: the file is cut back to where that
    write began, so it ends with complete records only (readable up to there, repairable by :func:`recover_bag`),
    and the OSError is raised.
    """

    def __init__(self, path: Path):
        self.path = Path(path)
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        self._position = 0

    def write(self, data: bytes) -> int:
        view = memoryview(data)
        try:
            while view:
                written = os.write(self._fd, view)
                view = view[written:]
        except OSError:
            try:
                os.ftruncate(self._fd, self._position)
            except OSError:             # pragma: no cover - a reader still stops at the cut record
                pass
            raise
        self._position += len(data)
        return len(data)

    def tell(self) -> int:
        return self._position

    def flush(self) -> None:
        pass

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


class _PackedChunkIndex(bytes):
    """A chunk index record kept as its serialized bytes (~100 B) instead of a ChunkIndex object (~1 kB)."""

    def write(self, stream) -> None:
        stream.write(self)


class _PackedChunkIndexes(list):
    """The mcap writer's list of chunk indexes, kept serialized until the summary is written: the index of a
    long recording is held in memory until its file is finished (23 chunks/min at 490 Hz)."""

    def append(self, chunk_index) -> None:
        from mcap.data_stream import RecordBuilder
        builder = RecordBuilder()
        chunk_index.write(builder)
        super().append(_PackedChunkIndex(builder.end()))


@dataclass
class TopicInfo:
    """A topic in a bag: what ``metadata.yaml`` says about it."""

    name: str
    type: str
    schema_text: str = ''
    offered_qos_profiles: list[dict[str, Any]] = field(default_factory=list)
    type_hash: str = ''
    message_count: int = 0


@dataclass
class _FileInfo:
    path: str
    start_ns: int | None = None
    end_ns: int | None = None
    message_count: int = 0


def _compression_type(compression: str):
    from mcap.writer import CompressionType
    table = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4, 'none': CompressionType.NONE,
             '': CompressionType.NONE}
    if compression not in table:
        raise AeropendError(f'unknown compression {compression!r}: use zstd, lz4 or none')
    return table[compression]


class BagWriter:
    """Write a rosbag2-compatible MCAP bag folder from serialized (CDR) messages.

    Parameters
    ----------
    folder
        The bag folder to create (must not exist, or be empty). Files are named ``<folder name>_<i>.mcap``.
    max_file_bytes
        Start a new file once the current one reaches this many bytes (0: never). Files are cut at chunk
        boundaries, so a file may exceed the limit by up to one compressed chunk.
    max_file_duration
        Start a new file once the log time spanned by the current file reaches this many seconds (0: never).
    chunk_size
        Uncompressed bytes per chunk. Smaller chunks lose less on a kill and compress worse.
    compression
        ``'zstd'`` (default, as rosbag2's ``zstd_fast`` preset), ``'lz4'`` or ``'none'``.
    ros_distro
        Written to the metadata (``ros_distro``, ``ROS_DISTRO``).

    Examples
    --------
    >>> with BagWriter('run1') as bag:                                     # doctest: +SKIP
    ...     bag.add_topic('/aeropend/samples', 'sensor_msgs/msg/JointState', schema_text)
    ...     bag.write('/aeropend/samples', cdr_bytes, log_time_ns, publish_time_ns)
    """

    def __init__(self, folder: str | os.PathLike, *, max_file_bytes: int = 0, max_file_duration: float = 0.0,
                 chunk_size: int = 1024 * 1024, compression: str = 'zstd', ros_distro: str = 'jazzy'):
        self.folder = Path(folder)
        if self.folder.exists() and not self.folder.is_dir():
            raise AeropendError(f'bag folder {self.folder} already exists and is not a folder: choose a new name')
        if self.folder.exists() and any(self.folder.iterdir()):
            raise AeropendError(f'bag folder {self.folder} already exists and is not empty: choose a new name')
        if max_file_bytes < 0 or max_file_duration < 0:
            raise AeropendError('split limits must be >= 0 (0 means no split)')
        if chunk_size <= 0:
            raise AeropendError('chunk_size must be positive')
        self._compression = _compression_type(compression)
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            self._lock = bag_lock.acquire(self.folder)   # marks the bag as being written until finish()
        except OSError as error:
            raise storage_error(error, f'cannot create bag folder {self.folder}: {error.strerror or error}') \
                from None
        self.name = self.folder.name
        #: written to metadata.yaml's ``custom_data`` (string -> string), e.g. the recorder's loss accounting
        self.custom_data: dict[str, str] = {}
        self.max_file_bytes = int(max_file_bytes)
        self.max_file_duration_ns = round(max_file_duration * NS_PER_S)
        self.chunk_size = int(chunk_size)
        self.ros_distro = ros_distro
        self.topics: dict[str, TopicInfo] = {}
        self.files: list[_FileInfo] = []
        self._schema_ids: dict[str, int] = {}
        self._channel_ids: dict[str, int] = {}
        self._writer = None
        self._stream: _DirectFile | None = None
        self._finished = False
        self._failure = ''
        self._on_disk = 0                              # messages in chunks handed to the OS (closed files included)
        self._on_disk_by_topic: dict[str, int] = {}
        try:
            self._open_file()
        except OSError as error:
            self._fail(error)

    # -- public API --------------------------------------------------------------------------------------------
    def add_topic(self, topic: str, type_name: str, schema_text: str,
                  offered_qos_profiles: list[dict[str, Any]] | None = None, type_hash: str = '') -> None:
        """Declare a topic (once) before writing its messages.

        Parameters
        ----------
        topic
            Topic name, e.g. ``'/aeropend/samples'``.
        type_name
            ``pkg/msg/Type``.
        schema_text
            ``ros2msg`` definition with dependencies (:func:`ros2msg_definition`).
        offered_qos_profiles
            QoS offered by the publishers (dicts as :func:`offered_qos` returns).
        type_hash
            Type description hash, ``RIHS01_<64 hex>`` (empty if unknown).
        """
        self._check_open()
        if topic in self.topics:
            known = self.topics[topic]
            if known.type != type_name:
                raise AeropendError(f'topic {topic} already recorded as {known.type}, not {type_name}')
            return
        _split_type(type_name)
        self.topics[topic] = TopicInfo(topic, type_name, schema_text, list(offered_qos_profiles or []),
                                       type_hash)
        try:
            self._register(self.topics[topic])
        except OSError as error:
            self._fail(error)

    def write(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int | None = None,
              sequence: int = 0) -> None:
        """Append one serialized message.

        Parameters
        ----------
        topic
            A topic declared with :meth:`add_topic`.
        data
            The CDR bytes exactly as received (4-byte encapsulation header included).
        log_time_ns
            Receive time, integer ns.
        publish_time_ns
            Send time, integer ns (default: ``log_time_ns``).
        sequence
            Publisher sequence number if known (0 otherwise).
        """
        self._check_open()
        channel_id = self._channel_ids.get(topic)
        if channel_id is None:
            raise AeropendError(f'topic {topic} was not declared with add_topic()')
        log_time_ns = int(log_time_ns)
        try:
            current = self.files[-1]
            if (self.max_file_duration_ns and current.start_ns is not None
                    and log_time_ns - current.start_ns >= self.max_file_duration_ns):
                self._split()
                current = self.files[-1]
                channel_id = self._channel_ids[topic]
            position = self._stream.tell()
            try:
                self._writer.add_message(channel_id=channel_id, log_time=log_time_ns, data=data,
                                         publish_time=log_time_ns if publish_time_ns is None
                                         else int(publish_time_ns), sequence=int(sequence) & 0xFFFFFFFF)
            except OSError:
                if self._stream.tell() != position:   # the chunk with this message is on disk, its index is not
                    current.message_count += 1
                    self.topics[topic].message_count += 1
                    self._mark_on_disk()
                raise
            current.message_count += 1
            current.start_ns = log_time_ns if current.start_ns is None else min(current.start_ns, log_time_ns)
            current.end_ns = log_time_ns if current.end_ns is None else max(current.end_ns, log_time_ns)
            self.topics[topic].message_count += 1
            if self._stream.tell() != position:          # the chunk was full: it (and this message) went to disk
                self._mark_on_disk()
            if self.max_file_bytes and self._stream.tell() >= self.max_file_bytes:
                self._split()
        except OSError as error:
            self._fail(error)

    @property
    def message_count(self) -> int:
        """Messages written so far, all files (including those still in the chunk being built)."""
        return sum(f.message_count for f in self.files)

    @property
    def messages_on_disk(self) -> int:
        """Messages in complete chunks handed to the operating system: what a SIGKILL right now would keep."""
        return self._on_disk

    def messages_on_disk_by_topic(self) -> dict[str, int]:
        """:attr:`messages_on_disk` per topic (a copy)."""
        return dict(self._on_disk_by_topic)

    @property
    def failure(self) -> str:
        """Why writing stopped (disk full...), or '' while the bag is healthy."""
        return self._failure

    @property
    def paths(self) -> list[Path]:
        """The ``.mcap`` files of the bag so far."""
        return [self.folder / f.path for f in self.files]

    def finish(self) -> None:
        """Write the last chunk, the summary and footer, and ``metadata.yaml``. Safe to call more than once."""
        if self._finished:
            return
        self._finished = True
        if self._failure:               # the file stays as cut at the failure; bag-recover finalises it
            return
        try:
            self._close_file()
            _write_metadata_yaml(self.folder, self._metadata_dict())
        except OSError as error:
            self._fail(error)
        bag_lock.release(self.folder)

    close = finish

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.finish()

    # -- internals ---------------------------------------------------------------------------------------------
    def _check_open(self) -> None:
        if self._failure:
            raise StorageError(self._failure)
        if self._finished:
            raise AeropendError(f'bag {self.folder} is finished; open a new BagWriter to record more')

    def _mark_on_disk(self) -> None:
        self._on_disk = self.message_count
        self._on_disk_by_topic = {name: info.message_count for name, info in self.topics.items()}

    def _fail(self, error: OSError):
        """Stop writing after the system refused a write: keep what is on disk, raise a clear AeropendError."""
        file = self._stream.path if self._stream is not None else self.folder
        lost = self.message_count - self._on_disk
        reason = error.strerror or str(error)
        if error.errno in (28, 27):     # ENOSPC, EFBIG
            reason += ' (the disk or the file size limit is full)'
        self._failure = (f'writing the bag {self.folder} failed: {reason} in {file.name}. The {self._on_disk} '
                         f'message(s) in complete chunks are kept in the file; the {lost} message(s) of the chunk '
                         f'being built are lost. Free space (or fix the permissions), then run: '
                         f'aeropend bag-recover {self.folder}')
        if self._stream is not None:
            self._stream.close()
        self._writer = None
        self._stream = None
        bag_lock.release(self.folder)   # nothing more is written: bag-recover may finalise it
        raise StorageError(self._failure) from None

    def _open_file(self) -> None:
        from mcap.writer import Writer
        info = _FileInfo(f'{self.name}_{len(self.files)}.mcap')
        self.files.append(info)
        self._stream = _DirectFile(self.folder / info.path)
        self._writer = Writer(self._stream, chunk_size=self.chunk_size, compression=self._compression)
        if isinstance(getattr(self._writer, '_Writer__chunk_indices', None), list):
            self._writer._Writer__chunk_indices = _PackedChunkIndexes()     # same summary bytes, less memory
        self._writer.start(profile=ROS2_PROFILE, library='aeropend')
        self._writer.add_metadata('rosbag2', {'ROS_DISTRO': self.ros_distro})
        self._schema_ids = {}
        self._channel_ids = {}
        for topic in self.topics.values():
            self._register(topic)
        # a provisional metadata.yaml lets a reader open the folder even if the recorder is killed
        _write_metadata_yaml(self.folder, self._metadata_dict())

    def _register(self, topic: TopicInfo) -> None:
        schema_id = self._schema_ids.get(topic.type)
        if schema_id is None:
            schema_id = self._writer.register_schema(name=topic.type, encoding=SCHEMA_ENCODING,
                                                     data=topic.schema_text.encode('utf-8'))
            self._schema_ids[topic.type] = schema_id
        self._channel_ids[topic.name] = self._writer.register_channel(
            topic=topic.name, message_encoding=MESSAGE_ENCODING, schema_id=schema_id,
            metadata={'offered_qos_profiles': _dump_qos(topic.offered_qos_profiles),
                      'topic_type_hash': topic.type_hash})

    def _close_file(self) -> None:
        if self._writer is None:
            return
        self._writer.add_metadata('rosbag2', {'serialized_metadata': yaml.safe_dump(
            self._metadata_dict(), sort_keys=False)})
        self._writer.finish()
        self._stream.close()
        self._writer = None
        self._stream = None
        self._mark_on_disk()

    def _split(self) -> None:
        self._close_file()
        self._open_file()

    def _metadata_dict(self) -> dict[str, Any]:
        return _metadata_dict(self.topics.values(), self.files, self.ros_distro, self.custom_data)


def _dump_qos(profiles: list[dict[str, Any]]) -> str:
    return yaml.safe_dump(profiles, sort_keys=False).strip() if profiles else ''


def _metadata_dict(topics: Iterable[TopicInfo], files: list[_FileInfo], ros_distro: str,
                   custom_data: dict[str, str] | None = None) -> dict[str, Any]:
    starts = [f.start_ns for f in files if f.start_ns is not None]
    ends = [f.end_ns for f in files if f.end_ns is not None]
    start = min(starts) if starts else 0
    return {
        'version': METADATA_VERSION,
        'storage_identifier': 'mcap',
        'duration': {'nanoseconds': (max(ends) - start) if ends else 0},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': sum(f.message_count for f in files),
        'topics_with_message_count': [
            {'topic_metadata': {'name': t.name, 'type': t.type, 'serialization_format': MESSAGE_ENCODING,
                                'offered_qos_profiles': t.offered_qos_profiles,
                                'type_description_hash': t.type_hash},
             'message_count': t.message_count}
            for t in topics],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [f.path for f in files],
        'files': [{'path': f.path,
                   'starting_time': {'nanoseconds_since_epoch': f.start_ns or 0},
                   'duration': {'nanoseconds': (f.end_ns - f.start_ns) if f.start_ns is not None else 0},
                   'message_count': f.message_count}
                  for f in files],
        'custom_data': dict(custom_data or {}),
        'ros_distro': ros_distro,
    }


def _write_metadata_yaml(folder: Path, metadata: dict[str, Any]) -> None:
    tmp = folder / '.metadata.yaml.tmp'
    tmp.write_text(yaml.safe_dump({'rosbag2_bagfile_information': metadata}, sort_keys=False), encoding='utf-8')
    os.replace(tmp, folder / 'metadata.yaml')


# --------------------------------------------------------------------------------------------------------------
# Reading (tolerant of files cut short by a kill)
# --------------------------------------------------------------------------------------------------------------
@dataclass
class BagMessage:
    """One message read from a bag: raw CDR bytes plus where and when it was recorded."""

    topic: str
    type: str
    log_time_ns: int
    publish_time_ns: int
    data: bytes
    sequence: int = 0


@dataclass
class _Schema:
    id: int
    name: str
    encoding: str
    data: bytes


@dataclass
class _Channel:
    id: int
    schema_id: int
    topic: str
    message_encoding: str
    metadata: dict[str, str]


@dataclass
class _ScanState:
    path: Path
    schemas: dict[int, _Schema] = field(default_factory=dict)
    channels: dict[int, _Channel] = field(default_factory=dict)
    metadata: list[tuple[str, dict[str, str]]] = field(default_factory=list)
    complete: bool = False          # footer reached
    end_offset: int = 0             # first byte after the last record read completely
    problem: str = ''               # why the scan stopped early


def _read_str(buf: bytes, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from('<I', buf, pos)
    pos += 4
    if pos + n > len(buf):
        raise ValueError('string runs past its record')
    return buf[pos:pos + n].decode('utf-8'), pos + n


def _read_bytes(buf: bytes, pos: int) -> tuple[bytes, int]:
    (n,) = struct.unpack_from('<I', buf, pos)
    pos += 4
    if pos + n > len(buf):
        raise ValueError('byte array runs past its record')
    return buf[pos:pos + n], pos + n


def _read_map(buf: bytes, pos: int) -> tuple[dict[str, str], int]:
    (n,) = struct.unpack_from('<I', buf, pos)
    pos += 4
    end = pos + n
    out: dict[str, str] = {}
    while pos < end:
        key, pos = _read_str(buf, pos)
        value, pos = _read_str(buf, pos)
        out[key] = value
    return out, pos


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == '':
        return data
    if compression == 'zstd':
        import zstandard
        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == 'lz4':
        import lz4.frame
        return lz4.frame.decompress(data)
    raise ValueError(f'unsupported chunk compression {compression!r}')


def _iter_records(buf: bytes, pos: int, end: int) -> Iterator[tuple[int, int, int]]:
    """(opcode, body start, body end) of complete records in ``buf[pos:end]``; stops at a cut record."""
    while pos + 9 <= end:
        opcode = buf[pos]
        (length,) = struct.unpack_from('<Q', buf, pos + 1)
        body = pos + 9
        if body + length > end:
            return
        yield opcode, body, body + length
        pos = body + length


def _scan_mcap(path: Path, state: _ScanState, want_messages: bool) -> Iterator[tuple[int, int, int, int, bytes]]:
    """Yield ``(channel_id, sequence, log_time, publish_time, data)`` of every message of a (possibly cut) file.

    Fills ``state`` with schemas, channels and metadata as they appear; stops at the first incomplete or corrupt
    record (recording what happened in ``state.problem``). The file is memory-mapped, not read into memory.
    """
    import mmap
    try:
        handle = open(path, 'rb')  # noqa: SIM115 - closed in the finally below, after the generator is done
    except OSError as error:
        raise storage_error(error, f'cannot read {path}: {error.strerror or error}') from None
    mapped = None
    try:
        size = os.fstat(handle.fileno()).st_size
        if size < len(MCAP_MAGIC):
            raise AeropendError(f'{path} is not an MCAP file (no MCAP magic at its start)')
        mapped = mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ)
        yield from _scan_buffer(mapped, path, state, want_messages)
    finally:
        if mapped is not None:
            mapped.close()
        handle.close()


def _scan_buffer(buf, path: Path, state: _ScanState, want_messages: bool) \
        -> Iterator[tuple[int, int, int, int, bytes]]:
    if len(buf) < len(MCAP_MAGIC) or buf[:len(MCAP_MAGIC)] != MCAP_MAGIC:
        raise AeropendError(f'{path} is not an MCAP file (no MCAP magic at its start)')
    pos = len(MCAP_MAGIC)
    state.end_offset = pos
    total = len(buf)
    for opcode, body, end in _iter_records(buf, pos, total):
        try:
            if opcode == _OP_CHUNK:
                _start, _end, usize, crc = struct.unpack_from('<QQQI', buf, body)
                compression, p = _read_str(buf, body + 28)
                (csize,) = struct.unpack_from('<Q', buf, p)
                p += 8
                if p + csize > end:
                    raise ValueError('chunk data runs past its record')
                data = _decompress(compression, buf[p:p + csize], usize)
                if len(data) != usize or (crc and zlib.crc32(data) != crc):
                    raise ValueError('chunk CRC or size mismatch')
                for inner_op, ib, ie in _iter_records(data, 0, len(data)):
                    if inner_op == _OP_MESSAGE and want_messages:
                        channel_id, seq, log_t, pub_t = struct.unpack_from('<HIQQ', data, ib)
                        yield channel_id, seq, log_t, pub_t, data[ib + 22:ie]
                    elif inner_op in (_OP_SCHEMA, _OP_CHANNEL):
                        _parse_definition(inner_op, data, ib, state)
            elif opcode == _OP_MESSAGE and want_messages:
                channel_id, seq, log_t, pub_t = struct.unpack_from('<HIQQ', buf, body)
                yield channel_id, seq, log_t, pub_t, buf[body + 22:end]
            elif opcode in (_OP_SCHEMA, _OP_CHANNEL):
                _parse_definition(opcode, buf, body, state)
            elif opcode == _OP_METADATA:
                name, p = _read_str(buf, body)
                meta, _ = _read_map(buf, p)
                state.metadata.append((name, meta))
            elif opcode == _OP_HEADER:
                profile, _ = _read_str(buf, body)
                if profile != ROS2_PROFILE:
                    raise AeropendError(f'{path} has MCAP profile {profile!r}, not ros2: not a ROS 2 bag')
            elif opcode == _OP_FOOTER:
                state.complete = True
                state.end_offset = end
                return
        except (struct.error, ValueError, UnicodeDecodeError) as error:
            state.problem = f'corrupt record at byte {body - 9}: {error}'
            return
        except Exception as error:  # decompression errors of the zstd/lz4 bindings
            if isinstance(error, AeropendError):
                raise
            state.problem = f'corrupt chunk at byte {body - 9}: {error}'
            return
        state.end_offset = end
    if state.end_offset < total:
        state.problem = f'file ends inside a record at byte {state.end_offset} of {total}'
    else:
        state.problem = 'file ends without a footer'


def _parse_definition(opcode: int, buf: bytes, pos: int, state: _ScanState) -> None:
    if opcode == _OP_SCHEMA:
        (schema_id,) = struct.unpack_from('<H', buf, pos)
        name, p = _read_str(buf, pos + 2)
        encoding, p = _read_str(buf, p)
        data, _ = _read_bytes(buf, p)
        state.schemas.setdefault(schema_id, _Schema(schema_id, name, encoding, data))
    else:
        channel_id, schema_id = struct.unpack_from('<HH', buf, pos)
        topic, p = _read_str(buf, pos + 4)
        encoding, p = _read_str(buf, p)
        meta, _ = _read_map(buf, p)
        state.channels.setdefault(channel_id, _Channel(channel_id, schema_id, topic, encoding, meta))


def bag_files(path: str | os.PathLike) -> list[Path]:
    """The ``.mcap`` files of a bag folder in recording order (``metadata.yaml`` order, else by split index), or
    ``[path]`` for a single ``.mcap`` file.

    Raises
    ------
    AeropendError
        When the path does not exist or holds no MCAP file.
    """
    path = Path(path)
    if not path.exists():
        raise AeropendError(f'{path} {path_problem(path)}')
    if path.is_file():
        return [path]
    listed: list[Path] = []
    meta_path = path / 'metadata.yaml'
    if meta_path.is_file():
        try:
            info = yaml.safe_load(meta_path.read_text(encoding='utf-8'))['rosbag2_bagfile_information']
            listed = [path / Path(p).name for p in info.get('relative_file_paths', [])]
        except (yaml.YAMLError, KeyError, TypeError):
            listed = []
    found = sorted(path.glob('*.mcap'), key=_split_index)
    files = [p for p in listed if p.is_file()] + [p for p in found if p not in listed]
    if not files:
        raise AeropendError(f'{path} holds no .mcap file: not an MCAP bag folder')
    return files


def _split_index(path: Path) -> tuple[int, str]:
    match = re.search(r'_(\d+)\.mcap$', path.name)
    return (int(match.group(1)) if match else -1, path.name)


def read_messages(path: str | os.PathLike, topics: Iterable[str] | None = None,
                  on_incomplete: str = 'warn') -> Iterator[BagMessage]:
    """Messages of a bag folder or ``.mcap`` file, in file order, as raw CDR bytes.

    Parameters
    ----------
    path
        Bag folder (``metadata.yaml`` + ``*.mcap``) or a single ``.mcap`` file.
    topics
        Only these topics (default: all).
    on_incomplete
        What to do with a file cut short (recording killed, disk full): ``'warn'`` (read it up to its last
        complete chunk and warn), ``'ignore'``, or ``'raise'`` (:class:`AeropendError`).

    Raises
    ------
    AeropendError
        Not an MCAP file, not a ROS 2 bag, or (with ``on_incomplete='raise'``) an incomplete file.
    """
    wanted = None if topics is None else set(topics)
    for file in bag_files(path):
        state = _ScanState(file)
        for channel_id, seq, log_t, pub_t, data in _scan_mcap(file, state, want_messages=True):
            channel = state.channels.get(channel_id)
            if channel is None:
                continue
            if wanted is not None and channel.topic not in wanted:
                continue
            schema = state.schemas.get(channel.schema_id)
            yield BagMessage(channel.topic, schema.name if schema else '', log_t, pub_t, data, seq)
        if not state.complete:
            in_bag = Path(path).is_dir() or (file.parent / 'metadata.yaml').is_file()
            writer = bag_lock.live_writer(file)
            if writer is not None:      # being recorded: no repair to advise, only that the end is still coming
                message = (f'{file} is still being recorded by {writer.describe()}; read up to its last complete '
                           'chunk (the newest samples are not in it yet; read it again once the recording ends)')
                if on_incomplete == 'raise':
                    raise AeropendError(message)
                if on_incomplete == 'warn':
                    warnings.warn(message, stacklevel=2)
                continue
            message = (f'{file} is incomplete ({state.problem}); read up to its last complete chunk. '
                       f'Repair it with: aeropend bag-recover {file.parent if in_bag else file}')
            if on_incomplete == 'raise':
                raise AeropendError(message)
            if on_incomplete == 'warn':
                warnings.warn(message, stacklevel=2)


def bag_topics(path: str | os.PathLike) -> dict[str, str]:
    """Topic name -> message type of every channel in a bag (all files)."""
    out: dict[str, str] = {}
    for file in bag_files(path):
        state = _ScanState(file)
        for _ in _scan_mcap(file, state, want_messages=False):
            pass
        for channel in state.channels.values():
            schema = state.schemas.get(channel.schema_id)
            out.setdefault(channel.topic, schema.name if schema else '')
    return out


def _joint_state_decoder():
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    return lambda data: store.deserialize_cdr(data, _JOINT_STATE)


def _joint_state_layout(data: bytes) -> tuple[int, int] | None:
    """(byte offset of ``position[0]``, len(position)) of a little-endian CDR JointState, or None if unusual."""
    if len(data) < 16 or data[0] != 0 or data[1] != 1:             # CDR little endian only
        return None
    try:
        p = 12                                                     # 4 encapsulation + stamp (sec, nanosec)

        def align(p: int, n: int) -> int:
            return p + (-(p - 4) % n)

        (n,) = struct.unpack_from('<I', data, p)                    # frame_id
        p = align(p + 4 + n, 4)
        (count,) = struct.unpack_from('<I', data, p)                # names
        p += 4
        for _ in range(count):
            p = align(p, 4)
            (n,) = struct.unpack_from('<I', data, p)
            p += 4 + n
        p = align(p, 4)
        (n_pos,) = struct.unpack_from('<I', data, p)
        p = align(p + 4, 8)
        return (p, n_pos) if p + 8 * n_pos <= len(data) else None
    except struct.error:
        return None


def _decode_samples(datas: list[bytes], where: str) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (int64 ns) and the SAMPLE_CHANNELS values (n, 5) of JointState CDR messages.

    Fast path: messages with the same length and the same bytes as the first one outside the stamp and the position
    values (same frame_id, names, array lengths: every sample of one publisher) are decoded at once with numpy
    views. Any other message goes through the ``rosbags`` deserialiser. The fast path is checked against rosbags
    on the first message.
    """
    n_msgs = len(datas)
    stamps = np.empty(n_msgs, dtype=np.int64)
    table = np.empty((n_msgs, len(SAMPLE_CHANNELS)))
    done = np.zeros(n_msgs, dtype=bool)
    decode = _joint_state_decoder()

    def decoded(data: bytes):
        try:
            return decode(data)
        except Exception as error:
            raise AeropendError(f'a message in {where} is not valid CDR for JointState: {error}') from error

    def channel_index(names: tuple[str, ...]) -> list[int]:
        missing = [n for n in SAMPLE_CHANNELS if n not in names]
        if missing:
            raise AeropendError(f'{where}: JointState lacks the channel(s) {missing} (names {list(names)}): '
                                'not an aeropend samples topic')
        return [names.index(n) for n in SAMPLE_CHANNELS]

    first = datas[0]
    layout = _joint_state_layout(first)
    if layout is not None:
        pos_offset, n_pos = layout
        reference = decoded(first)
        index = channel_index(tuple(reference.name))
        length = len(first)
        same_length = np.fromiter((len(d) == length for d in datas), dtype=bool, count=n_msgs)
        rows = np.flatnonzero(same_length)
        block = np.frombuffer(b''.join(datas[k] for k in rows), dtype=np.uint8).reshape(len(rows), length)
        ref = block[0]
        end = pos_offset + 8 * n_pos
        alike = np.all(block[:, 12:pos_offset] == ref[12:pos_offset], axis=1) & \
            np.all(block[:, end:] == ref[end:], axis=1)
        block, rows = block[alike], rows[alike]
        sec = np.ascontiguousarray(block[:, 4:8]).view('<i4')[:, 0].astype(np.int64)
        nsec = np.ascontiguousarray(block[:, 8:12]).view('<u4')[:, 0].astype(np.int64)
        values = np.ascontiguousarray(block[:, pos_offset:end]).view('<f8')
        if len(index) and n_pos > max(index) and \
                np.array_equal(values[0], np.asarray(reference.position, dtype=float)) and \
                sec[0] * NS_PER_S + nsec[0] == reference.header.stamp.sec * NS_PER_S + reference.header.stamp.nanosec:
            stamps[rows] = sec * NS_PER_S + nsec
            table[rows] = values[:, index]
            done[rows] = True
    for k in np.flatnonzero(~done):                                   # anything unusual: the general decoder
        msg = decoded(datas[k])
        names = tuple(msg.name)
        index = channel_index(names)
        if len(msg.position) < len(names):
            raise AeropendError(f'{where}: a JointState has fewer positions than names')
        stamps[k] = int(msg.header.stamp.sec) * NS_PER_S + int(msg.header.stamp.nanosec)
        table[k] = [msg.position[i] for i in index]
    return stamps, table


def read_samples(path: str | os.PathLike, topic: str = _SAMPLES_TOPIC, on_incomplete: str = 'warn') \
        -> dict[str, np.ndarray]:
    """Acquisition samples of a recording as arrays (the JointState messages of ``/aeropend/samples``).

    Parameters
    ----------
    path
        Bag folder or ``.mcap`` file.
    topic
        Topic of the samples.
    on_incomplete
        See :func:`read_messages`.

    Returns
    -------
    dict of numpy arrays, each of shape ``(n_samples,)``, in recording order:
        ``time`` (s, acquisition stamp relative to the first sample), ``angle`` (rad), ``armature_voltage`` (V),
        ``armature_current`` (A), ``duty`` (fraction 0..1), ``sequence`` (int64, acquisition counter),
        ``stamp_ns`` (int64, acquisition stamp, ns since the publisher clock's epoch), ``receive_time_ns``
        (int64, recorder receive time).

    Raises
    ------
    AeropendError
        Not a bag, no message on ``topic``, wrong message type, or a message without the aeropend channel names.
    """
    datas: list[bytes] = []
    received: list[int] = []
    with warnings.catch_warnings(record=True) as cut:
        warnings.simplefilter('always')
        for message in read_messages(path, topics=[topic], on_incomplete=on_incomplete):
            if message.type != _JOINT_STATE:
                raise AeropendError(f'{topic} in {path} carries {message.type}, not {_JOINT_STATE}')
            datas.append(message.data)
            received.append(message.log_time_ns)
    incomplete = [w for w in cut if 'is incomplete' in str(w.message)]
    live = [w for w in cut if 'is still being recorded' in str(w.message)]
    if not datas and live:
        raise AeropendError(f'no {topic} message in {path} yet: {live[0].message}')
    if not datas:
        if incomplete:
            raise AeropendError(f'no {topic} message in {path} before it is cut short: {incomplete[0].message}')
        topics = bag_topics(path)
        raise AeropendError(f'no {topic} messages in {path} (it holds: '
                            f'{", ".join(f"{t} [{k}]" for t, k in topics.items()) or "no topic"}): '
                            'was the sample topic recorded? (recorder_node records it by default)')
    for record in cut:
        warnings.warn_explicit(record.message, record.category, record.filename, record.lineno)
    stamp_ns, table = _decode_samples(datas, f'{topic} in {path}')
    out = {'time': (stamp_ns - stamp_ns[0]) * 1e-9}
    for column, name in enumerate(SAMPLE_CHANNELS):
        out[name] = table[:, column]
    out['sequence'] = np.rint(out['sequence']).astype(np.int64)
    out['stamp_ns'] = stamp_ns
    out['receive_time_ns'] = np.asarray(received, dtype=np.int64)
    return out


# --------------------------------------------------------------------------------------------------------------
# Recovery of killed recordings
# --------------------------------------------------------------------------------------------------------------
@dataclass
class RecoveryReport:
    """What :func:`recover_bag` did."""

    folder: Path
    repaired: list[Path]
    intact: list[Path]
    message_count: int
    notes: list[str]
    metadata_yaml: Path | None = None      # the regenerated metadata.yaml (None for a lone .mcap file)
    removed_lock: str = ''                 # the stale recording lock removed (its process is gone), if any


def recover_bag(path: str | os.PathLike, keep_original: bool = False) -> RecoveryReport:
    """Repair a bag whose recorder was killed: finalise every cut ``.mcap`` and regenerate ``metadata.yaml``.

    Every complete chunk of a cut file is kept (messages after the last complete chunk were never written and
    are lost). Intact files are left as they are. The repaired file replaces the cut one atomically; with
    ``keep_original`` the cut file is kept as ``<file>.orig``.

    Parameters
    ----------
    path
        The bag folder, its ``metadata.yaml``, or one ``.mcap`` file. A file listed in its folder's
        ``metadata.yaml`` repairs that whole bag; a lone ``.mcap`` file (no bag folder around it) is repaired alone
        and no ``metadata.yaml`` is written next to it.

    Returns
    -------
    RecoveryReport

    Raises
    ------
    AeropendError
        When the path is not an MCAP bag, a file is unreadable from its start (no MCAP magic), or the repaired
        file cannot be written (disk full: the cut file is then left as it was).
    """
    path = Path(path)
    if not path.exists():
        raise AeropendError(f'{path} {path_problem(path)}')
    bag_lock.refuse_if_live(path, 'repair')
    folder, files, bag_folder = _recovery_targets(path)
    try:
        report = _recover_files(folder, files, bag_folder, keep_original)
        stale = bag_lock.remove_stale(folder)
        if stale is not None:
            report.removed_lock = f'removed the recording lock of {stale.describe()}, which no longer runs'
        return report
    except OSError as error:
        raise StorageError(f'cannot repair {path}: {error.strerror or error}'
                           f'{" (" + str(error.filename) + ")" if error.filename else ""}; nothing was changed in '
                           'the bag files. Free space (or copy the bag to another disk) and run '
                           f'aeropend bag-recover again') from None


def _recovery_targets(path: Path) -> tuple[Path, list[Path], bool]:
    """(folder, files to scan, whether the folder is a bag whose metadata.yaml is regenerated)."""
    if path.is_dir():
        return path, bag_files(path), True
    if path.name == 'metadata.yaml':
        return path.parent, bag_files(path.parent), True
    if path.suffix.lower() != '.mcap':
        raise AeropendError(f'{path} is not an MCAP file: give a bag folder, its metadata.yaml or a .mcap file')
    meta = path.parent / 'metadata.yaml'
    if meta.is_file():
        try:
            info = yaml.safe_load(meta.read_text(encoding='utf-8'))['rosbag2_bagfile_information']
            listed = {Path(p).name for p in info.get('relative_file_paths', [])}
        except (yaml.YAMLError, KeyError, TypeError, OSError):
            listed = set()
        if path.name in listed:
            return path.parent, bag_files(path.parent), True
    return path.parent, [path], False


def _recover_files(folder: Path, files: list[Path], bag_folder: bool, keep_original: bool) -> RecoveryReport:
    from mcap.writer import Writer
    repaired: list[Path] = []
    intact: list[Path] = []
    notes: list[str] = []
    topic_infos: dict[str, TopicInfo] = {}
    file_infos: list[_FileInfo] = []
    ros_distro = 'jazzy'
    for file in files:
        state = _ScanState(file)
        info = _FileInfo(file.name)
        messages = []
        for channel_id, seq, log_t, pub_t, data in _scan_mcap(file, state, want_messages=True):
            messages.append((channel_id, seq, log_t, pub_t, data))
            info.message_count += 1
            info.start_ns = log_t if info.start_ns is None else min(info.start_ns, log_t)
            info.end_ns = log_t if info.end_ns is None else max(info.end_ns, log_t)
        for name, meta in state.metadata:
            if name == 'rosbag2' and 'ROS_DISTRO' in meta:
                ros_distro = meta['ROS_DISTRO']
        for channel in state.channels.values():
            schema = state.schemas.get(channel.schema_id)
            if channel.topic not in topic_infos:
                qos = yaml.safe_load(channel.metadata.get('offered_qos_profiles') or '[]') or []
                topic_infos[channel.topic] = TopicInfo(
                    channel.topic, schema.name if schema else '', schema.data.decode() if schema else '',
                    qos if isinstance(qos, list) else [], channel.metadata.get('topic_type_hash', ''))
        for channel_id, *_ in messages:
            channel = state.channels.get(channel_id)
            if channel is not None:
                topic_infos[channel.topic].message_count += 1
        file_infos.append(info)
        if state.complete:
            intact.append(file)
            continue
        notes.append(f'{file.name}: {state.problem}; kept {len(messages)} messages')
        tmp = file.with_name(file.name + '.recovering')
        try:
            _write_recovered(Writer, tmp, state, messages, topic_infos, file_infos, ros_distro)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        if keep_original:
            os.replace(file, file.with_name(file.name + '.orig'))
        os.replace(tmp, file)
        repaired.append(file)
    meta = None
    if bag_folder:
        _write_metadata_yaml(folder, _metadata_dict(topic_infos.values(), file_infos, ros_distro))
        meta = folder / 'metadata.yaml'
    return RecoveryReport(folder, repaired, intact, sum(f.message_count for f in file_infos), notes, meta)


def _write_recovered(Writer, tmp: Path, state: _ScanState, messages, topic_infos, file_infos, ros_distro) -> None:
    """Write the kept messages of a cut file to `tmp` as a complete MCAP file (summary, footer, metadata)."""
    stream = _DirectFile(tmp)
    try:
        writer = Writer(stream, compression=_compression_type('zstd'))
        writer.start(profile=ROS2_PROFILE, library='aeropend bag-recover')
        writer.add_metadata('rosbag2', {'ROS_DISTRO': ros_distro})
        schema_map: dict[int, int] = {}
        channel_map: dict[int, int] = {}
        for channel in state.channels.values():
            schema = state.schemas.get(channel.schema_id)
            if schema is not None and schema.id not in schema_map:
                schema_map[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            channel_map[channel.id] = writer.register_channel(
                channel.topic, channel.message_encoding, schema_map.get(channel.schema_id, 0), channel.metadata)
        for channel_id, seq, log_t, pub_t, data in messages:
            if channel_id in channel_map:
                writer.add_message(channel_map[channel_id], log_t, data, pub_t, seq)
        writer.add_metadata('rosbag2', {'serialized_metadata': yaml.safe_dump(
            _metadata_dict(topic_infos.values(), file_infos, ros_distro), sort_keys=False)})
        writer.finish()
    finally:
        stream.close()

