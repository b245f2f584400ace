"""Acquisition time stamps for a sampled device: sample counter x Ts, anchored to the host clock, drift-corrected.

A device that samples on its own crystal (the rig's Timer1, Ts = 2.04 ms) numbers its samples; the host only knows
when each one *arrived*, late by a variable transport delay (USB frames, OS scheduling, bursts after a stall).
Stamping with the arrival time would put that jitter into the data. Instead :class:`SampleClock` models

    stamp(sequence) = anchor + period * sequence

and fits ``anchor`` and ``period`` to the *lower envelope* of the arrival times: per window of samples only the
earliest arrival relative to the model is kept (the least-delayed sample), and the lower convex hull of the recent
window minima gives the drift-corrected period of the device's clock as seen by the host clock (the hull edge
under the middle of the history: the line below every minimum that is closest to them on average, as in Moon,
Skelly and Towsley's clock-skew estimate for network delays). Late windows (a stalled host, a burst) lie above
the hull and cannot bend it. Stamps are therefore the acquisition times plus the link's minimum latency (a
constant, ~1 ms on USB; subtract it with `latency` if known). Delayed bursts never pull the stamps later.

The Arduino Mega 2560 R3 clocks its ATmega2560 from a ceramic resonator (tolerance about +-0.5 %, not a crystal's
+-100 ppm), so the believable drift defaults to +-0.6 % and the first slope is taken after 3 windows (~3 s); a
device 0.5 % off is stamped within 2 ms of its acquisition times from ~10 s on.
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
        Largest believable relative deviation of the device period from nominal (default 6e-3 = 0.6 %: the Mega
        2560's 16 MHz ceramic resonator; a crystal-clocked board is within ~1e-4). Slopes outside are clamped.
    latency : float
        Known constant minimum latency of the link [s], subtracted from the stamps.
    min_span : int
        Windows between the first and the last minimum before their slope replaces the nominal period (default 3,
        ~3 s: a 0.5 % clock error is then 15 ms, removed within the next few windows).
    min_spacing : float
        Smallest spacing of consecutive stamps, in sample periods per sequence step (default 0.6).
    max_slew : float
        Largest move of the line per window when the fit changes, in sample periods (default 3: 6 ms per second
        on the rig, spread over the next window as a period change of at most 0.6 %, so stamps never jump).
    """

    #: default believable clock error: a ceramic resonator
    DEFAULT_MAX_DRIFT = 6e-3

    def __init__(self, sample_period: float, window: int = 490, history: int = 60,
                 max_drift: float = DEFAULT_MAX_DRIFT, latency: float = 0.0, min_span: int = 3,
                 min_spacing: float = 0.6, max_slew: float = 3.0) -> None:
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
        self._slope = self.nominal_period    # estimated device period [host s]
        self._period = self.nominal_period   # period of the stamping line (the slope plus a slew correction)
        self._anchor = 0.0              # relative host time of sequence 0 on the stamping line
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
        return self._slope

    @property
    def drift_ppm(self) -> float:
        """Estimated deviation of the device period from nominal, parts per million."""
        return (self._slope / self.nominal_period - 1.0) * 1e6

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
        key = relative - self._slope * sequence
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
        """Add the window's minimum, refit the line and steer towards it over the next window (from sequence `now`)."""
        sequence, relative, _ = self._window_best
        self._window_best = None
        self._minima.append((sequence, relative))
        points = np.array(self._minima, dtype=float)
        sequences, times = points[:, 0], points[:, 1]
        slope = self._slope
        if sequences[-1] - sequences[0] >= self.min_span * self.window:
            low = self.nominal_period * (1.0 - self.max_drift)
            high = self.nominal_period * (1.0 + self.max_drift)
            slope = min(high, max(low, _hull_slope(sequences, times)))
        # Lower envelope: the line with that slope under every window minimum. Steered towards over the next
        # window (at most `max_slew` x Ts), as a change of the stamping period, so stamps never jump; a sample
        # arriving below the line still lowers it at once (observe).
        target = float(np.min(times - slope * sequences))
        current = self._anchor + self._period * now
        wanted = target + slope * now
        step = self.max_slew * self.nominal_period
        correction = min(step, max(-step, wanted - current))
        self._slope = slope
        self._period = slope + correction / self.window
        self._anchor = current - self._period * now


def _hull_slope(x: np.ndarray, y: np.ndarray) -> float:
    """Slope of the lower convex hull of the points (x ascending) at the mean of x.

    Of all lines below every point, this one minimises the summed vertical distance to them (Moon, Skelly and
    Towsley 1999); points above the hull (delayed arrivals) do not move it.
    """
    hull: list[int] = []
    for k in range(len(x)):
        while len(hull) >= 2:
            i, j = hull[-2], hull[-1]
            # keep j only if i -> j -> k turns left (counter-clockwise): j is then below the chord i -> k
            if (x[j] - x[i]) * (y[k] - y[i]) - (y[j] - y[i]) * (x[k] - x[i]) > 0:
                break
            hull.pop()
        hull.append(k)
    middle = float(np.mean(x))
    for i, j in zip(hull[:-1], hull[1:]):
        if x[j] >= middle:
            return float((y[j] - y[i]) / (x[j] - x[i]))
    i, j = hull[-2], hull[-1]
    return float((y[j] - y[i]) / (x[j] - x[i]))
