"""The mark of a bag that is being written: an ``fcntl.flock`` on ``<bag>/recording.lock`` held for the writer's life.

:class:`~aeropend_core.io.bag_writer.BagWriter` takes an exclusive ``flock`` on ``<bag>/recording.lock`` when it
opens a bag and keeps the file descriptor open until the bag is finished (or writing fails for good, e.g. a full
disk). The kernel releases the lock when the process ends in any way, SIGKILL and crashes included, so **a bag is
live exactly while somebody holds the lock**: no process ids, boot ids or start times are compared, and nothing
is unlinked on a guess. The file also holds a small YAML mapping for messages only (``pid``, ``host``,
``program``, ``purpose`` = ``recording`` or ``repair``, ``started`` in UTC ISO 8601).

``aeropend bag-recover`` takes the same lock (purpose ``repair``) for the whole repair, so it cannot replace a file
that a recorder has just started to write, and a recorder that starts while a repair holds its folder waits for
it (up to :data:`REPAIR_WAIT` s). Readers use :func:`live_writer` (a shared ``flock`` tried without waiting) to
read a live bag up to its last complete chunk with a note, never advising a repair.

The lock file of a finished bag is removed by its holder while it still holds the lock; one left by a killed
writer is **stale** (nobody holds it) and is removed by the next repair. ``flock`` works between processes of one
machine; on network file systems its reach depends on the server (Linux NFSv4 maps it to a network-wide lock).
"""
from __future__ import annotations

import contextlib
import datetime
import errno
import fcntl
import os
import socket
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import yaml

from aeropend_core.errors import AeropendError

__all__ = ['LOCK_NAME', 'REPAIR_WAIT', 'BagLock', 'acquire', 'hold', 'live_writer', 'read_lock', 'refuse_if_live',
           'release', 'remove_stale', 'still_held']

#: Name of the lock file inside a bag folder.
LOCK_NAME = 'recording.lock'

#: How long a starting recorder waits for a repair (``aeropend bag-recover``) holding its folder [s].
REPAIR_WAIT = 60.0

# folder (resolved) -> file descriptor holding this process's exclusive lock
_HELD: dict[str, int] = {}


@dataclass(frozen=True)
class BagLock:
    """What a lock file says about the process writing a bag, and whether somebody holds its ``flock`` now."""

    path: Path
    pid: int
    host: str
    program: str = ''
    started: str = ''
    purpose: str = 'recording'
    held: bool = False

    @property
    def on_this_host(self) -> bool:
        """True when the lock file was written on this machine."""
        return self.host == socket.gethostname()

    def is_live(self) -> bool:
        """True while a process holds the lock (checked when the lock was read)."""
        return self.held

    def describe(self) -> str:
        """'process 1234 (recorder_node) on host rigpc, writing since 2026-11-24T03:00:00Z'."""
        program = f' ({self.program})' if self.program else ''
        doing = 'repairing' if self.purpose == 'repair' else 'writing'
        since = f', {doing} since {self.started}' if self.started else ''
        return f'process {self.pid}{program} on host {self.host}{since}'


def _key(folder: str | os.PathLike) -> str:
    return os.path.realpath(folder)


def _program() -> str:
    name = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else ''
    if name in ('', '-c', '-m', '__main__.py') or name.startswith('python'):
        name = Path(sys.executable).name
    return name


def _held_by_someone(path: Path) -> bool | None:
    """True when some open file description holds ``path``'s flock, False when not, None when there is no file."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC | os.O_NONBLOCK)      # a FIFO planted there never blocks
    except FileNotFoundError:
        return None
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except OSError as error:
        if error.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            return True
        return False
    finally:
        os.close(fd)            # closing drops the shared lock taken for the test
    return False


def _try_exclusive(path: Path, create: bool) -> int | None:
    """A descriptor holding ``path``'s exclusive flock, or None when another process holds it (or, without
    ``create``, when there is no lock file). The descriptor is checked to still name the file at ``path`` (a
    holder may unlink it between our open and our lock)."""
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CLOEXEC | (os.O_CREAT if create else 0), 0o644)
        except FileNotFoundError:
            if create:
                raise
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as error:
            os.close(fd)
            if error.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                return None
            raise
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)
        if not create:
            return None


def _write_content(fd: int, purpose: str) -> None:
    content = {'pid': os.getpid(), 'host': socket.gethostname(), 'program': _program(), 'purpose': purpose,
               'started': datetime.datetime.now(datetime.UTC).strftime('%Y-%m-%dT%H:%M:%SZ')}
    data = yaml.safe_dump(content, sort_keys=False).encode('utf-8')
    os.ftruncate(fd, 0)
    os.pwrite(fd, data, 0)
    os.fsync(fd)


def _busy_error(folder: Path, holder: BagLock | None, action: str) -> AeropendError:
    who = holder.describe() if holder is not None else 'another process'
    if holder is not None and holder.purpose == 'repair':
        return AeropendError(f'cannot {action} {folder}: it is being repaired by {who} (aeropend bag-recover); '
                             'wait until it finishes')
    return AeropendError(f'{folder} is already being written by {who}; choose another bag folder')


def acquire(folder: str | os.PathLike, purpose: str = 'recording', wait: float = REPAIR_WAIT) -> Path:
    """Take the exclusive lock of ``folder`` for this process and keep it until :func:`release`.

    Parameters
    ----------
    folder : str or PathLike [-]
        The bag folder (it must exist).
    purpose : str [-]
        ``'recording'`` (a writer) or ``'repair'`` (``aeropend bag-recover``).
    wait : float [s]
        How long a recording waits for a repair that holds the folder (a recording holding it is refused at once).

    Returns
    -------
    Path
        The lock file.

    Raises
    ------
    AeropendError
        When another process holds the folder (naming it).
    OSError
        When the lock file cannot be created (the caller reports it).
    """
    folder = Path(folder)
    path = folder / LOCK_NAME
    key = _key(folder)
    if key in _HELD:
        raise AeropendError(f'{folder} is already locked by this process; finish the other writer first')
    deadline = time.monotonic() + wait
    while True:
        fd = _try_exclusive(path, create=True)
        if fd is not None:
            break
        holder = read_lock(folder)
        waiting_is_useful = purpose == 'recording' and (holder is None or holder.purpose != 'recording'
                                                        or holder.pid == 0)
        if not waiting_is_useful or time.monotonic() > deadline:
            raise _busy_error(folder, holder, 'record into' if purpose == 'recording' else 'repair')
        time.sleep(0.05)
    try:
        _write_content(fd, purpose)
    except OSError:
        os.close(fd)
        raise
    _HELD[key] = fd
    return path


def release(folder: str | os.PathLike) -> None:
    """Drop this process's lock of ``folder``: the lock file is removed while still held, then the lock released."""
    fd = _HELD.pop(_key(folder), None)
    if fd is None:
        return
    try:
        (Path(folder) / LOCK_NAME).unlink(missing_ok=True)
    except OSError:                      # pragma: no cover - a lock file that stays is unheld, hence stale
        pass
    os.close(fd)


@contextlib.contextmanager
def hold(folder: str | os.PathLike, action: str = 'repair') -> Iterator[BagLock | None]:
    """Hold ``folder``'s lock for a repair; yields the stale lock found there (a killed writer's), or None.

    Raises :class:`AeropendError` (naming the holder) when a recorder or another repair holds the folder.
    """
    folder = Path(folder)
    path = folder / LOCK_NAME
    if _key(folder) in _HELD:
        raise AeropendError(f'cannot {action} {folder}: this process is writing it')
    fd = _try_exclusive(path, create=True)
    if fd is None:
        holder = read_lock(folder)
        raise _refusal(folder, holder, action) if holder is not None else _busy_error(folder, None, action)
    stale = _parse(path, os.pread(fd, 65536, 0).decode('utf-8', errors='replace'), held=False)
    try:
        _write_content(fd, 'repair')
    except OSError:
        os.close(fd)
        raise
    _HELD[_key(folder)] = fd
    try:
        yield stale
    finally:
        release(folder)


def still_held(folder: str | os.PathLike) -> bool:
    """True when this process holds ``folder``'s lock and the lock file at its path is still the one it locked."""
    fd = _HELD.get(_key(folder))
    if fd is None:
        return False
    try:
        return os.stat(Path(folder) / LOCK_NAME).st_ino == os.fstat(fd).st_ino
    except OSError:
        return False


def _parse(path: Path, text: str, held: bool) -> BagLock | None:
    if not text.strip():
        return None
    from aeropend_core.io.inputs import check_yaml_text
    try:
        check_yaml_text(text, str(path))
        data = yaml.safe_load(text)
        return BagLock(path, int(data['pid']), str(data['host']), str(data.get('program') or ''),
                       str(data.get('started') or ''), str(data.get('purpose') or 'recording'), held)
    except (yaml.YAMLError, AttributeError, KeyError, TypeError, ValueError, AeropendError):
        return BagLock(path, 0, socket.gethostname(), held=held)


def read_lock(folder: str | os.PathLike) -> BagLock | None:
    """The lock of a bag folder, or None when it has no lock file.

    A lock file whose content is empty or unreadable (its writer is starting, or was killed while writing it) is
    reported with pid 0; whether it is live is decided by the ``flock`` alone.
    """
    path = Path(folder) / LOCK_NAME
    held = _held_by_someone(path)
    if held is None:
        return None
    from aeropend_core.io.inputs import read_input_text
    try:
        text = read_input_text(path, 'the lock file', 64 * 1024)    # a FIFO, device or huge file: unreadable
    except FileNotFoundError:
        return None
    except (OSError, AeropendError):
        text = ''
    return _parse(path, text, held) or BagLock(path, 0, socket.gethostname(), held=held)


def live_writer(path: str | os.PathLike) -> BagLock | None:
    """The held lock of the bag holding ``path`` (a bag folder, its ``metadata.yaml`` or one of its ``.mcap``
    files), or None when nobody is writing it."""
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    lock = read_lock(folder)
    return lock if lock is not None and lock.held else None


def _refusal(path: Path, lock: BagLock, action: str) -> AeropendError:
    if lock.purpose == 'repair':
        return AeropendError(f'cannot {action} {path}: it is being repaired by {lock.describe()}; wait until that '
                             'repair finishes')
    if lock.on_this_host:
        advice = ('stop that recorder first (Ctrl-C finalises the bag, so nothing needs repair), or wait until '
                  'it finishes')
    else:
        advice = 'it runs on another machine: stop it there first'
    return AeropendError(f'cannot {action} {path}: the bag is being written by {lock.describe()} (it holds the lock '
                         f'on {lock.path}); {advice}')


def refuse_if_live(path: str | os.PathLike, action: str) -> None:
    """Raise :class:`AeropendError` (exit status 2) naming the writing process when the bag is being written."""
    lock = live_writer(path)
    if lock is not None:
        raise _refusal(Path(path), lock, action)


def remove_stale(folder: str | os.PathLike) -> BagLock | None:
    """Delete the lock file of ``folder`` when nobody holds it; returns what it said (None: nothing removed)."""
    path = Path(folder) / LOCK_NAME
    fd = _try_exclusive(path, create=False)
    if fd is None:
        return None
    try:
        lock = _parse(path, os.pread(fd, 65536, 0).decode('utf-8', errors='replace'), held=False) \
            or BagLock(path, 0, socket.gethostname())
        path.unlink(missing_ok=True)
    finally:
        os.close(fd)
    return lock
