"""ROS-free rosbag2-compatible MCAP bags: their conventions, and reading them into arrays.

Writing is :mod:`aeropend_core.io.bag_writer`, repair :mod:`aeropend_core.io.bag_recover`, the shared format
pieces :mod:`aeropend_core.io.mcap_format`.

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
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from aeropend_core.errors import AeropendError
from aeropend_core.io import bag_lock
from aeropend_core.io.paths import path_problem, storage_error
from aeropend_core.io.mcap_format import (
    _OP_CHANNEL,
    _OP_CHUNK,
    _OP_FOOTER,
    _OP_HEADER,
    _OP_MESSAGE,
    _OP_METADATA,
    _OP_SCHEMA,
    MCAP_MAGIC,
    NS_PER_S,
    ROS2_PROFILE,
    SAMPLE_CHANNELS,
    _JOINT_STATE,
    _SAMPLES_TOPIC,
)


__all__ = ['BagMessage', 'bag_files', 'bag_topics', 'read_messages', 'read_samples']


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
        Topic of the samples. With the default (``/aeropend/samples``, the default graph's), a bag that holds one
        rig's ``/<name>/aeropend/samples`` instead is read from that topic (``aeropend run --rig NAME``).
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
        topics = bag_topics(path)
        rigs = sorted(t for t in topics if t.endswith(_SAMPLES_TOPIC) and t != _SAMPLES_TOPIC)
        if topic == _SAMPLES_TOPIC and len(rigs) == 1:        # the bag of one rig in its namespace
            return read_samples(path, rigs[0], on_incomplete)
        if topic == _SAMPLES_TOPIC and len(rigs) > 1:
            raise AeropendError(f'{path} holds the samples of several rigs ({", ".join(rigs)}), not one: record '
                                'each rig with its own recorder (aeropend run --rig NAME, or a recorder_node in '
                                'the rig\'s namespace)')
        if incomplete:
            raise AeropendError(f'no {topic} message in {path} before it is cut short: {incomplete[0].message}')
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
