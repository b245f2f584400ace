"""Errors a user can cause and fix; the CLI prints their message without a traceback."""


class AeropendError(Exception):
    """A problem with the user's input or data; the message says what is wrong and what to do.

    The CLI prints the message on one line and exits with :attr:`exit_status` (2: fix the input or arguments).

    >>> from aeropend_core import AeropendError, load_recording
    >>> try:
    ...     load_recording('no_such_run.csv')
    ... except AeropendError as error:
    ...     error.exit_status, 'no_such_run.csv' in str(error)
    (2, True)
    """

    exit_status = 2


class UnknownEffectError(AeropendError, KeyError):
    """An effect name that is not in the catalog.

    >>> from aeropend_core.model.effects import get_effect
    >>> try:
    ...     get_effect('no_such_effect')
    ... except UnknownEffectError as error:
    ...     isinstance(error, AeropendError), isinstance(error, KeyError), str(error).startswith("unknown effect")
    (True, True, True)
    """

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ''


class InsufficientDataError(AeropendError):
    """The data cannot support the requested fit (too short, not excited, NaN...).

    >>> import numpy as np
    >>> from aeropend_core import identify_pendulum
    >>> time = np.arange(0.0, 0.2, 0.002)                                # s: 0.2 s, far too short
    >>> try:
    ...     identify_pendulum(time, np.ones_like(time), np.ones_like(time), np.zeros_like(time))
    ... except InsufficientDataError as error:
    ...     error.exit_status
    2
    """


class StorageError(AeropendError):
    """The system refused to store data (disk full, file size limit, permissions): the input was fine; free space
    or choose another place. The CLI exits with status 1 for it.

    >>> StorageError('disk full: free space or choose another folder').exit_status
    1
    """

    exit_status = 1
