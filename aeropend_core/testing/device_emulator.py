"""A fake rig on a pseudo-terminal: the firmware's serial behaviour, the simulator's physics, injectable faults.

:class:`DeviceEmulator` opens a pty, points a stable symlink at it (like ``/dev/serial/by-id/...``), and streams
SAMPLE frames at the firmware's 490.196 Hz in real time. The measured values come from
:class:`aeropend_core.sim.simulate.RigSimulator` (hidden effects and measurement noise as configured), converted to raw
ADC counts through the rig's analog front end (:mod:`aeropend_core.testing.measurement_chain`: the angle's RC
filter and encoder wrap, the current read at the hold instant of a PWM-resolved armature current, ADC noise) and the
inverse of the bridge's :class:`~aeropend_core.rig.protocol.Calibration` (``chain=None``: ideal counts).
Commands written to the port behave as on the firmware: SET_DUTY clamped to the maximum duty, a watchdog that cuts
the duty when no valid command arrives in time (checked every emission, ~20 ms), STATUS on boot, after
configuration and every second. The closed loop of protocol version 2 too (the firmware's rules, the docstring of
:mod:`aeropend_core.rig.protocol`): SET_CONTROL_COEFFICIENT, SET_REFERENCE, SET_CONTROL_MODE and
SET_ANGLE_CALIBRATION, each answered by an ACK with the firmware's result codes; in closed loop the Python law
(:func:`aeropend_core.control.law.law_step`, on float32-rounded coefficients) runs once per sample on the angle
counts just produced, its duty applies from the next sample, and CONTROL_SAMPLE frames replace SAMPLE frames (the
angle trip latched until a new reference, the watchdog halting the law, SET_DUTY back to open loop).

Faults (all thread-safe, take effect at the next emission):

* :meth:`inject_garbage` random bytes between frames;
* :meth:`corrupt_frames` flip one random bit in each of the next N frames;
* :meth:`truncate_frames` cut each of the next N frames short (its closing delimiter is kept or dropped);
* :meth:`tamper_frames` send the next frames with changed fields *and a valid CRC* (what a damaged frame that
  passes CRC-16 looks like: a sequence number +100000, an ADC count of 65535);
* :meth:`pause` stop writing for a while (frames delayed and delivered in a burst, or lost);
* :attr:`locked_rotor` hold the propeller (for the locked-rotor calibration: Ia = Va / Ra in steady state);
* :meth:`unplug` / :meth:`replug` close the pty and open a new one behind the same symlink, optionally resetting
  the device (sequence back to 0, configuration back to defaults: what a USB power cycle does).

Every emitted sample is logged in :attr:`emitted` as ``(sequence, state)`` with state ``'intact'``, ``'corrupt'``,
``'truncated'``, ``'tampered'`` or ``'lost'`` (not written: paused with loss, unplugged, or no program has the port
open), so tests know the truth (``keep_log=False`` keeps only the counts, for long runs: :meth:`samples_sent`).

**Auto-reset and bootloader** (``auto_reset=True``, the default: an Arduino Mega 2560). Opening the port asserts DTR,
which resets the board; the stk500v2 bootloader then listens for ``config.boot_delay`` (~1 s) and answers nothing.
If no byte arrives in that time it starts the sketch (sequence 0, STATUS with the boot flag, samples); if any byte
arrives it stays in programming mode and never starts the sketch, until the next reset (the port opened again).
:attr:`state` is ``'bootloader'``, ``'programming'`` or ``'running'``; :attr:`resets` counts resets and
:attr:`bootloader_bytes` the bytes the bootloader swallowed. While no program has the port open nothing is written
(the USB-serial chip drops it). ``auto_reset=False`` is a board whose auto-reset is disabled (or a device powered
from elsewhere): it streams from :meth:`start` on, whoever opens the port. Opening and closing are noticed at the
emulator's emission cadence (~20 ms): a close and reopen within that time is one open.

No ROS or serial library is needed: the emulator uses ``os.openpty``.
"""
from __future__ import annotations

import math
import os
import random
import select
import threading
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from aeropend_core.control import law
from aeropend_core.rig import protocol as P
from aeropend_core.sim.simulate import RigSimulator
from aeropend_core.testing.measurement_chain import MeasurementChain

__all__ = ['DeviceEmulator', 'EmulatorConfig']

def _f32(value):
    """Rounded to float32 (as the firmware stores it), returned as float64."""
    return np.asarray(value, dtype=np.float32).astype(np.float64)


def _encode(sample) -> bytes:
    return P.encode_control_sample(sample) if isinstance(sample, P.ControlSampleFrame) else P.encode_sample(sample)


#: Bytes the emulated device keeps when the host does not read (bounded, like a USB-serial link; generous so
#: that bursts after a pause reach a reader intact).
DEVICE_BUFFER = 1 << 16


@dataclass
class EmulatorConfig:
    """Firmware defaults mirrored by the emulator (see firmware/aeropend/aeropend.ino)."""

    max_duty: float = 0.70
    watchdog_timeout: float = 0.5   #: s
    pwm_mode: int = P.PWM_PHASE_CORRECT
    status_every: int = 490         #: samples
    boot_delay: float = 1.0         #: s the bootloader listens (silent) after a reset before starting the sketch


@dataclass
class _Faults:
    garbage: bytearray = field(default_factory=bytearray)
    corrupt: int = 0
    truncate: int = 0
    truncate_keep_delimiter: bool = True
    pause_until: float = 0.0
    pause_drop: bool = False
    tamper: list = field(default_factory=list)


class DeviceEmulator:
    """Pty-backed fake rig streaming simulated samples (see module docstring).

    Parameters
    ----------
    link : path, optional
        Symlink to create to the pty slave (the port name a bridge opens); default: a name in a fresh temporary
        directory. Replugging keeps this name while the pty behind it changes.
    simulator : RigSimulator, optional
        Source of the physics; default ``RigSimulator(sample_time=protocol.SAMPLE_PERIOD)``.
    calibration : Calibration
        Conversion SI -> counts; the bridge must use the same one to read back the simulator's values.
    config : EmulatorConfig
        Firmware defaults (maximum duty, watchdog timeout).
    seed : int
        Seed of the fault-injection random generator.
    block : int
        Samples simulated per emission (default 10: one write every ~20 ms, like USB bulk transfers).
    clock_ppm : float
        Deviation of the emulated clock from nominal (positive = the device samples slower), parts per million
        (the Mega 2560's ceramic resonator: up to ~5000).
    auto_reset : bool
        Model the Mega's DTR auto-reset and bootloader (see the module docstring); default True.
    keep_log : bool
        Log every emitted sample in :attr:`emitted` (default True; False for long runs).
    chain : MeasurementChain or None
        The analog front end between the physics and the counts (default: the rig's, see
        :mod:`aeropend_core.testing.measurement_chain`); None sends the ideal counts of the simulator's values.
    """

    def __init__(self, link: str | os.PathLike | None = None, simulator: RigSimulator | None = None,
                 calibration: P.Calibration | None = None, config: EmulatorConfig | None = None,
                 seed: int = 0, block: int = 10, clock_ppm: float = 0.0, auto_reset: bool = True,
                 chain: MeasurementChain | None = MeasurementChain(),  # noqa: B008 - frozen settings
                 keep_log: bool = True) -> None:
        if link is None:
            import tempfile
            self._tmpdir = tempfile.mkdtemp(prefix='aeropend-emu-')
            link = Path(self._tmpdir) / 'ttyAEROPEND0'
        else:
            self._tmpdir = None
        self.link = Path(link)
        self.simulator = simulator or RigSimulator(sample_time=P.SAMPLE_PERIOD)
        self.calibration = calibration or P.Calibration()
        self.config = config or EmulatorConfig()
        self.sample_period = P.SAMPLE_PERIOD * (1.0 + clock_ppm * 1e-6)
        self.block = int(block)
        self.rng = random.Random(seed)
        self.emitted: list[tuple[int, str]] = []
        self.commands: list[tuple[float, P.CommandFrame]] = []
        self.samples_written = 0
        self.keep_log = bool(keep_log)
        self._sent = 0
        self._lost = 0
        self.bytes_written = 0
        #: Largest delay [s] of a write's newest sample behind its schedule: a real board's UART sends on time, this
        #: Python thread can write late on a loaded host, and a reader cannot tell that from a slower clock.
        self.write_lateness_max = 0.0
        self._lock = threading.RLock()
        self._faults = _Faults()
        self._master = -1
        self._slave = -1
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._decoder = P.FrameDecoder(accept_commands=True)
        self._held = bytearray()
        #: Hold the propeller (locked-rotor calibration): no back-EMF, no thrust.
        self.locked_rotor = False
        self._locked_current = 0.0
        self.auto_reset = bool(auto_reset)
        self.chain = chain
        self._front_end = chain.start(self.calibration, self.simulator.parameters, self.config.pwm_mode,
                                      seed) if chain is not None else None
        #: 'bootloader' (silent after a reset), 'programming' (bytes arrived during it: stuck), 'running' (sketch)
        self.state = 'running'
        #: resets of the board (power-up included) when `auto_reset`
        self.resets = 0
        self.bootloader_bytes = 0
        #: times [s, time.monotonic] at which a program opened the port, and at which the sketch started
        self.host_opens: list[float] = []
        self.sketch_starts: list[float] = []
        self._host_open = False
        self._boot_until = 0.0
        self._reset_device()

    # -------------------------------------------------------------------------------------------------- life cycle
    def _reset_device(self) -> None:
        self.sequence = 0
        self.max_duty_q16 = P.duty_to_q16(self.config.max_duty)
        self.watchdog_ms = round(self.config.watchdog_timeout * 1000)
        self.commanded_q16 = 0
        self.applied_q16 = 0
        self._watchdog_armed = False    # armed by the first valid command
        self._last_command_time = 0.0
        self.flags = 0
        self.rx_bad_frames = 0
        self.tx_dropped = 0
        self._status_due = True
        self._boot = True
        self._decoder.reset()
        # closed loop (the firmware's boot values)
        self.control_mode = P.MODE_OPEN_LOOP
        self.law_coefficients = np.zeros(law.N_COEFFICIENTS)
        self.law_coefficients[[law.I_MIN, law.I_MAX, law.U_MIN, law.U_MAX, law.ANGLE_MIN, law.ANGLE_MAX,
                               law.SETPOINT_WEIGHT]] = _f32([-1.0, 1.0, 0.0, 1.0, -3.14159265, 3.14159265, 1.0])
        self.law_set = set()
        self.law_state = law.new_state()
        self.law_reference = 0.0
        self.law_feedforward = 0.0
        self.angle_zero_counts = P.DEFAULT_DEVICE_ANGLE_ZERO
        self.angle_rad_per_count = _f32(P.DEFAULT_DEVICE_ANGLE_SCALE)
        #: every ACK sent, in order
        self.acks: list[P.AckFrame] = []
        self._replies = bytearray()
        if self.auto_reset:
            # The bootloader runs first (a power-up or a DTR reset); the sketch starts after it, if left alone.
            self.state = 'bootloader'
            self._boot_until = time.monotonic() + self.config.boot_delay
            self.resets += 1

    def start(self) -> DeviceEmulator:
        """Open the pty and start streaming; returns self."""
        self._open_pty()
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name='aeropend-device-emulator', daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop streaming, close the pty and remove the symlink (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        with self._lock:
            self._close_pty()
        if self._tmpdir:
            try:
                os.rmdir(self._tmpdir)
            except OSError:
                pass

    def __enter__(self) -> DeviceEmulator:  # noqa: PYI034
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def port(self) -> str:
        """The port name to open (the symlink)."""
        return str(self.link)

    @property
    def host_open(self) -> bool:
        """Whether a program has the port open (as last seen, every ~20 ms)."""
        return self._host_open

    @property
    def plugged(self) -> bool:
        return self._master >= 0

    def _open_pty(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        name = os.ttyname(slave)
        # The slave is closed here, so the master sees (POLLHUP) whether a program has the port open: that is
        # when the Mega's DTR auto-reset happens.
        os.close(slave)
        self._master, self._slave = master, -1
        self._host_open = False
        tmp = self.link.with_name(self.link.name + '.new')
        if tmp.is_symlink() or tmp.exists():
            tmp.unlink()
        os.symlink(name, tmp)
        from aeropend_core.io.atomic import replace_durably
        replace_durably(tmp, self.link)

    def _close_pty(self) -> None:
        if self.link.is_symlink():
            self.link.unlink()
        for fd in (self._master, self._slave):
            if fd >= 0:
                os.close(fd)
        self._master = self._slave = -1
        self._host_open = False

    def _check_host(self) -> None:
        """Notice a program opening or closing the port; opening resets the board when `auto_reset`."""
        if self._master < 0:
            return
        poller = select.poll()
        poller.register(self._master, select.POLLHUP)
        is_open = not any(event & select.POLLHUP for _, event in poller.poll(0))
        if is_open and not self._host_open:
            self.host_opens.append(time.monotonic())
            if self.auto_reset:
                self._held.clear()
                self._reset_device()
        self._host_open = is_open

    def _bootloader(self) -> bool:
        """Run the bootloader's part of an emission; True while the sketch is not running."""
        if self.state == 'running':
            return False
        data = b''
        if self._master >= 0:
            try:
                data = os.read(self._master, 4096)
            except (BlockingIOError, OSError):
                data = b''
        if data:
            # stk500v2: a byte during the listening window enters programming mode, which waits for a programmer.
            self.bootloader_bytes += len(data)
            self.state = 'programming'
        if self.state == 'bootloader' and time.monotonic() >= self._boot_until:
            self.state = 'running'
            self.sketch_starts.append(time.monotonic())
            return False
        return True

    # ------------------------------------------------------------------------------------------------------ faults
    def inject_garbage(self, data: bytes | int) -> None:
        """Send `data` (or that many random bytes) before the next frame."""
        with self._lock:
            if isinstance(data, int):
                data = self.rng.randbytes(data)
            self._faults.garbage += data

    def corrupt_frames(self, count: int = 1) -> None:
        """Flip one random bit in each of the next `count` frames."""
        with self._lock:
            self._faults.corrupt += int(count)

    def truncate_frames(self, count: int = 1, keep_delimiter: bool = True) -> None:
        """Cut each of the next `count` frames short (with or without its closing 0x00)."""
        with self._lock:
            self._faults.truncate += int(count)
            self._faults.truncate_keep_delimiter = keep_delimiter

    def tamper_frames(self, *changes: dict) -> None:
        """Send the next ``len(changes)`` frames with their fields changed and a valid CRC.

        Each element maps SampleFrame field names to new values, plus ``sequence_offset`` (added to the true
        sequence number modulo 2^32); e.g. ``tamper_frames({'sequence_offset': 100000}, {'angle_counts': 65535})``.
        The device's own counter is not changed (the next frames are numbered as if nothing happened).
        """
        for change in changes:
            unknown = set(change) - set(P.SampleFrame._fields) - {'sequence_offset'}
            if unknown:
                raise ValueError(f'unknown SampleFrame fields {sorted(unknown)}')
        with self._lock:
            self._faults.tamper.extend(dict(change) for change in changes)

    def pause(self, seconds: float, drop: bool = False) -> None:
        """Stop writing for `seconds`: frames are held and sent in one burst afterwards, or lost when `drop`."""
        with self._lock:
            self._faults.pause_until = time.monotonic() + float(seconds)
            self._faults.pause_drop = bool(drop)

    def unplug(self) -> None:
        """Close the pty (the reader gets an I/O error) and remove the symlink; the device keeps sampling."""
        with self._lock:
            self._close_pty()

    def replug(self, reset: bool = True) -> None:
        """Open a new pty behind the same symlink; `reset` restarts the device (sequence 0, default config)."""
        with self._lock:
            if self.plugged:
                self._close_pty()
            if reset:
                self._reset_device()
            self._open_pty()

    # ---------------------------------------------------------------------------------------------------- run loop
    def _run(self) -> None:
        start = time.monotonic()
        produced = 0
        period = self.sample_period
        while not self._stop.is_set():
            now = time.monotonic()
            due = int((now - start) / period)
            if due - produced < self.block:
                time.sleep(max(0.0005, (produced + self.block) * period - (now - start)))
                continue
            with self._lock:
                self._check_host()
                if self._bootloader():
                    produced = due          # not sampling: the sketch is not running
                    continue
                self._read_commands()
                n = due - produced
                self._emit_samples(n)
                self.write_lateness_max = max(self.write_lateness_max, time.monotonic() - start - due * period)
            produced = due

    def _read_commands(self) -> None:
        if self._master < 0:
            return
        try:
            data = os.read(self._master, 4096)
        except (BlockingIOError, OSError):
            return
        corrupt_before = self._decoder.counters.corrupt
        now = time.monotonic()
        for message in self._decoder.feed(data):
            if isinstance(message, P.CommandFrame) and message.kind == P.SET_CONTROL_MODE:
                self.commands.append((now, message))
                self._control_command(message)
            elif isinstance(message, P.CommandFrame):
                self.commands.append((now, message))
                self._apply_command(message)
            elif isinstance(message, (P.CoefficientCommand, P.ReferenceCommand, P.AngleCalibrationCommand)):
                self.commands.append((now, message))
                self._control_command(message)
        self.rx_bad_frames += self._decoder.counters.corrupt - corrupt_before

    def _coefficient_result(self, index: int, value: float) -> int:
        c = self.law_coefficients
        if not 0 <= index < law.N_COEFFICIENTS:
            return P.ACK_UNKNOWN_INDEX
        if not math.isfinite(value):
            return P.ACK_OUT_OF_RANGE
        if index in (law.P, law.I_TS, law.D_GAIN, law.AW_GAIN):
            ok = value >= 0.0
        elif index == law.D_POLE:
            ok = 0.0 <= value < 1.0
        elif index == law.I_MIN:
            ok = value <= c[law.I_MAX]
        elif index == law.I_MAX:
            ok = value >= c[law.I_MIN]
        elif index == law.U_MIN:
            ok = 0.0 <= value <= c[law.U_MAX]
        elif index == law.U_MAX:
            ok = c[law.U_MIN] <= value <= 1.0
        elif index == law.AW_CODE:
            ok = value in (0.0, 1.0, 2.0)
        elif index == law.ANGLE_MIN:
            ok = value < c[law.ANGLE_MAX]
        elif index == law.ANGLE_MAX:
            ok = value > c[law.ANGLE_MIN]
        elif index == law.SETPOINT_WEIGHT:
            ok = 0.0 <= value <= 1.0
        else:
            ok = True
        return P.ACK_OK if ok else P.ACK_OUT_OF_RANGE

    def _law_restart(self) -> None:
        self.law_state = law.new_state()
        self.flags &= ~(P.FLAG_WATCHDOG_TRIPPED | P.FLAG_DUTY_CLAMPED)

    def _control_command(self, command) -> None:
        """The closed loop's commands, as the firmware's handle_control_command: an ACK for each."""
        c = self.law_coefficients
        index, result, value = 0, P.ACK_OK, 0.0
        if command.kind == P.SET_CONTROL_COEFFICIENT:
            index = command.index
            result = self._coefficient_result(index, command.value)
            if result == P.ACK_OK:
                c[index] = command.value
                self.law_set.add(index)
                self.law_state[law.INTEGRAL] = min(max(self.law_state[law.INTEGRAL], c[law.I_MIN]), c[law.I_MAX])
            value = c[index] if result != P.ACK_UNKNOWN_INDEX else 0.0
        elif command.kind == P.SET_REFERENCE:
            reference, feedforward = command.reference, command.feedforward
            if not (math.isfinite(reference) and math.isfinite(feedforward) and 0.0 <= feedforward <= 1.0
                    and c[law.ANGLE_MIN] <= reference <= c[law.ANGLE_MAX]):
                result = P.ACK_OUT_OF_RANGE
            else:
                self.law_reference, self.law_feedforward = reference, feedforward
                if self.control_mode == P.MODE_CLOSED_LOOP and (self.flags & P.FLAG_WATCHDOG_TRIPPED
                                                                 or self.law_state[law.TRIPPED]):
                    self._law_restart()
            value = self.law_reference
        elif command.kind == P.SET_CONTROL_MODE:
            if command.value == P.MODE_OPEN_LOOP:
                self.control_mode = P.MODE_OPEN_LOOP
                self.commanded_q16 = 0
            elif command.value != P.MODE_CLOSED_LOOP:
                result = P.ACK_OUT_OF_RANGE
            elif not self.law_set >= set(range(law.SETPOINT_WEIGHT)):    # b may stay at its boot value 1
                result = P.ACK_REFUSED
            else:
                self._law_restart()
                self.control_mode = P.MODE_CLOSED_LOOP
            value = float(self.control_mode)
        else:   # SET_ANGLE_CALIBRATION
            if not (math.isfinite(command.zero_counts) and math.isfinite(command.rad_per_count)
                    and command.rad_per_count != 0.0):
                result = P.ACK_OUT_OF_RANGE
            elif self.control_mode == P.MODE_CLOSED_LOOP:
                result = P.ACK_REFUSED
            else:
                self.angle_zero_counts, self.angle_rad_per_count = command.zero_counts, command.rad_per_count
            value = self.angle_zero_counts
        if result == P.ACK_OK:
            self._last_command_time = time.monotonic()
            self._watchdog_armed = True
        ack = P.AckFrame(command.kind, index, result, float(value))
        self.acks.append(ack)
        self._replies += P.encode_ack(ack)

    def _law_step(self, angle_counts: int) -> None:
        """One sample of the closed loop (as the firmware's control_step): the duty from the next sample."""
        if self.flags & P.FLAG_WATCHDOG_TRIPPED:
            return
        angle = float(_f32((np.float32(angle_counts) - np.float32(self.angle_zero_counts))
                           * np.float32(self.angle_rad_per_count)))
        duty = law.law_step(self.law_coefficients, self.law_state, self.law_reference, self.law_feedforward, angle)
        wanted = 0 if not duty > 0.0 else 65535 if duty >= 1.0 else int(duty * 65535.0 + 0.5)
        self.commanded_q16 = min(wanted, self.max_duty_q16)
        if wanted > self.max_duty_q16:
            self.flags |= P.FLAG_DUTY_CLAMPED
        else:
            self.flags &= ~P.FLAG_DUTY_CLAMPED

    def _mode_flags(self) -> int:
        if self.control_mode != P.MODE_CLOSED_LOOP:
            return 0
        return P.FLAG_CLOSED_LOOP | (P.FLAG_LAW_TRIPPED if self.law_state[law.TRIPPED] else 0)

    def _apply_command(self, command: P.CommandFrame) -> None:
        if command.kind == P.SET_DUTY:
            self.control_mode = P.MODE_OPEN_LOOP     # SET_DUTY always wins, as on the firmware
            value = command.value
            if value > self.max_duty_q16:
                value = self.max_duty_q16
                self.flags |= P.FLAG_DUTY_CLAMPED
            else:
                self.flags &= ~P.FLAG_DUTY_CLAMPED
            self.commanded_q16 = value
            self.flags &= ~P.FLAG_WATCHDOG_TRIPPED
        elif command.kind == P.SET_MAX_DUTY:
            self.max_duty_q16 = command.value
            if self.commanded_q16 > command.value:
                self.commanded_q16 = command.value
                self.flags |= P.FLAG_DUTY_CLAMPED
            self._status_due = True
        elif command.kind == P.SET_WATCHDOG:
            if not P.WATCHDOG_MS_RANGE[0] <= command.value <= P.WATCHDOG_MS_RANGE[1]:
                self.rx_bad_frames += 1
                self._status_due = True
                return
            self.watchdog_ms = command.value
            self._status_due = True
        elif command.kind == P.REQUEST_STATUS:
            self._status_due = True
        self._last_command_time = time.monotonic()
        self._watchdog_armed = True

    def _emit_samples(self, n: int) -> None:
        # Watchdog on the host clock at each emission (the firmware counts Timer1 overflows; commands are only
        # read here, every ~20 ms, so counting samples would trip when this thread is scheduled late).
        if self._watchdog_armed and time.monotonic() - self._last_command_time > self.watchdog_ms / 1000.0:
            self._watchdog_armed = False
            self.commanded_q16 = 0
            self.flags |= P.FLAG_WATCHDOG_TRIPPED
        if self.control_mode == P.MODE_CLOSED_LOOP:
            self._emit_closed_loop(n)
            return
        duties = np.empty(n)
        applied = np.empty(n, dtype=np.int64)
        flags = np.empty(n, dtype=np.int64)
        for k in range(n):
            # As the firmware: the duty reported is the one in effect during the sample.
            applied[k] = self.applied_q16
            flags[k] = self.flags
            duties[k] = self.applied_q16 / 65535.0
            self.applied_q16 = self.commanded_q16
        counts = self._measure(duties)
        out = bytearray(self._replies)
        self._replies.clear()
        for k in range(n):
            sequence = self.sequence
            self.sequence += 1
            sample = P.SampleFrame(sequence, int(counts[0][k]), int(counts[1][k]), int(counts[2][k]),
                                   int(applied[k]), int(flags[k]))
            out += self._sample_bytes(sequence, sample)
            if self._status_due or sequence % self.config.status_every == self.config.status_every - 1:
                out += self._status_frame()
        self._write(out, n)

    def _emit_closed_loop(self, n: int) -> None:
        """n samples of the closed loop, one at a time: measure, step the law, CONTROL_SAMPLE."""
        out = bytearray(self._replies)
        self._replies.clear()
        for _ in range(n):
            applied, flags = self.applied_q16, self.flags
            counts = self._measure(np.array([applied / 65535.0]))
            self._law_step(int(counts[1][0]))
            self.applied_q16 = self.commanded_q16
            sequence = self.sequence
            self.sequence += 1
            s = self.law_state
            sample = P.ControlSampleFrame(
                sequence, int(counts[0][0]), int(counts[1][0]), int(counts[2][0]), int(applied),
                int(flags | self._mode_flags()), self.law_reference, self.law_feedforward,
                float(s[law.UNSATURATED]), float(s[law.INTEGRAL]))
            out += self._sample_bytes(sequence, sample)
            if self._status_due or sequence % self.config.status_every == self.config.status_every - 1:
                out += self._status_frame()
        self._write(out, n)

    def _sample_bytes(self, sequence: int, sample) -> bytes:
        if self._faults.tamper:
            change = self._faults.tamper.pop(0)
            offset = change.pop('sequence_offset', 0)
            sample = sample._replace(sequence=(sequence + offset) % (1 << 32), **change)
            self._log(sequence, 'tampered')
            return _encode(sample)
        return self._apply_faults(sequence, _encode(sample))

    def _measure(self, duties: np.ndarray) -> np.ndarray:
        """Raw counts (3, n) of the samples taken while `duties` are applied."""
        n = len(duties)
        if self.locked_rotor:
            # Propeller held: no thrust, so the rod only settles; the armature obeys La dIa/dt = Va - Ra Ia.
            trajectory = self.simulator.run(np.zeros(n))
            p = self.simulator.parameters
            voltage_now = np.asarray(p.voltage_from_duty(duties), dtype=float).reshape(n)
            decay = math.exp(-P.SAMPLE_PERIOD * p.armature_resistance / p.armature_inductance)
            currents = np.empty(n)
            for k in range(n):
                currents[k] = self._locked_current
                target = voltage_now[k] / p.armature_resistance
                self._locked_current = target + (self._locked_current - target) * decay
            measured_current, measured_voltage = currents, voltage_now
        else:
            trajectory = self.simulator.run(duties)
            self._locked_current = 0.0
            measured_current, measured_voltage = trajectory.armature_current, trajectory.armature_voltage
        if self._front_end is not None:
            return self._front_end.counts(trajectory.angle, measured_current, measured_voltage, duties)
        return np.array([self.calibration.to_counts(float(trajectory.angle[k]), float(measured_current[k]),
                                                    float(measured_voltage[k])) for k in range(n)],
                        dtype=np.int64).reshape(n, 3).T

    def _status_frame(self) -> bytes:
        flags = self.flags | (P.FLAG_BOOT if self._boot else 0) | self._mode_flags()
        self._boot = False
        self._status_due = False
        return P.encode_status(P.StatusFrame(
            P.PROTOCOL_VERSION, self.config.pwm_mode, flags, P.PWM_TOP[self.config.pwm_mode], self.max_duty_q16,
            self.watchdog_ms, self.rx_bad_frames & 0xFFFF, self.tx_dropped & 0xFFFF, self.sequence))

    def _apply_faults(self, sequence: int, wire: bytes) -> bytes:
        faults = self._faults
        prefix = b''
        if faults.garbage:
            prefix = bytes(faults.garbage)
            faults.garbage.clear()
        if faults.corrupt:
            faults.corrupt -= 1
            data = bytearray(wire)
            index = self.rng.randrange(1, len(data) - 1)   # inside the frame, delimiters untouched
            data[index] ^= 1 << self.rng.randrange(8)
            self._log(sequence, 'corrupt')
            return prefix + bytes(data)
        if faults.truncate:
            faults.truncate -= 1
            cut = self.rng.randrange(2, len(wire) - 2)
            self._log(sequence, 'truncated')
            return prefix + wire[:cut] + (b'\x00' if faults.truncate_keep_delimiter else b'')
        self._log(sequence, 'intact')
        return prefix + wire

    def _write(self, data: bytes, samples: int) -> None:
        faults = self._faults
        paused = time.monotonic() < faults.pause_until
        if self._master < 0 or (paused and faults.pause_drop) or not self._host_open:
            self._mark_lost(samples)     # unplugged, dropped, or nobody has the port open (the chip drops it)
            self._held.clear()
            return
        self._held += data
        self._sent += samples
        if paused:
            return
        try:
            written = os.write(self._master, self._held)
        except BlockingIOError:
            written = 0
        except OSError:
            self._sent -= samples
            self._mark_lost(samples)
            self._held.clear()
            return
        self.bytes_written += written
        del self._held[:written]
        if len(self._held) > DEVICE_BUFFER:
            # Nobody reads: like the USB-serial chip, keep a small FIFO and drop the rest.
            del self._held[DEVICE_BUFFER:]

    def _log(self, sequence: int, state: str) -> None:
        if self.keep_log:
            self.emitted.append((sequence, state))

    def _mark_lost(self, samples: int) -> None:
        self._lost += samples
        if self.keep_log:
            for index in range(len(self.emitted) - samples, len(self.emitted)):
                self.emitted[index] = (self.emitted[index][0], 'lost')

    def samples_sent(self) -> int:
        """Samples produced by the running sketch and written to the port (damaged ones included)."""
        return self._sent

    # ---------------------------------------------------------------------------------------------------- queries
    def sequences(self, state: str = 'intact') -> list[int]:
        """Sequence numbers of the emitted samples in `state` ('intact', 'corrupt', 'truncated', 'lost')."""
        with self._lock:
            return [sequence for sequence, s in self.emitted if s == state]
