"""The character of what a model leaves unexplained: its size beyond the noise, its correlation time and its spectrum.

A real rig always leaves a remainder the catalog cannot write. Said beside the verdict, its character tells a user
what kind of thing it is: a remainder of slow, long-correlated error (a correlation time of seconds, power below 1 Hz)
is a missing torque or a drift; one of fast, short-correlated error near the sensor's bandwidth is a sensor effect; one
within the noise is nothing to chase.

The held-out part's free-run residual (measured minus simulated angle) is used, stretch by stretch:

* ``correlation_time`` [s]: the lag at which its autocorrelation (as scipy.signal.correlate, averaged over stretches
  weighted by length) first falls below 1/e;
* ``median_frequency`` [Hz]: the frequency below which half of the power beyond the white-noise floor lies (Welch's
  periodogram as scipy.signal.welch gives it, with the noise RMS's flat spectrum removed);
* ``beyond_noise`` [rad]: the RMS error beyond the noise.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Remainder:
    """What a model leaves unexplained on the held-out part (module docstring). NaN where not measurable."""

    beyond_noise: float          #: [rad]
    noise_rms: float             #: [rad]
    correlation_time: float      #: [s]
    median_frequency: float      #: [Hz]

    @property
    def material(self) -> bool:
        """Beyond half the noise RMS (the diagnosis's line for "unexplained")."""
        return math.isfinite(self.beyond_noise) and self.beyond_noise > 0.5 * self.noise_rms

    def to_dict(self) -> dict:
        def finite(value):
            return float(value) if math.isfinite(value) else None
        return {'error_beyond_noise': finite(self.beyond_noise), 'unit': 'rad', 'noise_rms': finite(self.noise_rms),
                'correlation_time': finite(self.correlation_time), 'correlation_time_unit': 's',
                'median_frequency': finite(self.median_frequency), 'median_frequency_unit': 'Hz',
                'material': self.material}

    def sentence(self) -> str:
        """One sentence for a person (mrad, s, Hz)."""
        size = f'{self.beyond_noise * 1e3:.2f} mrad RMS beyond the noise ({self.noise_rms * 1e3:.2f} mrad)'
        if not self.material:
            return f'What is left: {size}, within half the noise: nothing to chase.'
        parts = ['']
        if math.isfinite(self.correlation_time):
            parts.append(f'correlated over {self.correlation_time:.2g} s')
        if math.isfinite(self.median_frequency):
            parts.append(f'half its power beyond the noise below {self.median_frequency:.2g} Hz')
        kind = ''
        if math.isfinite(self.median_frequency):
            kind = (' -- slow: a torque or force the model lacks, or a drift' if self.median_frequency < 2.0 else
                    ' -- fast: look at the sensor (a filter, a lag, glitches) or the motor')
        return f'What is left unexplained: {size}' + ', '.join(parts) + kind + '.'


def _stretches(index: np.ndarray) -> list[np.ndarray]:
    """Runs of `index` at one stride (the held-out residuals are every STRIDE-th sample), each at least 64 long.

    The stride is the most common step, not the smallest: one short step where two pieces of the held-out part
    meet made the smallest step 1, cut every run to one sample and left the correlation time NaN."""
    if index.size < 2:
        return []
    values, counts = np.unique(np.diff(index), return_counts=True)
    stride = int(values[np.argmax(counts)])
    breaks = np.flatnonzero(np.diff(index) != stride) + 1
    return [piece for piece in np.split(index, breaks) if piece.size >= 64]


def remainder_of(prep, comparison) -> Remainder:
    """The :class:`Remainder` of `comparison` on `prep`'s held-out part."""
    from aeropend_core.diagnosis.compare import excess_error
    from aeropend_core.signals.filters import autocorrelation, welch_density
    noise = float(comparison.noise_rms)
    beyond = float(excess_error(comparison.rms_error, noise))
    residual = prep.angle - comparison.evaluation.simulated
    stretches = _stretches(np.asarray(prep.heldout.residual_index))
    step = prep.sample_time * (int(stretches[0][1] - stretches[0][0]) if stretches else 1)
    pieces = [residual[p] for p in stretches]
    pieces = [p for p in pieces if np.all(np.isfinite(p))]
    if not pieces:
        return Remainder(beyond, noise, math.nan, math.nan)
    longest = max(p.size for p in pieces)
    lags = min(longest // 2, int(5.0 / step))
    acf, weight = np.zeros(lags), 0.0
    spectra, frequencies = [], None
    segment = min(longest, int(8.0 / step))
    for piece in pieces:
        centred = piece - piece.mean()
        full = autocorrelation(centred)[centred.size - 1:]
        if full[0] <= 0:
            continue
        count = min(lags, full.size)
        acf[:count] += piece.size * full[:count] / full[0]
        weight += piece.size
        if piece.size >= segment:
            frequencies, power = welch_density(centred, 1.0 / step, segment)
            spectra.append(power)
    correlation_time = math.nan
    if weight > 0:
        acf /= weight
        below = np.flatnonzero(acf < math.exp(-1.0))
        correlation_time = float(below[0] * step) if below.size else math.nan
    median_frequency = math.nan
    if spectra:
        excess = np.clip(np.mean(spectra, axis=0) - 2.0 * noise ** 2 * step, 0.0, None)
        cumulative = np.cumsum(excess)
        if cumulative[-1] > 0:
            median_frequency = float(frequencies[np.searchsorted(cumulative, 0.5 * cumulative[-1])])
    return Remainder(beyond, noise, correlation_time, median_frequency)


__all__ = ['Remainder', 'remainder_of']
