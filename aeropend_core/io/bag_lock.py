"""The mark of a bag that is being written: a lock file in the bag folder naming the writing process.

:class:`~aeropend_core.io.bag.BagWriter` creates ``<bag>/recording.lock`` when it opens a bag and removes it when
the bag is finished (or when writing fails for good, e.g. a full disk). The file is a small YAML mapping:
``pid``, ``host``, ``program``, ``started`` (UTC, ISO 8601), ``process_start`` (the process's start time in clock
ticks since boot, from ``/proc/<pid>/stat``) and ``boot_id`` (``/proc/sys/kernel/random/boot_id``).

A lock is **live** while its process runs; it is **stale** once that process is gone (killed with SIGKILL, power
cut): on the same host, when no process has that pid, or the pid now belongs to another process (a different
start time), or the machine rebooted since (a different boot id). A lock written on another host cannot be
checked from here and counts as live (the message says so and how to override: delete the lock file).

Readers use :func:`live_writer` to read a live bag up to its last complete chunk with a note (never advising a
repair); ``aeropend bag-recover`` refuses a live bag (:func:`refuse_if_live`, exit status 2, naming the process)
and removes a stale lock after repairing the bag.
"""
from __future__ import annotations

import datetime
import os
import socket
import sys
from dataclasses import dataclass
from pathlib import Path

import yaml

from aeropend_core.errors import AeropendError

__all__ = ['LOCK_NAME', 'BagLock', 'acquire', 'live_writer', 'read_lock', 'refuse_if_live', 'release',
           'remove_stale']

#: Name of the lock file inside a bag folder.
LOCK_NAME = 'recording.lock'


@dataclass(frozen=True)
class BagLock:
    """What a lock file says about the process writing a bag, and whether that process still runs."""

    path: Path
    pid: int
    host: str
    program: str = ''
    started: str = ''
    process_start: int | None = None
    boot_id: str = ''

    @property
    def on_this_host(self) -> bool:
        """True when the lock was written on this machine (its process can be checked)."""
        return self.host == socket.gethostname()

    def is_live(self) -> bool:
        """True while the writing process runs (or cannot be checked: another host)."""
        if not self.on_this_host:
            return True
        if self.boot_id and _boot_id() and self.boot_id != _boot_id():
            return False                                   # written before the last reboot
        if not _pid_exists(self.pid):
            return False
        if self.process_start is not None:
            now = _process_start(self.pid)
            if now is not None and now != self.process_start:
                return False                               # the pid was reused by another process
        return True

    def describe(self) -> str:
        """'process 1234 (recorder_node) on host rigpc, writing since 2026-11-24T03:00:00Z'."""
        program = f' ({self.program})' if self.program else ''
        since = f', writing since {self.started}' if self.started else ''
        return f'process {self.pid}{program} on host {self.host}{since}'


def _boot_id() -> str:
    try:
        return Path('/proc/sys/kernel/random/boot_id').read_text(encoding='ascii').strip()
    except OSError:
        return ''


def _pid_exists(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:                 # exists, owned by someone else
        return True
    except OSError:
        return False
    return True


def _process_start(pid: int) -> int | None:
    """Start time of a process in clock ticks since boot (field 22 of /proc/<pid>/stat), None if unknown."""
    try:
        text = Path(f'/proc/{pid}/stat').read_text(encoding='ascii', errors='replace')
    except OSError:
        return None
    try:                                    # the command name (field 2) may hold spaces and parentheses
        return int(text[text.rindex(')') + 2:].split()[19])
    except (ValueError, IndexError):
        return None


def _program() -> str:
    name = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else ''
    if name in ('', '-c', '-m', '__main__.py') or name.startswith('python'):
        name = Path(sys.executable).name
    return name


def acquire(folder: str | os.PathLike) -> Path:
    """Mark ``folder`` as being written by this process; returns the lock file's path.

    A stale lock (its process is gone) is replaced. Raises :class:`AeropendError` when a live process already
    holds the folder, and ``OSError`` when the lock file cannot be written (the caller reports it).
    """
    path = Path(folder) / LOCK_NAME
    existing = read_lock(folder)
    if existing is not None:
        if existing.is_live() and not (existing.pid == os.getpid() and existing.on_this_host):
            raise AeropendError(f'{folder} is already being written by {existing.describe()}; choose another bag '
                                'folder')
        path.unlink(missing_ok=True)
    content = {'pid': os.getpid(), 'host': socket.gethostname(), 'program': _program(),
               'started': datetime.datetime.now(datetime.UTC).strftime('%Y-%m-%dT%H:%M:%SZ'),
               'process_start': _process_start(os.getpid()), 'boot_id': _boot_id()}
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    try:
        os.write(fd, yaml.safe_dump(content, sort_keys=False).encode('utf-8'))
    finally:
        os.close(fd)
    return path


def release(folder: str | os.PathLike) -> None:
    """Remove this process's lock of ``folder`` (a lock of another process is left alone)."""
    lock = read_lock(folder)
    if lock is not None and lock.pid == os.getpid() and lock.on_this_host:
        try:
            lock.path.unlink(missing_ok=True)
        except OSError:                      # pragma: no cover - a lock that stays is found stale later
            pass


def read_lock(folder: str | os.PathLike) -> BagLock | None:
    """The lock of a bag folder, or None when it has none. An unreadable lock file counts as held by pid 0 on
    this host (stale)."""
    path = Path(folder) / LOCK_NAME
    try:
        text = path.read_text(encoding='utf-8')
    except FileNotFoundError:
        return None
    except OSError:
        return BagLock(path, 0, socket.gethostname())
    try:
        data = yaml.safe_load(text)
        start = data.get('process_start')
        return BagLock(path, int(data['pid']), str(data['host']), str(data.get('program') or ''),
                       str(data.get('started') or ''), int(start) if start is not None else None,
                       str(data.get('boot_id') or ''))
    except (yaml.YAMLError, AttributeError, KeyError, TypeError, ValueError):
        # half-written by a process killed between open and write: nobody is writing under it
        return BagLock(path, 0, socket.gethostname())


def live_writer(path: str | os.PathLike) -> BagLock | None:
    """The live lock of the bag holding ``path`` (a bag folder, its ``metadata.yaml`` or one of its ``.mcap``
    files), or None when nobody is writing it."""
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    lock = read_lock(folder)
    return lock if lock is not None and lock.is_live() else None


def refuse_if_live(path: str | os.PathLike, action: str) -> None:
    """Raise :class:`AeropendError` (exit status 2) naming the writing process when the bag is being written."""
    lock = live_writer(path)
    if lock is None:
        return
    if lock.on_this_host:
        advice = (f'stop that recorder first (Ctrl-C finalises the bag, so nothing needs repair), or wait until '
                  f'it finishes. If process {lock.pid} is not writing this bag, delete {lock.path}')
    else:
        advice = (f'it runs on another machine, so whether it still writes cannot be checked from here: stop it '
                  f'there first, or delete {lock.path} if it is certainly gone')
    raise AeropendError(f'cannot {action} {path}: the bag is being written by {lock.describe()} (lock file '
                        f'{lock.path}); {advice}')


def remove_stale(folder: str | os.PathLike) -> BagLock | None:
    """Delete the lock of ``folder`` when its process is gone; returns the removed lock (None: nothing removed)."""
    lock = read_lock(folder)
    if lock is None or lock.is_live():
        return None
    lock.path.unlink(missing_ok=True)
    return lock
