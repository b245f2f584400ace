"""The serial bridge node (a real process over DDS) on the pty device emulator, which streams the simulator's
physics as raw ADC frames and injects the faults of a real USB serial link.

* the emulator itself behaves like the firmware (clamping, watchdog, STATUS) and labels what it damaged;
* fuzz: > 1,000,000 bytes of garbage and damaged frames interleaved with the stream: the bridge keeps running,
  publishes exactly the intact frames and counts the rest;
* unplug/replug (pty closed and reopened behind the same name): publishing resumes within 5 s and the lost samples
  are reported; after a device reset the configuration is sent again and the stamps re-anchor;
* the Mega's auto-reset: the bridge writes nothing to a port whose device has not spoken (a bare pty: 0 bytes),
  starts the emulated Mega through its bootloader, and a client that writes at once leaves it in the bootloader.
"""
from __future__ import annotations

import os
import select
import time
import tty

import numpy as np
import pytest

from aeropend_core.rig import protocol as P
from aeropend_core.testing.device_emulator import DeviceEmulator
from tests.bridge_helpers import DISCOVERY_TIMEOUT, Listener, poll
from tests.ros_helpers import NodeProcess, own_context, private_domain_id, use_domain

DOMAIN_ID = private_domain_id()
use_domain(DOMAIN_ID)

pytestmark = pytest.mark.timeout(240)


def read_until(link, decoder, condition, timeout: float = 30.0, write=None) -> list:
    """Decode the link's frames until ``condition(messages)`` holds (a generous timeout: a loaded machine may
    delay the emulator or this reader; the condition, not a window, decides). Writes ``write`` between reads."""
    messages = []
    end = time.monotonic() + timeout
    while not condition(messages):
        assert time.monotonic() < end, f'condition not met within {timeout} s; last messages {messages[-3:]}'
        if write is not None:
            link.write(write)
        messages += decoder.feed(link.read(max(1, link.in_waiting)))
    return messages


def read_for(link, decoder, seconds: float) -> list:
    """Everything decoded from the link during `seconds` (only to show that nothing arrives: a silence check)."""
    messages = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        messages += decoder.feed(link.read(max(1, link.in_waiting)))
    return messages


def wait_for_frames(link, decoder, timeout: float = 10.0) -> list:
    """Read until the first valid frame (the way to talk to a Mega: let its bootloader time out first)."""
    messages = []
    end = time.monotonic() + timeout
    while not messages and time.monotonic() < end:
        messages = decoder.feed(link.read(max(1, link.in_waiting)))
    return messages


def test_emulator_behaves_like_the_firmware():
    import serial
    with DeviceEmulator(seed=11) as emulator, serial.Serial(emulator.port, 250000, timeout=0.02) as link:
        decoder = P.FrameDecoder()
        opened = time.monotonic()
        # Opening the port reset the emulated Mega: its bootloader stays silent for boot_delay, then the sketch
        # starts with a boot STATUS and sequence 0.
        first = wait_for_frames(link, decoder)
        assert time.monotonic() - opened >= emulator.config.boot_delay - 0.05
        assert emulator.state == 'running' and emulator.resets == 2          # power-up, then the open
        boot = next(m for m in first if isinstance(m, P.StatusFrame))
        assert boot.flags & P.FLAG_BOOT
        link.write(P.encode_command(P.SET_MAX_DUTY, 0.5) + P.encode_command(P.SET_WATCHDOG, 0.1))

        def configured(messages) -> bool:      # the STATUS with the new limits, then a clamped sample after it
            status = [k for k, m in enumerate(messages) if isinstance(m, P.StatusFrame)
                      and m.max_duty_q16 == P.duty_to_q16(0.5) and m.watchdog_ms == 100]
            return bool(status) and any(isinstance(m, P.SampleFrame) and m.duty_q16 == P.duty_to_q16(0.5)
                                        for m in messages[status[0]:])
        messages = read_until(link, decoder, configured, write=P.encode_command(P.SET_DUTY, 0.8))
        samples = [m for m in messages if isinstance(m, P.SampleFrame)]
        assert samples[-1].duty_q16 == P.duty_to_q16(0.5) and samples[-1].flags & P.FLAG_DUTY_CLAMPED
        # The simulated motor draws current at that duty (once it has spun up: wait for it, not a fixed time).
        messages = read_until(link, decoder, lambda ms: sum(isinstance(m, P.SampleFrame) for m in ms) > 200,
                              write=P.encode_command(P.SET_DUTY, 0.8))
        last = [m for m in messages if isinstance(m, P.SampleFrame)][-1]
        _, voltage, current, _ = P.Calibration().to_si(last)
        assert voltage == pytest.approx(P.Calibration().voltage_from_duty(0.5), abs=1e-3) and current > 0.1
        # Watchdog: silence (no command for more than its 0.1 s) cuts the duty and flags it.
        messages = read_until(link, decoder, lambda ms: any(isinstance(m, P.SampleFrame) and m.duty_q16 == 0
                                                            for m in ms))
        tripped = next(m for m in messages if isinstance(m, P.SampleFrame) and m.duty_q16 == 0)
        assert tripped.flags & P.FLAG_WATCHDOG_TRIPPED
        # Faults are labelled; damaged frames never decode.
        corrupt_before = decoder.counters.corrupt
        emulator.corrupt_frames(5)
        emulator.truncate_frames(5, keep_delimiter=False)

        def past_the_damage(messages) -> bool:
            damaged = set(emulator.sequences('corrupt')) | set(emulator.sequences('truncated'))
            return len(damaged) == 10 and any(isinstance(m, P.SampleFrame) and m.sequence > max(damaged) + 5
                                              for m in messages)
        messages = read_until(link, decoder, past_the_damage)
        damaged = set(emulator.sequences('corrupt')) | set(emulator.sequences('truncated'))
        received = {m.sequence for m in messages if isinstance(m, P.SampleFrame)}
        assert not received & damaged
        assert decoder.counters.corrupt - corrupt_before >= 10


def test_a_client_that_does_not_wait_keeps_the_mega_in_its_bootloader():
    """What the bridge used to do: configure right after opening. The bootloader takes the bytes as the start of a
    programming session and never starts the sketch; only the next reset (opening the port again) and silence
    bring it back."""
    import serial
    with DeviceEmulator(seed=14) as emulator:
        with serial.Serial(emulator.port, 250000, timeout=0.02) as link:
            link.write(P.encode_command(P.SET_MAX_DUTY, 0.7) + P.encode_command(P.SET_WATCHDOG, 0.5))
            decoder = P.FrameDecoder()
            messages = read_for(link, decoder, 3.0 * emulator.config.boot_delay)
            assert messages == [] and decoder.counters.bytes_received == 0      # not a byte in 3 s
            assert emulator.state == 'programming' and emulator.bootloader_bytes > 0
            assert emulator.sketch_starts == [] or emulator.sketch_starts[-1] < emulator.host_opens[-1]
        time.sleep(0.2)                  # the emulator looks at the port every ~20 ms: let it see the close
        with serial.Serial(emulator.port, 250000, timeout=0.02) as link:     # reset again, and wait this time
            messages = wait_for_frames(link, P.FrameDecoder())
            assert messages and emulator.state == 'running'


@pytest.fixture()
def ros_context():
    with own_context(DOMAIN_ID) as context:
        yield context


def quiescent_snapshot(listener: Listener, emulator: DeviceEmulator) -> dict[str, str]:
    """Hold the emulator's output and return the bridge's diagnostics once two reports show nothing new."""
    emulator.pause(4.0)
    time.sleep(0.2)                      # frames already in flight reach the bridge
    start = len(listener.diagnostics)

    def settled() -> bool:
        recent = listener.diagnostics[start:]
        return len(recent) >= 2 and recent[-1]['last_sequence'] == recent[-2]['last_sequence']
    assert poll(settled, 3.5), 'bridge did not settle'
    return listener.diagnostics[-1]


def test_bridge_fuzz_publishes_every_intact_frame(ros_context):
    with DeviceEmulator(seed=12) as emulator:
        listener = Listener(ros_context)
        with NodeProcess('aeropend_ros.serial_bridge_node', ['-p', f'port:={emulator.port}'],
                         domain_id=DOMAIN_ID) as bridge:
            try:
                assert poll(lambda: len(listener.samples) > 50, DISCOVERY_TIMEOUT), bridge.output()
                assert poll(lambda: listener.duty_publisher.get_subscription_count() > 0, DISCOVERY_TIMEOUT)
                listener.publish_duty(0.45)
                before = quiescent_snapshot(listener, emulator)
                time.sleep(4.0 - 0.2)
                assert poll(lambda: int(listener.last_diagnostics()['last_sequence']) > int(
                    before['last_sequence']), 5.0)

                # ~12 s: 2 kB of random bytes every ~20 ms, a bit flip and a truncation every ~100 ms.
                injected = 0
                start = time.monotonic()
                tick = 0
                while injected < 1_050_000 or time.monotonic() - start < 5.0:
                    emulator.inject_garbage(2100)
                    injected += 2100
                    if tick % 5 == 0:
                        emulator.corrupt_frames(1)
                        emulator.truncate_frames(1, keep_delimiter=tick % 10 == 0)
                        injected += 2 * (P.SAMPLE_WIRE_LENGTH + 2)
                    tick += 1
                    time.sleep(0.02)
                    assert bridge.process.poll() is None, bridge.output()
                    assert time.monotonic() - start < 60.0, 'fuzzing too slow'
                time.sleep(0.3)                  # the last damaged frames go out
                after = quiescent_snapshot(listener, emulator)
                assert bridge.process.poll() is None, bridge.output()
                assert after['connected'] == 'True'

                low, high = int(before['last_sequence']), int(after['last_sequence'])
                fates = {sequence: state for sequence, state in emulator.emitted if low < sequence <= high}
                intact = {s for s, state in fates.items() if state == 'intact'}
                damaged = {s for s, state in fates.items() if state in ('corrupt', 'truncated')}
                assert injected >= 1_000_000 and len(damaged) >= 200
                # Exactly the intact frames were published; the damaged ones show up as sequence gaps and
                # corrupt-frame counts (random garbage adds corrupt chunks of its own).
                published = int(after['samples_published']) - int(before['samples_published'])
                assert published == len(intact), (after, bridge.output()[-2000:])
                assert int(after['samples_lost']) - int(before['samples_lost']) == len(damaged)
                assert int(after['frames_corrupt']) - int(before['frames_corrupt']) >= len(damaged)
                # What the listener got is intact, never damaged, and nearly all of it (best-effort DDS).
                received = {s.sequence for s in listener.samples if low < s.sequence <= high}
                assert not received & damaged
                assert received <= intact
                assert len(received) >= 0.95 * len(intact)
                # Samples are physical values of the simulated rig at the commanded duty (commanded again: beside a
                # busy loop the device's watchdog may have cut the duty during the fuzzing, and no sample kept it).
                listener.publish_duty(0.45)
                assert poll(lambda: any(s.duty > 0.4 for s in listener.samples[-200:]), DISCOVERY_TIMEOUT)
                sample = next(s for s in reversed(listener.samples) if s.duty > 0.4)
                assert sample.armature_voltage == pytest.approx(P.Calibration().voltage_from_duty(sample.duty))
                assert 0.05 < sample.armature_current < 2.0
            finally:
                listener.close()


def test_bridge_survives_unplug_and_device_reset(ros_context):
    # A board without auto-reset (powered from elsewhere), so that an unplug without a reset can happen; the duty is
    # commanded once and held (command_timeout 0).
    with DeviceEmulator(seed=13, auto_reset=False) as emulator:
        listener = Listener(ros_context)
        with NodeProcess('aeropend_ros.serial_bridge_node',
                         ['-p', f'port:={emulator.port}', '-p', 'max_duty:=0.55', '-p', 'watchdog_timeout:=0.3',
                          '-p', 'command_timeout:=0.0'],
                         domain_id=DOMAIN_ID) as bridge:
            try:
                assert poll(lambda: len(listener.samples) > 50, DISCOVERY_TIMEOUT), bridge.output()
                assert poll(lambda: listener.duty_publisher.get_subscription_count() > 0, DISCOVERY_TIMEOUT)
                listener.publish_duty(0.5)
                assert poll(lambda: listener.samples[-1].duty > 0.49, 5.0), (listener.last_diagnostics(),
                                                                             bridge.output()[-2000:])
                assert emulator.max_duty_q16 == P.duty_to_q16(0.55) and emulator.watchdog_ms == 300

                # 1. Unplug for 1.5 s, replug; the device kept sampling (powered from elsewhere).
                last_before = listener.samples[-1].sequence
                emulator.unplug()
                time.sleep(1.5)                              # the outage itself
                emulator.replug(reset=False)
                replugged = time.monotonic()
                assert poll(lambda: listener.samples[-1].sequence > last_before + 700, 5.0), bridge.output()
                assert time.monotonic() - replugged < 5.0
                assert poll(lambda: listener.last_diagnostics().get('reconnects') == '1', 3.0)
                diagnostics = listener.last_diagnostics()
                lost = int(diagnostics['last_outage_lost'])
                # At least the 1.5 s unplugged, at most that plus the time to notice and reopen (< 5 s).
                assert 1.5 / P.SAMPLE_PERIOD * 0.95 < lost < 5.0 / P.SAMPLE_PERIOD
                assert int(diagnostics['samples_lost']) == lost
                assert 'samples lost during the outage' in bridge.output()
                # The watchdog (0.3 s) did not stop the motor for good: the heartbeat resumed.
                assert poll(lambda: listener.samples[-1].duty > 0.49, 3.0)

                # 2. Unplug and replug with a device reset (USB power cycle): configuration sent again.
                last_before = listener.samples[-1].sequence
                emulator.unplug()
                time.sleep(0.5)
                emulator.replug(reset=True)
                replugged = time.monotonic()
                assert poll(lambda: listener.samples[-1].sequence < last_before and listener.samples[-1].duty > 0.49,
                            5.0), bridge.output()
                assert time.monotonic() - replugged < 5.0
                assert emulator.max_duty_q16 == P.duty_to_q16(0.55) and emulator.watchdog_ms == 300
                assert poll(lambda: listener.last_diagnostics().get('device_resets') == '1', 3.0)
                # The loss estimate against the truth (the emulator logs every sample it produced): the old run's
                # samples after the last one the bridge published (the listener sees it: nothing follows it for the
                # outage, so its best-effort history keeps it), plus the new run's before the first one written to
                # the reopened port (the bridge reads every one of those; the listener may drop some of a burst).
                samples = list(listener.samples)
                index = max(i for i in range(1, len(samples)) if samples[i].sequence < samples[i - 1].sequence)
                with emulator._lock:
                    emitted = list(emulator.emitted)
                old_end = max(i for i, (q, _) in enumerate(emitted) if q == samples[index - 1].sequence)
                restart = next(i for i in range(old_end + 1, len(emitted)) if emitted[i][0] < emitted[i - 1][0])
                new_start = next(i for i in range(restart, len(emitted)) if emitted[i][1] == 'intact')
                truth = new_start - old_end - 1
                estimate = int(listener.last_diagnostics()['outage_samples_lost'])
                assert truth > 0.5 / P.SAMPLE_PERIOD * 0.9
                # The bridge promises an upper estimate: never below the truth (but for rounding), above it by the
                # delay of the new run's first read (the reset's own time is counted too; the emulator's is ~0).
                # A late read of the old run's last frame must not shorten it (it used to, by 0.18 s under load).
                assert truth - 2 <= estimate <= truth + 0.5 / P.SAMPLE_PERIOD, (estimate, truth)
                # Stamps re-anchored: increasing after the reset and close to the receive time.
                recent = samples[index:]
                stamps = np.array([s.stamp_ns for s in recent])
                receive = np.array(listener.receive_ns[index:index + len(recent)])
                assert np.all(np.diff(stamps) > 0)
                assert np.all(stamps <= receive) and np.median(receive - stamps) < 0.5e9
                assert bridge.process.poll() is None
            finally:
                listener.close()


def test_bridge_writes_nothing_until_the_device_talks(ros_context, tmp_path):
    """A bare pty with nobody talking on it: in 6 s the bridge writes 0 bytes (it used to write ~500: configuration
    and a heartbeat every 0.1 s, which keeps a Mega's bootloader from ever starting the sketch). Once a valid frame
    arrives (after the boot delay), the configuration follows."""
    master, slave = os.openpty()
    tty.setraw(slave)
    name = os.ttyname(slave)
    os.close(slave)                      # POLLHUP on the master until the bridge opens the port
    os.set_blocking(master, False)

    def port_open() -> bool:
        poller = select.poll()
        poller.register(master, select.POLLHUP)
        return not poller.poll(0)

    listener = Listener(ros_context)
    try:
        with NodeProcess('aeropend_ros.serial_bridge_node', ['-p', f'port:={name}'], domain_id=DOMAIN_ID) as bridge:
            assert poll(port_open, DISCOVERY_TIMEOUT), bridge.output()
            assert poll(lambda: listener.diagnostics and listener.last_diagnostics()['connected'] == 'True',
                        DISCOVERY_TIMEOUT), bridge.output()
            opened = time.monotonic()
            assert listener.last_diagnostics()['device_talking'] == 'False'
            written = bytearray()
            while time.monotonic() - opened < 6.0:         # the measurement window: the 6 s
                try:
                    written += os.read(master, 4096)
                except BlockingIOError:
                    time.sleep(0.05)
            assert len(written) == 0, written[:64]
            assert port_open() and bridge.process.poll() is None
            assert 'no valid frame from' in bridge.output()            # it says why it is waiting

            # The device speaks: one STATUS and a few samples. The bridge configures it.
            frames = P.encode_status(P.StatusFrame(P.PROTOCOL_VERSION, P.PWM_PHASE_CORRECT, P.FLAG_BOOT, 255,
                                                   P.duty_to_q16(0.7), 500, 0, 0, 0))
            frames += b''.join(P.encode_sample(P.SampleFrame(k, 0, 512, 0, 0, 0)) for k in range(5))
            os.write(master, frames)
            decoder = P.FrameDecoder(accept_commands=True)
            commands = []

            def configured() -> bool:
                try:
                    commands.extend(decoder.feed(os.read(master, 4096)))
                except BlockingIOError:
                    pass
                return any(isinstance(c, P.CommandFrame) and c.kind == P.SET_WATCHDOG for c in commands)
            assert poll(configured, 10.0), bridge.output()
            kinds = [c.kind for c in commands]
            assert kinds[:4] == [P.SET_MAX_DUTY, P.SET_WATCHDOG, P.SET_DUTY, P.REQUEST_STATUS]
            assert commands[0].value == P.duty_to_q16(0.7) and commands[1].value == 500
    finally:
        listener.close()
        os.close(master)


def test_bridge_starts_the_emulated_mega(ros_context):
    """Port opened -> the emulated Mega resets, its bootloader listens in silence, the sketch starts, and only then
    does the bridge configure it and send duty commands. Its resonator runs 0.5 % slow: the bridge's default clock
    limit (0.6 %) follows it, and the stamps are spaced by the device's true period."""
    with DeviceEmulator(seed=15, clock_ppm=5000.0) as emulator:
        listener = Listener(ros_context)
        try:
            with NodeProcess('aeropend_ros.serial_bridge_node',
                             ['-p', f'port:={emulator.port}', '-p', 'watchdog_timeout:=0.4'],
                             domain_id=DOMAIN_ID) as bridge:
                assert poll(lambda: len(listener.samples) > 50, DISCOVERY_TIMEOUT), bridge.output()
                assert emulator.state == 'running' and emulator.bootloader_bytes == 0
                assert len(emulator.host_opens) == 1 and emulator.resets == 2     # power-up and the open
                started = emulator.sketch_starts[-1]
                assert started - emulator.host_opens[0] >= emulator.config.boot_delay - 0.05
                with emulator._lock:
                    commands = list(emulator.commands)
                assert commands and commands[0][0] >= started                      # nothing before the sketch
                assert poll(lambda: emulator.watchdog_ms == 400, 5.0)                # configured
                assert poll(lambda: listener.last_diagnostics().get('device_talking') == 'True', 5.0)
                # The bridge published the run from the sketch's sequence 0 (the listener itself may join later).
                # Judged on a status from after the clock's priming (the first ~0.1 s of reads are held back, then
                # published): beside a CPU hog the latest status read here had been sent during it (published 0 of
                # sequence 9) although 50 samples had arrived since.
                assert poll(lambda: int(listener.last_diagnostics().get('samples_published', '0')) > 0,
                            DISCOVERY_TIMEOUT), listener.last_diagnostics()
                diagnostics = listener.last_diagnostics()
                assert diagnostics['samples_lost'] == '0' and diagnostics['device_resets'] == '0', diagnostics
                assert int(diagnostics['samples_published']) >= int(diagnostics['last_sequence']) - 1, diagnostics
                # Clock: the drift estimate within 500 ppm of the truth, and (once the line has caught up, ~10 s)
                # the stamps of the last second spaced by the device's period (1.005 Ts), not the nominal one.
                assert poll(lambda: abs(float(listener.last_diagnostics().get('clock_drift_ppm', 0)) - 5000) < 500,
                            25.0), listener.last_diagnostics()

                def spacing() -> float:
                    recent = listener.samples[-490:]
                    steps = np.diff([s.stamp_ns for s in recent]) * 1e-9 / np.diff([s.sequence for s in recent])
                    return float(np.median(steps))
                assert poll(lambda: len(listener.samples) > 980 and
                            abs(spacing() / (P.SAMPLE_PERIOD * 1.005) - 1) < 5e-4, 30.0, period=0.2), spacing()
        finally:
            listener.close()
