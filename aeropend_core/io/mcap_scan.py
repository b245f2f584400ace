"""Reading one MCAP file record by record with the ``mcap`` library, past the damage a file can carry.

The records are parsed by the ``mcap`` package's record classes (:class:`mcap.records.Chunk`, ``Schema``,
``Channel``, ...) and every chunk is opened and CRC-checked by ``mcap.stream_reader.breakup_chunk`` (the code
``StreamReader(validate_crcs=True)`` runs on each chunk). What this module adds is what a stream reader cannot
do after its first error: it goes on.

- A chunk whose data fail the CRC (or do not decompress to their declared size) is **skipped** and the walk
  continues after it (at the end its length field gives, else at the next chunk found by :func:`_resync`);
  its time span comes from its header, its message count from the message index records after it.
- A record whose type byte or length field is damaged (a chunk read as a footer, a length that runs past the
  file) is skipped by looking for the next chunk whose CRC matches.
- A duplicated chunk is read once; a chunk without CRC is read and counted (bit flips in it are undetectable).
- The summary (statistics, channel and schema records) is read first when the footer at the file's end and
  its CRC are intact, so messages after a lost first chunk keep their channel; once the records are read, the
  summary's counts are compared with them and a disagreement is reported.

Everything found is a :class:`BagDamage` in :attr:`FileScan.damage`; chunks come out of :func:`scan_file` in
file order as :class:`ChunkRead` (readers put them in time order). Memory: one chunk at a time (the file is
memory-mapped).
"""
from __future__ import annotations

import mmap
import os
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from aeropend_core.errors import AeropendError
from aeropend_core.io.mcap_format import _OP_CHUNK, _OP_FOOTER, MCAP_MAGIC, ROS2_PROFILE
from aeropend_core.io.paths import storage_error

__all__ = ['BagDamage', 'ChunkRead', 'FileScan', 'scan_file']

#: Largest uncompressed chunk accepted [bytes]: a damaged size field must not make the reader allocate gigabytes.
MAX_CHUNK_BYTES = 256 * 1024 * 1024

_COMPRESSIONS = ('', 'zstd', 'lz4')
_FOOTER_BYTES = 1 + 8 + 20            # opcode, length, summary_start, summary_offset_start, summary_crc
_OP_DATA_END, _OP_MESSAGE_INDEX, _OP_STATISTICS, _OP_CHUNK_INDEX = 0x0F, 0x07, 0x0B, 0x08


@dataclass
class BagDamage:
    """One thing a reader found wrong with a file, where, and what it cost.

    Attributes
    ----------
    file : Path
        The ``.mcap`` file.
    offset : int [bytes]
        Where in the file the problem starts.
    kind : str
        ``chunk_skipped`` (data lost), ``record_skipped`` (a damaged record skipped; a chunk in it, if any, was
        lost), ``cut`` (the file ends early: recorder killed, disk full), ``unknown_channel`` (messages whose
        channel definition was lost), and notes that lose nothing: ``duplicate_chunk``, ``no_crc``,
        ``summary_damaged``, ``summary_mismatch``, ``no_footer``, ``repaired_in_place`` (a record read although
        its type byte or length field was damaged).
    detail : str
        One line saying what was found and done.
    start_ns, end_ns : int or None [ns]
        Log-time span of the lost messages when the damaged chunk's header still says it.
    messages : int or None [-]
        Messages lost, when the file says (message index records, summary); None when unknown.
    after_messages : int [-]
        Messages this file yielded before the problem (file order): where the loss sits when its time is unknown.
    lost : bool [-]
        True when data were (or may have been) lost; False for notes.
    """

    file: Path
    offset: int
    kind: str
    detail: str
    start_ns: int | None = None
    end_ns: int | None = None
    messages: int | None = None
    after_messages: int = 0
    lost: bool = True


@dataclass
class ChunkRead:
    """The messages of one readable chunk (or one message outside chunks), in file order."""

    offset: int
    start_ns: int
    end_ns: int
    messages: list = field(default_factory=list)        # mcap.records.Message
    verified: bool = True       # False: a message outside chunks, or a chunk without CRC (damage undetectable)


@dataclass
class FileScan:
    """What :func:`scan_file` learnt about a file: definitions, metadata records, summary and damage."""

    path: Path
    schemas: dict = field(default_factory=dict)          # id -> mcap.records.Schema
    channels: dict = field(default_factory=dict)         # id -> mcap.records.Channel
    metadata: list = field(default_factory=list)         # mcap.records.Metadata, file order
    damage: list[BagDamage] = field(default_factory=list)
    complete: bool = False                               # ends with a footer and the magic
    chunks_read: int = 0
    chunks_without_crc: int = 0
    messages_read: int = 0
    reordered: bool = False                              # chunks not in time order (valid MCAP; read sorted)
    statistics: object = None                            # mcap.records.Statistics of an intact summary
    problem: str = ''                                    # why the file is incomplete ('' when complete)
    undecodable: dict = field(default_factory=dict)      # chunk offset -> indexes of messages that do not decode
    indexed_chunks: set = field(default_factory=set)     # chunk offsets the summary's chunk indexes point at
    chunk_offsets: list = field(default_factory=list)    # offsets of the chunks read

    @property
    def lost(self) -> list[BagDamage]:
        """The damage that lost (or may have lost) data."""
        return [d for d in self.damage if d.lost]


class _Window:
    """A read-only stream over ``buf[start:stop]`` for ``mcap.data_stream.ReadDataStream``: reads never pass
    ``stop`` (a damaged length cannot make the reader allocate past the file)."""

    def __init__(self, buf, start: int, stop: int):
        self._buf, self.position, self._stop = buf, start, stop

    def read(self, n: int = -1) -> bytes:
        end = self._stop if n < 0 else min(self._stop, self.position + n)
        data = self._buf[self.position:end]
        self.position = end
        return data


@dataclass
class _ChunkTry:
    ok: bool
    reason: str = ''
    chunk: object = None
    records: list = field(default_factory=list)
    end: int = 0
    start_ns: int | None = None
    end_ns: int | None = None


def _try_chunk(buf, body: int, size: int, need_crc: bool = False) -> _ChunkTry:
    """Parse and open a chunk whose body starts at ``body``; ``ok`` when its data decompress and pass the CRC."""
    from mcap.data_stream import ReadDataStream
    from mcap.records import Chunk
    from mcap.stream_reader import breakup_chunk
    if body + 36 > size:
        return _ChunkTry(False, 'chunk header runs past the end of the file')
    start_ns, end_ns, usize, crc, clen = struct.unpack_from('<QQQII', buf, body)
    if clen > 8 or body + 32 + clen + 8 > size:
        return _ChunkTry(False, 'chunk header is damaged (compression field)')
    compression = bytes(buf[body + 32:body + 32 + clen])
    if compression.decode('latin-1') not in _COMPRESSIONS:
        return _ChunkTry(False, f'chunk header is damaged (compression {compression!r})')
    (dlen,) = struct.unpack_from('<Q', buf, body + 32 + clen)
    end = body + 32 + clen + 8 + dlen
    spans = {'start_ns': start_ns, 'end_ns': end_ns} if start_ns <= end_ns else {}
    if end > size:
        return _ChunkTry(False, 'chunk data run past the end of the file', **spans)
    if usize > MAX_CHUNK_BYTES or (clen == 0 and usize != dlen):
        return _ChunkTry(False, f'chunk header is damaged (uncompressed size {usize} bytes)', end=end, **spans)
    if need_crc and crc == 0:
        return _ChunkTry(False, 'no CRC to confirm a chunk found by searching', end=end, **spans)
    chunk = Chunk.read(ReadDataStream(_Window(buf, body, end)))
    try:
        records = _split_chunk(chunk) if FAST_MESSAGES else None
        if records is None:
            records = breakup_chunk(chunk, validate_crc=True)
    except Exception as error:      # CRC mismatch, zstd/lz4 errors, records cut inside the chunk
        reason = str(error) or type(error).__name__
        if 'crc validation failed' in reason:
            reason = 'CRC mismatch (the data changed after they were written)'
        return _ChunkTry(False, f'chunk unreadable: {reason}', end=end, **spans)
    return _ChunkTry(True, chunk=chunk, records=records, end=end, start_ns=start_ns, end_ns=end_ns)


#: Split chunks that hold only messages with :func:`_split_chunk` (else ``breakup_chunk`` for every chunk).
FAST_MESSAGES = True

# checks left of the fast splitter against ``breakup_chunk`` (the first chunk it splits in a process)
_SELF_CHECKS = [1]


def _split_chunk(chunk) -> list | None:
    """The message records of a chunk, split with ``struct`` instead of ``breakup_chunk``'s per-field reads.

    Decompression and the CRC check are the ``mcap`` library's (``get_chunk_data_stream(validate_crc=True)``);
    only the framing of the records inside is done here: 3x faster on a 490 Hz recording (bench/bench_bag_read.py).
    Returns None (use ``breakup_chunk``) for a chunk holding anything but messages (schemas, channels: the first
    chunk of a file) or records that do not tile it. The first chunk it splits is also split by ``breakup_chunk``
    and must give identical records, else the fast splitter is switched off for the process.
    """
    global FAST_MESSAGES
    from mcap.records import Message
    from mcap.stream_reader import breakup_chunk, get_chunk_data_stream
    stream, size = get_chunk_data_stream(chunk, validate_crc=True)
    data = stream.read(size) if size else b''
    messages = []
    unpack = struct.unpack_from
    position = 0
    while position < size:
        if size - position < 9 or data[position] != 0x05:
            return None
        (length,) = unpack('<Q', data, position + 1)
        body, end = position + 9, position + 9 + length
        if length < 22 or end > size:
            return None
        channel_id, sequence, log_time, publish_time = unpack('<HIQQ', data, body)
        messages.append(Message(channel_id, log_time, data[body + 22:end], publish_time, sequence))
        position = end
    if _SELF_CHECKS[0] > 0:
        _SELF_CHECKS[0] -= 1
        if breakup_chunk(chunk, validate_crc=True) != messages:       # pragma: no cover - a library change
            FAST_MESSAGES = False
            return None
    return messages


def _resync(buf, start: int, size: int) -> int:
    """The offset of the next chunk at or after ``start`` whose CRC matches, or ``size`` when there is none."""
    position = start
    while True:
        position = buf.find(b'\x06', position)
        if position < 0 or position + 9 > size:
            return size
        if _try_chunk(buf, position + 9, size, need_crc=True).ok:
            return position
        position += 1


_KNOWN_OPCODES = frozenset((0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x09, 0x0A, 0x0B, 0x0C, 0x0D, 0x0E, 0x0F))


def _framed(buf, end: int, size: int) -> bool:
    """Whether a record ends at ``end``: the file ends there, or a record of a known type whose length fits in the
    file starts there."""
    if end == size:
        return True
    if end + 9 > size or buf[end] not in _KNOWN_OPCODES:
        return False
    return end + 9 + struct.unpack_from('<Q', buf, end + 1)[0] <= size


def _ends_data(buf, position: int, length: int, size: int) -> bool:
    """Whether a data-end record at ``position`` really ends the data section: its length is 4 (the data CRC) and it
    sits right before the summary (or the footer) an intact footer points at; without a footer, no chunk whose CRC
    matches follows it."""
    if length != 4:
        return False
    end = position + 9 + length
    footer = _footer_at_end(buf, size)
    if footer is not None:
        footer_start = size - len(MCAP_MAGIC) - _FOOTER_BYTES
        return end == (footer.summary_start or footer_start) or _resync(buf, end, footer_start) >= footer_start
    return _resync(buf, end, size) >= size


def _footer_at_end(buf, size: int):
    """The file's footer (mcap.records.Footer) when it ends with a footer and the magic, else None."""
    from mcap.data_stream import ReadDataStream
    from mcap.records import Footer
    start = size - len(MCAP_MAGIC) - _FOOTER_BYTES
    if start < len(MCAP_MAGIC) or buf[size - len(MCAP_MAGIC):size] != MCAP_MAGIC or buf[start] != _OP_FOOTER:
        return None
    if struct.unpack_from('<Q', buf, start + 1)[0] != 20:
        return None
    return Footer.read(ReadDataStream(_Window(buf, start + 9, start + _FOOTER_BYTES)))


def _read_summary(buf, size: int, scan: FileScan) -> None:
    """Definitions and statistics from an intact summary section (footer at the end, its CRC matching)."""
    from mcap.data_stream import ReadDataStream
    from mcap.records import Statistics
    footer = _footer_at_end(buf, size)
    footer_start = size - len(MCAP_MAGIC) - _FOOTER_BYTES
    if footer is None or not footer.summary_start or not len(MCAP_MAGIC) < footer.summary_start <= footer_start:
        return
    summary_start = footer.summary_start
    if footer.summary_crc and zlib.crc32(buf[summary_start:footer_start + 25]) != footer.summary_crc:
        # bytes inserted or removed before it shift the summary: it starts after the data-end record (its CRC,
        # over the summary and the footer's fields as written, then still matches)
        moved = buf.rfind(b'\x0f\x04\x00\x00\x00\x00\x00\x00\x00', len(MCAP_MAGIC), footer_start) + 13
        if moved > 12 and zlib.crc32(buf[moved:footer_start + 25]) == footer.summary_crc:
            scan.damage.append(BagDamage(scan.path, moved, 'summary_mismatch', f'the footer says the summary starts '
                                         f'at byte {summary_start}, it starts at byte {moved} (bytes inserted or '
                                         'removed before it): read there', lost=False))
            summary_start = moved
        else:
            scan.damage.append(BagDamage(scan.path, footer.summary_start, 'summary_damaged',
                                         'the summary section fails its CRC: it was not used; the records were read '
                                         'without it', lost=False))
            return
    position = summary_start
    try:
        while position + 9 <= footer_start:
            opcode = buf[position]
            (length,) = struct.unpack_from('<Q', buf, position + 1)
            body, end = position + 9, position + 9 + length
            if end > footer_start:
                break
            stream = ReadDataStream(_Window(buf, body, end))
            if _remember_definition(scan, opcode, stream):
                pass
            elif opcode == _OP_STATISTICS:
                scan.statistics = Statistics.read(stream)
            elif opcode == _OP_CHUNK_INDEX and length >= 24:
                scan.indexed_chunks.add(struct.unpack_from('<Q', buf, body + 16)[0])
            position = end
    except Exception:               # a summary that passed its CRC but does not parse: written by a broken writer
        scan.statistics = None


def _remember_definition(scan, opcode: int, stream) -> bool:
    """Read a schema (0x03) or channel (0x04) record from `stream` into `scan`, under its id, the first definition
    of an id winning (in the data and in the summary alike); False for any other record, `stream` untouched."""
    from mcap.records import Channel, Schema
    if opcode == 0x03:
        schema = Schema.read(stream)
        scan.schemas.setdefault(schema.id, schema)
    elif opcode == 0x04:
        channel = Channel.read(stream)
        scan.channels.setdefault(channel.id, channel)
    else:
        return False
    return True


def _open(path: Path):
    from aeropend_core.io.inputs import open_input
    try:
        handle = open_input(path, 'the bag file')      # a FIFO or device is refused, never waited on
    except OSError as error:
        raise storage_error(error, f'cannot read {path}: {error.strerror or error}') from None
    size = os.fstat(handle.fileno()).st_size
    if size < len(MCAP_MAGIC):
        handle.close()
        raise AeropendError(f'{path} is not an MCAP file (no MCAP magic at its start)')
    return handle, mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ)


def scan_file(path: str | os.PathLike, scan: FileScan | None = None) -> Iterator[ChunkRead]:
    """Yield the readable chunks of one ``.mcap`` file in file order, skipping and recording damage.

    Parameters
    ----------
    path : str or PathLike [-]
        The file.
    scan : FileScan, optional
        Filled as the walk goes (definitions, metadata, damage, summary comparison once the generator is done).

    Yields
    ------
    ChunkRead
        Each readable chunk's messages (``mcap.records.Message``, times in ns).

    Raises
    ------
    AeropendError
        Not an MCAP file (no magic), or not a ROS 2 bag (another profile).
    """
    path = Path(path)
    scan = scan if scan is not None else FileScan(path)
    handle, buf = _open(path)
    try:
        if buf[:len(MCAP_MAGIC)] != MCAP_MAGIC:
            raise AeropendError(f'{path} is not an MCAP file (no MCAP magic at its start)')
        yield from _walk(buf, len(buf), scan)
    finally:
        buf.close()
        handle.close()


def _walk(buf, size: int, scan: FileScan) -> Iterator[ChunkRead]:
    from mcap.data_stream import ReadDataStream
    from mcap.records import Channel, Header, Message, MessageIndex, Metadata, Schema
    _read_summary(buf, size, scan)
    position = len(MCAP_MAGIC)
    seen: dict[tuple, int] = {}
    last_end_ns = None
    lost_chunk: BagDamage | None = None        # the skipped chunk the following message indexes describe
    data_end = False

    def skip(offset: int, kind: str, detail: str, **extra) -> int:
        nonlocal lost_chunk
        damage = BagDamage(scan.path, offset, kind, detail, after_messages=scan.messages_read, **extra)
        scan.damage.append(damage)
        lost_chunk = damage if kind == 'chunk_skipped' else None
        resumed = _resync(buf, offset + 1, size)
        if resumed < size:
            damage.detail += f'; reading resumed at byte {resumed}'
        return resumed

    while position < size:
        if size - position < 9:
            scan.problem = f'file ends inside a record at byte {position} of {size}'
            break
        opcode = buf[position]
        (length,) = struct.unpack_from('<Q', buf, position + 1)
        body = position + 9
        if opcode == _OP_FOOTER and body + length + len(MCAP_MAGIC) == size and length == 20 and \
                buf[size - len(MCAP_MAGIC):size] == MCAP_MAGIC:
            scan.complete = True
            break
        if opcode in (_OP_CHUNK, _OP_FOOTER) or opcode not in (0x01, 0x03, 0x04, 0x05, 0x07, 0x08, 0x09, 0x0A,
                                                               0x0B, 0x0C, 0x0D, 0x0E, 0x0F):
            got = _try_chunk(buf, body, size, need_crc=opcode != _OP_CHUNK)
            framed = opcode not in (_OP_CHUNK, _OP_FOOTER) and _framed(buf, body + length, size)
            if not got.ok and framed:   # a chunk without CRC under a damaged type byte: read when it opens whole
                got = _try_chunk(buf, body, size)
                got.ok = got.ok and got.end == body + length
            if not got.ok and framed:
                # a record of unknown type whose length field frames it (a valid record follows): skip that one
                # record and read on, instead of searching for the next chunk with a CRC (a file without CRCs has
                # none, and everything after the record was lost)
                scan.damage.append(BagDamage(scan.path, position, 'repaired_in_place', f'record of unknown type '
                                             f'0x{opcode:02x} ({length} bytes by its length field) skipped; the '
                                             'record after it is intact and reading went on', lost=False))
                position = body + length
                continue
            if not got.ok:
                if opcode == _OP_FOOTER:
                    position = skip(position, 'record_skipped', 'a footer record before the end of the file (a '
                                    'damaged type byte?) skipped')
                elif opcode != _OP_CHUNK:
                    position = skip(position, 'record_skipped', f'record of unknown type 0x{opcode:02x} '
                                    f'({length} bytes by its length field) skipped')
                elif got.end and got.end == body + length:        # a consistent chunk whose data are bad
                    damage = BagDamage(scan.path, position, 'chunk_skipped', got.reason, got.start_ns, got.end_ns,
                                       after_messages=scan.messages_read)
                    scan.damage.append(damage)
                    lost_chunk = damage
                    position = got.end
                elif got.end > size or body + length > size:
                    scan.problem = f'file ends inside a chunk at byte {position} of {size}'
                    break
                else:
                    position = skip(position, 'chunk_skipped', got.reason, start_ns=got.start_ns,
                                    end_ns=got.end_ns)
                continue
            lost_chunk = None
            if opcode != _OP_CHUNK or got.end != body + length:
                scan.damage.append(BagDamage(
                    scan.path, position, 'repaired_in_place',
                    f'chunk with a damaged {"type byte" if opcode != _OP_CHUNK else "length field"} read '
                    '(its content passes the CRC)', lost=False))
            chunk = got.chunk
            key = (chunk.message_start_time, chunk.message_end_time, chunk.uncompressed_crc, chunk.uncompressed_size,
                   chunk.compression, len(chunk.data))
            if chunk.uncompressed_crc and key in seen:
                scan.damage.append(BagDamage(scan.path, position, 'duplicate_chunk',
                                             f'chunk repeats the chunk at byte {seen[key]}: read once', lost=False))
                position = got.end
                continue
            seen[key] = position
            scan.chunk_offsets.append(position)
            scan.chunks_read += 1
            scan.chunks_without_crc += chunk.uncompressed_crc == 0
            if last_end_ns is not None and chunk.message_start_time < last_end_ns:
                scan.reordered = True
            last_end_ns = max(last_end_ns or 0, chunk.message_end_time)
            messages = []
            for record in got.records:
                if isinstance(record, Message):
                    messages.append(record)
                elif isinstance(record, Schema):
                    scan.schemas.setdefault(record.id, record)
                elif isinstance(record, Channel):
                    scan.channels.setdefault(record.id, record)
            scan.messages_read += len(messages)
            yield ChunkRead(position, chunk.message_start_time, chunk.message_end_time, messages,
                            verified=bool(chunk.uncompressed_crc))
            position = got.end
            continue
        end = body + length
        if end > size:
            resumed = _resync(buf, position + 1, size)
            if resumed >= size:
                scan.problem = f'file ends inside a record at byte {position} of {size}'
                break
            position = skip(position, 'record_skipped', f'record of type 0x{opcode:02x} with a length field '
                            f'({length} bytes) that runs past the end of the file skipped')
            continue
        if opcode == _OP_DATA_END and not _ends_data(buf, position, length, size):
            # a data-end record with chunks after it: a damaged type byte (e.g. a message index's 0x07 turned into
            # 0x0f). Its length field framed a record: skip that one record and read on (before: the walk stopped
            # here and everything after it was silently not read).
            scan.damage.append(BagDamage(scan.path, position, 'repaired_in_place', 'a data-end record (0x0f) with '
                                         f'data after it (a damaged type byte?): its {length} bytes skipped, '
                                         'reading went on', lost=False))
            position = end
            continue
        if opcode == _OP_DATA_END:
            data_end = True
            footer = _footer_at_end(buf, size)
            scan.complete = footer is not None
            if footer is None:
                scan.damage.append(BagDamage(scan.path, position, 'no_footer', 'the data are complete but the '
                                             'summary or footer after them is cut or damaged', lost=False))
            break
        try:
            stream = ReadDataStream(_Window(buf, body, end))
            if opcode == 0x01:
                profile = Header.read(stream).profile
                if profile != ROS2_PROFILE:
                    raise AeropendError(f'{scan.path} has MCAP profile {profile!r}, not ros2: not a ROS 2 bag')
            elif _remember_definition(scan, opcode, stream):
                pass
            elif opcode == 0x05:
                message = Message.read(stream, length)
                scan.messages_read += 1
                yield ChunkRead(position, message.log_time, message.log_time, [message], verified=False)
            elif opcode == 0x0C:
                scan.metadata.append(Metadata.read(stream))
            elif opcode == _OP_MESSAGE_INDEX and lost_chunk is not None:
                lost_chunk.messages = (lost_chunk.messages or 0) + len(MessageIndex.read(stream).records)
        except AeropendError:
            raise
        except Exception as error:
            position = skip(position, 'record_skipped', f'record of type 0x{opcode:02x} does not parse ({error})')
            continue
        position = end
    if position >= size and not scan.complete and not scan.problem and not data_end:
        footer = _footer_at_end(buf, size)
        scan.complete = footer is not None
        if not scan.complete:
            scan.problem = 'file ends without a footer'
    if scan.problem and not scan.complete:
        scan.damage.append(BagDamage(scan.path, position, 'cut', scan.problem, after_messages=scan.messages_read))
    _compare_summary(scan)


def _compare_summary(scan: FileScan) -> None:
    """Notes: chunks without CRC; the summary's counts against the records read."""
    if scan.chunks_without_crc:
        scan.damage.append(BagDamage(scan.path, 0, 'no_crc', f'{scan.chunks_without_crc} of {scan.chunks_read} '
                                     'chunks carry no CRC: bit flips in them cannot be detected', lost=False))
    stats = scan.statistics
    if stats is None:
        return
    lost = scan.lost
    moved = scan.indexed_chunks - set(scan.chunk_offsets)
    if scan.indexed_chunks and moved and not lost:
        scan.damage.append(BagDamage(scan.path, min(moved), 'summary_mismatch', f'the summary\'s chunk index points '
                                     f'at {len(moved)} offset(s) where no chunk was found (chunks moved): every chunk '
                                     'was read by walking the file, but readers that follow the index fail there',
                                     lost=False))
    expected = int(stats.message_count)
    if not lost and expected != scan.messages_read:
        scan.damage.append(BagDamage(scan.path, 0, 'summary_mismatch', f'the summary says {expected} messages and '
                                     f'{stats.chunk_count} chunks; the records hold {scan.messages_read} messages in '
                                     f'{scan.chunks_read} chunks', lost=expected > scan.messages_read))
    elif lost and expected > scan.messages_read:
        unknown = [d for d in lost if d.messages is None and d.kind in ('chunk_skipped', 'record_skipped')]
        missing = expected - scan.messages_read - sum(d.messages or 0 for d in lost)
        if len(unknown) == 1 and missing > 0:
            unknown[0].messages = missing
