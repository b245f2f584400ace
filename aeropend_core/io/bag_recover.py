"""Repair of a damaged or cut bag (CLI ``aeropend bag-recover``): everything still readable is kept, streamed.

Each file is read by :func:`aeropend_core.io.mcap_scan.scan_file` (the ``mcap`` library's records, every chunk
CRC-checked): a damaged chunk is dropped and the chunks after it are kept, a cut file keeps every complete chunk.
The kept messages are written, one chunk at a time (never the whole file in memory), to a new complete MCAP file
with its index, summary, footer and the rosbag2 metadata record, and ``metadata.yaml`` is regenerated.

By default nothing of the original is changed: a bag folder ``run1`` is recovered into ``run1_recovered`` beside
it (intact files are copied), a lone ``x.mcap`` into ``x_recovered.mcap``. With ``in_place`` the damaged files are
replaced (the originals kept as ``<file>.orig`` with ``keep_original``). The bag's lock
(:mod:`aeropend_core.io.bag_lock`) is held for the whole repair: a live recording is refused, a recorder that
starts meanwhile waits, and before each replacement the lock is checked to still be held by this repair.
"""
from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from aeropend_core.errors import AeropendError, StorageError
from aeropend_core.io import bag_lock
from aeropend_core.io.atomic import fsync_folder, replace_durably
from aeropend_core.io.bag import bag_files
from aeropend_core.io.bag_writer import (
    TopicInfo,
    _compression_type,
    _DirectFile,
    _FileInfo,
    _metadata_dict,
    _write_metadata_yaml,
)
from aeropend_core.io.mcap_format import ROS2_PROFILE
from aeropend_core.io.mcap_scan import BagDamage, FileScan, scan_file
from aeropend_core.io.paths import path_problem

__all__ = ['ChunkOutcome', 'RecoveryReport', 'recover_bag']

#: Damage kinds that make a file worth rewriting (the rest are notes about an otherwise intact file).
_REWRITE = {'chunk_skipped', 'record_skipped', 'cut', 'unknown_channel', 'duplicate_chunk', 'summary_damaged',
            'summary_mismatch', 'no_footer', 'repaired_in_place', 'undecodable'}


@dataclass
class ChunkOutcome:
    """One chunk (or damaged record) of a recovered file: kept with its messages, or dropped and why.

    Attributes
    ----------
    file : str
        The file's name.
    offset : int [bytes]
        Where the chunk or record starts in the original file.
    kept : bool
        True when its messages are in the recovered file.
    messages : int or None [-]
        Messages kept (kept) or lost (dropped, when the file says; None when unknown).
    start_ns, end_ns : int or None [ns]
        Log-time span of the chunk, when its header is readable.
    reason : str
        Why it was dropped (empty when kept).
    """

    file: str
    offset: int
    kept: bool
    messages: int | None
    start_ns: int | None = None
    end_ns: int | None = None
    reason: str = ''

    def to_dict(self) -> dict:
        """Plain JSON types."""
        return {'file': self.file, 'offset': self.offset, 'kept': self.kept, 'messages': self.messages,
                'start_ns': self.start_ns, 'end_ns': self.end_ns, 'reason': self.reason}


@dataclass
class RecoveryReport:
    """What :func:`recover_bag` did."""

    folder: Path                            # where the recovered bag is (the original folder with in_place)
    repaired: list[Path]                    # files written (recovered copies, or replaced files with in_place)
    intact: list[Path]                      # original files that needed nothing
    message_count: int                      # messages in the recovered bag
    notes: list[str]                        # one line per file that needed work, and per dropped chunk
    metadata_yaml: Path | None = None       # the regenerated metadata.yaml (None for a lone .mcap file)
    removed_lock: str = ''                  # the stale lock of a killed writer, removed
    chunks: list[ChunkOutcome] = field(default_factory=list)
    in_place: bool = False
    source: Path | None = None              # the bag or file given


def recover_bag(path: str | os.PathLike, keep_original: bool = False, in_place: bool = False,
                output: str | os.PathLike | None = None) -> RecoveryReport:
    """Recover everything readable from a damaged or cut bag into a complete one.

    Parameters
    ----------
    path
        The bag folder, its ``metadata.yaml``, or one ``.mcap`` file. A file listed in its folder's
        ``metadata.yaml`` recovers that whole bag; a lone ``.mcap`` file is recovered alone (no ``metadata.yaml``).
    keep_original
        With ``in_place``: keep each replaced file as ``<file>.orig``.
    in_place
        Replace the damaged files (and ``metadata.yaml``) of the bag itself instead of writing a new bag beside it.
    output
        Where the new bag folder (or file, for a lone ``.mcap``) goes; default ``<bag>_recovered`` beside it.

    Returns
    -------
    RecoveryReport
        Files written and intact, and per chunk what was kept and dropped.

    Raises
    ------
    AeropendError
        Not an MCAP bag, a file unreadable from its start (no MCAP magic), a bag being recorded (naming the
        recorder), or an output that exists already.
    StorageError
        The system refused a write (disk full): the original files are then unchanged.
    """
    from aeropend_core.io.inputs import check_input
    path = Path(path)
    if not path.exists():
        raise AeropendError(f'{path} {path_problem(path)}')
    check_input(path, 'the bag', folder=True)      # a FIFO, device or socket would block or never end
    folder, files, bag_folder = _recovery_targets(path)
    if in_place and output is not None:
        raise AeropendError('give either --in-place or --output, not both')
    if not in_place:
        default = folder.with_name(folder.name + '_recovered') if bag_folder else \
            path.with_name(path.stem + '_recovered.mcap')
        target = Path(output) if output is not None else default
        if target.exists():
            raise AeropendError(f'{target} exists already: remove it, give another --output, or repair the bag '
                                'itself with --in-place')
    else:
        target = folder
    try:
        with bag_lock.hold(folder, 'repair') as stale:
            report = _recover(path, folder, files, bag_folder, target, in_place, keep_original)
        if stale is not None:
            report.removed_lock = f'removed the recording lock of {stale.describe()}, which no longer runs'
        return report
    except OSError as error:
        raise StorageError(f'cannot repair {path}: {error.strerror or error}'
                           f'{" (" + str(error.filename) + ")" if error.filename else ""}; the original bag files '
                           'were not changed. Free space (or copy the bag to another disk) and run '
                           'aeropend bag-recover again') from None


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
        from aeropend_core.io.inputs import load_yaml
        try:
            info = load_yaml(meta, 'metadata file')['rosbag2_bagfile_information']
            listed = {Path(p).name for p in info.get('relative_file_paths', [])}
        except (yaml.YAMLError, KeyError, TypeError, AttributeError, OSError, AeropendError):
            listed = set()
        if path.name in listed:
            return path.parent, bag_files(path.parent), True
    return path.parent, [path], False


def _survey(file: Path) -> FileScan:
    """First pass: definitions, metadata, damage (no message kept). Messages that nothing vouches for (outside
    chunks, or in a chunk without CRC) are decoded with their schema: those that do not decode are listed in
    ``scan.undecodable`` (chunk offset -> message indexes) and never written (an ``undecodable`` damage)."""
    scan = FileScan(file)
    decodes = _decoder(scan)
    for chunk in scan_file(file, scan):
        if chunk.verified:
            continue
        bad = {k for k, message in enumerate(chunk.messages) if not decodes(message)}
        if bad:
            scan.undecodable[chunk.offset] = bad
            where = 'outside chunks' if len(chunk.messages) == 1 and chunk.start_ns == chunk.end_ns else \
                'in a chunk without CRC'
            scan.damage.append(BagDamage(file, chunk.offset, 'undecodable', f'{len(bad)} message(s) {where} that '
                                         'do not decode with their schema: left out', chunk.start_ns, chunk.end_ns,
                                         messages=len(bad)))
    return scan


def _decoder(scan: FileScan):
    """``decodes(message) -> bool``: whether a message's bytes decode as its channel's schema (``rosbags``, from
    the schema text the file carries, as an independent reader would). Messages of an unknown channel, or of a
    schema that cannot be parsed, do not decode; a channel not in CDR/ros2msg cannot be judged and passes."""
    stores: dict[int, object] = {}

    def store_for(schema):
        if schema.id not in stores:
            from rosbags.typesys import Stores, get_types_from_msg, get_typestore
            try:
                store = get_typestore(Stores.EMPTY)
                store.register(get_types_from_msg(schema.data.decode('utf-8'), schema.name))
            except Exception:   # a schema text rosbags cannot parse: the distribution's definition, if any
                store = get_typestore(Stores.ROS2_JAZZY)
            stores[schema.id] = store
        return stores[schema.id]

    def decodes(message) -> bool:
        channel = scan.channels.get(message.channel_id)
        schema = None if channel is None else scan.schemas.get(channel.schema_id)
        if schema is None:
            return False
        if channel.message_encoding != 'cdr' or schema.encoding != 'ros2msg':
            return True
        try:
            store_for(schema).deserialize_cdr(message.data, schema.name)
            return True
        except Exception:
            return False
    return decodes


def _recover(path: Path, folder: Path, files: list[Path], bag_folder: bool, target: Path, in_place: bool,
             keep_original: bool) -> RecoveryReport:
    report = RecoveryReport(target, [], [], 0, [], in_place=in_place, source=path)
    topic_infos: dict[str, TopicInfo] = {}
    file_infos: list[_FileInfo] = []
    ros_distro = 'jazzy'
    plans: list[tuple[Path, FileScan, bool]] = []
    for file in files:
        scan = _survey(file)
        for record in scan.metadata:
            if record.name == 'rosbag2' and 'ROS_DISTRO' in record.metadata:
                ros_distro = record.metadata['ROS_DISTRO']
        needs_work = any(d.kind in _REWRITE for d in scan.damage) or not scan.complete
        plans.append((file, scan, needs_work))
    if not in_place and not any(work for *_, work in plans):
        report.intact = list(files)
        report.folder = folder
        report.message_count = sum(scan.messages_read for _, scan, _ in plans)
        return report
    out_folder = folder if in_place else target if bag_folder else target.parent
    if not in_place and bag_folder:
        target.mkdir(parents=True)
    written: list[tuple[Path, Path]] = []          # (temporary or final file, the file it replaces)
    try:
        for file, scan, needs_work in plans:
            info = _FileInfo(file.name)
            file_infos.append(info)
            destination = (out_folder / file.name) if bag_folder or in_place else target
            if not needs_work:
                report.intact.append(file)
                _count_intact(file, scan, info, topic_infos)
                if not in_place:
                    shutil.copyfile(file, destination)
                    with open(destination, 'rb') as copy:
                        os.fsync(copy.fileno())
                    written.append((destination, destination))
                continue
            temporary = destination.with_name(destination.name + '.recovering') if in_place else destination
            written.append((temporary, destination))
            report.repaired.append(destination)
            kept, outcomes = _rewrite(file, scan, temporary, topic_infos, info, ros_distro)
            report.chunks.extend(outcomes)
            dropped = [o for o in outcomes if not o.kept]
            lost = sum(o.messages or 0 for o in dropped)
            unknown = any(o.messages is None for o in dropped)
            report.notes.append(
                f'{file.name}: kept {sum(o.kept for o in outcomes)} chunk(s) with {kept} messages; dropped '
                f'{len(dropped)} chunk(s)/record(s) with {lost}{"+" if unknown else ""} messages'
                + ('' if scan.complete else f'; {scan.problem}'))
            for item in scan.damage:
                if item.kind != 'no_crc':
                    report.notes.append(f'{file.name}: byte {item.offset}: {item.detail}'
                                        + (f' ({item.messages} messages lost)' if item.lost and item.messages
                                           is not None else ''))
        for temporary, destination in written:
            if temporary == destination:
                continue
            if not bag_lock.still_held(folder):
                raise AeropendError(f'{folder}: the repair lost its lock before replacing {destination.name}; '
                                    'nothing was replaced (the recovered copies are the *.recovering files)')
            if keep_original:
                os.link(destination, destination.with_name(destination.name + '.orig'))
            replace_durably(temporary, destination)
        fsync_folder(out_folder)
    except BaseException:
        for temporary, destination in written:
            if temporary != destination or not in_place:
                temporary.unlink(missing_ok=True)
        if not in_place and bag_folder and target.is_dir() and not any(target.iterdir()):
            target.rmdir()
        raise
    if bag_folder:
        _write_metadata_yaml(out_folder, _metadata_dict(topic_infos.values(), file_infos, ros_distro))
        report.metadata_yaml = out_folder / 'metadata.yaml'
    report.message_count = sum(f.message_count for f in file_infos)
    return report


def _topic(topic_infos: dict[str, TopicInfo], scan: FileScan, channel) -> TopicInfo:
    if channel.topic not in topic_infos:
        schema = scan.schemas.get(channel.schema_id)
        from aeropend_core.io.inputs import check_yaml_text
        text = channel.metadata.get('offered_qos_profiles') or '[]'
        try:                # the channel's QoS YAML, from the damaged file: within the limits of every YAML input
            check_yaml_text(text, f'the QoS of {channel.topic}')
            qos = yaml.safe_load(text) or []
        except (AeropendError, yaml.YAMLError):
            qos = []
        topic_infos[channel.topic] = TopicInfo(
            channel.topic, schema.name if schema else '', schema.data.decode('utf-8', 'replace') if schema else '',
            qos if isinstance(qos, list) else [], channel.metadata.get('topic_type_hash', ''))
    return topic_infos[channel.topic]


def _account(info: _FileInfo, log_time: int) -> None:
    info.message_count += 1
    info.start_ns = log_time if info.start_ns is None else min(info.start_ns, log_time)
    info.end_ns = log_time if info.end_ns is None else max(info.end_ns, log_time)


def _count_intact(file: Path, scan: FileScan, info: _FileInfo, topic_infos: dict[str, TopicInfo]) -> None:
    for channel in scan.channels.values():
        _topic(topic_infos, scan, channel)
    for chunk in scan_file(file, FileScan(file)):
        for message in chunk.messages:
            _account(info, message.log_time)
            channel = scan.channels.get(message.channel_id)
            if channel is not None:
                topic_infos[channel.topic].message_count += 1


def _rewrite(file: Path, scan: FileScan, destination: Path, topic_infos: dict[str, TopicInfo], info: _FileInfo,
             ros_distro: str) -> tuple[int, list[ChunkOutcome]]:
    """Second pass: stream the readable chunks of ``file`` into a complete MCAP file at ``destination``."""
    from mcap.writer import Writer
    outcomes: list[ChunkOutcome] = []
    stream = _DirectFile(destination)
    kept = 0
    try:
        writer = Writer(stream, compression=_compression_type('zstd'))
        writer.start(profile=ROS2_PROFILE, library='aeropend bag-recover')
        writer.add_metadata('rosbag2', {'ROS_DISTRO': ros_distro})
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}

        def channel_id(old: int) -> int:
            if old in channel_ids:
                return channel_ids[old]
            channel = scan.channels.get(old)
            if channel is None:          # its definition was lost with a damaged chunk: kept under a placeholder
                channel_ids[old] = writer.register_channel(f'/aeropend/recovered/unknown_channel_{old}', 'cdr', 0)
                return channel_ids[old]
            schema = scan.schemas.get(channel.schema_id)
            if schema is not None and schema.id not in schema_ids:
                schema_ids[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            channel_ids[old] = writer.register_channel(channel.topic, channel.message_encoding,
                                                       schema_ids.get(channel.schema_id, 0), dict(channel.metadata))
            _topic(topic_infos, scan, channel)
            return channel_ids[old]

        for channel in scan.channels.values():
            channel_id(channel.id)
        second = FileScan(file)
        for chunk in scan_file(file, second):
            bad = scan.undecodable.get(chunk.offset, ())
            if bad:                         # never written: an independent reader could not read the bag after
                outcomes.append(ChunkOutcome(file.name, chunk.offset, False, len(bad), chunk.start_ns, chunk.end_ns,
                                             f'{len(bad)} message(s) that do not decode with their schema'))
                chunk.messages = [m for k, m in enumerate(chunk.messages) if k not in bad]
                if not chunk.messages:
                    continue
            for message in chunk.messages:
                writer.add_message(channel_id(message.channel_id), message.log_time, message.data,
                                   message.publish_time, message.sequence)
                _account(info, message.log_time)
                channel = scan.channels.get(message.channel_id)
                if channel is not None:
                    topic_infos[channel.topic].message_count += 1
            kept += len(chunk.messages)
            outcomes.append(ChunkOutcome(file.name, chunk.offset, True, len(chunk.messages), chunk.start_ns,
                                         chunk.end_ns))
        outcomes.extend(_dropped(file, second.damage))
        outcomes.sort(key=lambda o: o.offset)
        writer.add_metadata('rosbag2', {'serialized_metadata': yaml.safe_dump(
            _metadata_dict(topic_infos.values(), [info], ros_distro), sort_keys=False)})
        writer.finish()
        stream.sync()
    finally:
        stream.close()
    return kept, outcomes


def _dropped(file: Path, damage: list[BagDamage]) -> list[ChunkOutcome]:
    return [ChunkOutcome(file.name, d.offset, False, d.messages, d.start_ns, d.end_ns, d.detail)
            for d in damage if d.lost and d.kind in ('chunk_skipped', 'record_skipped', 'cut')]
