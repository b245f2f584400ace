"""Measurement noise at a stated PSNR and the rig's ADC quantisation.

PSNR (peak signal-to-noise ratio) per signal: ``PSNR = 20 log10(max|x| / sigma)`` [dB], with sigma the standard
deviation of additive white Gaussian noise. 50 dB means sigma = max|x| / 316; 40 dB means max|x| / 100.

Quantisation mimics the rig: the AS5040 angle through a 10-bit ADC (one count = 2 pi / 1024 rad = 0.35 deg) and
the motor shield's current sense (3.3 V <-> 2 A) read by the 10-bit, 5 V ADC (one count = 2.96 mA). The sense is
taken as bipolar (braking current keeps its sign); a real shield's unipolar sense would clip it.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from aeropend_core.errors import AeropendError

#: One count of the 10-bit angle [rad].
ANGLE_LSB = 2.0 * np.pi / 1024
#: One count of the current sense [A]: 2 A at 3.3 V on a 10-bit ADC with a 5 V reference.
CURRENT_LSB = 2.0 / 3.3 * 5.0 / 1024
#: Full-scale peaks used for a stream's PSNR when no record exists yet: Va at duty 1 [V], 2 A, 90 deg.
FULL_SCALE = {'armature_voltage': 2.32, 'armature_current': 2.0, 'angle': np.pi / 2}


def sigma_for_psnr(peak: float, psnr_db: float) -> float:
    """Noise standard deviation giving `psnr_db` for a signal whose max |x| is `peak`."""
    return float(peak) / 10.0 ** (psnr_db / 20.0)


def psnr(clean: np.ndarray, noisy: np.ndarray) -> float:
    """Measured PSNR [dB] of `noisy` against `clean`: 20 log10(max|clean| / rms(noisy - clean))."""
    error = np.sqrt(np.mean((np.asarray(noisy) - np.asarray(clean)) ** 2))
    return float(20.0 * np.log10(np.max(np.abs(clean)) / error))


def add_noise(signal: np.ndarray, psnr_db: float, rng: np.random.Generator,
              peak: float | None = None) -> np.ndarray:
    """`signal` plus white Gaussian noise at `psnr_db` (peak = max|signal| unless given)."""
    signal = np.asarray(signal, dtype=float)
    if not np.isfinite(psnr_db):
        raise AeropendError(f'PSNR must be a finite number of dB, got {psnr_db!r}')
    peak = float(np.max(np.abs(signal))) if peak is None else float(peak)
    return signal + rng.normal(0.0, sigma_for_psnr(peak, psnr_db), size=signal.shape)


def quantise(signal: np.ndarray, step: float) -> np.ndarray:
    """Round to the nearest multiple of `step` (an ADC with that resolution)."""
    return np.round(np.asarray(signal, dtype=float) / step) * step


@dataclass(frozen=True)
class MeasurementNoise:
    """Noise added to the rig's measured signals.

    Parameters
    ----------
    psnr_db : float or None [dB]
        PSNR of additive Gaussian noise on each signal in `signals`, 20 log10(max|x| / sigma); None for no noise.
    quantise : bool [-]
        Also quantise the angle (10 bit) and the current (2.96 mA) like the rig's ADC.
    signals : tuple of str [-]
        Which signals get noise; Va is computed from the duty on the rig, but noise on it models the fit error.
    peaks : mapping of str -> float [unit of each signal]
        Peak |x| per signal for the PSNR of a stream (batch simulation uses each record's own max).

    Examples
    --------
    >>> import numpy as np
    >>> from aeropend_core import MeasurementNoise, simulate
    >>> noise = MeasurementNoise(psnr_db=40, quantise=True)            # the rig's 10-bit angle ADC too
    >>> clean, noisy = simulate(np.full(490, 0.5), seed=1), simulate(np.full(490, 0.5), noise=noise, seed=1)
    >>> 0 < float(np.std(noisy.angle - clean.angle)) < 0.01                            # rad
    True
    """

    psnr_db: float | None = None
    quantise: bool = False
    signals: tuple[str, ...] = ('armature_voltage', 'armature_current', 'angle')
    peaks: Mapping[str, float] = field(default_factory=lambda: dict(FULL_SCALE))


def apply_measurement_noise(measured: Mapping[str, np.ndarray], noise: MeasurementNoise,
                            rng: np.random.Generator, peaks_from_data: bool = False) -> dict[str, np.ndarray]:
    """Return a copy of `measured` with noise (and quantisation) per `noise`."""
    result = {name: np.array(values, dtype=float) for name, values in measured.items()}
    if noise.psnr_db is not None:
        for name in noise.signals:
            if name in result:
                peak = None if peaks_from_data else noise.peaks.get(name)
                result[name] = add_noise(result[name], noise.psnr_db, rng, peak)
    if noise.quantise:
        if 'angle' in result:
            result['angle'] = quantise(result['angle'], ANGLE_LSB)
        if 'armature_current' in result:
            result['armature_current'] = quantise(result['armature_current'], CURRENT_LSB)
    return result
