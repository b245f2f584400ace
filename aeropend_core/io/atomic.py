"""Replace a file whole or not at all, and durably: the one atomic-write helper of the project.

:func:`atomic_write` writes to a temporary file in the target's folder, flushes and ``fsync``\\ s it, renames it
onto the target (``os.replace``, atomic on POSIX within one file system) and ``fsync``\\ s the folder so that the
rename itself survives a power cut. A reader (or a crash) therefore sees either the old file or the new one, never
a half-written one. :func:`replace_durably` is the last two steps for a file (or a symbolic link) the caller has
already written and synced.
"""
from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

__all__ = ['atomic_write', 'fsync_folder', 'replace_durably']


def fsync_folder(folder: str | os.PathLike) -> None:
    """``fsync`` a folder, so that a rename or a new file in it is on disk (no-op where folders cannot be opened).

    Parameters
    ----------
    folder : str or PathLike [-]
        The folder.
    """
    try:
        fd = os.open(folder, os.O_RDONLY | getattr(os, 'O_DIRECTORY', 0))
    except OSError:                     # pragma: no cover - platforms without directory handles
        return
    try:
        os.fsync(fd)
    except OSError:                     # pragma: no cover - some file systems refuse fsync on folders
        pass
    finally:
        os.close(fd)


def replace_durably(source: str | os.PathLike, target: str | os.PathLike) -> None:
    """Rename ``source`` onto ``target`` atomically and ``fsync`` the target's folder.

    Parameters
    ----------
    source, target : str or PathLike [-]
        Paths in the same folder (the caller has written and synced ``source``).
    """
    os.replace(source, target)
    fsync_folder(Path(target).parent)


def atomic_write(path: str | os.PathLike, write: Callable[[IO[Any]], None], binary: bool = False,
                 keep_mode: bool = True) -> Path:
    """Write a file whole with ``write(handle)``: temporary file in the same folder, fsync, rename, fsync folder.

    Parameters
    ----------
    path : str or PathLike [-]
        The file to create or replace (a symbolic link is replaced by a file: resolve it first to write through).
    write : callable [-]
        Called once with the open temporary file (text, UTF-8, or binary with ``binary=True``).
    binary : bool [-]
        Open the temporary file in binary mode.
    keep_mode : bool [-]
        Give the new file the permission bits of the file it replaces (else 0o644 less the umask).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    OSError
        What the system refused (disk full, no permission); the target is then unchanged and the temporary file
        removed.
    """
    target = Path(path)
    fd, temporary = tempfile.mkstemp(prefix=f'.{target.name}.', suffix='.partial', dir=target.parent)
    try:
        with os.fdopen(fd, 'wb' if binary else 'w', **({} if binary else {'encoding': 'utf-8'})) as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
        mode = None
        if keep_mode:
            try:
                mode = stat.S_IMODE(os.stat(target).st_mode)
            except OSError:
                mode = None
        if mode is None:
            umask = os.umask(0)
            os.umask(umask)
            mode = 0o644 & ~umask
        os.chmod(temporary, mode)
        replace_durably(temporary, target)
    except BaseException:
        try:
            os.unlink(temporary)
        except OSError:
            pass
        raise
    return target
