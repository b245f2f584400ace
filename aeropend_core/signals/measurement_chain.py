"""Undo a known measurement chain on a recorded angle before an equation fit (weak SINDy).

The rig's angle passes a 2nd-order RC low-pass (:mod:`aeropend_core.rig.calibration`, ``angle_filter_delay``):
``H(s) = 1 / ((d s / 3)^2 + d s + 1)`` with DC group delay ``d``. Its inverse, ``1 + d s + (d s)^2 / 9``, agrees
with a time advance ``exp(d s) = 1 + d s + (d s)^2 / 2 + ...`` to first order in ``d s``: at the pendulum's
frequencies (below ~3 Hz, ``d s`` < 0.27 for 14 ms) advancing the angle by ``d`` removes the filter's phase lag
and leaves an amplitude error below ``(d w)^2 / 2`` (3.5 % at 3 Hz for 14 ms; 0.8 % at the rod's ~1.9 Hz).
Differentiating the angle to invert ``H`` exactly would amplify its noise; the output-error diagnosis models the
filter exactly instead (the angle-filter effect of the catalog, held at ``d``).
"""
from __future__ import annotations

import numpy as np

from aeropend_core.errors import InsufficientDataError


def advance_angle(time: np.ndarray, angle: np.ndarray, delay: float) -> tuple[np.ndarray, np.ndarray]:
    """The angle advanced by `delay`: ``angle(t + delay)`` by linear interpolation, on the samples that have it.

    Parameters
    ----------
    time : ndarray, shape (n,) [s]
        Sample times, increasing.
    angle : ndarray, shape (n,) [rad]
        The angle as measured through the filter.
    delay : float [s]
        The filter's DC group delay (0: unchanged).

    Returns
    -------
    keep : ndarray of bool, shape (n,)
        The samples kept (the last ones, within `delay` of the end, have no later sample to take the angle from).
    advanced : ndarray, shape (count of kept,) [rad]
        The advanced angle at the kept samples.
    """
    time = np.asarray(time, dtype=float)
    angle = np.asarray(angle, dtype=float)
    keep = time + delay <= time[-1] if time.size else np.zeros(0, dtype=bool)
    if not np.any(keep):
        raise InsufficientDataError(f'a record of {time.size} samples is shorter than the angle filter delay '
                                    f'{delay:g} s')
    return keep, np.interp(time[keep] + delay, time, angle)
