"""Paths: where results are written (regular files only, through symbolic links, replaced atomically), why a
path cannot be opened, and which exit status an operating-system refusal gets.

Every writer of a result file (``aeropend simulate -o`` CSV, ``diagnose --report`` HTML, ``calibrate --write``
YAML) goes through :func:`output_target` and :func:`write_atomically`:

- a **symbolic link** is written through: the file it points to is replaced, the link stays (a dangling link
  creates its target); a link loop is refused with a message that says so;
- a **folder, device, named pipe (FIFO) or socket** is refused (:class:`AeropendError`, exit status 2): the
  content is written under a temporary name and renamed onto the target when complete, which would replace a
  device node or a FIFO by a regular file (run as root, ``-o /dev/full`` would replace the system's device);
- a **regular file** (or a new name) is written to a temporary ``.<name>.*.partial`` in the same folder, synced
  and renamed onto it when complete (:func:`aeropend_core.io.atomic.atomic_write`), so a failure never leaves a
  shorter file that reads as a valid one; the mode of a replaced file is kept.

The system refusing (permissions, disk full) raises :class:`StorageError` (exit status 1).
"""
from __future__ import annotations

import errno
import os
import stat
from collections.abc import Callable
from pathlib import Path
from typing import IO

from aeropend_core.errors import AeropendError, StorageError

__all__ = ['output_target', 'path_problem', 'storage_error', 'write_atomically']

_KINDS = ((stat.S_ISCHR, 'a character device'), (stat.S_ISBLK, 'a block device'),
          (stat.S_ISFIFO, 'a named pipe (FIFO)'), (stat.S_ISSOCK, 'a socket'))
#: errno values meaning "the system refused" (exit status 1), not "the path is wrong" (exit status 2).
SYSTEM_REFUSALS = frozenset({errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOSPC, errno.EFBIG, errno.EDQUOT,
                             errno.EIO})


def storage_error(error: OSError, text: str) -> AeropendError:
    """The error to raise for an OSError: :class:`StorageError` (exit 1) when the system refused (permissions,
    read-only or full disk, I/O error), :class:`AeropendError` (exit 2) when the path itself is wrong."""
    return (StorageError if error.errno in SYSTEM_REFUSALS else AeropendError)(text)


def path_problem(path: str | os.PathLike) -> str:
    """Why ``path`` cannot be opened, for a message: 'is a symbolic link loop', 'is a dangling symbolic link
    (to X)', 'does not exist', or '' when it exists."""
    path = Path(path)
    try:
        os.stat(path)
        return ''
    except OSError as error:
        if error.errno == errno.ELOOP:
            return 'is a symbolic link loop (it points, in the end, back at itself); point it at a file or remove it'
        if path.is_symlink():
            return f'is a dangling symbolic link (to {os.readlink(path)}, which does not exist)'
        if error.errno in SYSTEM_REFUSALS:
            return f'cannot be reached: {error.strerror}'
        return 'does not exist'


def output_target(path: str | os.PathLike, option: str = '--output', stdout_hint: bool = False) -> Path:
    """The regular file that writing ``path`` will replace (the link's target for a symbolic link).

    Parameters
    ----------
    path
        The output path as given.
    option
        The option that named it, for messages (e.g. ``'--output'``).
    stdout_hint
        Mention ``-`` (standard output) in the refusal of a device or a pipe.

    Raises
    ------
    AeropendError
        A folder, device, FIFO, socket, symbolic link loop, or a missing folder (exit status 2).
    """
    given = Path(path)
    try:
        info = os.stat(given)
    except FileNotFoundError:
        info = None
    except OSError as error:
        if error.errno == errno.ELOOP:
            raise AeropendError(f'{option} {given} {path_problem(given)}') from None
        raise storage_error(error, f'{option} {given}: {error.strerror}') from None
    target = Path(os.path.realpath(given)) if given.is_symlink() else given
    through = f' (the symbolic link points to {target})' if target != given else ''
    if info is not None:
        if stat.S_ISDIR(info.st_mode):
            raise AeropendError(f'{option} {given} is a folder{through}; give a file name, e.g. '
                                f'{given / "result"}')
        kind = next((name for test, name in _KINDS if test(info.st_mode)), None)
        if kind is not None:
            raise AeropendError(f'{option} {given} is {kind}{through}, not a regular file: results are written '
                                'under a temporary name and renamed onto the file when complete, which would '
                                'replace it; give a file name' + (' (or - for standard output)' if stdout_hint
                                                                  else ''))
    if not target.parent.is_dir():
        raise AeropendError(f'folder {target.parent} does not exist{through}; create it or choose another {option}')
    return target


def write_atomically(path: str | os.PathLike, write: Callable[[IO[str]], None], option: str = '--output',
                     what: str = 'the file') -> Path:
    """Write text with ``write(handle)`` to ``path`` as :func:`output_target` allows: to a temporary file in the
    same folder, renamed onto the target when complete. Returns the path written (the link's target).

    Raises
    ------
    AeropendError
        As :func:`output_target`.
    StorageError
        The system refused the write (nothing was changed; the temporary file is removed).
    """
    from aeropend_core.io.atomic import atomic_write
    target = output_target(path, option)
    try:
        atomic_write(target, write)
    except OSError as error:
        raise StorageError(f'cannot write {what} {path}: {error.strerror or error}; nothing was written (free '
                           f'space, check permissions or choose another {option})') from None
    return target
