"""Acquisition time stamps for a sampled device: sample counter x Ts, anchored to the host clock, drift-corrected.

A device that samples on its own crystal (the rig's Timer1, Ts = 2.04 ms) numbers its samples; the host only knows
when each one *arrived*, late by a variable transport delay (USB frames, OS scheduling, bursts after a stall).
Stamping with the arrival time would put that jitter into the data. Instead :class:`SampleClock` models

    stamp(sequence) = anchor + period * sequence

and fits ``anchor`` and ``period`` to the *lower envelope* of the arrival times: per window of samples only the
earliest arrival relative to the model is kept (the least-delayed sample), and a straight line through the recent
window minima gives the drift-corrected period of the device's crystal as seen by the host clock. Stamps are
therefore the acquisition times plus the link's minimum latency (a constant, ~1 ms on USB; subtract it with
`latency` if known). Delayed bursts never pull the stamps later.
"""
from __future__ import annotations

from collections import deque

import numpy as np

__all__ = ['SampleClock']


class SampleClock:
    """Stamp device samples by their sequence number (see module docstring).

    Parameters
    ----------
    sample_period : float
        Nominal device sampling period Ts [s].
    window : int
        Samples per envelope window (default 490, about 1 s on the rig).
    history : int
        Window minima used for the line fit (default 60: the drift estimate spans about a minute).
    max_drift : float
        Largest believable relative deviation of the device period from nominal (default 2e-4 = 200 ppm: the Mega
        2560's 16 MHz crystal is within ~100 ppm; boards clocked by a ceramic resonator need ~5e-3). A heavily
        loaded host delays whole windows of samples and biases the slope; the bound limits the damage.
    latency : float
        Known constant minimum latency of the link [s], subtracted from the stamps.
    min_span : int
        Windows between two minima used for a slope (default 20, ~20 s): shorter baselines make the period
        estimate follow latency noise (a host stalled for a second biases it); until then the nominal period is
        used (a 100 ppm crystal drifts 2 ms in 20 s).
    min_spacing : float
        Smallest spacing of consecutive stamps, in sample periods per sequence step (default 0.6).
    max_slew : float
        Largest move of the line per window when the fit changes, in sample periods (default 0.25: 0.5 ms per
        second on the rig, 500 ppm).
    """

    def __init__(self, sample_period: float, window: int = 490, history: int = 60, max_drift: float = 2e-4,
                 latency: float = 0.0, min_span: int = 20, min_spacing: float = 0.6,
                 max_slew: float = 0.25) -> None:
        if not sample_period > 0:
            raise ValueError(f'sample_period must be positive, got {sample_period!r}')
        if window < 2 or history < 2:
            raise ValueError('window and history must be at least 2')
        self.nominal_period = float(sample_period)
        self.window = int(window)
        self.history = int(history)
        self.max_drift = float(max_drift)
        self.latency = float(latency)
        self.min_span = int(min_span)
        self.min_spacing = float(min_spacing)
        self.max_slew = float(max_slew)
        self.reset()

    def reset(self) -> None:
        """Forget the anchor (the device restarted its counter): the next sample anchors again."""
        self._reference = None          # host time [s] that relative times are measured from
        self._period = self.nominal_period
        self._anchor = 0.0              # relative host time of sequence 0
        self._minima: deque[tuple[int, float]] = deque(maxlen=self.history)
        self._window_start = None
        self._window_best: tuple[int, float] | None = None
        self._last_stamp = None
        self._last_sequence = 0
        #: Arrivals observed since the last reset (a caller may hold its first stamps until this is large).
        self.observed = 0

    @property
    def period(self) -> float:
        """Current estimate of the device's sampling period in host seconds."""
        return self._period

    @property
    def drift_ppm(self) -> float:
        """Estimated deviation of the device period from nominal, parts per million."""
        return (self._period / self.nominal_period - 1.0) * 1e6

    def stamp(self, sequence: int, arrival: float) -> float:
        """Acquisition time [s, host clock] of sample `sequence` that arrived at host time `arrival` [s].

        Sequences must not decrease between :meth:`reset` calls; gaps (lost samples) are fine.
        """
        return self.stamp_many([sequence], arrival)[0]

    def stamp_many(self, sequences, arrival: float) -> list[float]:
        """Stamps of several samples that arrived together (one read), in the order given.

        The newest of them had the least delay, so it alone updates the envelope; the others are placed on the
        line by their sequence numbers (a backlog read at once is spread over the times it was acquired, not
        piled up at the arrival time).
        """
        if not len(sequences):
            return []
        self.observe(max(sequences), arrival)
        return self.place(sequences)

    def observe(self, sequence: int, arrival: float) -> None:
        """Update the envelope with one arrival (the newest sample of a read) without stamping anything."""
        if self._reference is None:
            self._reference = arrival
            self._anchor = -sequence * self._period
            self._window_start = sequence
        self.observed += 1
        relative = arrival - self._reference
        # Window minimum of the arrival relative to a line of the current period (fixed within a window).
        key = relative - self._period * sequence
        if self._window_best is None or key < self._window_best[2]:
            self._window_best = (sequence, relative, key)
        if sequence - self._window_start >= self.window:
            self._close_window(sequence)
            self._window_start = sequence
        predicted = self._anchor + self._period * sequence
        if relative < predicted:
            # Earlier than the lower envelope: this sample had less delay than any before; move the line down.
            self._anchor += relative - predicted

    def place(self, sequences) -> list[float]:
        """Stamps [s] of `sequences` on the current line (after :meth:`observe`), in the order given.

        Consecutive stamps stay at least ``min_spacing`` x Ts x (sequence step) apart: when the line moves down
        (a less-delayed sample showed that earlier stamps were late) the following stamps catch up gradually
        instead of piling up on the last one.
        """
        if self._reference is None:
            raise ValueError('place() before any observe(): no anchor yet')
        stamps = []
        base = self._reference - self.latency
        for sequence in sequences:
            stamp = base + self._anchor + self._period * sequence
            if self._last_stamp is not None:
                floor = self._last_stamp + self.min_spacing * self._period * max(1, sequence - self._last_sequence)
                stamp = max(stamp, floor)
            self._last_stamp = stamp
            self._last_sequence = sequence
            stamps.append(stamp)
        return stamps

    def _close_window(self, now: int) -> None:
        """Add the window's minimum, refit the line and move towards it (slewed at sequence `now`)."""
        sequence, relative, _ = self._window_best
        self._window_best = None
        self._minima.append((sequence, relative))
        points = np.array(self._minima, dtype=float)
        sequences, times = points[:, 0], points[:, 1]
        slope = self._period
        # Theil-Sen slope over pairs of window minima at least `min_span` windows apart: robust to the odd late
        # window (start-up bursts, a stalled host) that a least-squares line would follow.
        i, j = np.triu_indices(len(points), k=1)
        far = sequences[j] - sequences[i] >= self.min_span * self.window
        if np.any(far):
            slopes = (times[j[far]] - times[i[far]]) / (sequences[j[far]] - sequences[i[far]])
            low = self.nominal_period * (1.0 - self.max_drift)
            high = self.nominal_period * (1.0 + self.max_drift)
            slope = min(high, max(low, float(np.median(slopes))))
        # Lower envelope: the line with that slope under every window minimum. Moved towards gradually (at most
        # `max_slew` x Ts per window, measured at the newest sequence), so stamps never jump when the estimate
        # changes; a sample arriving below the line still lowers it at once (observe).
        target = float(np.min(times - slope * sequences))
        current = self._anchor + self._period * now
        wanted = target + slope * now
        step = self.max_slew * self.nominal_period
        value = current + min(step, max(-step, wanted - current))
        self._period = slope
        self._anchor = value - slope * now
