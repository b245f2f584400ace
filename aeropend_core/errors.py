"""Errors a user can cause and fix; the CLI prints their message without a traceback."""


class AeropendError(Exception):
    """A problem with the user's input or data; the message says what is wrong and what to do."""


class UnknownEffectError(AeropendError, KeyError):
    """An effect name that is not in the catalog."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ''


class InsufficientDataError(AeropendError):
    """The data cannot support the requested fit (too short, not excited, NaN...)."""
