"""Writing rosbag2-compatible MCAP bags (see :mod:`aeropend_core.io.bag` for the conventions): :class:`BagWriter`
(chunked, compressed, split by size or time, crash-tolerant), the bag's ``metadata.yaml``.
"""
from __future__ import annotations

import os
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Self

import yaml

from aeropend_core.errors import AeropendError, StorageError
from aeropend_core.io import bag_lock
from aeropend_core.io.paths import storage_error
from aeropend_core.io.mcap_format import (
    MESSAGE_ENCODING,
    METADATA_VERSION,
    NS_PER_S,
    ROS2_PROFILE,
    SCHEMA_ENCODING,
    _split_type,
)


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

    def sync(self) -> None:
        """``fsync`` what was written (a finished file that is about to replace another)."""
        os.fsync(self._fd)

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


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
    max_chunk_duration
        Close the chunk in progress (hand it to the OS) once its first message waited this many seconds of wall
        time (0: by size only). A SIGKILL then loses at most about this much of the recording whatever the rate;
        :meth:`tick` applies it between messages too.
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
                 chunk_size: int = 1024 * 1024, compression: str = 'zstd', ros_distro: str = 'jazzy',
                 max_chunk_duration: float = 0.0):
        self.folder = Path(folder)
        if self.folder.exists() and not self.folder.is_dir():
            raise AeropendError(f'bag folder {self.folder} already exists and is not a folder: choose a new name')
        if self.folder.exists() and any(p.name != bag_lock.LOCK_NAME for p in self.folder.iterdir()):
            raise AeropendError(f'bag folder {self.folder} already exists and is not empty: choose a new name')
        if max_file_bytes < 0 or max_file_duration < 0:
            raise AeropendError('split limits must be >= 0 (0 means no split)')
        if chunk_size <= 0:
            raise AeropendError('chunk_size must be positive')
        if not max_chunk_duration >= 0:
            raise AeropendError('max_chunk_duration must be >= 0 (0: chunks closed by size only)')
        self.max_chunk_duration = float(max_chunk_duration)
        self._chunk_opened: float | None = None       # monotonic time of the first message of the chunk in progress
        self.chunks_closed_on_time = 0
        self._compression = _compression_type(compression)
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            self._lock = bag_lock.acquire(self.folder)   # held (flock) until finish(); the kernel drops it on a kill
        except OSError as error:
            raise storage_error(error, f'cannot create bag folder {self.folder}: {error.strerror or error}') \
                from None
        if any(p.name != bag_lock.LOCK_NAME for p in self.folder.iterdir()):   # filled while we waited for the lock
            bag_lock.release(self.folder)
            raise AeropendError(f'bag folder {self.folder} already exists and is not empty: choose a new name')
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
            elif self._chunk_opened is None:
                self._chunk_opened = time.monotonic()
            elif self.max_chunk_duration and time.monotonic() - self._chunk_opened >= self.max_chunk_duration:
                self._close_chunk()
            if self.max_file_bytes and self._stream.tell() >= self.max_file_bytes:
                self._split()
        except OSError as error:
            self._fail(error)

    def tick(self) -> None:
        """Close the chunk in progress when it has waited ``max_chunk_duration`` (call it while no message comes)."""
        if (self.max_chunk_duration and self._chunk_opened is not None and self._writer is not None
                and not self._failure and time.monotonic() - self._chunk_opened >= self.max_chunk_duration):
            try:
                self._close_chunk()
            except OSError as error:
                self._fail(error)

    def _close_chunk(self) -> None:
        """Write the chunk in progress and its message indexes now (the ``mcap`` writer's ``flush``)."""
        self._writer.flush()
        self.chunks_closed_on_time += 1
        self._mark_on_disk()

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
        self._chunk_opened = None
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
        # the writer keeps one ChunkIndex object per chunk until the file is finished (23 chunks/min at 490 Hz closed
        # by size, about 1 MB per recorded hour, bench/recorder_memory.py; 80/min with the recorder's chunk_duration
        # of 0.75 s, about 3.5 times as much); split long recordings with max_file_duration
        self._writer = Writer(self._stream, chunk_size=self.chunk_size, compression=self._compression)
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
    from aeropend_core.io.atomic import atomic_write
    text = yaml.safe_dump({'rosbag2_bagfile_information': metadata}, sort_keys=False)
    atomic_write(folder / 'metadata.yaml', lambda handle: handle.write(text))


__all__ = ['BagWriter', 'TopicInfo']
