"""aeropend_core.rig.protocol: framing, CRC, message layouts, the streaming decoder (fuzzed), calibration; and the
drift-corrected sample clock. Pure Python, no ROS, no serial port."""
from __future__ import annotations

import math
import random

import numpy as np
import pytest

from aeropend_core.rig import protocol as P
from aeropend_core.rig.sample_clock import SampleClock


def crc16_bitwise(data: bytes) -> int:
    """Independent CRC-16/CCITT-FALSE, bit by bit."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def test_crc16_check_value_and_independent_implementation():
    assert P.crc16(b'123456789') == 0x29B1
    rng = random.Random(1)
    for _ in range(200):
        data = rng.randbytes(rng.randrange(0, 40))
        assert P.crc16(data) == crc16_bitwise(data)


@pytest.mark.parametrize(('raw', 'encoded'), [
    (b'', b'\x01'),
    (b'\x00', b'\x01\x01'),
    (b'\x00\x00', b'\x01\x01\x01'),
    (b'\x11\x22\x00\x33', b'\x03\x11\x22\x02\x33'),
    (b'\x11\x22\x33\x44', b'\x05\x11\x22\x33\x44'),
    (b'\x11\x00\x00\x00', b'\x02\x11\x01\x01\x01'),
    (bytes(range(1, 255)), b'\xff' + bytes(range(1, 255)) + b'\x01'),
])
def test_cobs_reference_vectors(raw, encoded):
    """Vectors of the COBS paper / Wikipedia article."""
    assert P.cobs_encode(raw) == encoded
    assert P.cobs_decode(encoded) == raw


def test_cobs_round_trip_random():
    rng = random.Random(2)
    for _ in range(500):
        size = rng.choice([0, 1, 2, 5, 16, 253, 254, 255, 300, 600])
        raw = bytes(rng.choice([0, 0, rng.randrange(256)]) for _ in range(size))
        encoded = P.cobs_encode(raw)
        assert b'\x00' not in encoded
        if size < 254:
            assert len(encoded) == size + 1
        assert P.cobs_decode(encoded) == raw


def test_cobs_decode_rejects_bad_input():
    with pytest.raises(P.ProtocolError):
        P.cobs_decode(b'\x05\x11\x22')      # block runs past the end
    with pytest.raises(P.ProtocolError):
        P.cobs_decode(b'\x02\x11\x00\x01')  # zero inside


def test_message_round_trips():
    sample = P.SampleFrame(0xDEADBEEF, 1023, 0, 512, 65535, P.FLAG_WATCHDOG_TRIPPED)
    wire = P.encode_sample(sample)
    assert wire[0] == 0 and wire[-1] == 0 and b'\x00' not in wire[1:-1]
    assert len(wire) == P.SAMPLE_WIRE_LENGTH + 2 == 19
    assert P.decode_message(wire[1:-1]) == sample
    status = P.StatusFrame(1, P.PWM_FAST, P.FLAG_BOOT, 509, 45875, 500, 3, 4, 123456)
    assert P.decode_message(P.encode_status(status)[1:-1]) == status
    command = P.encode_command(P.SET_DUTY, 0.5)
    assert P.decode_message(command[1:-1]) == P.CommandFrame(P.SET_DUTY, 32768)
    assert P.decode_message(P.encode_command(P.SET_WATCHDOG, 0.25)[1:-1]) == P.CommandFrame(P.SET_WATCHDOG, 250)


def test_command_range_errors():
    with pytest.raises(P.ProtocolError, match='fraction'):
        P.encode_command(P.SET_DUTY, 1.5)
    with pytest.raises(P.ProtocolError, match='watchdog'):
        P.encode_command(P.SET_WATCHDOG, 0.001)
    with pytest.raises(P.ProtocolError, match='unknown'):
        P.encode_command(0x55, 0)


def test_decode_message_rejects_corruption():
    wire = bytearray(P.encode_sample(P.SampleFrame(7, 1, 2, 3, 4, 0)))
    wire[5] ^= 0x10
    with pytest.raises(P.ProtocolError):
        P.decode_message(bytes(wire[1:-1]))


def test_decoder_is_split_invariant():
    messages = [P.SampleFrame(i, i % 1024, (3 * i) % 1024, 0, (i * 97) % 65536, i % 16) for i in range(300)]
    stream = b''.join(P.encode_sample(m) for m in messages)
    stream += P.encode_status(P.StatusFrame(1, 0, 0, 255, 1, 2, 3, 4, 5))
    whole = P.FrameDecoder().feed(stream)
    assert whole[:300] == messages and isinstance(whole[300], P.StatusFrame)
    decoder = P.FrameDecoder()
    pieces = []
    rng = random.Random(3)
    index = 0
    while index < len(stream):
        step = rng.randrange(1, 40)
        pieces += decoder.feed(stream[index:index + step])
        index += step
    assert pieces == whole
    assert decoder.counters.corrupt == 0 and decoder.counters.samples == 300


def build_fuzz_stream(seed: int, n_frames: int, garbage_bytes: int):
    """Valid frames interleaved with garbage, bit flips, truncations and long zero-free runs.

    Returns the stream, the intact frames in order, the number of damaged frames and the total bytes of noise
    (garbage + damaged frames).
    """
    rng = random.Random(seed)
    parts = []
    intact = []
    damaged = 0
    noise = 0
    budget = garbage_bytes
    for sequence in range(n_frames):
        if rng.random() < 0.6 and budget > 0:
            kind = rng.random()
            if kind < 0.7:
                blob = rng.randbytes(rng.randrange(1, 400))                     # random, zeros included
            elif kind < 0.9:
                blob = bytes(rng.randrange(1, 256) for _ in range(rng.randrange(30, 600)))  # no zeros: oversize
            else:
                blob = b'\x00' * rng.randrange(1, 10)                            # runs of delimiters
            parts.append(blob)
            budget -= len(blob)
            noise += len(blob)
        frame = P.SampleFrame(sequence, rng.randrange(1024), rng.randrange(1024), rng.randrange(1024),
                              rng.randrange(65536), rng.randrange(16))
        wire = P.encode_sample(frame)
        fate = rng.random()
        if fate < 0.08:          # one bit flipped inside the frame
            data = bytearray(wire)
            data[rng.randrange(1, len(data) - 1)] ^= 1 << rng.randrange(8)
            parts.append(bytes(data))
            damaged += 1
            noise += len(data)
        elif fate < 0.12:        # truncated, with or without its closing delimiter
            cut = rng.randrange(2, len(wire) - 1)
            parts.append(wire[:cut] + (b'\x00' if rng.random() < 0.5 else b''))
            damaged += 1
            noise += cut
        else:
            parts.append(wire)
            intact.append(frame)
    return b''.join(parts), intact, damaged, noise


def test_fuzz_every_intact_frame_recovered_and_corruption_counted():
    """>= 1,000,000 bytes of garbage and damaged frames interleaved with valid frames."""
    stream, intact, damaged, noise = build_fuzz_stream(seed=4, n_frames=12000, garbage_bytes=1_100_000)
    assert noise >= 1_000_000
    decoder = P.FrameDecoder()
    rng = random.Random(5)
    recovered = []
    index = 0
    while index < len(stream):      # arbitrary read sizes, like a serial port
        step = rng.choice([1, 7, 64, 512, 4096])
        recovered += decoder.feed(stream[index:index + step])
        index += step
    recovered_samples = [m for m in recovered if isinstance(m, P.SampleFrame)]
    # Every intact frame, in order, and nothing else (a damaged frame passing CRC-16 would show up here).
    assert recovered_samples == intact
    assert decoder.counters.samples == len(intact)
    # Each damaged frame is counted at least once (garbage adds more).
    assert decoder.counters.corrupt >= damaged
    assert decoder.counters.oversize > 0


def test_calibration_round_trip_and_defaults():
    calibration = P.Calibration()
    # Shield current sense: 3.3 V <-> 2 A on a 5 V, 10-bit ADC.
    counts = round(3.3 / 5.0 * 1024)
    angle, voltage, current, duty = calibration.to_si(P.SampleFrame(0, counts, 512 + 256, 0, 65535, 0))
    assert current == pytest.approx(2.0, abs=calibration.current_scale)
    assert angle == pytest.approx(math.pi / 2)
    assert duty == 1.0
    assert voltage == pytest.approx(2.3187, abs=1e-3)   # eq (8) at duty 1
    assert calibration.voltage_from_duty(0.7) == pytest.approx(1.89, abs=0.01)
    assert calibration.voltage_from_duty(0.0) == 0.0
    current_counts, angle_counts, _ = calibration.to_counts(-0.3, 0.8, 1.5)
    back = calibration.to_si(P.SampleFrame(0, current_counts, angle_counts, 0, 0, 0))
    assert back[0] == pytest.approx(-0.3, abs=calibration.angle_scale / 2)
    assert back[2] == pytest.approx(0.8, abs=calibration.current_scale / 2)
    adc = P.Calibration(voltage_source='adc', voltage_scale=0.02, voltage_offset=10, angle_scale=-0.01,
                        angle_zero=100)
    angle, voltage, _, _ = adc.to_si(P.SampleFrame(0, 0, 90, 110, 0, 0))
    assert voltage == pytest.approx(2.0) and angle == pytest.approx(0.1)
    assert adc.to_counts(10.0, 100.0, 1000.0) == (1023, 0, 1023)   # saturates like the ADC


def test_calibration_rejects_bad_values():
    with pytest.raises(P.ProtocolError, match='voltage_source'):
        P.Calibration(voltage_source='shunt')
    with pytest.raises(P.ProtocolError, match='current_scale'):
        P.Calibration(current_scale=0.0)


@pytest.mark.parametrize(('ppm', 'max_drift'), [(150.0, 2e-4), (-400.0, 1e-3)])
def test_sample_clock_tracks_drift_and_ignores_late_bursts(ppm, max_drift):
    rng = np.random.default_rng(6)
    period = P.SAMPLE_PERIOD
    n = 490 * 90
    sequence = np.arange(n) + 1000
    acquisition = 5000.0 + (sequence - 1000) * period * (1 + ppm * 1e-6)
    min_latency = 0.0008
    arrival = acquisition + min_latency + rng.exponential(0.003, n)
    arrival[20000:20300] = acquisition[20300] + 0.4      # a stalled host: 300 samples arrive in one burst
    clock = SampleClock(period, max_drift=max_drift)
    # As the bridge does: observe the first 50 arrivals before stamping them (the envelope needs a few).
    for s, a in zip(sequence[:50], arrival[:50]):
        clock.observe(int(s), float(a))
    stamps = clock.place([int(s) for s in sequence[:50]])
    stamps = np.array(stamps + [clock.stamp(int(s), float(a)) for s, a in zip(sequence[50:], arrival[50:])])
    assert np.all(np.diff(stamps) >= 0.6 * period - 1e-9)   # evenly spaced: never piled up
    assert np.all(stamps <= arrival)                     # acquisition never after arrival
    assert clock.drift_ppm == pytest.approx(ppm, abs=20.0)
    error = stamps - acquisition - min_latency
    # After the estimate settles the stamps are the acquisition times (+ the minimum latency) within 0.1 ms,
    # while arrival times scatter by milliseconds (and 0.4 s in the burst).
    assert np.max(np.abs(error[-490 * 30:])) < 1e-4
    assert np.max(np.abs(error[20000:20300])) < 1e-3
    assert np.std(arrival - acquisition) > 10 * np.std(error[-490 * 30:])
    clock.reset()
    assert clock.stamp(0, 9000.0) == pytest.approx(9000.0)


def test_sample_clock_stays_even_through_a_stalled_host():
    """The host stalls for 3 s (every sample 15-40 ms late), twice: stamps stay evenly spaced and recover."""
    rng = np.random.default_rng(8)
    period = P.SAMPLE_PERIOD
    n = 490 * 80
    sequence = np.arange(n)
    acquisition = 100.0 + sequence * period * (1 + 60e-6)
    arrival = acquisition + 0.0005 + rng.exponential(0.002, n)
    for start in (490 * 12, 490 * 40):
        arrival[start:start + 490 * 3] += rng.uniform(0.015, 0.040, 490 * 3)
    clock = SampleClock(period)
    stamps = np.array([clock.stamp(int(s), float(a)) for s, a in zip(sequence, arrival)])
    steps = np.diff(stamps)
    assert np.all(np.abs(steps - period) < 0.5 * period)        # what the diagnosis requires of a recording
    assert np.max(np.abs(stamps - acquisition - 0.0005)[-490 * 10:]) < 3e-4


def test_sample_clock_spreads_a_backlog_read_at_once():
    """A port opened on a running device returns a backlog in one read: stamps go back by sequence x Ts."""
    period = P.SAMPLE_PERIOD
    clock = SampleClock(period)
    backlog = list(range(100, 300))
    stamps = clock.stamp_many(backlog, 50.0)
    assert stamps[-1] == pytest.approx(50.0)
    assert np.allclose(np.diff(stamps), period)
    later = clock.stamp_many([300, 301, 302], 50.0 + 3 * period + 0.0004)
    assert np.allclose(np.diff([stamps[-1], *later]), period)


def test_envelope_arrival_is_the_least_delayed_line_not_the_last_read():
    """The bridge measures a device reset's gap from the old run's end on the envelope line: a last read that came
    0.2 s late (a loaded host) must not move that end, and asking changes nothing."""
    rng = np.random.default_rng(3)
    period = P.SAMPLE_PERIOD
    clock = SampleClock(period)
    assert clock.envelope_arrival(0) is None
    sequence = np.arange(490 * 5)
    arrival = 20.0 + sequence * period + 0.0005 + rng.exponential(0.002, sequence.size)
    arrival[-10:] += 0.2
    for chunk in np.array_split(np.arange(sequence.size), sequence.size // 10):
        clock.stamp_many(sequence[chunk].tolist(), float(arrival[chunk[-1]]))
    last = int(sequence[-1])
    end = clock.envelope_arrival(last)
    assert end == clock.envelope_arrival(last)
    assert 20.0 + last * period <= end < 20.0 + last * period + 0.003
    assert arrival[-1] - end > 0.19


@pytest.mark.parametrize('error', [+5e-3, -5e-3])
def test_sample_clock_follows_a_ceramic_resonator(error):
    """The Mega 2560's resonator 0.5 % slow or fast, read in USB-like blocks of ~10 samples with jitter and a
    stalled host: with the defaults (limit +-0.6 %) the stamps are within 2 ms of the acquisition times from 10 s on
    and after 60 s, and the drift estimate is right."""
    rng = np.random.default_rng(21)
    period = P.SAMPLE_PERIOD
    n = 490 * 70
    sequence = np.arange(n)
    acquisition = 300.0 + sequence * period * (1 + error)
    min_latency = 0.001
    clock = SampleClock(period)
    assert clock.max_drift == pytest.approx(6e-3)
    stamps = np.empty(n)
    start = 0
    while start < n:
        stop = min(n, start + int(rng.integers(5, 16)))
        arrival = acquisition[stop - 1] + min_latency + rng.exponential(0.0015)
        if 490 * 30 <= start < 490 * 32:
            arrival += rng.uniform(0.02, 0.05)         # the host stalls for 2 s
        stamps[start:stop] = clock.stamp_many([int(s) for s in sequence[start:stop]], arrival)
        start = stop
    error_s = stamps - acquisition - min_latency
    settled = acquisition - acquisition[0] >= 10.0
    assert np.max(np.abs(error_s[settled])) < 2e-3, np.max(np.abs(error_s[settled]))
    assert np.max(np.abs(error_s[acquisition - acquisition[0] >= 60.0])) < 2e-3
    assert clock.drift_ppm == pytest.approx(error * 1e6, abs=50.0)
    assert np.all(np.diff(stamps) > 0.5 * period)      # still evenly spaced


# ---------------------------------------------------------------------------------------------- protocol version 2
def test_closed_loop_messages_round_trip_and_layout():
    ack = P.AckFrame(P.SET_CONTROL_COEFFICIENT, 7, P.ACK_OUT_OF_RANGE, 0.75)
    control = P.ControlSampleFrame(12345, 1, 552, 3, 26453, P.FLAG_CLOSED_LOOP | P.FLAG_LAW_TRIPPED, 0.5, 0.375,
                                   -0.25, 0.125)          # (float32-exact values: they round-trip unchanged)
    commands = [P.encode_coefficient(3, 0.5), P.encode_reference(0.5, 0.2), P.encode_control_mode(1),
                P.encode_angle_calibration(512.0, 2 * math.pi / 1024)]
    # Payload sizes (type included): ACK 8, CONTROL_SAMPLE 30, commands 6 / 9 / 3 / 9.
    assert [len(P.cobs_decode(b[1:-1])) - 2 for b in [P.encode_ack(ack), P.encode_control_sample(control),
                                                       *commands]] == [8, 30, 6, 9, 3, 9]
    assert len(P.encode_control_sample(control)) == P.CONTROL_SAMPLE_WIRE_LENGTH + 2 == 35
    assert P.decode_message(P.encode_ack(ack)[1:-1]) == ack
    assert P.decode_message(P.encode_control_sample(control)[1:-1]) == control
    assert control.sample == P.SampleFrame(12345, 1, 552, 3, 26453, control.flags) and control.tripped
    assert P.decode_message(commands[0][1:-1]) == P.CoefficientCommand(3, 0.5)
    assert P.decode_message(commands[2][1:-1]) == P.CommandFrame(P.SET_CONTROL_MODE, 1)
    decoded = P.decode_message(commands[3][1:-1])
    assert decoded.rad_per_count == np.float32(2 * math.pi / 1024) and decoded.zero_counts == 512.0
    # The host decoder: device messages always, commands only when asked; CONTROL_SAMPLEs count as samples.
    stream = b''.join([P.encode_ack(ack), P.encode_control_sample(control), *commands])
    host = P.FrameDecoder()
    assert host.feed(b'\x00' + stream) == [ack, control] and host.counters.corrupt == 4
    assert host.counters.samples == 1
    device = P.FrameDecoder(accept_commands=True)
    assert len(device.feed(b'\x00' + stream)) == 6 and device.counters.corrupt == 0
    # Non-finite values travel (the device refuses them); values beyond float32 do not.
    assert math.isnan(P.decode_message(P.encode_coefficient(0, math.nan)[1:-1]).value)
    with pytest.raises(P.ProtocolError):
        P.encode_coefficient(0, 1e40)
    with pytest.raises(P.ProtocolError):
        P.encode_coefficient(256, 1.0)
    assert P.PROTOCOL_VERSION == 2


def test_gains_upload_checks_every_ack_and_orders_limits():
    from aeropend_core.control import law
    from aeropend_core.rig.control_link import GainsUpload, device_coefficients

    gains = law.PidGains(angle_min=1.8, angle_max=2.5)
    upload = GainsUpload(gains)
    values = device_coefficients(gains)
    sent = P.FrameDecoder(accept_commands=True).feed(b'\x00' + upload.start())
    assert [c.index for c in sent] == list(range(law.N_COEFFICIENTS)) and law.N_COEFFICIENTS == 14
    assert all(np.float32(c.value) == np.float32(values[c.index]) for c in sent)
    # The device still holds angle_max 1.75: angle_min 1.8 refused, resent once angle_max is in.
    for index in range(law.N_COEFFICIENTS):
        if index == law.ANGLE_MIN:
            assert upload.accept(P.AckFrame(P.SET_CONTROL_COEFFICIENT, index, P.ACK_OUT_OF_RANGE, -0.35)) == b''
            continue
        resend = upload.accept(P.AckFrame(P.SET_CONTROL_COEFFICIENT, index, P.ACK_OK, float(values[index])))
        assert (resend != b'') == (index == law.ANGLE_MAX)
        if index == law.ANGLE_MAX:
            angle_min_again = resend
    assert not upload.done
    assert P.decode_message(angle_min_again[1:-1]) == P.CoefficientCommand(law.ANGLE_MIN, np.float32(1.8))
    upload.accept(P.AckFrame(P.SET_CONTROL_COEFFICIENT, law.ANGLE_MIN, P.ACK_OK, float(values[law.ANGLE_MIN])))
    assert upload.done and upload.error is None
    # A wrong stored value or any other refusal is an error.
    upload = GainsUpload(gains)
    upload.accept(P.AckFrame(P.SET_CONTROL_COEFFICIENT, law.P, P.ACK_OK, 0.25))
    assert 'stored 0.25' in upload.error
    upload = GainsUpload(gains)
    upload.accept(P.AckFrame(P.SET_CONTROL_COEFFICIENT, law.AW_CODE, P.ACK_OUT_OF_RANGE, 0.0))
    assert 'out of range' in upload.error and not upload.done
