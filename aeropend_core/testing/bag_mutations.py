"""Damaged MCAP bags on purpose, and an independent judge of what is still readable in them.

Used by ``bench/bag_mutations.py`` (hundreds of mutated bags) and ``tests/test_bag_recovery.py`` (a fast subset).

- :func:`write_sample_bag` writes a small ``ros2`` MCAP file of ``/aeropend/samples`` JointState messages (CDR by
  the ``rosbags`` serialiser) and ``/aeropend/duty_cmd`` Float64 messages with the ``mcap`` writer, with or
  without chunk CRCs.
- :data:`OPERATORS` damage its bytes: CRC or data byte flips, truncation, a chunk's type byte made a footer's or an
  unknown one, reordered or duplicated chunks, a damaged chunk length field, the summary removed or damaged, zeroed
  blocks, inserted garbage, bit flips in a file without CRCs; and (issue 43) a message index's type byte made a
  data end's (0x0f), a message's (0x05) or an unknown one, the CRC of the chunk before last, a flipped bit in one
  sample's time stamp and one in any byte of one message in an uncompressed file without CRCs.
- :func:`judge_messages` is the referee: it looks for chunks everywhere in a file and keeps those that the ``mcap``
  package itself opens with ``breakup_chunk(validate_crc=True)`` (chunks without CRC only where a chunk record
  starts). It shares no code with :mod:`aeropend_core.io.mcap_scan`.
"""
from __future__ import annotations

import io
import math
import os
import random
import struct
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

__all__ = ['NEEDS', 'OPERATORS', 'Layout', 'judge_messages', 'layout', 'message_keys', 'write_sample_bag']

SAMPLES_TOPIC, DUTY_TOPIC = '/aeropend/samples', '/aeropend/duty_cmd'
SAMPLE_PERIOD_NS = 2_040_816                 # 1/490 s
START_NS = 1_763_700_000_000_000_000


def _schema_text(type_name: str) -> bytes:
    from aeropend_core.io.mcap_format import msg_file_loader, ros2msg_definition
    prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p] + [sys.prefix]
    try:
        return ros2msg_definition(type_name, msg_file_loader(prefixes)).encode()
    except Exception:           # noqa: BLE001 - no .msg files installed: the readers do not need the text
        return b''


def write_sample_bag(path: str | os.PathLike, samples: int, chunk_size: int = 16 * 1024, crcs: bool = True,
                     seed: int = 0, compression: str = 'zstd') -> Path:
    """Write ``samples`` JointState samples (490 Hz, sequence 0..n-1) and a duty command every 49 samples.

    Parameters
    ----------
    path : str or PathLike [-]
        The ``.mcap`` file to write.
    samples : int [-]
        Number of samples.
    chunk_size : int [bytes]
        Uncompressed chunk size of the writer.
    crcs : bool [-]
        Write chunk and summary CRCs (``False``: a file whose bit flips cannot be detected).
    seed : int [-]
        Seed of the sample values.
    compression : str [-]
        ``'zstd'`` or ``'none'`` (the bytes of each message lie in the file as written).

    Returns
    -------
    Path
        ``path``.
    """
    import numpy as np
    from mcap.writer import CompressionType, Writer
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    joint_state = store.types['sensor_msgs/msg/JointState']
    header_type = store.types['std_msgs/msg/Header']
    time_type = store.types['builtin_interfaces/msg/Time']
    float64 = store.types['std_msgs/msg/Float64']
    rng = random.Random(seed)
    path = Path(path)
    with open(path, 'wb') as stream:
        writer = Writer(stream, chunk_size=chunk_size, enable_crcs=crcs,
                        compression=CompressionType.ZSTD if compression == 'zstd' else CompressionType.NONE)
        writer.start(profile='ros2', library='aeropend bag_mutations')
        writer.add_metadata('rosbag2', {'ROS_DISTRO': 'jazzy'})
        js = writer.register_schema('sensor_msgs/msg/JointState', 'ros2msg',
                                    _schema_text('sensor_msgs/msg/JointState'))
        fl = writer.register_schema('std_msgs/msg/Float64', 'ros2msg', _schema_text('std_msgs/msg/Float64'))
        samples_channel = writer.register_channel(SAMPLES_TOPIC, 'cdr', js, {'offered_qos_profiles': ''})
        duty_channel = writer.register_channel(DUTY_TOPIC, 'cdr', fl, {'offered_qos_profiles': ''})
        for k in range(samples):
            stamp = START_NS + k * SAMPLE_PERIOD_NS
            message = joint_state(
                header=header_type(stamp=time_type(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id='aeropend'),
                name=['angle', 'armature_voltage', 'armature_current', 'duty', 'sequence'],
                # smooth signals with a little noise: the data-quality gate takes the intact file as a recording
                position=np.array([0.5 * math.sin(k * 0.01) + rng.gauss(0, 0.002),
                                   6.0 + 2.0 * math.sin(k * 0.013) + rng.gauss(0, 0.01),
                                   0.5 + 0.2 * math.sin(k * 0.013) + rng.gauss(0, 0.002), (k % 100) / 100,
                                   float(k)]),
                velocity=np.array([], dtype=float), effort=np.array([], dtype=float))
            writer.add_message(samples_channel, stamp + 300_000,
                               bytes(store.serialize_cdr(message, joint_state.__msgtype__)), stamp + 100_000, k + 1)
            if k % 49 == 0:
                writer.add_message(duty_channel, stamp + 200_000,
                                   bytes(store.serialize_cdr(float64(data=(k % 100) / 100), float64.__msgtype__)),
                                   stamp + 200_000, k // 49 + 1)
        writer.finish()
    return path


@dataclass(frozen=True)
class Layout:
    """Where the records of an intact file are: chunk blocks (chunk + its message indexes), summary, footer."""

    chunks: tuple[tuple[int, int, int], ...]     # (chunk start, chunk record length, block end) [bytes]
    data_end: int                                # offset of the DataEnd record [bytes]
    summary_start: int                           # [bytes]
    footer: int                                  # offset of the footer record [bytes]


def layout(data: bytes) -> Layout:
    """The :class:`Layout` of an intact MCAP file, from its summary (read by the ``mcap`` package)."""
    from mcap.reader import make_reader
    summary = make_reader(io.BytesIO(data)).get_summary()
    chunks = sorted((c.chunk_start_offset, c.chunk_length, c.chunk_start_offset + c.chunk_length
                     + c.message_index_length) for c in summary.chunk_indexes)
    footer = len(data) - 8 - 29
    (summary_start,) = struct.unpack_from('<Q', data, footer + 9)
    return Layout(tuple(chunks), chunks[-1][2], summary_start, footer)


def _flip(data: bytearray, position: int) -> None:
    data[position] ^= 0xFF


def _crc_flip(data: bytes, lay: Layout, rng: random.Random) -> bytes:
    out = bytearray(data)
    start = rng.choice(lay.chunks)[0]
    _flip(out, start + 9 + 24 + rng.randrange(4))             # inside uncompressed_crc
    return bytes(out)


def _data_flip(data: bytes, lay: Layout, rng: random.Random) -> bytes:
    out = bytearray(data)
    start, length, _ = rng.choice(lay.chunks)
    _flip(out, start + length - 1 - rng.randrange(max(1, length - 60)))   # inside the compressed data
    return bytes(out)


def _truncate(data: bytes, lay: Layout, rng: random.Random) -> bytes:
    return data[:rng.randrange(9, len(data) - 1)]


def _opcode(value: int) -> Callable[[bytes, Layout, random.Random], bytes]:
    def mutate(data: bytes, lay: Layout, rng: random.Random) -> bytes:
        out = bytearray(data)
        out[rng.choice(lay.chunks)[0]] = value
        return bytes(out)
    return mutate


def _reorder(data: bytes, lay: Layout, rng: random.Random) -> bytes:
    i = rng.randrange(len(lay.chunks) - 1)
    j = rng.randrange(i + 1, len(lay.chunks))
    blocks = [data[s:e] for s, _, e in lay.chunks]
    blocks[i], blocks[j] = blocks[j], blocks[i]
    first, last = lay.chunks[0][0], lay.chunks[-1][2]
    return data[:first] + b''.join(blocks) + data[last:]


def _duplicate(data: bytes, lay: Layout, rng: random.Random) -> bytes:
    start, _, end = rng.choice(lay.chunks)
    return data[:end] + data[start:end] + data[end:]


def _chunk_length(data: bytes, lay: Layout, rng: random.Random) -> bytes:
    out = bytearray(data)
    start = rng.choice(lay.chunks)[0]
    (length,) = struct.unpack_from('<Q', out, start + 1)
    struct.pack_into('<Q', out, start + 1, rng.choice([length + rng.randrange(1, 5000), length // 2, 0, 2**40]))
    return bytes(out)


def _summary_removed(data: bytes, lay: Layout, rng: random.Random) -> bytes:
    return data[:lay.data_end + rng.choice([0, 13])]       # cut at the data end record, or just after it


def _summary_damaged(data: bytes, lay: Layout, rng: random.Random) -> bytes:
    out = bytearray(data)
    _flip(out, rng.randrange(lay.summary_start, lay.footer))
    return bytes(out)


def _zero_block(data: bytes, lay: Layout, rng: random.Random) -> bytes:
    out = bytearray(data)
    start = rng.randrange(8, len(data) - 64)
    size = rng.choice([16, 512, 4096])
    out[start:start + size] = bytes(len(out[start:start + size]))
    return bytes(out)


def _insert_garbage(data: bytes, lay: Layout, rng: random.Random) -> bytes:
    at = rng.randrange(8, len(data) - 8)
    return data[:at] + bytes(rng.randrange(256) for _ in range(rng.choice([1, 7, 100, 3000]))) + data[at:]


def _index_opcode(value: int) -> Callable[[bytes, Layout, random.Random], bytes]:
    """The type byte of the first message index after a random chunk set to `value` (issue 43: 0x0f made the data
    end there, 0x05 a junk message)."""
    def mutate(data: bytes, lay: Layout, rng: random.Random) -> bytes:
        out = bytearray(data)
        start, length, _ = rng.choice(lay.chunks[:-1])
        assert out[start + length] == 0x07, 'no message index after the chunk'
        out[start + length] = value
        return bytes(out)
    return mutate


def _crc_flip_near_end(data: bytes, lay: Layout, rng: random.Random) -> bytes:
    """The CRC of the chunk before the last one damaged (issue 43: the short piece after the gap)."""
    out = bytearray(data)
    _flip(out, lay.chunks[-2][0] + 9 + 24 + rng.randrange(4))
    return bytes(out)


def _sample_messages(data: bytes, lay: Layout) -> list[tuple[int, int]]:
    """(offset of the CDR bytes, their length) of every JointState message in the uncompressed chunks of `data`."""
    found = []
    for start, length, _ in lay.chunks:
        body = start + 9
        (clen,) = struct.unpack_from('<I', data, body + 28)
        assert clen == 0, 'the file is compressed'
        position = body + 32 + clen + 8
        end = start + length
        while position + 9 <= end:
            (record,) = struct.unpack_from('<Q', data, position + 1)
            if data[position] == 0x05 and record > 22 + 40:
                found.append((position + 9 + 22, record - 22))
            position += 9 + record
    return found


def _stamp_flip(data: bytes, lay: Layout, rng: random.Random) -> bytes:
    """One bit of the seconds of one sample's header stamp flipped (an uncompressed file without CRCs)."""
    out = bytearray(data)
    offset, _ = rng.choice(_sample_messages(data, lay))
    out[offset + 4 + rng.randrange(4)] ^= 1 << rng.randrange(8)
    return bytes(out)


def _message_flip(data: bytes, lay: Layout, rng: random.Random) -> bytes:
    """One bit of one sample message's CDR bytes flipped (an uncompressed file without CRCs)."""
    out = bytearray(data)
    offset, length = rng.choice(_sample_messages(data, lay))
    out[offset + rng.randrange(length)] ^= 1 << rng.randrange(8)
    return bytes(out)


def _chunk_from_other(data: bytes, lay: Layout, rng: random.Random) -> bytes:
    """Two chunks damaged at once (the reader must go on after each)."""
    return _data_flip(_crc_flip(data, lay, rng), lay, rng)


#: name -> mutate(data, layout, rng) -> damaged bytes. ``no_crc_flip`` expects a file written without CRCs,
#: ``stamp_flip`` and ``message_flip`` one written without CRCs and without compression (:data:`NEEDS`).
OPERATORS: dict[str, Callable[[bytes, Layout, random.Random], bytes]] = {
    'crc_flip': _crc_flip,
    'data_flip': _data_flip,
    'truncate': _truncate,
    'opcode_footer': _opcode(0x02),
    'opcode_unknown': _opcode(0x55),
    'chunk_reorder': _reorder,
    'duplicate_chunk': _duplicate,
    'chunk_length': _chunk_length,
    'summary_removed': _summary_removed,
    'summary_damaged': _summary_damaged,
    'zero_block': _zero_block,
    'insert_garbage': _insert_garbage,
    'two_chunks_damaged': _chunk_from_other,
    'no_crc_flip': _data_flip,
    'index_opcode_data_end': _index_opcode(0x0F),
    'index_opcode_message': _index_opcode(0x05),
    'index_opcode_unknown': _index_opcode(0x55),
    'crc_flip_near_end': _crc_flip_near_end,
    'stamp_flip': _stamp_flip,
    'message_flip': _message_flip,
}

#: The original an operator damages: (chunk CRCs, compression); the rest take a zstd file with CRCs.
NEEDS: dict[str, tuple[bool, str]] = {'no_crc_flip': (False, 'zstd'), 'stamp_flip': (False, 'none'),
                                      'message_flip': (False, 'none')}


def message_keys(messages) -> set[tuple[int, int, int, bytes]]:
    """``(log_time, publish_time, sequence, data)`` of ``mcap.records.Message`` objects: a message's identity
    that does not depend on channel numbering."""
    return {(m.log_time, m.publish_time, m.sequence, bytes(m.data)) for m in messages}


def judge_messages(data: bytes) -> set[tuple[int, int, int, bytes]]:
    """Every message the ``mcap`` package decodes from any chunk of ``data``, chunk by chunk.

    Each position holding a chunk-like header is opened with ``mcap.records.Chunk.read`` and
    ``mcap.stream_reader.breakup_chunk(validate_crc=True)``; a chunk counts when its CRC is set and matches, or,
    without CRC, when a chunk record (type byte 0x06) starts there and its content opens.
    """
    from mcap.data_stream import ReadDataStream
    from mcap.records import Chunk, Message
    from mcap.stream_reader import breakup_chunk
    found: set = set()
    position = data.find(b'\x06')
    size = len(data)
    while 0 <= position:
        body = position + 9
        if body + 40 <= size:
            (clen,) = struct.unpack_from('<I', data, body + 28)
            if clen <= 4 and data[body + 32:body + 32 + clen] in (b'', b'zstd', b'lz4') and \
                    body + 32 + clen + 8 <= size:
                (dlen,) = struct.unpack_from('<Q', data, body + 32 + clen)
                end = body + 32 + clen + 8 + dlen
                if end <= size:
                    try:
                        chunk = Chunk.read(ReadDataStream(io.BytesIO(data[body:end])))
                        if chunk.uncompressed_size <= 64 * 1024 * 1024:
                            records = breakup_chunk(chunk, validate_crc=True)
                            if chunk.uncompressed_crc or data[position] == 0x06:
                                found |= message_keys(r for r in records if isinstance(r, Message))
                    except Exception:   # noqa: BLE001 - not a chunk here, or a damaged one
                        pass
        position = data.find(b'\x06', position + 1)
    return found
