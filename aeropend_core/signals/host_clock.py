"""Time from the sample order when the stamps are a host's (a PC stamping lines as its serial buffer delivers them).

A logger that prints one line every N PWM periods emits lines at a constant rate; the PC that stamps them sees them
late, by a delay that is usually a few milliseconds and sometimes, when the operating system or the logging program
stalls, a few hundred, after which the buffered lines arrive in a burst with (nearly) equal stamps. Such stamps are
not rounded times: each stamp is the emission time plus a delay >= 0. The emission times are recovered from the
sample order: ``t_k = t_0 + k / rate``, the rate given (``--sample-rate``, a log profile) or fitted to the lower
envelope of the stamps (a robust line through the earliest stamp of each block of lines, which carries the
smallest delays). What the stamps then say about the record is checked, not assumed:

* the residual ``stamp - grid`` is the delay, >= 0 within the clock's resolution; its median and largest values
  are reported with the repair;
* a step of the envelope by about one line period or more is lines lost (the later lines are stamped one or more
  periods "early" for their index); a trend of the envelope is a rate that is not the one assumed, or a rate that
  changed: both are refused, with where it happens and what to do.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Lines per block of the lower envelope (the earliest stamp of each block is taken as undelayed).
ENVELOPE_BLOCK_LINES = 40
#: The envelope may wander by this fraction of a line period (or the clock's resolution, if coarser) before the
#: stamps are said to contradict a constant rate.
ENVELOPE_TOLERANCE = 0.45
#: Relative difference between a given rate and the one the stamps' envelope shows that is refused.
RATE_MISMATCH = 0.01


@dataclass(frozen=True)
class RegularisedClock:
    """Time stamps regularised from the sample order.

    Attributes
    ----------
    time : ndarray, shape (n,) [s]
        ``t_0 + k * period`` for sample k.
    period : float [s]
        The line period used (given or fitted).
    rate_given : bool [-]
        True when the period was given (``--sample-rate``, a profile), False when fitted to the stamps.
    delay_median, delay_max : float [s]
        Median and largest stamp minus grid (the host's delay, bursts included).
    envelope_rms : float [s]
        RMS of the lower envelope of the stamps about the grid: how well one constant rate fits them.
    bursts : int [-]
        Lines stamped less than a quarter period after the line before (delivered in a burst).
    """

    time: np.ndarray
    period: float
    rate_given: bool
    delay_median: float
    delay_max: float
    envelope_rms: float
    bursts: int

    def describe(self) -> str:
        """One sentence saying what was done and how well it fits."""
        how = 'given' if self.rate_given else 'fitted to the earliest stamps'
        return (f'time regularised from the sample order at {1 / self.period:.6g} Hz ({how}); the host stamps lag '
                f'that grid by {self.delay_median * 1e3:.3g} ms (median) and up to {self.delay_max * 1e3:.4g} ms '
                f'({self.bursts} line(s) delivered in bursts), their earliest stamps fit it within '
                f'{self.envelope_rms * 1e3:.3g} ms RMS')


class ClockContradiction(ValueError):
    """The stamps contradict a constant line rate; the message says where, the likely cause and the fix."""


def looks_host_buffered(time: np.ndarray) -> bool:
    """True when stamps show host buffering: non-decreasing, most lines one step apart (median step at least half the
    mean), with bursts (steps under a quarter of the mean step in at least 2 % of the lines) and stalls (a step of
    at least twice the mean step)."""
    time = np.asarray(time, dtype=float)
    if time.size < 20 or not np.all(np.isfinite(time)):
        return False
    step = np.diff(time)
    if np.any(step < 0):
        return False
    mean_step = (time[-1] - time[0]) / (time.size - 1)
    if not mean_step > 0:
        return False
    # most lines arrive one by one (median step near the mean): stamps rounded to a coarse clock (epoch seconds,
    # 490 lines per stamp) have a zero median step and are the precision check's business
    return bool(np.mean(step < 0.25 * mean_step) >= 0.02 and np.max(step) >= 2.0 * mean_step
                and np.median(step) >= 0.5 * mean_step)


def _envelope(time: np.ndarray, period: float) -> tuple[np.ndarray, np.ndarray]:
    """Index and residual (stamp - index x period) of the earliest-for-its-index stamp of each block."""
    index = np.arange(time.size, dtype=float)
    residual = time - index * period
    block = max(ENVELOPE_BLOCK_LINES, time.size // 200)
    starts = np.arange(0, time.size, block)
    where = np.array([s + int(np.argmin(residual[s:s + block])) for s in starts])
    return index[where], residual[where]


def regularise(time: np.ndarray, rate: float | None = None, resolution: float = 0.0) -> RegularisedClock:
    """Regularise host stamps from the sample order.

    Parameters
    ----------
    time : ndarray, shape (n,) [s]
        The host stamps (any origin), non-decreasing.
    rate : float, optional [Hz]
        The device's line rate when known; None: fitted to the stamps' lower envelope.
    resolution : float [s]
        Resolution of the stamps (e.g. 1e-3 for milliseconds); widens the tolerance of the checks.

    Returns
    -------
    RegularisedClock

    Raises
    ------
    ClockContradiction
        The stamps go backwards, lines were lost (a step of the envelope), or the rate is not constant or not the
        given one; the message says which, where, and what to do.
    """
    from scipy.stats import theilslopes
    time = np.asarray(time, dtype=float)
    n = time.size
    if n < 3:
        raise ClockContradiction('too few stamps to regularise')
    back = np.flatnonzero(np.diff(time) < 0)
    if back.size:
        raise ClockContradiction(f'the stamps go backwards at line {back[0] + 1}: the lines are out of order or the '
                                 'clock was set back; sort them or split the record there')
    period = (time[-1] - time[0]) / (n - 1)
    for _ in range(3):          # the envelope's slope corrects the end-to-end mean (whose ends may be delayed)
        idx, res = _envelope(time, period)
        if idx.size < 3:
            break
        slope = theilslopes(res, idx)[0]
        period += slope
    fitted_period = period
    given = rate is not None
    if given:
        period = 1.0 / rate
        if abs(fitted_period / period - 1.0) > RATE_MISMATCH:
            raise ClockContradiction(
                f'the stamps advance by {fitted_period * 1e3:.4g} ms per line ({1 / fitted_period:.5g} Hz) but the '
                f'given rate is {rate:.6g} Hz: lines were lost or the rate is wrong; give the rate the device logs '
                'at (the stamps suggest ' f'{1 / fitted_period:.5g} Hz), or the device\'s own counter as time')
    idx, res = _envelope(time, period)
    # the earliest stamp over three neighbouring blocks: a block whose every line was held back by stalls in a row
    # is a bump that returns, lost lines a step that stays (and stays in this minimum too)
    from scipy.ndimage import minimum_filter1d
    res = minimum_filter1d(res, 3, mode='nearest') if res.size >= 3 else res
    offset = float(np.median(res))
    deviation = res - offset
    tolerance = max(ENVELOPE_TOLERANCE * period, 2.0 * resolution)
    if np.ptp(deviation) > 2 * tolerance:
        jumps = np.diff(deviation)
        k = int(np.argmax(np.abs(jumps)))
        line = int(idx[k + 1])
        lines = jumps[k] / period
        if abs(jumps[k]) > 0.6 * np.ptp(deviation) and abs(lines) >= 0.6:
            cause = (f'about {abs(lines):.1f} line period(s) {"lost" if lines > 0 else "too many"} between lines '
                     f'{int(idx[k])} and {line} (t = {time[line] - time[0]:.3f} s into the record)')
            fix = ('split the record there (--start/--stop), or log a line counter (a sequence column) so that '
                   'lost lines are seen as gaps')
        else:
            cause = (f'the earliest stamps drift from one constant rate by up to {np.ptp(deviation) * 1e3:.4g} ms '
                     f'({np.ptp(deviation) / period:.2g} line periods): the rate changed during the record')
            fix = 'split the record where the rate changed, or give the device\'s own counter as time'
        raise ClockContradiction(f'the host stamps contradict a constant line rate of {1 / period:.6g} Hz: {cause}; '
                                 f'{fix}')
    grid = offset + np.arange(n) * period
    delay = time - grid
    if np.min(delay) < -tolerance:
        k = int(np.argmin(delay))
        raise ClockContradiction(f'line {k} is stamped {-np.min(delay) * 1e3:.3g} ms before its place at '
                                 f'{1 / period:.6g} Hz: lines were lost before it or the rate is not constant; split '
                                 'the record there or log a line counter')
    steps = np.diff(time)
    return RegularisedClock(time=grid, period=float(period), rate_given=given,
                            delay_median=float(np.median(delay)), delay_max=float(np.max(delay)),
                            envelope_rms=float(np.sqrt(np.mean(deviation ** 2))),
                            bursts=int(np.count_nonzero(steps < 0.25 * period)))


def resolution_of(time: np.ndarray) -> float:
    """The stamps' resolution [s]: the smallest positive step, if the steps are whole multiples of it (else 0)."""
    step = np.diff(np.asarray(time, dtype=float))
    positive = step[step > 0]
    if positive.size == 0:
        return 0.0
    quantum = float(np.min(positive))
    units = positive / quantum
    return quantum if np.mean(np.abs(units - np.round(units)) < 0.02) > 0.98 and quantum > 0 else 0.0


__all__ = ['RegularisedClock', 'ClockContradiction', 'looks_host_buffered', 'regularise', 'resolution_of']
