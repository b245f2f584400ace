"""The angle sensor's analogue low-pass: a 2nd-order RC ladder, described by its DC group delay.

The rig reads the AS5040 encoder's PWM output through two RC sections (R1 = R2 = 4.7 kOhm, C1 = C2 = 1 uF,
tau = RC = 4.7 ms). Unbuffered, equal sections give

    H(s) = 1 / ((tau s)^2 + 3 tau s + 1),   DC group delay d = 3 tau = 14.1 ms,   -3 dB cut-off f_c = 0.1787 / d
                                                                                   (12.7 Hz for the rig).

The filter is parameterised by its delay ``d`` [s] because that is what the pendulum data see: far below the
cut-off any 2nd-order low-pass acts as a delay of d (a Butterworth with cut-off f_c has d = sqrt(2)/(2 pi f_c)),
so the number transfers between filter shapes. This module is the one implementation used by the simulator
(sampled at Ts) and by the output-error kernel (sampled at its integration step): the filter is discretised
with a first-order hold (the angle is smooth between samples) and run as :func:`scipy.signal.lfilter` does
(:mod:`aeropend_core.signals.filters`: scipy.signal's numbers without importing it).
"""
from __future__ import annotations

import functools

import numpy as np

#: The rig's RC values (R1 = R2 [ohm], C1 = C2 [F]) and the filter delay they give [s].
RIG_RESISTANCE = 4.7e3
RIG_CAPACITANCE = 1e-6
RIG_FILTER_DELAY = 3.0 * RIG_RESISTANCE * RIG_CAPACITANCE
#: Delays below this [s] are read as no filter (far below any sample step; the discretisation is ill-conditioned
#: there).
MIN_DELAY = 1e-4


def cutoff_frequency(delay: float) -> float:
    """-3 dB cut-off [Hz] of the equal-section RC ladder with DC group delay `delay` [s]."""
    return 0.1787 / delay


@functools.lru_cache(maxsize=256)
def coefficients(delay: float, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Discrete (b, a) of the ladder with DC delay `delay` [s], first-order hold at `step` [s]."""
    from aeropend_core.signals.filters import foh_transfer_function   # scipy.signal's cont2discrete, bit for bit,
    tau = delay / 3.0                                                 # without its ~0.3-1 s import (issue 41)
    b, a = foh_transfer_function([1.0], [tau * tau, 3.0 * tau, 1.0], step)
    b = np.atleast_1d(np.squeeze(b))
    return b / a[0], a / a[0]


def filter_angle(angle: np.ndarray, delay: float, step: float, rate: float = 0.0) -> np.ndarray:
    """The angle [rad] sampled every `step` [s] as read through the filter, started in its steady ramp response.

    `rate` [rad/s] is the angle's rate at the first sample; before it the angle is taken as the ramp through the
    first sample with that rate (so the filter output starts at ``angle[0] - delay * rate``).
    """
    angle = np.asarray(angle, dtype=float)
    if not delay >= MIN_DELAY or angle.size == 0:
        return angle.copy()
    from aeropend_core.signals.filters import lfilter, lfiltic
    b, a = coefficients(float(delay), float(step))
    order = max(len(a), len(b)) - 1
    past = np.arange(1, order + 1) * step
    x_past = angle[0] - rate * past
    y_past = angle[0] - rate * (past + delay)
    zi = lfiltic(b, a, y_past, x_past)
    return lfilter(b, a, angle, zi=zi)[0]


class StreamingFilter:
    """The same filter over consecutive blocks of samples (the streaming simulator); starts at rest."""

    def __init__(self, delay: float, step: float) -> None:
        self.b, self.a = coefficients(max(float(delay), MIN_DELAY), float(step))
        self.state: np.ndarray | None = None

    def __call__(self, angle: np.ndarray) -> np.ndarray:
        angle = np.asarray(angle, dtype=float)
        if angle.size == 0:
            return angle.copy()
        from aeropend_core.signals.filters import lfilter, lfilter_zi
        if self.state is None:
            self.state = lfilter_zi(self.b, self.a) * angle[0]
        out, self.state = lfilter(self.b, self.a, angle, zi=self.state)
        return out


__all__ = ['RIG_FILTER_DELAY', 'cutoff_frequency', 'coefficients', 'filter_angle', 'StreamingFilter']
