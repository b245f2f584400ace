"""Input files: every file aeropend reads is checked to be a regular file (or a folder where a bag is expected)
before it is read, and YAML is parsed with limits.

- :func:`check_input` refuses a **named pipe (FIFO), device or socket** in one line (:class:`AeropendError`, exit
  status 2): reading one blocks until somebody writes to it (forever, silently) or never ends (``/dev/zero``).
- :func:`open_input` opens with ``O_NONBLOCK`` and checks the *opened* file with ``fstat``, so a path swapped for
  a FIFO between the check and the open cannot block either; the flag is cleared before the file is read.
- :func:`load_yaml` / :func:`check_yaml_text` refuse a YAML document larger than :data:`YAML_MAX_BYTES`, nested
  deeper than :data:`YAML_MAX_DEPTH` or with more than :data:`YAML_MAX_ALIASES` aliases (a "billion laughs"
  document), in one line, before any object is built: the nesting is counted on the parser's event stream, which
  does not recurse (PyYAML's composer does, and a 100,000-deep ``[[[...]]]`` ends in a ``RecursionError``).
"""
from __future__ import annotations

import errno
import fcntl
import os
import stat
from pathlib import Path

from aeropend_core.errors import AeropendError

__all__ = ['YAML_MAX_ALIASES', 'YAML_MAX_BYTES', 'YAML_MAX_DEPTH', 'check_input', 'check_yaml_text', 'load_yaml',
           'load_yaml_text', 'open_input', 'read_input_text']

#: Largest YAML input read [bytes] (a configuration, profile, schedule or calibration file is a few KiB).
YAML_MAX_BYTES = 256 * 1024
#: Deepest nesting of mappings and sequences accepted in a YAML input.
YAML_MAX_DEPTH = 64
#: Most aliases (``*name``) accepted in a YAML input.
YAML_MAX_ALIASES = 256

_KINDS = ((stat.S_ISFIFO, 'a named pipe (FIFO)'), (stat.S_ISCHR, 'a character device'),
          (stat.S_ISBLK, 'a block device'), (stat.S_ISSOCK, 'a socket'))


def _kind(mode: int) -> str | None:
    return next((name for test, name in _KINDS if test(mode)), None)


def _refusal(what: str, path, kind: str, folder: bool) -> AeropendError:
    expected = 'a regular file or a bag folder' if folder else 'a regular file'
    return AeropendError(f'{what} {path} is {kind}, not {expected}: reading it could block forever or never end; '
                         f'give {expected}')


def check_input(path: str | os.PathLike, what: str = 'input', folder: bool = False) -> Path:
    """``path`` as a :class:`Path` when it is a regular file (or, with ``folder``, a folder); refused otherwise.

    Parameters
    ----------
    path : str or PathLike [-]
        The input as given (a symbolic link is followed).
    what : str [-]
        What it is, for the message (e.g. ``'--calibration'``).
    folder : bool [-]
        Accept a folder (a bag).

    Raises
    ------
    AeropendError
        Missing, a link loop, a FIFO, device or socket, or a folder where a file is expected (exit status 2).
    """
    from aeropend_core.io.paths import path_problem, storage_error
    given = Path(path)
    try:
        info = os.stat(given)
    except FileNotFoundError:
        raise AeropendError(f'cannot read {what} {given}: it {path_problem(given)}') from None
    except OSError as error:
        if error.errno == errno.ELOOP:
            raise AeropendError(f'cannot read {what} {given}: it {path_problem(given)}') from None
        raise storage_error(error, f'cannot read {what} {given}: {error.strerror or error}') from None
    if stat.S_ISDIR(info.st_mode):
        if folder:
            return given
        raise AeropendError(f'{what} {given} is a folder, not a file; give a file')
    kind = _kind(info.st_mode)
    if kind is not None:
        raise _refusal(what, given, kind, folder)
    return given


def open_input(path: str | os.PathLike, what: str = 'input', text: bool = False, **kwargs):
    """Open a regular file for reading without ever blocking on a FIFO (``O_NONBLOCK``, then ``fstat``).

    ``text``: open in text mode (``kwargs`` go to :func:`open`, e.g. ``encoding``, ``newline``).

    Raises
    ------
    AeropendError
        As :func:`check_input`; :class:`~aeropend_core.errors.StorageError` when the system refuses.
    """
    from aeropend_core.io.paths import storage_error
    check_input(path, what)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, 'O_NOCTTY', 0))
    except OSError as error:
        raise storage_error(error, f'cannot read {what} {path}: {error.strerror or error}') from None
    try:
        mode = os.fstat(fd).st_mode
        kind = _kind(mode) or ('a folder' if stat.S_ISDIR(mode) else None)
        if kind is not None:
            raise _refusal(what, path, kind, False)
        fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_NONBLOCK)
        return os.fdopen(fd, 'r' if text else 'rb', **kwargs)
    except BaseException:
        os.close(fd)
        raise


def read_input_text(path: str | os.PathLike, what: str = 'input', max_bytes: int | None = None,
                    encoding: str = 'utf-8') -> str:
    """The text of a regular file (see :func:`open_input`); refused when longer than ``max_bytes``.

    Raises
    ------
    AeropendError
        Not a regular file, larger than ``max_bytes``, or not text in ``encoding``.
    """
    with open_input(path, what) as handle:
        data = handle.read() if max_bytes is None else handle.read(max_bytes + 1)
    if max_bytes is not None and len(data) > max_bytes:
        raise AeropendError(f'{what} {path} is larger than {max_bytes} bytes: not a file of this kind')
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as error:
        raise AeropendError(f'{what} {path} is not {encoding} text (byte {error.start})') from None


def check_yaml_text(text: str, where: str = 'YAML input', max_depth: int = YAML_MAX_DEPTH,
                    max_aliases: int = YAML_MAX_ALIASES, max_bytes: int = YAML_MAX_BYTES) -> None:
    """Refuse a YAML text over the limits (size, nesting depth, aliases) in one line, before it is composed.

    Syntax errors are left to the loader that follows (it names them its own way).

    Raises
    ------
    AeropendError
        Over a limit.
    """
    import yaml
    if len(text) > max_bytes:
        raise AeropendError(f'{where} is larger than {max_bytes} bytes: not a file of this kind')
    try:                        # libyaml's parser when there is one (~15x faster), else and where it refuses, PyYAML's
        _check_events(yaml.parse(text, Loader=_fast_safe_loader()), where, max_depth, max_aliases,
                      syntax_errors_pass=False)
        return
    except yaml.YAMLError:
        pass
    _check_events(yaml.parse(text, Loader=yaml.SafeLoader), where, max_depth, max_aliases)


def load_yaml_text(text: str, where: str = 'YAML input'):
    """The objects of a YAML text within the limits of :func:`check_yaml_text`: libyaml's safe loader where it is
    installed (~15x faster, the same safe constructor), PyYAML's where libyaml is absent or refuses the text.

    Raises
    ------
    AeropendError
        Over a limit; ``yaml.YAMLError`` for a syntax error (the caller names it).
    """
    import yaml
    check_yaml_text(text, where)
    try:
        return yaml.load(text, Loader=_fast_safe_loader())  # noqa: S506 - a safe loader
    except yaml.YAMLError:
        return yaml.safe_load(text)


def _fast_safe_loader():
    """libyaml's safe loader when PyYAML was built with it, else PyYAML's own."""
    import yaml
    return getattr(yaml, 'CSafeLoader', yaml.SafeLoader)


def _check_events(events, where: str, max_depth: int, max_aliases: int, syntax_errors_pass: bool = True) -> None:
    """:func:`check_yaml_text`'s limits on a YAML event stream. A syntax error (yaml.YAMLError) ends the check
    silently (the loader names it), or, with `syntax_errors_pass` False, is raised (the first, libyaml pass: PyYAML
    then checks the text)."""
    import yaml
    depth = aliases = 0
    try:
        for event in events:
            if isinstance(event, yaml.CollectionStartEvent):
                depth += 1
                if depth > max_depth:
                    raise AeropendError(f'{where} nests more than {max_depth} levels deep: refused (no '
                                        'configuration is that deep)')
            elif isinstance(event, yaml.CollectionEndEvent):
                depth -= 1
            elif isinstance(event, yaml.AliasEvent):
                aliases += 1
                if aliases > max_aliases:
                    raise AeropendError(f'{where} uses more than {max_aliases} aliases (*name): refused (an alias '
                                        'bomb expands to billions of nodes)')
    except yaml.YAMLError:
        if not syntax_errors_pass:
            raise
        return                  # not valid YAML: the loader says so in its own words
    except RecursionError:      # pragma: no cover - the event parser does not recurse
        raise AeropendError(f'{where} nests too deep: refused') from None


def load_yaml(path: str | os.PathLike, what: str = 'YAML file', max_bytes: int = YAML_MAX_BYTES,
              max_depth: int = YAML_MAX_DEPTH, max_aliases: int = YAML_MAX_ALIASES):
    """``yaml.safe_load`` of a regular file within the limits of :func:`check_yaml_text`.

    Raises
    ------
    AeropendError
        Not a regular file, not UTF-8, over a limit; ``yaml.YAMLError`` for a syntax error (the caller names it).
    """
    import yaml
    text = read_input_text(path, what, max_bytes)
    check_yaml_text(text, f'{what} {path}', max_depth, max_aliases, max_bytes)
    return yaml.safe_load(text)
