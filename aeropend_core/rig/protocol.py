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

Closed loop (protocol version 2)
~~~~~~~~~~~~~~~~~~~~~~~~~~~~~~~~
The firmware runs the controller law of :mod:`aeropend_core.control.law` (``law_step``, in single precision:
``firmware/aeropend/aeropend_control.h``) once per sample on the angle it has just measured, and applies the duty
from the next PWM period (clamped to the maximum duty). Open loop (the ``SET_DUTY`` behaviour above) is the mode at
boot. Host -> device, float32 little-endian::

    SET_CONTROL_COEFFICIENT (0x14)  u8 type | u8 index 0..13 | f32 value          (6 bytes)
    SET_REFERENCE           (0x15)  u8 type | f32 reference [rad] | f32 feedforward duty [0..1]   (9 bytes)
    SET_CONTROL_MODE        (0x16)  u8 type | u16 mode (0 open loop, 1 closed loop)                (3 bytes)
    SET_ANGLE_CALIBRATION   (0x17)  u8 type | f32 zero [counts] | f32 scale [rad/count]           (9 bytes)

The index is the coefficient layout of ``law.PidGains.coefficients`` (P, I_TS, D_POLE, D_GAIN, I_MIN, I_MAX, U_MIN,
U_MAX, AW_CODE, AW_GAIN, FF_GAIN, ANGLE_MIN, ANGLE_MAX, SETPOINT_WEIGHT), computed on the host at
:data:`SAMPLE_PERIOD`; SETPOINT_WEIGHT (b, in [0, 1]) is 1 at boot (the plain PID) and need not be sent. The angle is
``(angle_counts - zero) * scale`` (defaults 0 counts and 2 pi / 1024 rad/count). The device answers *each* of these
four commands with an ``ACK`` (type 0x03, 8 bytes)::

    u8 type | u8 command type | u8 index | u8 result | f32 value

``index`` is the coefficient's (0 for the other commands); ``value`` is what the device holds after the command: the
coefficient, the reference, the mode, the zero of the calibration (unchanged when refused; 0 for an unknown index).
``result``: ``ACK_OK`` 0; ``ACK_OUT_OF_RANGE`` 1 (a non-finite value; a negative gain; D_POLE outside [0, 1); AW_CODE
not 0, 1 or 2; SETPOINT_WEIGHT outside [0, 1]; I_MIN > I_MAX, U_MIN/U_MAX outside 0 <= U_MIN <= U_MAX <= 1 or ANGLE_MIN
>= ANGLE_MAX against the other limit as stored; a reference outside [ANGLE_MIN, ANGLE_MAX] or a feedforward outside [0,
1]; a zero scale; a mode other than 0 or 1); ``ACK_UNKNOWN_INDEX`` 2; ``ACK_REFUSED`` 3 (closed loop before the first 13
coefficients have been set since boot; an angle calibration while the loop runs). A refused command does not feed the
watchdog; an accepted one does.

Safety: an angle outside [ANGLE_MIN, ANGLE_MAX] sets the duty to 0 and *trips* the law (``FLAG_LAW_TRIPPED``,
latched) until the next accepted ``SET_REFERENCE`` or ``SET_CONTROL_MODE`` 1, which restart the law (integral 0,
derivative unprimed). The watchdog stays: in closed loop the host must keep sending valid commands (the bridge sends
``REQUEST_STATUS`` every 100 ms); when it expires the duty is 0 and the law stops until the next accepted
``SET_REFERENCE`` or ``SET_CONTROL_MODE`` 1. ``SET_DUTY`` in closed loop switches the device back to open loop (and
applies the duty): a host that only knows version 1 can always stop the motor with ``SET_DUTY 0``.
``SET_CONTROL_MODE`` 0 sets the duty to 0. ``SET_REFERENCE`` is accepted in open loop too (stored for later).

In closed loop every sample is a ``CONTROL_SAMPLE`` (type 0x04, 30 bytes) instead of a ``SAMPLE``::

    SAMPLE's 14 bytes (type 0x04) | f32 reference | f32 feedforward | f32 unsaturated | f32 integral

``duty_q16`` is, as in SAMPLE, the duty applied during this sample (the law's output of the previous one); the four
floats are the law's inputs and its state after this sample's step (its duty applies from the next sample); flags
gain ``FLAG_LAW_TRIPPED`` and ``FLAG_CLOSED_LOOP`` (also in STATUS). Link budget at 250000 baud 8N1 (25,000 B/s):
a CONTROL_SAMPLE is 35 bytes on the wire (30 + CRC 2 + COBS 1 + two delimiters), 490.196 x 35 = 17,157 B/s
(68.6 %); with STATUS at 1 Hz plus one per keep-alive REQUEST_STATUS at 10 Hz (11 x 23 = 253 B/s) 69.6 %, below
the 80 % ceiling. (SAMPLE: 19 bytes, 9,314 B/s, 37 %.)
"""
from __future__ import annotations

import binascii
import math
import struct
from dataclasses import dataclass, field
from typing import NamedTuple

from aeropend_core.model.parameters import DEFAULT_PARAMETERS

__all__ = [
    'ACK',
    'ACK_OK',
    'ACK_OUT_OF_RANGE',
    'ACK_REFUSED',
    'ACK_RESULTS',
    'ACK_UNKNOWN_INDEX',
    'ADC_FULL_SCALE',
    'CONTROL_SAMPLE',
    'CONTROL_SAMPLE_WIRE_LENGTH',
    'DEFAULT_DEVICE_ANGLE_SCALE',
    'DEFAULT_DEVICE_ANGLE_ZERO',
    'DELIMITER',
    'FLAG_BOOT',
    'FLAG_CLOSED_LOOP',
    'FLAG_DUTY_CLAMPED',
    'FLAG_LAW_TRIPPED',
    'FLAG_SAMPLES_DROPPED',
    'FLAG_WATCHDOG_TRIPPED',
    'MODE_CLOSED_LOOP',
    'MODE_OPEN_LOOP',
    'PROTOCOL_VERSION',
    'PWM_FAST',
    'PWM_PHASE_CORRECT',
    'PWM_TOP',
    'REQUEST_STATUS',
    'SAMPLE',
    'SAMPLE_PERIOD',
    'SAMPLE_WIRE_LENGTH',
    'SET_ANGLE_CALIBRATION',
    'SET_CONTROL_COEFFICIENT',
    'SET_CONTROL_MODE',
    'SET_DUTY',
    'SET_MAX_DUTY',
    'SET_REFERENCE',
    'SET_WATCHDOG',
    'STATUS',
    'WATCHDOG_MS_RANGE',
    'AckFrame',
    'AngleCalibrationCommand',
    'Calibration',
    'CoefficientCommand',
    'CommandFrame',
    'ControlSampleFrame',
    'DecoderCounters',
    'FrameDecoder',
    'ProtocolError',
    'ReferenceCommand',
    'SampleFrame',
    'StatusFrame',
    'cobs_decode',
    'cobs_encode',
    'crc16',
    'decode_message',
    'duty_to_q16',
    'encode_ack',
    'encode_angle_calibration',
    'encode_coefficient',
    'encode_command',
    'encode_control_mode',
    'encode_control_sample',
    'encode_reference',
    'encode_sample',
    'encode_status',
    'frame',
    'q16_to_duty',
]

PROTOCOL_VERSION = 2
DELIMITER = b'\x00'

# Message types.
SAMPLE = 0x01
STATUS = 0x02
ACK = 0x03
CONTROL_SAMPLE = 0x04
SET_DUTY = 0x10
SET_MAX_DUTY = 0x11
SET_WATCHDOG = 0x12
REQUEST_STATUS = 0x13
SET_CONTROL_COEFFICIENT = 0x14
SET_REFERENCE = 0x15
SET_CONTROL_MODE = 0x16
SET_ANGLE_CALIBRATION = 0x17
#: Commands in the ``u8 type | u16 value`` format.
COMMAND_TYPES = (SET_DUTY, SET_MAX_DUTY, SET_WATCHDOG, REQUEST_STATUS, SET_CONTROL_MODE)
#: Commands the device answers with an ACK.
ACKED_COMMANDS = (SET_CONTROL_COEFFICIENT, SET_REFERENCE, SET_CONTROL_MODE, SET_ANGLE_CALIBRATION)

# SET_CONTROL_MODE values.
MODE_OPEN_LOOP = 0
MODE_CLOSED_LOOP = 1

# ACK results.
ACK_OK = 0             #: accepted and stored
ACK_OUT_OF_RANGE = 1   #: a non-finite value or one outside its limits (module docstring)
ACK_UNKNOWN_INDEX = 2  #: no coefficient with that index
ACK_REFUSED = 3        #: not in this state: closed loop before the gains (0..12) are set; calibration in closed loop
ACK_RESULTS = {ACK_OK: 'ok', ACK_OUT_OF_RANGE: 'out of range', ACK_UNKNOWN_INDEX: 'unknown index',
               ACK_REFUSED: 'refused in this mode'}
#: The device's angle calibration at boot: zero [counts] and scale [rad/count].
DEFAULT_DEVICE_ANGLE_ZERO = 0.0
DEFAULT_DEVICE_ANGLE_SCALE = 2.0 * math.pi / 1024

# Bits of the ``flags`` byte (SAMPLE and STATUS).
FLAG_WATCHDOG_TRIPPED = 0x01  #: motor cut because no command arrived within the watchdog time
FLAG_DUTY_CLAMPED = 0x02      #: the last SET_DUTY asked for more than the maximum duty
FLAG_SAMPLES_DROPPED = 0x04   #: the transmit buffer was full: samples before this one were not sent
FLAG_BOOT = 0x08              #: set in the STATUS sent right after reset
FLAG_LAW_TRIPPED = 0x10       #: closed loop: the angle left [ANGLE_MIN, ANGLE_MAX], duty 0 (latched)
FLAG_CLOSED_LOOP = 0x20       #: closed loop runs (CONTROL_SAMPLE and STATUS)

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
_CONTROL_SAMPLE = struct.Struct('<BIHHHHBffff')
_ACK = struct.Struct('<BBBBf')
_COEFFICIENT = struct.Struct('<BBf')
_TWO_FLOATS = struct.Struct('<Bff')
_CRC = struct.Struct('<H')
#: Encoded length (without delimiters) of each device message: COBS adds one byte to payloads < 254 bytes.
SAMPLE_WIRE_LENGTH = _SAMPLE.size + 2 + 1
STATUS_WIRE_LENGTH = _STATUS.size + 2 + 1
CONTROL_SAMPLE_WIRE_LENGTH = _CONTROL_SAMPLE.size + 2 + 1
#: Longest encoded message; a run of non-zero bytes longer than this is garbage.
MAX_WIRE_LENGTH = max(SAMPLE_WIRE_LENGTH, STATUS_WIRE_LENGTH, CONTROL_SAMPLE_WIRE_LENGTH, _COMMAND.size + 3,
                      _TWO_FLOATS.size + 3)


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
    """One host -> device command in the u16 format: SET_DUTY, SET_MAX_DUTY, SET_WATCHDOG, REQUEST_STATUS or
    SET_CONTROL_MODE."""

    kind: int
    value: int


class ControlSampleFrame(NamedTuple):
    """One CONTROL_SAMPLE (closed loop): a SAMPLE's fields plus the law's reference, feedforward, unsaturated output
    and integral after this sample's step (float32 values)."""

    sequence: int
    current_counts: int
    angle_counts: int
    voltage_counts: int
    duty_q16: int
    flags: int
    reference: float
    feedforward: float
    unsaturated: float
    integral: float

    @property
    def duty(self) -> float:
        """Applied duty fraction 0..1 (during this sample: the law's output of the previous one)."""
        return self.duty_q16 / 65535.0

    @property
    def tripped(self) -> bool:
        return bool(self.flags & FLAG_LAW_TRIPPED)

    @property
    def sample(self) -> SampleFrame:
        """The SAMPLE part (for code that handles both)."""
        return SampleFrame(*self[:6])


class AckFrame(NamedTuple):
    """The device's answer to SET_CONTROL_COEFFICIENT, SET_REFERENCE, SET_CONTROL_MODE or SET_ANGLE_CALIBRATION."""

    command: int
    index: int
    result: int
    value: float

    @property
    def ok(self) -> bool:
        return self.result == ACK_OK

    def describe(self) -> str:
        return (f'ACK of 0x{self.command:02x}[{self.index}]: {ACK_RESULTS.get(self.result, self.result)}, '
                f'value {self.value!r}')


class CoefficientCommand(NamedTuple):
    """SET_CONTROL_COEFFICIENT as the device receives it."""

    index: int
    value: float
    kind: int = SET_CONTROL_COEFFICIENT


class ReferenceCommand(NamedTuple):
    """SET_REFERENCE as the device receives it."""

    reference: float
    feedforward: float
    kind: int = SET_REFERENCE


class AngleCalibrationCommand(NamedTuple):
    """SET_ANGLE_CALIBRATION as the device receives it."""

    zero_counts: float
    rad_per_count: float
    kind: int = SET_ANGLE_CALIBRATION


def _pack(layout: struct.Struct, *values) -> bytes:
    try:
        return layout.pack(*values)
    except (OverflowError, struct.error) as error:
        raise ProtocolError(f'cannot encode {values!r}: {error}') from None


def encode_coefficient(index: int, value: float) -> bytes:
    """Wire bytes of SET_CONTROL_COEFFICIENT (`value` rounded to float32; the device checks it, not this)."""
    if not 0 <= int(index) <= 255:
        raise ProtocolError(f'coefficient index must fit a byte, got {index!r}')
    return frame(_pack(_COEFFICIENT, SET_CONTROL_COEFFICIENT, int(index), float(value)))


def encode_reference(reference: float, feedforward: float = 0.0) -> bytes:
    """Wire bytes of SET_REFERENCE: reference angle [rad], feedforward duty [fraction]."""
    return frame(_pack(_TWO_FLOATS, SET_REFERENCE, float(reference), float(feedforward)))


def encode_control_mode(mode: int) -> bytes:
    """Wire bytes of SET_CONTROL_MODE (MODE_OPEN_LOOP or MODE_CLOSED_LOOP; other values reach the device, which
    refuses them)."""
    return frame(_pack(_COMMAND, SET_CONTROL_MODE, int(mode)))


def encode_angle_calibration(zero_counts: float, rad_per_count: float) -> bytes:
    """Wire bytes of SET_ANGLE_CALIBRATION: angle = (angle_counts - zero_counts) * rad_per_count."""
    return frame(_pack(_TWO_FLOATS, SET_ANGLE_CALIBRATION, float(zero_counts), float(rad_per_count)))


def encode_ack(ack: AckFrame) -> bytes:
    """Wire bytes of an ACK (device side: emulators)."""
    return frame(_pack(_ACK, ACK, *ack))


def encode_control_sample(sample: ControlSampleFrame) -> bytes:
    """Wire bytes of a CONTROL_SAMPLE (device side: emulators)."""
    return frame(_pack(_CONTROL_SAMPLE, CONTROL_SAMPLE, *sample))


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


def decode_message(encoded: bytes):
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
    message = _decode_v2(body)
    if message is not None:
        return message
    raise ProtocolError(f'unknown message type 0x{kind:02x} or wrong length {len(body)}')


def _decode_v2(body: bytes, commands: bool = True):
    """The version-2 messages (ACK, CONTROL_SAMPLE, the float commands when `commands`), or None."""
    kind, length = body[0], len(body)
    if kind == CONTROL_SAMPLE and length == _CONTROL_SAMPLE.size:
        return ControlSampleFrame(*_CONTROL_SAMPLE.unpack(body)[1:])
    if kind == ACK and length == _ACK.size:
        return AckFrame(*_ACK.unpack(body)[1:])
    if not commands:
        return None
    if kind == SET_CONTROL_COEFFICIENT and length == _COEFFICIENT.size:
        return CoefficientCommand(*_COEFFICIENT.unpack(body)[1:])
    if kind == SET_REFERENCE and length == _TWO_FLOATS.size:
        return ReferenceCommand(*_TWO_FLOATS.unpack(body)[1:])
    if kind == SET_ANGLE_CALIBRATION and length == _TWO_FLOATS.size:
        return AngleCalibrationCommand(*_TWO_FLOATS.unpack(body)[1:])
    return None


@dataclass
class DecoderCounters:
    """Link-health counters of a :class:`FrameDecoder` (all cumulative)."""

    bytes_received: int = 0
    messages: int = 0   #: valid messages of any type
    samples: int = 0    #: valid SAMPLE and CONTROL_SAMPLE messages
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
                message = _decode_v2(payload[:-2], self.accept_commands)
                if message is None:
                    corrupt += 1
                else:
                    append(message)
                    if kind == CONTROL_SAMPLE:
                        samples += 1
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
