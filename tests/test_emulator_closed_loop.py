"""The pty device emulator's closed loop (protocol version 2), as the firmware does it: every command answered by an
ACK with the firmware's result codes, the Python law on the emulated angle (replayed here sample by sample), the rod
held at the reference, the angle trip latched until a new reference, the watchdog halting the law, SET_DUTY and
SET_CONTROL_MODE 0 back to open loop. No ROS; pyserial on the emulator's pty (tests/test_firmware_sim.py does the
same on the real firmware in simavr)."""
from __future__ import annotations

import time

import numpy as np
import pytest

from aeropend_core.control import law
from aeropend_core.control.feedforward import static_duty
from aeropend_core.rig import protocol as P
from aeropend_core.rig.control_link import device_coefficients, send_gains
from aeropend_core.testing.device_emulator import DeviceEmulator
from tests.control_helpers import (
    Device,
    check_refusals_after_gains,
    check_refusals_before_gains,
    check_thirteen_coefficients_close_the_loop,
)

pytestmark = pytest.mark.timeout(120)


def keep_alive(device: Device, seconds: float, samples: int = 0) -> list:
    """Read for `seconds` and until `samples` control samples came (a loaded machine paces the emulator late; at most
    60 s more), sending REQUEST_STATUS every 0.1 s (the bridge's closed-loop keep-alive)."""
    new = []
    end, limit = time.monotonic() + seconds, time.monotonic() + seconds + 60.0
    while time.monotonic() < end or (sum(isinstance(m, P.ControlSampleFrame) for m in new) < samples
                                     and time.monotonic() < limit):
        device.link.write(P.encode_command(P.REQUEST_STATUS))
        new += device.read(0.1)
    return new


def test_emulator_runs_the_closed_loop_like_the_firmware():
    import serial
    with DeviceEmulator(seed=5, auto_reset=False) as emulator, \
            serial.Serial(emulator.port, 250000, timeout=0.02) as link:
        device = Device(link)
        status = device.status()
        assert status.protocol_version == 2 and not status.flags & P.FLAG_CLOSED_LOOP
        link.write(P.encode_command(P.SET_WATCHDOG, 30.0))
        check_refusals_before_gains(device)

        refusal_gains = law.PidGains(p=0.8, i=0.0, d=0.0, u_clamp_max=0.6, i_clamp_min=-0.2, i_clamp_max=0.2)
        check_thirteen_coefficients_close_the_loop(device, refusal_gains)   # b = 1 from boot: need not be sent
        send_gains(link, refusal_gains, decoder=device.decoder, messages=device.messages)
        check_refusals_after_gains(device)
        gains = law.PidGains(u_clamp_max=0.6, setpoint_weight=0.7)          # b < 1: the integral still settles it
        acks = send_gains(link, gains, decoder=device.decoder, messages=device.messages)
        coefficients = device_coefficients(gains)
        assert all(np.float32(a.value) == np.float32(coefficients[i]) for i, a in acks.items())
        calibration = emulator.calibration
        assert device.ack(P.encode_angle_calibration(calibration.angle_zero, calibration.angle_scale)).ok
        reference = 0.5
        feedforward = static_duty(reference, emulator.simulator.parameters)
        assert device.ack(P.encode_reference(reference, feedforward)).ok
        ack = device.ack(P.encode_control_mode(P.MODE_CLOSED_LOOP))
        assert (ack.result, ack.value) == (P.ACK_OK, 1.0)
        ack = device.ack(P.encode_angle_calibration(500.0, 0.006))
        assert (ack.result, ack.value) == (P.ACK_REFUSED, calibration.angle_zero)

        # 4 s of closed loop: the law replayed on the reported angles gives the reported values and duties, and
        # the rod settles at the reference.
        keep_alive(device, 4.0, samples=1600)
        closed_at = max(k for k, m in enumerate(device.messages) if isinstance(m, P.AckFrame)
                        and m.command == P.SET_CONTROL_MODE and m.ok and m.value == 1.0)
        samples = [m for m in device.messages[closed_at:] if isinstance(m, P.ControlSampleFrame)]
        assert len(samples) > 1500
        sequences = [s.sequence for s in samples]
        assert sequences == list(range(sequences[0], sequences[0] + len(sequences)))
        state = law.new_state()
        scale, zero = np.float32(calibration.angle_scale), np.float32(calibration.angle_zero)
        for k, sample in enumerate(samples):
            angle = float((np.float32(sample.angle_counts) - zero) * scale)
            duty = law.law_step(coefficients, state, sample.reference, sample.feedforward, angle)
            assert sample.unsaturated == np.float32(state[law.UNSATURATED]), k
            assert sample.integral == np.float32(state[law.INTEGRAL]), k
            assert sample.flags & P.FLAG_CLOSED_LOOP and not sample.tripped
            if k + 1 < len(samples):                        # the duty applies from the next sample
                q16 = 0 if not duty > 0 else int(duty * 65535.0 + 0.5)
                assert samples[k + 1].duty_q16 == min(q16, status.max_duty_q16), k
        angles = np.array([(s.angle_counts - calibration.angle_zero) * calibration.angle_scale for s in samples])
        assert np.mean(angles[-490:]) == pytest.approx(reference, abs=0.05)

        # The trip: angle_max lowered below the rod -> duty 0 at once, latched after angle_max is restored.
        assert device.ack(P.encode_coefficient(law.ANGLE_MAX, 0.3)).ok
        new = [m for m in keep_alive(device, 0.5) if isinstance(m, P.ControlSampleFrame)]
        tripped = [m for m in new if m.tripped]
        assert tripped and all(m.duty_q16 == 0 for m in tripped[2:]) and tripped[-1].unsaturated == 0.0
        assert device.ack(P.encode_coefficient(law.ANGLE_MAX, 1.75)).ok
        new = [m for m in keep_alive(device, 0.5, samples=150) if isinstance(m, P.ControlSampleFrame)]
        assert len(new) > 100 and all(m.tripped and m.duty_q16 == 0 for m in new)
        assert device.status().flags & P.FLAG_LAW_TRIPPED
        assert device.ack(P.encode_reference(reference, feedforward)).ok
        new = [m for m in keep_alive(device, 0.5) if isinstance(m, P.ControlSampleFrame)]
        assert not new[-1].tripped and new[-1].duty_q16 > 0

        # The watchdog (0.3 s): silence cuts the duty and halts the law; a keep-alive does not restart it.
        link.write(P.encode_command(P.SET_WATCHDOG, 0.3))
        # (waits for the condition: at load ~9 the emulator's frames came later than 2 s, s26)
        new = device.read(30.0, until=lambda ms: sum(isinstance(m, P.ControlSampleFrame)
                                                     and m.flags & P.FLAG_WATCHDOG_TRIPPED for m in ms) > 30)
        cut = [m for m in new if isinstance(m, P.ControlSampleFrame) and m.flags & P.FLAG_WATCHDOG_TRIPPED]
        assert len(cut) > 30 and all(m.duty_q16 == 0 for m in cut[1:])
        new = [m for m in keep_alive(device, 0.3) if isinstance(m, P.ControlSampleFrame)]
        assert all(m.flags & P.FLAG_WATCHDOG_TRIPPED and m.duty_q16 == 0 for m in new)
        # Neither does a new timeout; a new reference does. The long timeout keeps a loaded machine's pause of
        # more than 0.3 s between two keep-alives from tripping it again while the restart is read.
        link.write(P.encode_command(P.SET_WATCHDOG, 30.0))
        new = [m for m in keep_alive(device, 0.2) if isinstance(m, P.ControlSampleFrame)]
        assert all(m.flags & P.FLAG_WATCHDOG_TRIPPED and m.duty_q16 == 0 for m in new)
        assert device.ack(P.encode_reference(reference, feedforward)).ok
        new = [m for m in keep_alive(device, 0.2) if isinstance(m, P.ControlSampleFrame)]
        assert not new[-1].flags & P.FLAG_WATCHDOG_TRIPPED and new[-1].duty_q16 > 0

        # SET_DUTY: open loop again; closed, then SET_CONTROL_MODE 0: open loop at duty 0.
        link.write(P.encode_command(P.SET_DUTY, 0.3))
        new = device.samples(20, P.SampleFrame)
        assert new[-1].duty_q16 == P.duty_to_q16(0.3) and not new[-1].flags & P.FLAG_CLOSED_LOOP
        assert device.ack(P.encode_control_mode(P.MODE_CLOSED_LOOP)).ok
        device.samples(20)
        assert device.ack(P.encode_control_mode(P.MODE_OPEN_LOOP)).ok
        new = device.samples(20, P.SampleFrame)
        assert new[-1].duty_q16 == 0
        assert device.decoder.counters.corrupt == 0 and device.status().rx_bad_frames == 0
        assert [a.result for a in emulator.acks].count(P.ACK_OK) >= 2 * 14     # two gain sets and the rest
