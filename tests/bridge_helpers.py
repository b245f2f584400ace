"""Helpers for the rig-path tests: build the firmware, run it in the simavr harness, listen to the bridge.

``build_firmware(dir)`` runs ``make -C firmware BUILD=dir`` (avr-gcc + host gcc against libsimavr);
``Harness`` runs ``aeropend_harness`` (firmware on a pty, ADC inputs driven from the test, PWM pin measured);
``Listener`` is an in-test ROS node spun by its own thread, recording samples with receive times, diagnostics.
"""
from __future__ import annotations

import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from tests.ros_helpers import wait_for

ROOT = Path(__file__).resolve().parents[1]
FIRMWARE = ROOT / 'firmware'
#: Discovery plus the first message can take several seconds on a loaded machine (docs/ros.md section 4).
DISCOVERY_TIMEOUT = 25.0


def build_firmware(build_dir: Path) -> Path:
    """Compile the firmware (real chip + simavr variants), the harness and the protocol vector tool."""
    missing = [tool for tool in ('avr-gcc', 'avr-g++', 'avr-objcopy', 'make', 'cc') if shutil.which(tool) is None]
    if missing or not Path('/usr/include/simavr/sim_avr.h').exists():
        raise RuntimeError(f'firmware toolchain missing ({", ".join(missing) or "libsimavr-dev"}): '
                           'run `bash scripts/setup.sh` (installs gcc-avr avr-libc simavr libsimavr-dev ...)')
    result = subprocess.run(['make', '-C', str(FIRMWARE), f'BUILD={build_dir}'], capture_output=True, text=True,
                            check=False)
    if result.returncode != 0:
        raise RuntimeError(f'firmware build failed:\n{result.stdout}\n{result.stderr}')
    return build_dir


def poll(condition, timeout: float, period: float = 0.01) -> bool:
    """Poll `condition()` until true or `timeout` [s] passes (listeners spin in their own thread)."""
    return wait_for(condition, timeout, period=period)


class Harness:
    """The firmware in simavr with UART0 on a pty (see firmware/sim/harness.c)."""

    def __init__(self, build_dir: Path, link: Path, adc: dict[int, int] | None = None,
                 pwm_to_adc: int | None = None, firmware: str = 'aeropend_sim.elf',
                 options: list[str] | None = None) -> None:
        command = [str(build_dir / 'aeropend_harness'), str(build_dir / firmware), '--link', str(link),
                   *(options or [])]
        for channel, millivolts in (adc or {}).items():
            command += ['--adc', f'{channel}={millivolts}']
        if pwm_to_adc is not None:
            command += ['--pwm-to-adc', str(pwm_to_adc)]
        self.link = link
        #: (wall time read, sim time, duty, frequency, current sample-and-holds with the pin high, ... low, shortest
        #: and longest delay of the sample-and-hold after the Timer1 overflow [us] (-1 when none), the harness's
        #: time.monotonic() when it reported) per 0.5 s of simulated time
        self.pwm: list[tuple[float, ...]] = []
        self.log: list[str] = []
        self.process = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                        stderr=subprocess.STDOUT, text=True, bufsize=1)
        self.pty = None
        self._ready = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        if not self._ready.wait(10.0):
            self.stop()
            raise RuntimeError('harness did not start:\n' + '\n'.join(self.log))

    def _read(self) -> None:
        for line in self.process.stdout:
            self.log.append(line.rstrip())
            match = re.match(r'pty (\S+)', line)
            if match:
                self.pty = match.group(1)
                self._ready.set()
            match = re.match(r'pwm (\S+) (\S+) (\S+) (\S+) (\S+) (\S+) (\S+) (\S+)', line)
            if match:
                self.pwm.append((time.monotonic(), *(float(value) for value in match.groups())))

    def set_adc(self, channel: int, millivolts: int) -> None:
        self.process.stdin.write(f'adc {channel} {millivolts}\n')
        self.process.stdin.flush()

    def stop(self) -> None:
        if self.process.poll() is None:
            try:
                self.process.stdin.write('quit\n')
                self.process.stdin.flush()
            except (BrokenPipeError, ValueError):
                pass
            try:
                self.process.wait(5.0)
            except subprocess.TimeoutExpired:
                self.process.send_signal(signal.SIGKILL)
                self.process.wait()

    def __enter__(self) -> Harness:  # noqa: PYI034
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


class Listener:
    """In-test node on its own executor thread: samples (+ receive times), diagnostics, a duty publisher."""

    def __init__(self, context) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64

        from aeropend_ros import topics
        self.topics = topics
        self.Float64 = Float64
        self.node = rclpy.create_node('test_bridge_listener', context=context)
        self.samples: list = []
        self.receive_ns: list[int] = []
        self.diagnostics: list[dict[str, str]] = []
        self.diagnostic_stamps: list[float] = []     # header stamps [s] of the diagnostics messages
        self.diagnostic_levels: list[int] = []
        self.diagnostic_messages: list[str] = []
        # Best effort like the contract, with a deep queue so a slow Python listener does not drop.
        deep = QoSProfile(depth=5000, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.node.create_subscription(JointState, topics.SAMPLES_TOPIC, self._on_sample, deep)
        self.node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS_TOPIC, self._on_diagnostics,
                                      topics.diagnostics_qos())
        self.duty_publisher = self.node.create_publisher(Float64, topics.DUTY_COMMAND_TOPIC,
                                                         topics.command_qos())
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._running = True
        self._thread.start()

    def _spin(self) -> None:
        while self._running:
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception:
                if self._running:
                    raise
                return

    def _on_sample(self, msg) -> None:
        self.receive_ns.append(time.time_ns())
        self.samples.append(self.topics.msg_to_sample(msg))

    def _on_diagnostics(self, msg) -> None:
        for status in msg.status:
            if 'serial link' in status.name:
                self.diagnostic_stamps.append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
                self.diagnostics.append({kv.key: kv.value for kv in status.values})
                self.diagnostic_levels.append(int.from_bytes(status.level, 'little')
                                              if isinstance(status.level, bytes) else int(status.level))
                self.diagnostic_messages.append(status.message)

    def publish_duty(self, duty: float) -> None:
        self.duty_publisher.publish(self.Float64(data=float(duty)))

    def last_diagnostics(self) -> dict[str, str]:
        return self.diagnostics[-1] if self.diagnostics else {}

    def close(self) -> None:
        self._running = False
        self._thread.join(timeout=5.0)
        self.executor.shutdown()
        self.node.destroy_node()


#: `aeropend` as a child process (no console script needed), for the CLI-level tests.
AEROPEND = [sys.executable, '-c', 'import sys; from aeropend_core.cli import main; sys.exit(main())']


class EmulateProcess:
    """`aeropend emulate ARGUMENTS` as a child: standard output lines collected by a thread, Ctrl-C on exit.

    Entering waits (up to 60 s, a loaded machine) for the first line of standard output; after the block,
    ``returncode``, ``lines`` (all of standard output) and ``stderr`` hold what the process said.
    """

    def __init__(self, arguments: list[str]) -> None:
        self.arguments = arguments
        self.lines: list[str] = []
        self.stderr = ''
        self.returncode: int | None = None

    def __enter__(self) -> EmulateProcess:
        self.process = subprocess.Popen(AEROPEND + ['emulate', *self.arguments], cwd=ROOT, stdout=subprocess.PIPE,
                                        stderr=subprocess.PIPE, text=True)
        self._reader = threading.Thread(target=lambda: self.lines.extend(self.process.stdout), daemon=True)
        self._reader.start()
        if not poll(lambda: bool(self.lines) or self.process.poll() is not None, 60.0, period=0.05) \
                or not self.lines:
            self.__exit__(None, None, None)
            raise AssertionError(f'aeropend emulate printed nothing (exit {self.returncode}): {self.stderr[-500:]}')
        return self

    def __exit__(self, *exc_info) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        self.process.wait(timeout=30)
        self._reader.join(timeout=5)               # the reader thread owns stdout until its end
        self.stderr = self.process.stderr.read()
        self.returncode = self.process.returncode
