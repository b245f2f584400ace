"""The serial bridge in closed loop, a real process over DDS, on the pty device emulator (which runs the firmware's
closed loop with the Python law): gains as parameters sent and acknowledged, the reference topic, the telemetry on
aeropend/control from CONTROL_SAMPLE frames, gains changed at run time, invalid gains refused with the reason,
back to open loop. (The same commands on the real firmware in simavr: tests/test_firmware_sim.py.)"""
from __future__ import annotations

import numpy as np
import pytest

from aeropend_core.control import law
from aeropend_core.control.feedforward import static_duty
from aeropend_core.rig.control_link import device_coefficients
from aeropend_core.testing.device_emulator import DeviceEmulator
from tests.ros_helpers import NodeProcess, own_context, private_domain_id, use_domain

DOMAIN_ID = private_domain_id()
use_domain(DOMAIN_ID)

from std_msgs.msg import Float64MultiArray  # noqa: E402

from tests.control_helpers import Watcher  # noqa: E402

pytestmark = pytest.mark.timeout(300)

START_TIMEOUT = 120.0


def test_bridge_runs_the_device_closed_loop():
    gains = law.PidGains(u_clamp_max=0.6)
    with own_context(DOMAIN_ID) as context, DeviceEmulator(seed=8, auto_reset=False) as emulator:
        watcher = Watcher(context)
        bridge = NodeProcess('aeropend_ros.serial_bridge_node',
                             ['-p', f'port:={emulator.port}', '-p', 'control_mode:=closed_loop',
                              '-p', 'u_clamp_max:=0.6', '-p', 'boot_delay:=0.2',
                              '-p', 'clock_max_drift:=0.05'],     # a loaded machine paces the emulator late
                             domain_id=DOMAIN_ID)
        try:
            # The gains go out, are acknowledged, and the device closes the loop: telemetry flows.
            assert watcher.wait_for(lambda: len(watcher.control) > 50 or bridge.process.poll() is not None,
                                    START_TIMEOUT) and len(watcher.control) > 50, bridge.output()
            assert emulator.control_mode == 1
            np.testing.assert_array_equal(emulator.law_coefficients, device_coefficients(gains))
            assert (emulator.angle_zero_counts, emulator.angle_rad_per_count) == (512.0, np.float32(2 * np.pi / 1024))

            # A reference with its feedforward: forwarded, in the telemetry, and the rod follows it.
            feedforward = static_duty(0.5, emulator.simulator.parameters)
            watcher.reference.publish(Float64MultiArray(data=[0.5, feedforward]))
            assert watcher.wait_for(lambda: watcher.control[max(watcher.control)][0] == np.float32(0.5)), \
                bridge.output()
            start = max(watcher.control)
            assert watcher.wait_for(lambda: max(watcher.control) > start + 4 * 490, 60.0)
            end = max(watcher.control)
            # the samples come on their own topic: on a loaded machine they arrive after the telemetry (at a load
            # average of 20 only 42 of the last second's 490 had come when the telemetry reached its end)
            last_second = range(end - 490, end)
            watcher.wait_for(lambda: sum(k in watcher.samples for k in last_second) > 400, 60.0)
            angles = np.array([watcher.samples[k].angle for k in last_second if k in watcher.samples])
            assert len(angles) > 100 and np.mean(angles) == pytest.approx(0.5, abs=0.05), len(angles)
            row = watcher.control[end]
            assert row[1] == pytest.approx(feedforward, abs=1e-6) and row[5] == 0.0
            assert 0.0 < row[2] <= 0.6 + 1e-4                            # duty within u_clamp_max
            # The telemetry's duty is the sample's duty, and its integral is the device's (emulator's) state.
            common = [k for k in range(end - 100, end) if k in watcher.samples and k in watcher.control]
            assert common and all(watcher.control[k][2] == watcher.samples[k].duty for k in common)

            # Gains at run time: checked together, then sent and acknowledged.
            results = watcher.set(p=0.6)
            assert results[0].successful
            assert watcher.wait_for(lambda: emulator.law_coefficients[law.P] == np.float32(0.6)), bridge.output()
            results = watcher.set(u_clamp_min=0.9)
            assert not results[0].successful and 'u_clamp_min' in results[0].reason, results[0].reason
            assert emulator.law_coefficients[law.U_MIN] == 0.0
            # An unacceptable reference is refused by the bridge (outside the angle window): the device keeps 0.5.
            watcher.reference.publish(Float64MultiArray(data=[2.5, 0.3]))
            last = max(watcher.control)
            assert watcher.wait_for(lambda: max(watcher.control) > last + 100)
            assert watcher.control[max(watcher.control)][0] == np.float32(0.5)

            # Open loop again: duty 0 on the device, plain samples, no more telemetry.
            assert watcher.set(control_mode='open_loop')[0].successful
            assert watcher.wait_for(lambda: emulator.control_mode == 0), bridge.output()
            # samples already on their way when the mode changed may still carry the loop's duty: wait for the first
            # duty 0, then every later sample must keep it
            assert watcher.wait_for(lambda: watcher.samples[max(watcher.samples)].duty == 0.0), bridge.output()
            first_zero = max(watcher.samples)
            assert watcher.wait_for(lambda: max(watcher.samples) > first_zero + 200)
            assert all(sample.duty == 0.0 for k, sample in watcher.samples.items() if k >= first_zero)
            assert max(watcher.control) < max(watcher.samples) - 100
        finally:
            output = bridge.output()
            bridge.stop()
            watcher.close()
    assert 'the device refused' not in output, output
