"""The MCAP and rosbag2 conventions shared by the bag writer and reader: record opcodes, the ``ros2`` profile, the
``ros2msg`` schema text of a message type with its dependencies, the type hash and the QoS description.
"""
from __future__ import annotations

import os
import re
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any


from aeropend_core.errors import AeropendError


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


__all__ = ['SAMPLE_CHANNELS', 'msg_file_loader', 'msg_type_hash', 'offered_qos', 'ros2msg_definition']
