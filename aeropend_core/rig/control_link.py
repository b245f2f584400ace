"""Sending the controller's gains to the firmware: 14 SET_CONTROL_COEFFICIENT commands, every ACK checked.

:class:`GainsUpload` is the exchange as a small state machine (bytes to write, ACKs in), so that a node with its own
reader thread (the serial bridge) can drive it; :func:`send_gains` runs it on a serial port (pyserial-like
``write`` / ``read`` / ``in_waiting``) and returns when the device has acknowledged all 14 values (the setpoint
weight too, though the device starts with b = 1: what runs is then exactly what was sent).

The device checks each limit against its partner *as stored* (I_MIN <= I_MAX, U_MIN <= U_MAX, ANGLE_MIN < ANGLE_MAX;
docstring of :mod:`aeropend_core.rig.protocol`), so a lower limit above the stored upper one is refused on the way
(e.g. angle limits [2, 3] after [-0.35, 1.75]). The upload sends each lower limit before its upper one; a lower limit
refused as out of range is sent once more after its upper limit has been accepted. Any other refusal, an ACK whose
value is not the float32 value sent, or a missing ACK is an error.
"""
from __future__ import annotations

import time

import numpy as np

from aeropend_core.control.law import (
    ANGLE_MAX,
    ANGLE_MIN,
    I_MAX,
    I_MIN,
    N_COEFFICIENTS,
    U_MAX,
    U_MIN,
    PidGains,
)
from aeropend_core.rig import protocol as P

__all__ = ['ControlLinkError', 'GainsUpload', 'device_coefficients', 'send_gains']

#: Lower limit -> its upper limit.
_PAIRS = {I_MIN: I_MAX, U_MIN: U_MAX, ANGLE_MIN: ANGLE_MAX}


class ControlLinkError(P.ProtocolError):
    """The device refused a coefficient, stored another value, or did not answer."""


def device_coefficients(gains: PidGains, sample_time: float = P.SAMPLE_PERIOD) -> np.ndarray:
    """The 14 coefficients of `gains` at the firmware's period, rounded to float32 as the device stores them."""
    return np.asarray(gains.coefficients(sample_time), dtype=np.float32).astype(np.float64)


class GainsUpload:
    """One upload of a gain set (see the module docstring).

    >>> upload = GainsUpload(PidGains())
    >>> len(upload.start()) > 0, upload.done
    (True, False)
    """

    def __init__(self, gains: PidGains, sample_time: float = P.SAMPLE_PERIOD) -> None:
        self.gains = gains
        self.values = device_coefficients(gains, sample_time)
        self.pending: set[int] = set(range(N_COEFFICIENTS))
        self.acks: dict[int, P.AckFrame] = {}
        self.error: str | None = None
        self._retry: set[int] = set()     # lower limits waiting for their upper limit
        self._retried: set[int] = set()

    def command(self, index: int) -> bytes:
        return P.encode_coefficient(index, float(self.values[index]))

    def start(self) -> bytes:
        """The 14 commands, in index order (each lower limit before its upper one)."""
        return b''.join(self.command(index) for index in range(N_COEFFICIENTS))

    @property
    def done(self) -> bool:
        return not self.pending and self.error is None

    def accept(self, ack: P.AckFrame) -> bytes:
        """Take one ACK; returns the bytes to send next (a retried lower limit) or b''. Sets :attr:`error`."""
        if ack.command != P.SET_CONTROL_COEFFICIENT or ack.index not in self.pending or self.error is not None:
            return b''
        index = ack.index
        if ack.ok:
            if np.float32(ack.value) != np.float32(self.values[index]):
                self.error = (f'coefficient {index}: the device stored {ack.value!r}, '
                              f'not {float(self.values[index])!r}')
                return b''
            self.pending.discard(index)
            self.acks[index] = ack
            lower = next((low for low, high in _PAIRS.items() if high == index), None)
            if lower is not None and lower in self._retry:
                self._retry.discard(lower)
                self._retried.add(lower)
                return self.command(lower)
            return b''
        if ack.result == P.ACK_OUT_OF_RANGE and index in _PAIRS and index not in self._retried:
            upper = _PAIRS[index]
            if upper in self.pending:
                self._retry.add(index)       # sent again once the upper limit is in
                return b''
        self.error = f'coefficient {index} = {float(self.values[index])!r}: {ack.describe()}'
        return b''


def send_gains(link, gains: PidGains, sample_time: float = P.SAMPLE_PERIOD, timeout: float = 2.0,
               decoder: P.FrameDecoder | None = None, messages: list | None = None) -> dict[int, P.AckFrame]:
    """Send `gains` over `link` and wait for every ACK; returns the ACKs by coefficient index.

    Other messages read meanwhile are appended to `messages` (when given). Raises :class:`ControlLinkError` on a
    refusal, a wrong stored value or after `timeout` [s] without all ACKs.
    """
    decoder = decoder or P.FrameDecoder()
    upload = GainsUpload(gains, sample_time)
    link.write(upload.start())
    end = time.monotonic() + timeout
    while not upload.done and upload.error is None:
        if time.monotonic() > end:
            raise ControlLinkError(f'no ACK for coefficient(s) {sorted(upload.pending)} within {timeout} s')
        for message in decoder.feed(link.read(max(1, link.in_waiting))):
            if isinstance(message, P.AckFrame):
                resend = upload.accept(message)
                if resend:
                    link.write(resend)
            elif messages is not None:
                messages.append(message)
    if upload.error is not None:
        raise ControlLinkError(upload.error)
    return upload.acks
