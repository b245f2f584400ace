"""Errors a user can cause and fix; the CLI prints their message without a traceback."""


class AeropendError(Exception):
    """A problem with the user's input or data; the message says what is wrong and what to do.

    The CLI prints the message on one line and exits with :attr:`exit_status` (2: fix the input or arguments).
    """

    exit_status = 2


class UnknownEffectError(AeropendError, KeyError):
    """An effect name that is not in the catalog."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ''


class InsufficientDataError(AeropendError):
    """The data cannot support the requested fit (too short, not excited, NaN...)."""


class StorageError(AeropendError):
    """The system refused to store data (disk full, file size limit, permissions): the input was fine; free space
    or choose another place. The CLI exits with status 1 for it."""

    exit_status = 1
