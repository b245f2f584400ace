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

Reading: each file is read by :mod:`aeropend_core.io.mcap_scan` on the ``mcap`` library's records, every chunk
CRC-checked. A damaged chunk or record is skipped and reading goes on after it, and so is a message that does not
decode as a sample or whose stamp breaks the time order; a recording killed with SIGKILL leaves a
file readable up to its last complete chunk (no summary, no footer). Everything skipped is reported: a warning, and
with ``damage=`` a :class:`SampleDamage` per problem with the lost span [s] and sample count, which
:func:`aeropend_core.io.recording.load_recording` turns into findings. Chunks are read in time order.
:func:`~aeropend_core.io.bag_recover.recover_bag` (CLI ``aeropend bag-recover``) writes a complete copy of
everything readable.

Nothing here imports ROS: message definitions are given as text, and ``sensor_msgs/msg/JointState`` samples are
decoded with the ``rosbags`` CDR deserialiser.
"""
from __future__ import annotations

import functools
import os
import re
import struct
import warnings
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from aeropend_core.errors import AeropendError
from aeropend_core.io import bag_lock
from aeropend_core.io.mcap_format import NS_PER_S, SAMPLE_CHANNELS, _JOINT_STATE, _SAMPLES_TOPIC
from aeropend_core.io.mcap_scan import BagDamage, FileScan, scan_file
from aeropend_core.io.paths import path_problem


__all__ = ['BagDamage', 'BagMessage', 'bag_files', 'bag_information', 'bag_topics', 'damage_line', 'read_messages',
           'read_samples']


# --------------------------------------------------------------------------------------------------------------
# Reading (past damaged chunks, and files cut short by a kill)
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
    chunk_start_ns: int = 0         # log-time start of the chunk it was read from (readers sort chunks by it)
    chunk_offset: int = 0           # byte offset of that chunk in its file


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
        from aeropend_core.io.inputs import load_yaml
        try:
            info = load_yaml(meta_path, 'metadata file')['rosbag2_bagfile_information']
            listed = [path / Path(p).name for p in info.get('relative_file_paths', [])]
        except (yaml.YAMLError, KeyError, TypeError, AttributeError, OSError, AeropendError):
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
                  on_incomplete: str = 'warn', damage: list[BagDamage] | None = None) -> Iterator[BagMessage]:
    """Messages of a bag folder or ``.mcap`` file, in file order, as raw CDR bytes, read past damaged chunks.

    Each file is read by :func:`aeropend_core.io.mcap_scan.scan_file` (the ``mcap`` library's records, every
    chunk CRC-checked): a damaged chunk or record is skipped and reading goes on after it.

    Parameters
    ----------
    path
        Bag folder (``metadata.yaml`` + ``*.mcap``) or a single ``.mcap`` file.
    topics
        Only these topics (default: all).
    on_incomplete
        What to do with a file that is cut short (recording killed, disk full) or damaged: ``'warn'`` (read what
        can be read and warn), ``'ignore'``, or ``'raise'`` (:class:`AeropendError`).
    damage
        When given, every problem found (:class:`~aeropend_core.io.mcap_scan.BagDamage`, notes included) is
        appended to it as well.

    Raises
    ------
    AeropendError
        Not an MCAP file, not a ROS 2 bag, or (with ``on_incomplete='raise'``) an incomplete or damaged file.
    """
    for chunk, kept, names in _filtered_chunks(path, topics, on_incomplete, damage):
        for record in kept:
            topic, type_name = names[record.channel_id]
            yield BagMessage(topic, type_name, record.log_time, record.publish_time, record.data, record.sequence,
                             chunk.start_ns, chunk.offset)


def _filtered_chunks(path, topics: Iterable[str] | None, on_incomplete: str, damage: list[BagDamage] | None):
    """``(chunk, its messages on the wanted topics, channel id -> (topic, type))`` of every readable chunk of a bag,
    file by file; the damage of each file is stamped with its place among the messages yielded, then reported."""
    wanted = None if topics is None else set(topics)
    yielded = 0
    for file in bag_files(path):
        scan = FileScan(file)
        unknown: dict[int, int] = {}
        names: dict[int, tuple[str, str]] = {}
        stamped = 0
        for chunk in scan_file(file, scan):
            for late in scan.damage[stamped:]:      # where each problem sits among the messages yielded so far
                late.after_messages = yielded
            stamped = len(scan.damage)
            ids = {m.channel_id for m in chunk.messages}
            for channel_id in ids - names.keys():
                channel = scan.channels.get(channel_id)
                if channel is not None:
                    schema = scan.schemas.get(channel.schema_id)
                    names[channel_id] = (channel.topic, schema.name if schema else '')
            keep = {i for i in ids if i in names and (wanted is None or names[i][0] in wanted)}
            kept = chunk.messages if keep == ids else [m for m in chunk.messages if m.channel_id in keep]
            for channel_id in ids - names.keys():
                unknown[channel_id] = unknown.get(channel_id, 0) + sum(m.channel_id == channel_id
                                                                       for m in chunk.messages)
            yielded += len(kept)
            yield chunk, kept, names
        for late in scan.damage[stamped:]:
            late.after_messages = yielded
        if unknown:
            scan.damage.append(BagDamage(file, 0, 'unknown_channel', f'{sum(unknown.values())} message(s) on '
                                         f'channel id(s) {sorted(unknown)} whose definition was lost: not read',
                                         messages=sum(unknown.values()), after_messages=yielded))
        if damage is not None:
            damage.extend(scan.damage)
        _say_damage(path, file, scan, on_incomplete)


def _say_damage(path, file: Path, scan: FileScan, on_incomplete: str) -> None:
    """Warn about (or raise for) what reading ``file`` lost."""
    lost = scan.lost
    if not lost or on_incomplete == 'ignore':
        return
    message = _damage_message(path, file, lost)
    if on_incomplete == 'raise':
        raise AeropendError(message)
    warnings.warn(message, stacklevel=3)


def _damage_message(path, file: Path, lost: list[BagDamage]) -> str:
    """What reading ``file`` of the bag ``path`` lost (``lost``: its damage that lost data), and what to do."""
    in_bag = Path(path).is_dir() or (file.parent / 'metadata.yaml').is_file()
    writer = bag_lock.live_writer(file) if [d.kind for d in lost] == ['cut'] else None
    if writer is not None:      # being recorded: no repair to advise, only that the end is still coming
        message = (f'{file} is still being recorded by {writer.describe()}; read up to its last complete '
                   'chunk (the newest samples are not in it yet; read it again once the recording ends)')
    elif [d.kind for d in lost] == ['cut']:
        message = (f'{file} is incomplete ({lost[0].detail}); read up to its last complete chunk. '
                   f'Repair it with: aeropend bag-recover {file.parent if in_bag else file}')
    else:
        message = (f'{file} is damaged: ' + '; '.join(damage_line(d) for d in lost) + '; the rest was read. '
                   f'Write a repaired copy with: aeropend bag-recover {file.parent if in_bag else file}')
    return message


def damage_line(damage: BagDamage) -> str:
    """One line for a :class:`~aeropend_core.io.mcap_scan.BagDamage`: what, where, what it cost if known."""
    cost = f' ({damage.messages} messages lost)' if damage.lost and damage.messages is not None else ''
    return f'byte {damage.offset}: {damage.detail}{cost}'


def bag_information(path: str | os.PathLike) -> dict:
    """metadata.yaml's ``rosbag2_bagfile_information`` of a bag folder (or of the folder of a ``.mcap`` file), read
    once with libyaml when present (a big bag's metadata takes pure-Python YAML a tenth of a second); {} when there
    is none or it is unreadable."""
    from aeropend_core.io.inputs import YAML_MAX_BYTES, load_yaml_text, read_input_text
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    meta = folder / 'metadata.yaml'
    if not meta.is_file():
        return {}
    try:
        text = read_input_text(meta, 'metadata file', YAML_MAX_BYTES)
        info = load_yaml_text(text, f'metadata file {meta}')['rosbag2_bagfile_information']
    except (yaml.YAMLError, KeyError, TypeError, OSError, AeropendError):
        return {}
    return info if isinstance(info, dict) else {}


def bag_topics(path: str | os.PathLike) -> dict[str, str]:
    """Topic name -> message type of every channel in a bag (all files)."""
    out: dict[str, str] = {}
    for file in bag_files(path):
        scan = FileScan(file)
        for _ in scan_file(file, scan):
            pass
        for channel in scan.channels.values():
            schema = scan.schemas.get(channel.schema_id)
            out.setdefault(channel.topic, schema.name if schema else '')
    return out


#: The definitions of JointState and the types it holds, as ROS 2 Jazzy's (tests/test_bag.py compares them with
#: rosbags' Jazzy store): registering these three costs ~10 ms, the whole Jazzy store ~0.15-0.4 s (it imports every
#: older distribution's module).
_JOINT_STATE_TYPES = (('builtin_interfaces/msg/Time', 'int32 sec\nuint32 nanosec\n'),
                      ('std_msgs/msg/Header', 'builtin_interfaces/Time stamp\nstring frame_id\n'),
                      (_JOINT_STATE, 'std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n'
                                     'float64[] effort\n'))


@functools.lru_cache(maxsize=1)
def joint_state_store():
    """A rosbags type store holding only JointState and its field types (Jazzy's definitions)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    store = get_typestore(Stores.EMPTY)
    for name, text in _JOINT_STATE_TYPES:
        store.register(get_types_from_msg(text, name))
    return store


def _joint_state_decoder():
    store = joint_state_store()
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


def _decode_samples(datas: list[bytes], where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stamps (int64 ns), the SAMPLE_CHANNELS values (n, 5) of JointState CDR messages, and a mask of the
    messages that could not be decoded (their rows are meaningless; the caller drops them and says so).

    Fast path: messages with the same length and the same bytes as the first decodable one outside the stamp and the
    position values (same frame_id, names, array lengths: every sample of one publisher) are decoded at once with
    numpy views. Any other message goes through the ``rosbags`` deserialiser. The fast path is checked against
    rosbags on that first message. A message rosbags cannot decode, or without the aeropend channel names, is
    marked bad; when no message decodes, the first error is raised.
    """
    n_msgs = len(datas)
    stamps = np.zeros(n_msgs, dtype=np.int64)
    table = np.zeros((n_msgs, len(SAMPLE_CHANNELS)))
    done = np.zeros(n_msgs, dtype=bool)
    bad = np.zeros(n_msgs, dtype=bool)
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

    first_error = None
    for start, first in enumerate(datas):          # the first message that decodes is the reference
        try:
            reference = decoded(first)
            channel_index(tuple(reference.name))
            break
        except AeropendError as error:
            first_error = first_error or error
            bad[start] = True
    else:
        raise first_error
    layout = _joint_state_layout(first)
    if layout is not None:
        pos_offset, n_pos = layout
        index = channel_index(tuple(reference.name))
        length = len(first)
        same_length = np.fromiter((len(d) == length for d in datas), dtype=bool, count=n_msgs)
        rows = np.flatnonzero(same_length & ~bad)       # rows[0] is the reference (the ones before it are bad)
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
    for k in np.flatnonzero(~done & ~bad):                            # anything unusual: the general decoder
        try:
            msg = decoded(datas[k])
            names = tuple(msg.name)
            index = channel_index(names)
            if len(msg.position) < len(names):
                raise AeropendError(f'{where}: a JointState has fewer positions than names')
            stamps[k] = int(msg.header.stamp.sec) * NS_PER_S + int(msg.header.stamp.nanosec)
            table[k] = [msg.position[i] for i in index]
        except (AeropendError, OverflowError, TypeError, ValueError, IndexError):
            bad[k] = True                       # not a sample: dropped and reported by the caller
    return stamps, table, bad


@dataclass
class SampleDamage:
    """What a damaged or cut file cost the samples read from it (:func:`read_samples`).

    Attributes
    ----------
    damage : BagDamage
        What the reader found (``damage.lost`` False: a note that cost nothing).
    t_start, t_stop : float or None [s]
        Record time (from the first sample read) of the last sample before the loss and the first one after it;
        None where there is no sample on that side (a file cut at its end) or the loss cost nothing.
    samples : int or None [-]
        Samples lost, from the acquisition sequence counter around the loss (else the file's own message count);
        None when unknown.
    """

    damage: BagDamage
    t_start: float | None = None
    t_stop: float | None = None
    samples: int | None = None

    def line(self) -> str:
        """One line: the file, the problem, and the lost span and sample count when known."""
        d = self.damage
        text = f'{d.file.name}: {damage_line(d) if not d.lost else f"byte {d.offset}: {d.detail}"}'
        if not d.lost:
            return text
        count = 'an unknown number of samples' if self.samples is None else f'{self.samples} sample(s)'
        if self.t_start is not None and self.t_stop is not None:
            return f'{text}; {count} lost between t = {self.t_start:.3f} s and t = {self.t_stop:.3f} s'
        if self.t_start is not None:
            return f'{text}; {count} lost after t = {self.t_start:.3f} s (the end of the record)'
        if self.t_stop is not None:
            return f'{text}; {count} lost before t = {self.t_stop:.3f} s (the start of the record)'
        return f'{text}; {count} lost'


def _sample_damage(found: list[BagDamage], order: np.ndarray, receive_ns: np.ndarray, time: np.ndarray,
                   sequence: np.ndarray, kept_before: np.ndarray | None = None) -> list[SampleDamage]:
    """Locate each loss among the samples (by its chunk's log-time span, else by its place in file order;
    ``kept_before[k]``: the samples kept among the first k in file order, when some were dropped)."""
    n = len(order)
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)                      # file-order index -> index in the time-ordered arrays
    latest = np.maximum.accumulate(receive_ns) if n else receive_ns
    out = []
    for d in found:
        if not d.lost:
            out.append(SampleDamage(d))
            continue
        before = after = None
        if d.start_ns is not None and n and receive_ns[0] <= d.start_ns <= d.end_ns <= latest[-1]:
            k = int(np.searchsorted(latest, d.start_ns, side='left'))
            j = int(np.searchsorted(latest, d.end_ns, side='right'))
            before, after = (k - 1 if k > 0 else None), (j if j < n else None)
        else:
            k = d.after_messages if kept_before is None else int(kept_before[min(d.after_messages,
                                                                                 len(kept_before) - 1)])
            k = min(k, n)
            before = int(rank[k - 1]) if k > 0 else None
            after = int(rank[k]) if k < n else None
        samples = d.messages
        if before is not None and after is not None and sequence[after] > sequence[before]:
            samples = int(sequence[after] - sequence[before] - 1)
        out.append(SampleDamage(d, None if before is None else float(time[before]),
                                None if after is None else float(time[after]), samples))
    return out


def _refuse_empty(path, topic: str, found: list[BagDamage]) -> None:
    """Raise why a bag whose samples could not be read is empty on ``topic``, when its damage explains it (whatever
    ``on_incomplete`` asked for: with no sample read, the damage is the whole answer and must be said)."""
    lost = [d for d in found if d.lost]
    if not lost:
        return
    file = lost[0].file
    message = _damage_message(path, file, [d for d in lost if d.file == file])
    if 'is still being recorded' in message:
        raise AeropendError(f'no {topic} message in {path} yet: {message}')
    where = 'before it is cut short' if 'is incomplete' in message else 'outside its damaged parts'
    raise AeropendError(f'no {topic} message in {path} {where}: {message}')


def read_samples(path: str | os.PathLike, topic: str = _SAMPLES_TOPIC, on_incomplete: str = 'warn',
                 damage: list[SampleDamage] | None = None,
                 others: dict[str, list[bytes]] | None = None) -> dict[str, np.ndarray]:
    """Acquisition samples of a recording as arrays (the JointState messages of ``/aeropend/samples``).

    Chunks are read in time order (their start log time; valid MCAP files may hold them in any order), past
    damaged chunks (see :func:`read_messages`). A message that does not decode as a sample (not valid CDR for
    JointState, no aeropend channel names, a counter that is not a number), and a sample whose stamp breaks the time
    order (all but the longest run of stamps in order, at most 10 % of them), are skipped and reported (``damage``:
    kinds ``undecodable`` and ``stamp_out_of_order``, with the span between the samples kept around them); the bag is
    refused only when no message decodes.

    Parameters
    ----------
    path
        Bag folder or ``.mcap`` file.
    topic
        Topic of the samples. With the default (``/aeropend/samples``, the default graph's), a bag that holds one
        rig's ``/<name>/aeropend/samples`` instead is read from that topic (``aeropend run --rig NAME``).
    on_incomplete
        See :func:`read_messages`.
    damage
        When given, receives a :class:`SampleDamage` for every problem found (notes included): the lost span
        [s] and sample count of each damaged chunk or cut.
    others
        Topic -> list: the raw CDR bytes of each message on these other topics are appended to its list, in file
        order, in the same pass over the file (a closed-loop record's control telemetry: one read, not two).

    Returns
    -------
    dict of numpy arrays, each of shape ``(n_samples,)``, in time order:
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
    chunk_start: list[int] = []
    chunk_offset: list[int] = []
    found: list[BagDamage] = []
    with warnings.catch_warnings(record=True) as cut:
        warnings.simplefilter('always')
        for chunk, kept, names in _filtered_chunks(path, [topic, *(others or {})], on_incomplete, found):
            if others:
                for m in kept:
                    other = others.get(names[m.channel_id][0])
                    if other is not None and names[m.channel_id][0] != topic:
                        other.append(m.data)
                kept = [m for m in kept if names[m.channel_id][0] == topic]
            if not kept:
                continue
            wrong = {names[m.channel_id][1] for m in kept} - {_JOINT_STATE}
            if wrong:
                raise AeropendError(f'{topic} in {path} carries {wrong.pop()}, not {_JOINT_STATE}')
            datas.extend([m.data for m in kept])
            received.extend([m.log_time for m in kept])
            chunk_start.extend([chunk.start_ns] * len(kept))
            chunk_offset.extend([chunk.offset] * len(kept))
    if not datas:
        topics = bag_topics(path)
        rigs = sorted(t for t in topics if t.endswith(_SAMPLES_TOPIC) and t != _SAMPLES_TOPIC)
        if topic == _SAMPLES_TOPIC and len(rigs) == 1:        # the bag of one rig in its namespace
            return read_samples(path, rigs[0], on_incomplete, damage, others)
        if topic == _SAMPLES_TOPIC and len(rigs) > 1:
            raise AeropendError(f'{path} holds the samples of several rigs ({", ".join(rigs)}), not one: record '
                                'each rig with its own recorder (aeropend run --rig NAME, or a recorder_node in '
                                'the rig\'s namespace)')
        _refuse_empty(path, topic, found)
        raise AeropendError(f'no {topic} messages in {path} (it holds: '
                            f'{", ".join(f"{t} [{k}]" for t, k in topics.items()) or "no topic"}): '
                            'was the sample topic recorded? (recorder_node records it by default)')
    for record in cut:
        warnings.warn_explicit(record.message, record.category, record.filename, record.lineno)
    # the files in bag order; inside a file its chunks by start time (a stable sort: file order among equals)
    file_index = np.zeros(len(datas), dtype=np.int64)
    offsets = np.asarray(chunk_offset, dtype=np.int64)
    if len(offsets) > 1:
        file_index[1:] = np.cumsum(np.diff(offsets) < 0)           # offsets restart at each new file
    starts = np.asarray(chunk_start, dtype=np.int64)
    order = np.lexsort((np.arange(len(datas)), starts, file_index))
    if np.any(order != np.arange(len(order))):
        datas = [datas[k] for k in order]
        received = [received[k] for k in order]
    stamp_ns, table, undecodable = _decode_samples(datas, f'{topic} in {path}')
    bad_sequence = ~np.isfinite(table[:, SAMPLE_CHANNELS.index('sequence')]) & ~undecodable
    undecodable |= bad_sequence                 # a counter that is not a number cannot be a sample of ours
    out_of_order = _stamps_out_of_order(stamp_ns, undecodable)
    keep = ~(undecodable | out_of_order)
    received_ns = np.asarray(received, dtype=np.int64)
    if not keep.all():
        stamp_ns, table, received_ns = stamp_ns[keep], table[keep], received_ns[keep]
    out = {'time': (stamp_ns - stamp_ns[0]) * 1e-9}
    for column, name in enumerate(SAMPLE_CHANNELS):
        out[name] = table[:, column]
    out['sequence'] = np.rint(out['sequence']).astype(np.int64)
    out['stamp_ns'] = stamp_ns
    out['receive_time_ns'] = received_ns
    skipped = []
    if not keep.all():
        skipped = _skipped_samples(path, topic, keep, undecodable, out_of_order, file_index[order],
                                   offsets[order] if len(offsets) else offsets, out['time'], out['sequence'])
        for item in skipped:
            if on_incomplete == 'raise':
                raise AeropendError(f'{path}: {item.line()}')
            if on_incomplete == 'warn':
                warnings.warn(f'{path}: {item.line()}; the rest was read', stacklevel=2)
    if damage is not None:
        kept_file = np.ones(len(keep), dtype=bool)
        kept_file[order[~keep]] = False                 # file-order messages kept
        kept_before = np.concatenate(([0], np.cumsum(kept_file)))
        damage.extend(_sample_damage(found, kept_before[:-1][order[keep]], out['receive_time_ns'], out['time'],
                                     out['sequence'], kept_before))
        damage.extend(skipped)
    return out


#: Largest fraction of the samples :func:`_stamps_out_of_order` drops; beyond it the stamps are left as they are
#: (two recordings in one bag, a clock stepped back: the data-quality gate then refuses them with its own words).
MAX_OUT_OF_ORDER = 0.1


def _stamps_out_of_order(stamp_ns: np.ndarray, skip: np.ndarray) -> np.ndarray:
    """Mask of the samples whose stamps break the time order: all but the longest non-decreasing run of stamps
    (a subsequence, found in O(n log n) only when a stamp goes back), so that one damaged stamp, or a few garbled
    by a bit flip in a chunk without CRC, cost only themselves. ``skip`` marks samples already dropped. Nothing is
    marked when more than MAX_OUT_OF_ORDER of the samples would go."""
    import bisect
    bad = np.zeros(len(stamp_ns), dtype=bool)
    index = np.flatnonzero(~skip)
    s = stamp_ns[index]
    if len(s) < 2 or not np.any(np.diff(s) < 0):
        return bad
    tails: list[int] = []                  # smallest last stamp of a non-decreasing run of each length
    tail_at: list[int] = []                # its position in s
    previous = np.full(len(s), -1, dtype=np.int64)
    for k, value in enumerate(s.tolist()):
        length = bisect.bisect_right(tails, value)
        if length:
            previous[k] = tail_at[length - 1]
        if length == len(tails):
            tails.append(value)
            tail_at.append(k)
        else:
            tails[length], tail_at[length] = value, k
    if len(s) - len(tails) > MAX_OUT_OF_ORDER * len(s):
        return bad
    keep = np.zeros(len(s), dtype=bool)
    k = tail_at[-1]
    while k >= 0:
        keep[k] = True
        k = previous[k]
    bad[index[~keep]] = True
    return bad


def _skipped_samples(path, topic: str, keep: np.ndarray, undecodable: np.ndarray, out_of_order: np.ndarray,
                     file_of: np.ndarray, chunk_of: np.ndarray, time: np.ndarray,
                     sequence: np.ndarray) -> list[SampleDamage]:
    """One :class:`SampleDamage` per chunk and kind for the messages :func:`read_samples` dropped (not decodable
    as a sample, or a stamp out of order), with the span between the kept samples around them."""
    files = bag_files(path)
    kept_rank = np.cumsum(keep)                     # kept samples up to and including each index
    out = []
    for kind, mask, what in (
            ('undecodable', undecodable, f'message(s) on {topic} that are not decodable as samples (not valid CDR '
                                         'for JointState, or without the aeropend channels): skipped'),
            ('stamp_out_of_order', out_of_order, 'sample(s) whose time stamp is out of order with the samples '
                                                 'around them (a damaged stamp): skipped')):
        rows = np.flatnonzero(mask)
        if not rows.size:
            continue
        groups: dict[tuple[int, int], list[int]] = {}
        for k in rows:
            groups.setdefault((int(file_of[k]), int(chunk_of[k]) if len(chunk_of) else 0), []).append(int(k))
        for (file_number, offset), members in groups.items():
            before = int(kept_rank[members[0]]) - 1
            after = int(kept_rank[members[-1]])
            before = before if before >= 0 else None
            after = after if after < len(time) else None
            samples = len(members)
            if before is not None and after is not None and sequence[after] > sequence[before]:
                samples = int(sequence[after] - sequence[before] - 1)
            file = files[min(file_number, len(files) - 1)]
            damage = BagDamage(file, offset, kind, f'{len(members)} {what}', messages=len(members))
            out.append(SampleDamage(damage, None if before is None else float(time[before]),
                                    None if after is None else float(time[after]), samples))
    return out
