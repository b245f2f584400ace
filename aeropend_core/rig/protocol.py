"""The serial protocol between the rig's Arduino Mega (firmware/aeropend/aeropend.ino) and the host.

This module and ``firmware/aeropend/aeropend_protocol.h`` describe the same format; the tests compile the firmware
and check both ends against each other.

Wire format (both directions)
-----------------------------
Every message is ``0x00  COBS(payload + CRC)  0x00``:

* ``payload`` starts with a one-byte message type, then little-endian fields (below);
* ``CRC`` is CRC-16/CCITT-FALSE (polynomial 0x1021, initial value 0xFFFF, no reflection, no final XOR; the check
  value of ``b'123456789'`` is 0x29B1) of ``payload``, appended little-endian;
* COBS (Consistent Overhead Byte Stuffing) removes every zero byte, so ``0x00`` only ever delimits messages. A
  delimiter before *and* after each message means garbage, a truncated message or a lost byte costs at most the
  message it touches: the next message always starts clean. Empty chunks between two delimiters are ignored.

Device -> host
~~~~~~~~~~~~~~
``SAMPLE`` (type 0x01), one per Timer1 overflow (Ts = 64 * 510 / 16 MHz = 2.04 ms, 490.196 Hz), 14 bytes::

    u8 type | u32 sequence | u16 current_counts | u16 angle_counts | u16 voltage_counts | u16 duty_q16 | u8 flags

``sequence`` counts Timer1 overflows since reset (a gap = lost samples, a smaller value = the device reset);
``*_counts`` are raw 10-bit ADC results (0..1023, AVCC = 5 V reference) of the armature current (A0 on the motor
shield's channel A: 3.3 V <-> 2 A), the filtered angle sensor output and the optional armature voltage divider;
``duty_q16`` is the duty cycle applied during the sample, fraction * 65535; ``flags`` see ``FLAG_*``.

``STATUS`` (type 0x02), at boot, after each configuration command and once per second, 18 bytes::

    u8 type | u8 protocol_version | u8 pwm_mode | u8 flags | u16 pwm_top | u16 max_duty_q16 | u16 watchdog_ms
    | u16 rx_bad_frames | u16 tx_dropped_frames | u32 sequence

Host -> device
~~~~~~~~~~~~~~
``u8 type | u16 value`` (3 bytes): ``SET_DUTY`` (0x10, duty fraction * 65535, clamped by the device to its
maximum duty), ``SET_MAX_DUTY`` (0x11, fraction * 65535), ``SET_WATCHDOG`` (0x12, timeout in ms, 10..60000),
``REQUEST_STATUS`` (0x13, value ignored). *Every* valid command feeds the device's watchdog; when no valid command
arrives for the watchdog time the device sets the duty to zero and raises ``FLAG_WATCHDOG_TRIPPED`` until the next
``SET_DUTY``. A host must therefore repeat its duty command (the bridge node does it every 100 ms).
"""
from __future__ import annotations

import binascii
import math
import struct
from dataclasses import dataclass, field
from typing import NamedTuple

from aeropend_core.model.parameters import DEFAULT_PARAMETERS

__all__ = [
    'ADC_FULL_SCALE',
    'DELIMITER',
    'FLAG_BOOT',
    'FLAG_DUTY_CLAMPED',
    'FLAG_SAMPLES_DROPPED',
    'FLAG_WATCHDOG_TRIPPED',
    'PROTOCOL_VERSION',
    'PWM_FAST',
    'PWM_PHASE_CORRECT',
    'PWM_TOP',
    'REQUEST_STATUS',
    'SAMPLE',
    'SAMPLE_PERIOD',
    'SAMPLE_WIRE_LENGTH',
    'SET_DUTY',
    'SET_MAX_DUTY',
    'SET_WATCHDOG',
    'STATUS',
    'WATCHDOG_MS_RANGE',
    'Calibration',
    'CommandFrame',
    'DecoderCounters',
    'FrameDecoder',
    'ProtocolError',
    'SampleFrame',
    'StatusFrame',
    'cobs_decode',
    'cobs_encode',
    'crc16',
    'decode_message',
    'duty_to_q16',
    'encode_command',
    'encode_sample',
    'encode_status',
    'frame',
    'q16_to_duty',
]

PROTOCOL_VERSION = 1
DELIMITER = b'\x00'

# Message types.
SAMPLE = 0x01
STATUS = 0x02
SET_DUTY = 0x10
SET_MAX_DUTY = 0x11
SET_WATCHDOG = 0x12
REQUEST_STATUS = 0x13
COMMAND_TYPES = (SET_DUTY, SET_MAX_DUTY, SET_WATCHDOG, REQUEST_STATUS)

# Bits of the ``flags`` byte (SAMPLE and STATUS).
FLAG_WATCHDOG_TRIPPED = 0x01  #: motor cut because no command arrived within the watchdog time
FLAG_DUTY_CLAMPED = 0x02      #: the last SET_DUTY asked for more than the maximum duty
FLAG_SAMPLES_DROPPED = 0x04   #: the transmit buffer was full: samples before this one were not sent
FLAG_BOOT = 0x08              #: set in the STATUS sent right after reset

# PWM modes reported in STATUS.
PWM_PHASE_CORRECT = 0  #: Timer1 mode 10, TOP = ICR1 = 255, prescaler 64: the real chip's default
PWM_FAST = 1           #: Timer1 mode 14, TOP = ICR1 = 509, prescaler 64: build option for simavr 1.6
PWM_TOP = {PWM_PHASE_CORRECT: 255, PWM_FAST: 509}
#: Sampling period of the firmware in both PWM modes [s]: 64 * 510 / 16 MHz (490.196 Hz).
SAMPLE_PERIOD = 64 * 510 / 16e6
#: Largest 10-bit ADC result.
ADC_FULL_SCALE = 1023
#: Accepted watchdog timeouts [ms].
WATCHDOG_MS_RANGE = (10, 60000)

_SAMPLE = struct.Struct('<BIHHHHB')
_STATUS = struct.Struct('<BBBBHHHHHI')
_COMMAND = struct.Struct('<BH')
_CRC = struct.Struct('<H')
#: Encoded length (without delimiters) of each device message: COBS adds one byte to payloads < 254 bytes.
SAMPLE_WIRE_LENGTH = _SAMPLE.size + 2 + 1
STATUS_WIRE_LENGTH = _STATUS.size + 2 + 1
#: Longest encoded message; a run of non-zero bytes longer than this is garbage.
MAX_WIRE_LENGTH = max(SAMPLE_WIRE_LENGTH, STATUS_WIRE_LENGTH, _COMMAND.size + 3)


class ProtocolError(ValueError):
    """A malformed message (bad COBS, length, CRC or type)."""


def crc16(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE of `data` (poly 0x1021, init 0xFFFF); ``crc16(b'123456789') == 0x29B1``."""
    return binascii.crc_hqx(data, crc)


def cobs_encode(data: bytes) -> bytes:
    """COBS-encode `data`: the result has no zero byte and is ``len(data) + 1`` bytes for < 254 bytes."""
    out = bytearray()
    for block in bytes(data).split(b'\x00'):
        while len(block) >= 254:
            out.append(255)
            out += block[:254]
            block = block[254:]
        out.append(len(block) + 1)
        out += block
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Inverse of :func:`cobs_encode`.

    Raises
    ------
    ProtocolError
        When `data` contains a zero byte or a block runs past its end.
    """
    out = bytearray()
    index = 0
    size = len(data)
    while index < size:
        code = data[index]
        end = index + code
        if code == 0 or end > size:
            raise ProtocolError('invalid COBS block')
        out += data[index + 1:end]
        if code != 255 and end < size:
            out.append(0)
        index = end
    if b'\x00' in data:
        raise ProtocolError('zero byte inside a COBS message')
    return bytes(out)


def frame(payload: bytes) -> bytes:
    """The bytes on the wire for one message: ``0x00 COBS(payload + CRC-16) 0x00``."""
    return b'\x00' + cobs_encode(payload + _CRC.pack(crc16(payload))) + b'\x00'


def duty_to_q16(duty: float) -> int:
    """Duty fraction 0..1 -> the 16-bit wire value (clipped to 0..65535)."""
    return min(65535, max(0, math.floor(float(duty) * 65535.0 + 0.5)))   # half up, like the firmware


def q16_to_duty(value: int) -> float:
    """16-bit wire value -> duty fraction 0..1."""
    return value / 65535.0


class SampleFrame(NamedTuple):
    """One SAMPLE message: raw ADC counts (0..1023), applied duty (fraction * 65535) and flags."""

    sequence: int
    current_counts: int
    angle_counts: int
    voltage_counts: int
    duty_q16: int
    flags: int = 0

    @property
    def duty(self) -> float:
        """Applied duty fraction 0..1."""
        return self.duty_q16 / 65535.0


class StatusFrame(NamedTuple):
    """One STATUS message: the device's configuration and link counters."""

    protocol_version: int
    pwm_mode: int
    flags: int
    pwm_top: int
    max_duty_q16: int
    watchdog_ms: int
    rx_bad_frames: int
    tx_dropped_frames: int
    sequence: int


class CommandFrame(NamedTuple):
    """One host -> device command: ``kind`` is SET_DUTY, SET_MAX_DUTY, SET_WATCHDOG or REQUEST_STATUS."""

    kind: int
    value: int


def encode_sample(sample: SampleFrame) -> bytes:
    """Wire bytes (delimiters included) of a SAMPLE message."""
    return frame(_SAMPLE.pack(SAMPLE, *sample))


def encode_status(status: StatusFrame) -> bytes:
    """Wire bytes (delimiters included) of a STATUS message."""
    return frame(_STATUS.pack(STATUS, *status))


def encode_command(kind: int, value: float = 0) -> bytes:
    """Wire bytes of a host -> device command.

    Parameters
    ----------
    kind
        SET_DUTY or SET_MAX_DUTY (`value` a duty fraction 0..1), SET_WATCHDOG (`value` the timeout in s,
        0.01..60) or REQUEST_STATUS (`value` ignored).

    Raises
    ------
    ProtocolError
        For an unknown `kind` or a value out of range.
    """
    if kind in (SET_DUTY, SET_MAX_DUTY):
        if not 0.0 <= float(value) <= 1.0:
            raise ProtocolError(f'duty must be a fraction in [0, 1], got {value!r}')
        raw = duty_to_q16(value)
    elif kind == SET_WATCHDOG:
        raw = round(float(value) * 1000.0)
        if not WATCHDOG_MS_RANGE[0] <= raw <= WATCHDOG_MS_RANGE[1]:
            raise ProtocolError(f'watchdog timeout must be 0.01..60 s, got {value!r} s')
    elif kind == REQUEST_STATUS:
        raw = 0
    else:
        raise ProtocolError(f'unknown command type 0x{kind:02x}')
    return frame(_COMMAND.pack(kind, raw))


def decode_message(encoded: bytes) -> SampleFrame | StatusFrame | CommandFrame:
    """Decode one COBS chunk (without delimiters) into a message.

    Raises
    ------
    ProtocolError
        Bad COBS, CRC mismatch, unknown type or wrong length for the type.
    """
    payload = cobs_decode(encoded)
    if len(payload) < 3:
        raise ProtocolError('message too short')
    body = payload[:-2]
    if crc16(body) != _CRC.unpack_from(payload, len(body))[0]:
        raise ProtocolError('CRC mismatch')
    kind = body[0]
    if kind == SAMPLE and len(body) == _SAMPLE.size:
        return SampleFrame(*_SAMPLE.unpack(body)[1:])
    if kind == STATUS and len(body) == _STATUS.size:
        return StatusFrame(*_STATUS.unpack(body)[1:])
    if kind in COMMAND_TYPES and len(body) == _COMMAND.size:
        return CommandFrame(*_COMMAND.unpack(body))
    raise ProtocolError(f'unknown message type 0x{kind:02x} or wrong length {len(body)}')


@dataclass
class DecoderCounters:
    """Link-health counters of a :class:`FrameDecoder` (all cumulative)."""

    bytes_received: int = 0
    messages: int = 0   #: valid messages of any type
    samples: int = 0    #: valid SAMPLE messages
    corrupt: int = 0    #: chunks between delimiters that failed COBS, length, CRC or type checks
    oversize: int = 0   #: runs of non-zero bytes longer than any message (counted within `corrupt` too)


_SAMPLE_UNPACK = _SAMPLE.unpack
_STATUS_UNPACK = _STATUS.unpack
_COMMAND_UNPACK = _COMMAND.unpack
_crc_hqx = binascii.crc_hqx


@dataclass
class FrameDecoder:
    """Streaming decoder: feed it bytes as they arrive, get the valid messages back in order.

    Resynchronises on every ``0x00``; never raises on bad input (bad chunks are counted in ``counters.corrupt``).
    Bytes before the first delimiter after creation or :meth:`reset` are skipped silently (a port opened in the
    middle of a message).
    Decoding is a ``bytes.split`` plus a per-message COBS pass, ~0.4 M messages/s (bench/bench_decoder.py).

    Parameters
    ----------
    accept_commands
        Also return host -> device commands (the device side, e.g. the emulator, wants them).
    """

    accept_commands: bool = False
    counters: DecoderCounters = field(default_factory=DecoderCounters)
    _pending: bytes = b''
    #: Skip (without counting) up to the first delimiter: a port opened mid-stream starts inside a message.
    _discarding: bool = True

    def reset(self) -> None:
        """Forget a partial message (after a reconnect): resynchronise on the next delimiter."""
        self._pending = b''
        self._discarding = True

    def feed(self, data: bytes) -> list:
        """Decode `data` (any length, any split) and return the complete valid messages it finishes."""
        counters = self.counters
        counters.bytes_received += len(data)
        if self._discarding:
            cut = data.find(b'\x00')
            if cut < 0:
                return []
            data = data[cut:]
            self._discarding = False
        chunks = (self._pending + data).split(b'\x00')
        pending = chunks.pop()
        if len(pending) > MAX_WIRE_LENGTH:
            counters.corrupt += 1
            counters.oversize += 1
            pending = b''
            self._discarding = True
        self._pending = pending
        out = []
        append = out.append
        corrupt = 0
        samples = 0
        for chunk in chunks:
            size = len(chunk)
            if not size:
                continue
            # Inline COBS decode (hot path): collect the blocks, joined with zeros.
            if size > MAX_WIRE_LENGTH:
                corrupt += 1
                continue
            index = 0
            blocks = []
            ok = True
            while index < size:
                code = chunk[index]
                end = index + code
                if end > size or code == 255:  # messages are < 254 bytes: 0xFF blocks never occur
                    ok = False
                    break
                blocks.append(chunk[index + 1:end])
                index = end
            if not ok:
                corrupt += 1
                continue
            payload = b'\x00'.join(blocks)
            # The last block's implied zero is not data; payload = message + CRC.
            length = len(payload)
            if length < 5 or _crc_hqx(payload[:-2], 0xFFFF) != payload[-2] | (payload[-1] << 8):
                corrupt += 1
                continue
            kind = payload[0]
            if kind == SAMPLE and length == 16:
                append(SampleFrame(*_SAMPLE_UNPACK(payload[:-2])[1:]))
                samples += 1
            elif kind == STATUS and length == 20:
                append(StatusFrame(*_STATUS_UNPACK(payload[:-2])[1:]))
            elif self.accept_commands and kind in COMMAND_TYPES and length == 5:
                append(CommandFrame(*_COMMAND_UNPACK(payload[:-2])))
            else:
                corrupt += 1
        counters.corrupt += corrupt
        counters.samples += samples
        counters.messages += len(out)
        return out


# ----------------------------------------------------------------------------------------------------------------
# Raw counts <-> SI units
# ----------------------------------------------------------------------------------------------------------------
#: ADC volts per count with the AVCC = 5 V reference (ADC = Vin * 1024 / Vref on the ATmega2560).
ADC_VOLTS_PER_COUNT = 5.0 / 1024
#: Motor shield Rev3 current sense: 3.3 V at the A0 pin <-> 2 A, in A per count.
DEFAULT_CURRENT_SCALE = ADC_VOLTS_PER_COUNT * 2.0 / 3.3
#: AS5040 PWM output low-pass filtered to 0..5 V over one turn, in rad per count.
DEFAULT_ANGLE_SCALE = 2.0 * math.pi / 1024
#: Default angle zero: mid-scale (mount the magnet so the hanging rod reads near 512, away from the wrap).
DEFAULT_ANGLE_ZERO = 512.0
VOLTAGE_SOURCES = ('duty', 'adc')


@dataclass(frozen=True)
class Calibration:
    """Conversion of a SAMPLE's raw counts to SI units (and back, for emulators).

    Attributes
    ----------
    current_scale : float
        A per ADC count (default 5 V / 1024 * 2 A / 3.3 V).
    current_offset : float
        ADC counts read at zero current.
    angle_zero : float
        ADC counts read with the rod hanging at rest (angle 0).
    angle_scale : float
        rad per ADC count (negative to reverse the direction); default 2 pi / 1024.
    voltage_source : str
        ``'duty'``: armature voltage from the applied duty by eq (8) (the paper's choice: the H-bridge drop makes
        a direct reading unreliable); ``'adc'``: from the voltage divider input.
    voltage_scale : float
        V per ADC count of the divider input (``voltage_source='adc'``).
    voltage_offset : float
        ADC counts of the divider input at 0 V.
    duty_voltage : tuple of 4 floats
        k0 [V], k1 [V], k2, k3 of eq (8): Va = k0 + k1 sqrt(k2 duty + k3), 0 where negative or duty = 0.
    """

    current_scale: float = DEFAULT_CURRENT_SCALE
    current_offset: float = 0.0
    angle_zero: float = DEFAULT_ANGLE_ZERO
    angle_scale: float = DEFAULT_ANGLE_SCALE
    voltage_source: str = 'duty'
    voltage_scale: float = ADC_VOLTS_PER_COUNT
    voltage_offset: float = 0.0
    duty_voltage: tuple[float, float, float, float] = (
        DEFAULT_PARAMETERS.duty_voltage_k0, DEFAULT_PARAMETERS.duty_voltage_k1,
        DEFAULT_PARAMETERS.duty_voltage_k2, DEFAULT_PARAMETERS.duty_voltage_k3)

    def __post_init__(self) -> None:
        k0, k1, k2, k3 = (float(k) for k in self.duty_voltage)
        object.__setattr__(self, '_parameters', DEFAULT_PARAMETERS.replace(
            duty_voltage_k0=k0, duty_voltage_k1=k1, duty_voltage_k2=k2, duty_voltage_k3=k3))
        if self.voltage_source not in VOLTAGE_SOURCES:
            raise ProtocolError(f"voltage_source must be one of {VOLTAGE_SOURCES}, got {self.voltage_source!r}")
        for name in ('current_scale', 'angle_scale', 'voltage_scale'):
            value = getattr(self, name)
            if not math.isfinite(value) or value == 0.0:
                raise ProtocolError(f'{name} must be finite and non-zero, got {value!r}')

    def voltage_from_duty(self, duty: float) -> float:
        """Armature voltage [V] for a duty fraction by eq (8) (:meth:`RigParameters.voltage_from_duty`)."""
        return float(self._parameters.voltage_from_duty(duty))

    def to_si(self, sample: SampleFrame) -> tuple[float, float, float, float]:
        """``(angle rad, armature_voltage V, armature_current A, duty fraction)`` of one SAMPLE."""
        duty = sample.duty_q16 / 65535.0
        if self.voltage_source == 'duty':
            voltage = self.voltage_from_duty(duty)
        else:
            voltage = (sample.voltage_counts - self.voltage_offset) * self.voltage_scale
        return ((sample.angle_counts - self.angle_zero) * self.angle_scale, voltage,
                (sample.current_counts - self.current_offset) * self.current_scale, duty)

    def to_counts(self, angle: float, armature_current: float, armature_voltage: float = 0.0
                  ) -> tuple[int, int, int]:
        """Inverse conversion as an ideal 10-bit ADC would read it: ``(current, angle, voltage)`` counts.

        Rounded to the nearest count and clipped to 0..1023 (values beyond the ADC range saturate).
        """
        def count(value: float) -> int:
            return min(ADC_FULL_SCALE, max(0, round(value)))
        return (count(armature_current / self.current_scale + self.current_offset),
                count(angle / self.angle_scale + self.angle_zero),
                count(armature_voltage / self.voltage_scale + self.voltage_offset))
