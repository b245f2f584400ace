"""Plausibility checks on the rig's SAMPLE frames after the CRC: what a damaged frame that passes CRC-16 cannot fake.

CRC-16 lets about one damaged frame in 65,536 through (more for some damage patterns). Such a frame used to be
believed: a sequence number +100000 faked a device reset and 99,999 "lost" samples, one −3000 published a second
sample numbered 922, and ADC counts of 65535 became 399 rad and 194 A. :class:`FrameChecker` stands between the
decoder and the publisher:

* **range**: the three ADC fields are 10-bit results (0..1023) and the flags only use the bits the firmware
  defines; anything else is withheld (``implausible_range``). The duty is a 16-bit fraction of 65535, so it is in
  [0, 1] by construction.
* **sequence**: a sample whose number is the previous one + 1 is accepted at once. Any other step (a gap, a
  duplicate, a step back) is *held* until the next sample: if that one continues the held one (1..``max_follow``
  further on) the step was real (an outage, a device reset) and both are accepted; if it continues the old run
  instead (and the held one is not a small step ahead of it), the held sample contradicts the stream around it and
  is withheld (``implausible_sequence``). Two damaged frames that pass the CRC *and* agree with each other would be
  needed to fake a jump.
* **wrap**: the firmware's counter is 32 bits (2^32 samples = 101 days at 490 Hz). Sequence numbers are extended
  past the wrap (modular difference), so the wrap is a continuation, never a reset; the extended number is what
  the caller publishes.

A held sample costs one sample of latency, only around gaps and resets. The residual rate of damaged frames that
pass the CRC and these checks is measured by ``bench/bench_frame_checks.py`` (see docs/rig-link.md).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

from aeropend_core.rig import protocol as P

__all__ = ['SAMPLE_FLAGS', 'SEQUENCE_MODULUS', 'CheckCounters', 'CheckedSample', 'FrameChecker']

#: Flag bits a SAMPLE may carry (FLAG_BOOT is only sent in STATUS but tolerated; the closed loop's two in a
#: CONTROL_SAMPLE).
SAMPLE_FLAGS = P.FLAG_WATCHDOG_TRIPPED | P.FLAG_DUTY_CLAMPED | P.FLAG_SAMPLES_DROPPED | P.FLAG_BOOT \
    | P.FLAG_LAW_TRIPPED | P.FLAG_CLOSED_LOOP
#: The device's sequence counter wraps at this value (u32 on the wire).
SEQUENCE_MODULUS = 1 << 32


class CheckedSample(NamedTuple):
    """One accepted sample.

    Attributes
    ----------
    frame : SampleFrame
        The frame, with ``sequence`` extended past the 2^32 wrap (an int that only grows within a device run).
    lost : int
        Samples missing just before this one (a confirmed forward gap) [-].
    reset : bool
        This sample starts a new device run (a confirmed step back: the device restarted).
    """

    frame: P.SampleFrame
    lost: int = 0
    reset: bool = False


@dataclass
class CheckCounters:
    """Samples withheld by :class:`FrameChecker` (cumulative)."""

    implausible_range: int = 0      #: ADC counts > 1023 or undefined flag bits
    implausible_sequence: int = 0   #: a sequence step the following sample contradicted
    wraps: int = 0                  #: 2^32 wraps of the device's counter passed through


@dataclass
class FrameChecker:
    """Range and sequence checks on decoded SAMPLE frames (see module docstring).

    Parameters
    ----------
    max_follow : int
        Largest step [samples] from a held sample to the next one that still confirms it (default 490, 1 s:
        samples lost between them are fine).
    """

    max_follow: int = 490
    counters: CheckCounters = field(default_factory=CheckCounters)
    #: The last accepted sample's raw (wire) and extended sequence numbers.
    _last_raw: int | None = None
    _last_extended: int = 0
    _held: P.SampleFrame | None = None
    #: What the last withheld sample was, for the caller's log: (kind, raw sequence, expected next raw sequence).
    last_withheld: tuple[str, int, int] | None = None

    def reset(self) -> None:
        """Forget the stream (a reconnect): the next sample is accepted as it comes; a held sample is dropped
        without counting (its confirmation can no longer arrive)."""
        self._last_raw = None
        self._held = None

    @staticmethod
    def in_range(frame: P.SampleFrame) -> bool:
        """True when every field can come from the firmware (10-bit ADC counts, known flag bits)."""
        return (frame.current_counts <= P.ADC_FULL_SCALE and frame.angle_counts <= P.ADC_FULL_SCALE
                and frame.voltage_counts <= P.ADC_FULL_SCALE and not frame.flags & ~SAMPLE_FLAGS
                and 0 <= frame.duty_q16 <= 65535)

    @property
    def holding(self) -> bool:
        """A sample is held waiting for the next one to confirm its sequence step."""
        return self._held is not None

    def check(self, frames) -> list[CheckedSample]:
        """Accepted samples among `frames` (SampleFrame, in arrival order), in order; a held sample comes out with
        the call that confirms it."""
        out: list[CheckedSample] = []
        for frame in frames:
            if not self.in_range(frame):
                self.counters.implausible_range += 1
                self.last_withheld = ('range', frame.sequence, self._expected())
                continue
            self._sequence(frame, out)
        return out

    def _expected(self) -> int:
        return -1 if self._last_raw is None else (self._last_raw + 1) % SEQUENCE_MODULUS

    def _accept(self, frame: P.SampleFrame, out: list, lost: int = 0, reset: bool = False) -> None:
        step = (frame.sequence - self._last_raw) % SEQUENCE_MODULUS if self._last_raw is not None else 0
        if reset or self._last_raw is None:
            extended = frame.sequence
        else:
            extended = self._last_extended + step
            if frame.sequence < self._last_raw:
                self.counters.wraps += 1
        self._last_raw, self._last_extended = frame.sequence, extended
        out.append(CheckedSample(frame._replace(sequence=extended), lost, reset))

    def _sequence(self, frame: P.SampleFrame, out: list) -> None:
        if self._last_raw is None:
            self._accept(frame, out)
            return
        held = self._held
        if held is not None:
            follows_held = 1 <= (frame.sequence - held.sequence) % SEQUENCE_MODULUS <= self.max_follow
            follows_old = 1 <= (frame.sequence - self._last_raw) % SEQUENCE_MODULUS <= self.max_follow
            held_ahead = 1 <= (held.sequence - self._last_raw) % SEQUENCE_MODULUS <= self.max_follow
            if follows_held and (held_ahead or not follows_old):
                # The held step is confirmed by the stream after it: a real gap or a device reset.
                self._held = None
                self._accept_step(held, out)
                self._sequence(frame, out)
                return
            # The stream does not continue the held sample: it was damaged.
            self._held = None
            self.counters.implausible_sequence += 1
            self.last_withheld = ('sequence', held.sequence, self._expected())
        step = (frame.sequence - self._last_raw) % SEQUENCE_MODULUS
        if step == 1:
            self._accept(frame, out)
        else:
            self._held = frame

    def _accept_step(self, frame: P.SampleFrame, out: list) -> None:
        step = (frame.sequence - self._last_raw) % SEQUENCE_MODULUS
        if 1 <= step < SEQUENCE_MODULUS // 2 and frame.sequence > self._last_raw or \
                1 <= step <= self.max_follow:
            # Forward (a wrap only counts as forward for a small step: a device that restarted near 0 after a
            # long run is a reset, not 4 billion lost samples).
            self._accept(frame, out, lost=step - 1)
        else:
            self._accept(frame, out, reset=True)
