"""The live identification's stream of samples cut into sliding windows, without ROS (the identification node wraps
it; :func:`aeropend_core.diagnosis.online.analyze_window` analyses each window).

Samples arrive one at a time with a sequence number and a stamp [ns]. :meth:`SampleWindows.add` buffers a good one
and says what a bad one is (:data:`REJECTIONS`: not finite, duplicated, out of order, a stamp that does not advance);
a sequence number that goes back with a later stamp (the source restarted) or stamps that jump against the sequence
numbers (by more than :data:`STAMP_JUMP_TOLERANCE`) clear the buffer: the windows start again, and a run of such
restarts is one *restart condition* until :data:`STABLE_AFTER_RESTART` samples arrive in order. Lost samples (gaps
in the sequence numbers) are counted, not filled. :meth:`SampleWindows.due_window` hands out the last ``window_s``
seconds every ``hop_s`` seconds of acquisition time and keeps one window of history.

Examples
--------
>>> from aeropend_core.diagnosis.sample_windows import SampleWindows
>>> stream = SampleWindows(sample_time=0.002)                          # s (500 Hz)
>>> for n in range(3000):                                              # 6 s, sample 1000 lost
...     if n != 1000:
...         arrival = stream.add(n, n * 2_000_000, 1.0, 0.1, 0.0)         # sequence, stamp [ns], Va [V], Ia [A], rad
>>> stream.samples_received, stream.samples_missed
(2999, 1)
>>> window = stream.due_window(2999 * 2_000_000, window_s=4.0, hop_s=1.0)
>>> len(window['angle']), stream.windows_due                           # the last 4 s less the lost sample
(1999, 1)
>>> stream.add(2999, 2999 * 2_000_000, 1.0, 0.1, 0.0).rejected          # the same sequence number again
'duplicate'
>>> stream.add(5, 3000 * 2_000_000, 1.0, 0.1, 0.0).restart_kind, len(stream.stamps)    # the source restarted
('counter', 1)
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np

#: Largest believable mismatch between a stamp step and the sequence step times Ts: 0.1 s + 5 % of the step.
STAMP_JUMP_TOLERANCE = (0.1, 0.05)
#: Samples in order (counter +1.., stamps as expected) after a restart that end the restart condition: until then
#: further restarts are counted, not reported again (two interleaved sources never give two in a row).
STABLE_AFTER_RESTART = 50
#: Why a received sample is rejected (not buffered; it counts as lost, filled like one if the window still has
#: enough samples) -> the words used on /diagnostics and in the log.
REJECTIONS = {
    'not_finite': 'not finite (NaN/inf angle, voltage or current)',
    'duplicate': 'duplicated (same sequence number as the previous sample)',
    'out_of_order': 'out of order (older sequence number and stamp than the previous sample)',
    'stamp_not_increasing': 'non-monotonic stamp (sequence number advanced, stamp did not)',
    'unreadable': 'unreadable (not an aeropend sample, or its sequence number is not a whole number)',
}
#: The signals buffered per sample: armature voltage [V], armature current [A], angle [rad].
SIGNALS = ('armature_voltage', 'armature_current', 'angle')


@dataclass(frozen=True)
class Arrival:
    """What one sample did to the stream (:meth:`SampleWindows.add`).

    Parameters
    ----------
    rejected : str or None [-]
        The :data:`REJECTIONS` key when the sample was not buffered (counted in ``rejected``), with `detail`.
    detail : str [-]
        Which sample, and against which.
    restart : str or None [-]
        Why the stream restarted (the buffer was cleared; this sample is its first), or None.
    restart_kind : str or None [-]
        ``'counter'`` (sequence number back, later stamp) or ``'stamps'`` (stamps jumped).
    new_condition : bool [-]
        The restart began a restart condition (say it once; further restarts while it lasts are only counted).
    stable_again : bool [-]
        This sample ended a restart condition (:data:`STABLE_AFTER_RESTART` in order).
    restarts_in_condition : int [-]
        Restarts during the condition that `stable_again` ended.
    """

    rejected: str | None = None
    detail: str = ''
    restart: str | None = None
    restart_kind: str | None = None
    new_condition: bool = False
    stable_again: bool = False
    restarts_in_condition: int = 0


class SampleWindows:
    """A stream of samples buffered and cut into sliding windows (module docstring).

    Parameters
    ----------
    sample_time : float [s]
        The source's sample period (the rig's 1/490 s): gaps and stamp jumps are judged against it.

    Attributes
    ----------
    sequence, stamps : list of int [-, ns]
        The buffered samples' sequence numbers and stamps; ``signals`` their values (:data:`SIGNALS`).
    first_stamp_ns : int or None [ns]
        The first good sample's stamp (the origin of the run's relative times).
    samples_received, samples_missed, restarts, windows_due : int [-]
        Samples buffered, samples lost in gaps of the sequence numbers, restarts of the stream, windows handed
        out; ``rejected`` counts rejected samples by :data:`REJECTIONS` key.
    generation : int [-]
        Counts the clears (restarts): a window from before one belongs to another stream.
    lock : threading.Lock
        Held while the buffer changes (a reader on another thread takes it too).
    """

    def __init__(self, sample_time: float) -> None:
        self.sample_time = float(sample_time)
        self.lock = threading.Lock()
        self.sequence: list[int] = []
        self.stamps: list[int] = []
        self.signals: dict[str, list[float]] = {name: [] for name in SIGNALS}
        self.last_window_end_ns: int | None = None
        self.first_stamp_ns: int | None = None
        self.samples_received = 0
        self.samples_missed = 0
        self.rejected = dict.fromkeys(REJECTIONS, 0)
        self.restarts = 0
        self.generation = 0
        self.windows_due = 0
        self.restart_condition: str | None = None
        self._in_order_since_restart = 0
        self._restarts_at_condition = 0

    def reject(self, reason: str, detail: str = '') -> Arrival:
        """Count a sample that is not buffered (a :data:`REJECTIONS` key) and say so."""
        self.rejected[reason] += 1
        return Arrival(rejected=reason, detail=detail)

    def add(self, sequence: int, stamp_ns: int, armature_voltage: float, armature_current: float,
            angle: float) -> Arrival:
        """Buffer one sample, or reject it, or restart the stream with it (module docstring).

        Parameters
        ----------
        sequence : int [-]
            The source's sample counter.
        stamp_ns : int [ns]
            Its acquisition stamp.
        armature_voltage, armature_current, angle : float [V, A, rad]
            Its values.
        """
        if not (math.isfinite(angle) and math.isfinite(armature_voltage) and math.isfinite(armature_current)):
            return self.reject('not_finite', f'sample {sequence}')
        if self.first_stamp_ns is None:
            self.first_stamp_ns = stamp_ns
        restart, kind, stable_again, in_condition = None, None, False, 0
        with self.lock:
            if self.sequence:
                last_sequence, last_stamp = self.sequence[-1], self.stamps[-1]
                if sequence == last_sequence:
                    return self.reject('duplicate', f'sample {sequence}')
                if sequence < last_sequence:
                    if stamp_ns <= last_stamp:
                        return self.reject('out_of_order', f'sample {sequence} after {last_sequence}')
                    restart, kind = (f'sample counter went back from {last_sequence} to {sequence} with a later '
                                     'stamp: the source restarted (or two sources share the topic)', 'counter')
                elif stamp_ns <= last_stamp:
                    return self.reject('stamp_not_increasing', f'sample {sequence} stamped '
                                       f'{(stamp_ns - last_stamp) * 1e-9:+.6f} s after sample {last_sequence}')
                else:
                    expected = (sequence - last_sequence) * self.sample_time
                    step = (stamp_ns - last_stamp) * 1e-9
                    if abs(step - expected) > STAMP_JUMP_TOLERANCE[0] + STAMP_JUMP_TOLERANCE[1] * expected:
                        restart, kind = (f'stamps jumped by {step:.3f} s over {sequence - last_sequence} sample(s) '
                                         f'(expected {expected:.3f} s): the clock of the source jumped', 'stamps')
                    else:
                        self.samples_missed += sequence - last_sequence - 1
                        self._in_order_since_restart += 1
                        if self.restart_condition and self._in_order_since_restart >= STABLE_AFTER_RESTART:
                            self.restart_condition = None
                            stable_again = True
                            in_condition = self.restarts - self._restarts_at_condition
            new_condition = False
            if restart is not None:
                self.restarts += 1
                self._in_order_since_restart = 0
                self.clear()
                if self.restart_condition is None:     # two interleaved sources alternate the kinds: one condition
                    self.restart_condition = kind
                    self._restarts_at_condition = self.restarts - 1
                    new_condition = True
            self.samples_received += 1
            self.sequence.append(sequence)
            self.stamps.append(stamp_ns)
            for name, value in zip(SIGNALS, (armature_voltage, armature_current, angle)):
                self.signals[name].append(value)
        return Arrival(restart=restart, restart_kind=kind, new_condition=new_condition, stable_again=stable_again,
                       restarts_in_condition=in_condition)

    def clear(self) -> None:
        """Empty the buffer: the windows start again (``generation`` counts it)."""
        self.generation += 1
        self.sequence.clear()
        self.stamps.clear()
        for values in self.signals.values():
            values.clear()
        self.last_window_end_ns = None

    def due_window(self, now_ns: int, window_s: float, hop_s: float) -> dict[str, np.ndarray] | None:
        """The window that comes due at `now_ns` [ns], or None: the last `window_s` [s] of samples once the buffer
        spans it and `hop_s` [s] have passed since the last window; the buffer keeps one window of history.

        Returns
        -------
        dict of str -> ndarray or None
            ``sequence`` [-], ``stamp_ns`` [ns] and the :data:`SIGNALS` [V, A, rad], one entry per sample.
        """
        window_ns = int(window_s * 1e9)
        hop_ns = int(hop_s * 1e9)
        with self.lock:
            if not self.stamps or now_ns - self.stamps[0] < window_ns:
                return None
            if self.last_window_end_ns is not None and now_ns - self.last_window_end_ns < hop_ns:
                return None
            self.last_window_end_ns = now_ns
            self.windows_due += 1
            keep_from = int(np.searchsorted(np.asarray(self.stamps), now_ns - window_ns, side='right'))
            snapshot = {'sequence': np.array(self.sequence[keep_from:], dtype=np.int64),
                        'stamp_ns': np.array(self.stamps[keep_from:], dtype=np.int64)}
            snapshot.update({k: np.array(v[keep_from:]) for k, v in self.signals.items()})
            drop = max(0, keep_from - 1)          # keep one window of history (the next overlaps by window - hop)
            if drop:
                del self.sequence[:drop], self.stamps[:drop]
                for values in self.signals.values():
                    del values[:drop]
        return snapshot

    def buffered_span(self) -> float:
        """Acquisition time [s] between the first and the last buffered stamp (0 with fewer than two)."""
        with self.lock:
            return (self.stamps[-1] - self.stamps[0]) * 1e-9 if len(self.stamps) > 1 else 0.0


__all__ = ['SampleWindows', 'Arrival', 'REJECTIONS', 'STAMP_JUMP_TOLERANCE', 'STABLE_AFTER_RESTART', 'SIGNALS']
