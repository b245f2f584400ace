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

The clock is also *checked* (issue 23: a wrong clock used to be clamped silently):

* **rate**: besides the clamped slope used for stamping, the unclamped slope of the same hull (bounded to
  0.25x..4x nominal) is kept with an error bound (:attr:`SampleClock.rate_error`,
  :attr:`SampleClock.rate_error_bound`); :attr:`SampleClock.rate_fault` is true when the measured rate is outside
  ``max_drift`` by more than that bound (a device 1.5 % slow, or sending at twice its rate). A coarse check from the
  first arrival catches gross errors (2x) within ~1 s; the hull check needs ``min_span`` windows (~3 s) and
  :attr:`SampleClock.rate_verified` says whether it has run.
* **host clock steps** (an NTP step): an arrival earlier than the device counter allows by more than
  ``step_threshold`` (plus ``max_drift`` over the sequence step) can only be a host clock step back; arrivals all
  later than that for at least ``step_confirm`` s of host time are a step forward (or a device that stopped
  sampling): a host stall delivers its newest sample fresh and never confirms. The step is taken out of the arrival
  times, so the envelope goes on; **the stamps stay on the device's clock** (continuous, the device's spacing) and
  :attr:`SampleClock.host_offset` says how far they now are from the host clock.
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
    step_threshold : float
        Arrival-time jump [s] beyond which the host clock is taken to have stepped (default 0.5 s: far above USB
        and scheduling jitter; ntpd steps from 0.128 s, chrony's makestep commonly from 1 s). The lateness must
        *jump* by this much between two consecutive arrivals: a host that falls behind gradually (a loaded machine)
        is no step.
    step_confirm : float
        Host time [s] for which every arrival must stay off the line before a step is believed (default 1 s).
    """

    #: default believable clock error: a ceramic resonator
    DEFAULT_MAX_DRIFT = 6e-3

    def __init__(self, sample_period: float, window: int = 490, history: int = 60,
                 max_drift: float = DEFAULT_MAX_DRIFT, latency: float = 0.0, min_span: int = 3,
                 min_spacing: float = 0.6, max_slew: float = 3.0, step_threshold: float = 0.5,
                 step_confirm: float = 1.0) -> None:
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
        self.step_threshold = float(step_threshold)
        self.step_confirm = float(step_confirm)
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
        self._stamp_reference = None    # host time [s] of the stamping line's origin (never moved by host steps)
        self._first_point: tuple[int, float] | None = None
        self._late_since: tuple[float, float] | None = None   # (relative time, smallest lateness) of a late run
        self._observed_sequence: int | None = None
        self._raw_slope = self.nominal_period
        self._raw_bound = float('inf')
        self._coarse_fault = False
        self._coarse_since: float | None = None
        self._last_lateness = 0.0
        #: Whether the hull (``min_span`` windows) has checked the rate since the last reset.
        self.rate_verified = False
        #: Host clock steps detected since the last reset [s] (negative: the host clock went back), in order.
        self.host_steps: list[float] = []
        #: Offset of the stamps from the host clock [s]: the sum of the host steps (stamps - host clock = -offset).
        self.host_offset = 0.0

    @property
    def period(self) -> float:
        """Current estimate of the device's sampling period in host seconds."""
        return self._slope

    @property
    def drift_ppm(self) -> float:
        """Estimated deviation of the device period from nominal (as used for stamping, clamped), ppm."""
        return (self._slope / self.nominal_period - 1.0) * 1e6

    @property
    def rate_error(self) -> float:
        """Measured relative error of the device's sample period, unclamped (+0.015: 1.5 % slow; -0.5: samples at
        twice the nominal rate) [-]; 0 until measured."""
        return self._raw_slope / self.nominal_period - 1.0

    @property
    def rate_error_bound(self) -> float:
        """Uncertainty of :attr:`rate_error` from the arrival jitter over the measured span [-] (inf: none yet)."""
        return self._raw_bound

    @property
    def rate_error_bound_ppm(self) -> float:
        """:attr:`rate_error_bound` in ppm for display, at most 9.99e6 (inf before any measurement) [ppm]."""
        return min(self._raw_bound, 9.99) * 1e6

    @property
    def rate_fault(self) -> bool:
        """True when the measured rate is outside ``max_drift`` by more than its uncertainty."""
        if self.rate_verified:
            return abs(self.rate_error) - self._raw_bound > self.max_drift
        return self._coarse_fault

    @property
    def rate_within(self) -> bool:
        """True when the measured rate is inside ``max_drift`` by more than its uncertainty: shown good, not only
        "not a fault" (a rate whose +- spans the tolerance's edge is neither)."""
        return self.rate_verified and abs(self.rate_error) + self._raw_bound <= self.max_drift

    def stamp(self, sequence: int, arrival: float) -> float:
        """Acquisition time [s, host clock] of sample `sequence` that arrived at host time `arrival` [s].

        Sequences must not decrease between :meth:`reset` calls; gaps (lost samples) are fine.
        """
        return self.stamp_many([sequence], arrival)[0]

    def stamp_many(self, sequences, arrival: float, delay_bound: float | None = None) -> list[float]:
        """Stamps of several samples that arrived together (one read), in the order given.

        The newest of them had the least delay, so it alone updates the envelope; the others are placed on the
        line by their sequence numbers (a backlog read at once is spread over the times it was acquired, not
        piled up at the arrival time). `delay_bound`: see :meth:`observe`.
        """
        if not len(sequences):
            return []
        self.observe(max(sequences), arrival, delay_bound)
        return self.place(sequences)

    def envelope_arrival(self, sequence: int) -> float | None:
        """Host time [s] at which sample `sequence` arrived, or would have, with the link's least delay seen so far
        (the lower envelope's line; no state changes). None before the first :meth:`observe`.

        Unlike a read's arrival time it carries no scheduling delay: the end of a run measured with it is not moved
        later by a late read on a loaded host."""
        if self._reference is None:
            return None
        return self._reference + self._anchor + self._period * sequence

    def observe(self, sequence: int, arrival: float, delay_bound: float | None = None) -> None:
        """Update the envelope with one arrival (the newest sample of a read) without stamping anything.

        `delay_bound` [s]: the longest the sample can have waited on the host before this arrival, when the reader
        knows it (the time since it last found the port drained: a reader that fell behind on a loaded host knows
        its backlog waited). The rate's uncertainty then covers minima that came late; None: not known.
        """
        if self._reference is None:
            self._reference = self._stamp_reference = arrival
            self._anchor = -sequence * self._period
            self._window_start = sequence
            self._first_point = (sequence, 0.0)
        self.observed += 1
        if not self._check_step(sequence, arrival):
            return                      # a forward step not yet confirmed: this arrival moves nothing
        relative = arrival - self._reference
        # Window minimum of the arrival relative to a line of the current period (fixed within a window).
        key = relative - self._slope * sequence
        if self._window_best is None or key < self._window_best[2]:
            self._window_best = (sequence, relative, key, 0.0 if delay_bound is None else float(delay_bound))
        if sequence - self._window_start >= self.window:
            self._close_window(sequence)
            self._window_start = sequence
        predicted = self._anchor + self._period * sequence
        if relative < predicted:
            # Earlier than the lower envelope: this sample had less delay than any before; move the line down.
            self._anchor += relative - predicted

    def _check_step(self, sequence: int, arrival: float) -> bool:
        """Detect a host clock step (or a gross rate error) in this arrival; False while a run of arrivals off the
        line is being confirmed (such arrivals must not move the envelope).

        An arrival off the line by more than the allowed jitter starts a run; once the run spans ``step_confirm``
        s of host time it is judged: a constant offset (spread < ``step_threshold``) is a host clock step, taken
        out of ``_reference`` at the run's smallest delay; an offset that grows is no step (a host falling behind;
        a wrong device rate is measured by the window checks). One arrival back in line ends the run (a stall, a
        burst). The stamping line is never bent to a suspected rate: stamps of a clock outside tolerance are wrong
        by that rate, which is why the caller withholds them."""
        relative = arrival - self._reference
        lateness = relative - (self._anchor + self._period * sequence)
        since = sequence - (self._observed_sequence if self._observed_sequence is not None else sequence)
        self._observed_sequence = sequence
        allowed = self.step_threshold + self.max_drift * self.nominal_period * abs(since)
        jump = lateness - self._last_lateness
        self._last_lateness = lateness
        if abs(lateness) <= allowed or (self._late_since is not None and
                                        (lateness > 0) != (self._late_since[1] > 0)):
            self._late_since = None
            return True
        if self._late_since is None:
            if abs(jump) < self.step_threshold:
                return True             # drifted off gradually (a host falling behind): no step, the hull decides
            self._late_since = (relative, lateness, lateness)
            return False
        started, low, high = self._late_since
        low, high = min(low, lateness), max(high, lateness)
        self._late_since = (started, low, high)
        if relative - started < self.step_confirm:
            return False
        self._late_since = None
        if high - low < self.step_threshold:
            self._apply_step(low)
            return True
        # The offset grew within the run: a host falling behind (or the device's rate, which the window checks
        # measure): no step, and nothing here moves the stamping line.
        return True

    def _apply_step(self, step: float) -> None:
        """The host clock moved by `step` [s]: measure later arrivals from a reference moved by the same amount."""
        self._reference += step
        self.host_steps.append(float(step))
        self.host_offset += float(step)
        if self._window_best is not None:
            self._window_best = None        # its minimum straddles the step

    def place(self, sequences) -> list[float]:
        """Stamps [s] of `sequences` on the current line (after :meth:`observe`), in the order given.

        Consecutive stamps stay at least ``min_spacing`` x Ts x (sequence step) apart: when the line moves down
        (a less-delayed sample showed that earlier stamps were late) the following stamps catch up gradually
        instead of piling up on the last one.
        """
        if self._reference is None:
            raise ValueError('place() before any observe(): no anchor yet')
        stamps = []
        base = self._stamp_reference - self.latency   # steps of the host clock do not move the stamps
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
        sequence, relative, _, delay_bound = self._window_best
        self._window_best = None
        self._minima.append((sequence, relative, delay_bound))
        points = np.array(self._minima, dtype=float)
        sequences, times, delay_bounds = points[:, 0], points[:, 1], points[:, 2]
        slope = self._slope
        # The stamping line is fitted in host time measured from `_reference` (host steps taken out); the relative
        # times of the minima are on the same timeline.
        self._measure_rate(sequences, times, delay_bounds)
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

    def _measure_rate(self, sequences: np.ndarray, times: np.ndarray, delay_bounds: np.ndarray) -> None:
        """Unclamped rate of the device clock: the hull slope once ``min_span`` windows are in, before that a
        coarse slope from the first arrival to the newest window minimum (gross errors only)."""
        span = sequences[-1] - sequences[0]
        if span >= self.min_span * self.window and len(sequences) >= 2:
            self._raw_slope = _bounded(_hull_slope(sequences, times), self.nominal_period)
            low, high = _feasible_slopes(sequences, times, self._raw_slope, delay_bounds)
            # the distance to the farther feasible slope: never negative, also when the slope is clamped to its
            # bounds and every feasible slope lies beyond them (a device twice as fast said '± -0.00 %')
            self._raw_bound = max(abs(high - self._raw_slope), abs(self._raw_slope - low)) / self.nominal_period
            self.rate_verified = True
            return
        first_sequence, first_time = self._first_point
        steps = sequences[-1] - first_sequence
        elapsed = times[-1] - first_time
        if steps > 0 and elapsed > 0 and not self.rate_verified:
            self._raw_slope = _bounded(elapsed / steps, self.nominal_period)
            self._raw_bound = COARSE_JITTER / elapsed
            # A gross error must persist over step_confirm s of host time (a burst of late reads drains faster).
            if abs(self.rate_error) - self._raw_bound > self.max_drift:
                if self._coarse_since is None:
                    self._coarse_since = float(times[-1])
                self._coarse_fault = self._coarse_fault or times[-1] - self._coarse_since >= self.step_confirm
            else:
                self._coarse_since = None
                self._coarse_fault = False


#: Arrival jitter assumed by the coarse rate check (the first arrival against a window minimum) [s].
COARSE_JITTER = 0.5
#: Smallest uncertainty of a hull minimum [s] (the least-delayed arrival of ~1 s of USB reads); the scatter of the
#: minima above the hull raises it on a loaded host.
HULL_JITTER = 0.005
#: Bounds of the measured period, as fractions of nominal (the estimator never reports beyond them).
RATE_BOUNDS = (0.25, 4.0)


def _bounded(period: float, nominal: float) -> float:
    return min(RATE_BOUNDS[1] * nominal, max(RATE_BOUNDS[0] * nominal, period))


def _feasible_slopes(x: np.ndarray, y: np.ndarray, slope: float,
                     delay_bounds: np.ndarray | None = None) -> tuple[float, float]:
    """Range of line slopes [s per sample] consistent with the window minima (x sequences, y times [s]).

    Each minimum lies above the true line (an arrival is never before its acquisition) by a delay of at most J;
    J is taken as the largest height of the minima above the lowest line of `slope` (at least HULL_JITTER, so
    `slope` itself is always in the range), or the minimum's own `delay_bounds` [s] where the reader knows a larger
    one (it had fallen behind: a delay that grows over the span looks like a slower clock, and only the reader can
    tell). Every pair of minima then bounds the slope: (dy - J_j)/dx <= s <= (dy + J_i)/dx; the range is the
    intersection (the longest pairs decide: about +-2J/span).
    """
    heights = y - slope * x
    jitter = np.full(len(x), max(HULL_JITTER, float(np.max(heights) - np.min(heights))))
    if delay_bounds is not None:
        jitter = np.maximum(jitter, delay_bounds)
    i, j = np.triu_indices(len(x), k=1)
    dx = x[j] - x[i]
    dy = y[j] - y[i]
    keep = dx > 0
    if not np.any(keep):
        return -np.inf, np.inf
    return (float(np.max((dy[keep] - jitter[j][keep]) / dx[keep])),
            float(np.min((dy[keep] + jitter[i][keep]) / dx[keep])))


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
