"""Repair of a bag whose recorder was killed (CLI ``aeropend bag-recover``): the complete chunks are rewritten with
a summary and footer, and ``metadata.yaml`` is regenerated.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import yaml

from aeropend_core.errors import AeropendError, StorageError
from aeropend_core.io import bag_lock
from aeropend_core.io.paths import path_problem
from aeropend_core.io.bag import _ScanState, _scan_mcap, bag_files
from aeropend_core.io.bag_writer import (
    TopicInfo,
    _DirectFile,
    _FileInfo,
    _compression_type,
    _metadata_dict,
    _write_metadata_yaml,
)
from aeropend_core.io.mcap_format import ROS2_PROFILE


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


__all__ = ['RecoveryReport', 'recover_bag']
