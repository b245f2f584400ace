"""Conditioning of measured Va, Ia and angle before an output-error fit.

Two things matter (``docs/method.md`` section 2.2):

* At each duty step the quasi-static motor speed (Va - Ra Ia)/Kw of eq (5) has a spurious kick, because eq (5)
  neglects La dIa/dt and the electrical time constant La/Ra ~ 2 ms is one sample. The true motor speed is
  continuous (rotor inertia), so the few samples after a step of Va are replaced by a straight line between the
  samples on either side.
* Noise in Ia passes through the quadratic thrust terms; a zero-phase low-pass (no phase lag, so it cannot fake a
  thrust lag) well above the motor's and the pendulum's bandwidth removes most of it.

Both operations are linear, so conditioning Va and Ia separately conditions every combination Va - R Ia exactly
(R is fitted later).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aeropend_core.signals.filters import butter_lowpass_sos, savgol_filter, sosfiltfilt

#: Time after a step of Va bridged by interpolation [s]: ~10 ms ~ 5 La/Ra (5 samples at the rig's 490 Hz).
STEP_SETTLING_TIME = 5.0 / 490.0
#: Samples after a step of Va bridged at the rig's 490 Hz (:func:`settling_samples` gives it at any rate).
STEP_SETTLING_SAMPLES = 5


def settling_samples(sample_time: float) -> int:
    """Samples [-] covering :data:`STEP_SETTLING_TIME` at the sample time `sample_time` [s] (at least one).

    At 490 Hz 5 samples; at 25 Hz or slower the electrical transient is over within the first sample, and one
    sample after the step is bridged.
    """
    return max(1, int(math.ceil(STEP_SETTLING_TIME / sample_time - 1e-9)))
#: Cut-off of the zero-phase low-pass applied to Va and Ia [Hz]; the pendulum and motor respond below ~5 Hz.
INPUT_CUTOFF_HZ = 25.0


def quantisation_step(signal: np.ndarray) -> float:
    """The ADC step of a quantised signal [its unit] (0 when its values do not lie on a grid).

    The smallest gap between distinct values is the candidate step; the signal counts as quantised when at least
    99 % of its values are whole multiples of it (from the smallest value) within 1 %.
    """
    signal = np.asarray(signal, dtype=float)
    values = np.unique(signal[np.isfinite(signal)])
    if values.size < 3:
        return 0.0
    gaps = np.diff(values)
    step = float(np.min(gaps))
    if not step > 0:
        return 0.0
    units = (signal - values[0]) / step
    on_grid = np.abs(units - np.round(units)) < 0.01
    return step if np.mean(on_grid) >= 0.99 and values.size < 0.5 * signal.size else 0.0


def quantisation_bias_rms(step: float, noise: float) -> float:
    """RMS [unit of `step`] of the bias a quantiser leaves in the mean reading of a held (slowly moving) value.

    With Gaussian noise of standard deviation sigma added before an ADC of step q, the mean reading of a value
    held at a fraction u of a step is off by about ``(q / pi) exp(-2 pi^2 sigma^2 / q^2) sin(2 pi u)`` (the first
    Fourier term of the rounding error, smoothed by the noise): dithered away when sigma is a step or more (at
    sigma = q: 3e-9 q), up to 0.3 q without noise. Over random positions u its RMS is that amplitude / sqrt(2).
    sigma is taken as ``sqrt(max(noise^2 - q^2 / 12, 0))`` from the measured noise RMS, which holds the
    quantisation's own q^2/12 when dithered (conservative when not: it underestimates sigma).

    Parameters
    ----------
    step : float
        The ADC step q [unit of the signal]; 0 for a signal that is not quantised.
    noise : float
        The measured noise RMS of the quantised signal [unit of the signal].
    """
    if not step > 0:
        return 0.0
    sigma_squared = max(noise ** 2 - step ** 2 / 12.0, 0.0)
    return float(step / math.pi * math.exp(-2.0 * math.pi ** 2 * sigma_squared / step ** 2) / math.sqrt(2.0))


def noise_rms(signal: np.ndarray) -> float:
    """Robust estimate of the white measurement-noise RMS of a smooth signal sampled fast (same units as signal).

    Uses the third difference, which cancels any signal smooth over four samples (variance 20 sigma^2 for white
    noise), with the median absolute deviation for robustness to steps. Quantisation is counted as far as it
    varies from sample to sample.
    """
    signal = np.asarray(signal, dtype=float)
    if signal.size < 8:
        return float('nan')
    third = np.diff(signal, n=3)
    # The MAD alone is biased when quantisation is mixed in; it only sets the clipping of outliers.
    mad = 1.4826 * np.median(np.abs(third - np.median(third)))
    if mad > 0:
        third = third[np.abs(third - np.median(third)) < 8.0 * mad]
        return float(np.std(third) / np.sqrt(20.0))
    # Mostly constant (noise-free or coarsely quantised) signal: the few large values are steps. Drop the largest
    # 1 % and undo the trimming's shrinkage for Gaussian noise (a 2.576-sigma cut keeps 96.2 % of the std).
    kept = np.sort(np.abs(third))[:max(1, int(0.99 * third.size))]
    return float(np.sqrt(np.mean(kept ** 2)) / 0.9617 / np.sqrt(20.0))


def _exact_median(values: np.ndarray) -> float:
    """np.median of a 1-D float array, the same value (the middle element, or the mean of the two middle ones),
    through one partition (selection: no sort, no rounding)."""
    k = values.size // 2
    if values.size % 2:
        return float(np.partition(values, k)[k])
    part = np.partition(values, (k - 1, k))
    return float((part[k - 1] + part[k]) / 2)


def _third_difference_mad(x):
    """(median absolute deviation of the third difference, the third difference), as np.diff(x, 3) and
    np.median give them (selection by partition: the same values, several times faster than a sort)."""
    third = np.diff(x, 3)
    deviation = np.abs(third - _exact_median(third))
    return _exact_median(deviation), third


def estimate_noise_std(signal: np.ndarray) -> float:
    """The weak-SINDy variant of :func:`noise_rms` (its GLS weights): robust white-noise standard deviation of a
    smoothly varying, densely sampled signal (signal's units).

    The third difference cancels anything smooth over four samples (variance 20σ² for white noise); the median
    absolute deviation ignores the few samples around steps. When the MAD is 0 (quantised or held signals), the
    standard deviation of the third difference is used if at least 10 % of it is non-zero (quantisation of a
    moving signal); otherwise the signal is piecewise constant (a held input) and counts as noiseless.
    """
    x = np.asarray(signal, float)
    if x.size < 8:
        return 0.0
    mad, third = _third_difference_mad(np.ascontiguousarray(x))
    if mad > 0:
        return 1.4826 * mad / math.sqrt(20.0)
    if np.count_nonzero(third) < 0.1 * third.size:
        return 0.0
    return float(np.std(third) / math.sqrt(20.0))


#: Shortest level [s] :func:`detect_steps` splits off (10 samples at 490 Hz; at least 3 samples at a low rate).
MIN_LEVEL_TIME = 10.0 / 490.0


def detect_steps(armature_voltage: np.ndarray, sample_time: float, threshold: float = 6.0,
                 min_length: int | None = None) -> np.ndarray:
    """Indices k where a step of the armature voltage lands (Va[k] differs from Va[k-1] beyond the noise).

    Binary segmentation: in each interval, the split that maximises the two-sample t statistic of the means on
    either side is kept if that statistic exceeds `threshold` (well above the ~4.5 that pure noise reaches over
    10^4 candidate positions) and the jump exceeds 1 % of the peak; both halves are searched again. Steps a few
    noise standard deviations high are found this way, where a sliding window misses them. `min_length` [samples],
    the shortest level split off, defaults to :data:`MIN_LEVEL_TIME` at `sample_time` [s], at least 3 samples (10
    samples at 49 Hz left a step 4 samples before a record's end unfound, the level "not piecewise constant" and
    the motor observer unused: gravity_stiffness -13 %, thrust_gain -19 %).
    """
    voltage = np.asarray(armature_voltage, dtype=float)
    if min_length is None:
        min_length = max(3, int(round(MIN_LEVEL_TIME / sample_time))) if sample_time > 0 else 10
    n = voltage.size
    if n < 4 * min_length:
        return np.zeros(0, dtype=int)
    sigma = max(noise_rms(voltage), 1e-12)
    floor = 0.01 * max(np.max(np.abs(voltage)), 1e-12)
    cumulative = np.concatenate(([0.0], np.cumsum(voltage)))
    found: list[int] = []
    pending = [(0, n)]
    while pending:
        start, stop = pending.pop()
        length = stop - start
        if length < 2 * min_length:
            continue
        split = np.arange(start + min_length, stop - min_length + 1)
        left_n = split - start
        right_n = stop - split
        left_mean = (cumulative[split] - cumulative[start]) / left_n
        right_mean = (cumulative[stop] - cumulative[split]) / right_n
        jump = np.abs(right_mean - left_mean)
        statistic = jump / (sigma * np.sqrt(1.0 / left_n + 1.0 / right_n))
        best = int(np.argmax(statistic))
        if statistic[best] < threshold or jump[best] < floor:
            continue
        k = int(split[best])
        # sharpen to the largest single-sample change nearby (exact for a clean step)
        lo, hi = max(k - 3, start + 1), min(k + 4, stop)
        k = lo + int(np.argmax(np.abs(np.diff(voltage[lo - 1:hi]))))
        found.append(k)
        pending.extend([(start, k), (k, stop)])
    return np.unique(np.array(found, dtype=int))


#: Smallest one-sample jump of Va [V] :func:`sharp_steps` keeps as a step of a continuously varying input.
SHARP_STEP_VOLTS = 0.05


def sharp_steps(armature_voltage: np.ndarray, step_indices: np.ndarray, floor: float = SHARP_STEP_VOLTS) -> np.ndarray:
    """The steps of `step_indices` [samples] where Va [V] jumps within one sample by at least `floor` [V] and 8 noise
    sigmas: the real steps of an input that otherwise varies continuously (a chirp, where :func:`detect_steps` splits
    the smooth sweep into many levels), whose electrical transient the motor observer must not be fitted through."""
    voltage = np.asarray(armature_voltage, dtype=float)
    steps = np.asarray(step_indices, dtype=int)
    steps = steps[(steps >= 1) & (steps < voltage.size)]
    jump = np.abs(voltage[steps] - voltage[steps - 1])
    return steps[jump >= max(floor, 8.0 * noise_rms(voltage))]


#: Span [s] of the local cubic fit :func:`smooth_between_steps` takes (31 samples at 490 Hz, 0.16 of a 2.5 Hz period).
SMOOTHING_TIME = 31.0 / 490.0


def smooth_between_steps(signal: np.ndarray, step_indices: np.ndarray, sample_time: float) -> np.ndarray:
    """`signal` smoothed by a local cubic (Savitzky-Golay over :data:`SMOOTHING_TIME`) within each piece between
    `step_indices` [samples], the steps kept sharp; a piece shorter than the span is left as it is.

    For the motor observer on a continuously varying Va [V]: Va's measurement noise enters its modelled current
    one to one and biases its fit (errors in the input: on the own rig at 40 dB, Ra -0.8 %, La/Ra 3.5 ms for 2.0,
    the back-EMF 4 % off); a cubic over 63 ms leaves a 2.5 Hz sweep within 0.1 % and the noise at ~0.3 of itself.
    """
    out = np.array(signal, dtype=float)
    window = int(round(SMOOTHING_TIME / sample_time)) | 1 if sample_time > 0 else 0
    if window < 5:
        return out
    bounds = np.concatenate(([0], np.asarray(step_indices, dtype=int), [out.size]))
    for a, b in zip(bounds[:-1], bounds[1:]):
        if b - a >= window:
            out[a:b] = savgol_filter(out[a:b], window, 3)
    return out


#: Length [s] of the bootstrap intervals of a continuously varying Va (:func:`bootstrap_blocks`).
BOOTSTRAP_BLOCK_TIME = 0.25


def bootstrap_blocks(step_indices: np.ndarray, n: int, sample_time: float) -> np.ndarray:
    """Starts [samples] of the motor observer's bootstrap intervals for a continuously varying Va: its `step_indices`
    plus one every :data:`BOOTSTRAP_BLOCK_TIME` (longer than the smoothed Va's correlation, 63 ms), of `n` samples
    at `sample_time` [s]."""
    every = max(1, int(round(BOOTSTRAP_BLOCK_TIME / sample_time))) if sample_time > 0 else n
    grid = np.arange(every, int(n), every)
    return np.unique(np.concatenate((np.asarray(step_indices, dtype=int), grid)))


@dataclass(frozen=True)
class ConditionedInputs:
    """Va and Ia ready for the thrust term, plus what was done to them.

    Attributes
    ----------
    armature_voltage, armature_current : ndarray, shape (n,)
        Conditioned Va [V] and Ia [A].
    step_indices : ndarray of int
        Samples where a Va step was detected.
    """

    armature_voltage: np.ndarray
    armature_current: np.ndarray
    step_indices: np.ndarray


def bridge_steps(signal: np.ndarray, step_indices: np.ndarray, settling: int = STEP_SETTLING_SAMPLES) -> np.ndarray:
    """Replace samples [k, k + settling) after each step k by a line from sample k-1 to sample k + settling."""
    out = np.array(signal, dtype=float)
    n = out.size
    for k in step_indices:
        left, right = k - 1, min(k + settling, n - 1)
        if left < 0 or right <= left + 1:
            continue
        out[left + 1:right] = np.interp(np.arange(left + 1, right), [left, right], [out[left], out[right]])
    return out


def piecewise_constant(signal: np.ndarray, step_indices: np.ndarray) -> np.ndarray | None:
    """`signal` replaced by its median between consecutive steps, if it is piecewise constant within its noise.

    Returns None when the signal varies inside the intervals (not a step input), so the caller can fall back: when
    its spread about the medians exceeds twice the noise, or when the intervals' straight-line slopes are jointly
    significant (a chi-square of the slopes' t statistics, the first and last sample of each interval left out): a
    continuously varying input that :func:`detect_steps` cut into many short levels (a chirp at 40 dB passed the
    spread test with ~1,000 levels, and the motor observer then failed on the staircase).
    """
    signal = np.asarray(signal, dtype=float)
    bounds = np.concatenate(([0], step_indices, [signal.size])).astype(int)
    out = np.empty_like(signal)
    for a, b in zip(bounds[:-1], bounds[1:]):
        out[a:b] = np.median(signal[a:b]) if b > a else 0.0
    sigma = noise_rms(signal)
    floor = 1e-3 * max(np.max(np.abs(signal)), 1e-12)
    spread = np.std(signal - out)
    if spread > 2.0 * sigma + floor:
        return None
    chi2, count, ramp = 0.0, 0, 0.0
    for a, b in zip(bounds[:-1] + 1, bounds[1:] - 1):
        if b - a < 6:
            continue
        x = np.arange(b - a) - 0.5 * (b - a - 1)
        slope = float(np.dot(x, signal[a:b])) / float(np.dot(x, x))
        chi2 += slope ** 2 * float(np.dot(x, x)) / max(sigma, 1e-12) ** 2
        count += 1
        ramp = max(ramp, abs(slope) * (b - a))
    if count and chi2 > count + 6.0 * math.sqrt(2.0 * count) and ramp > floor:
        return None
    return out


def condition_inputs(armature_voltage: np.ndarray, armature_current: np.ndarray, sample_time: float,
                     cutoff_hz: float | None = None) -> ConditionedInputs:
    """Denoise Va and Ia for the thrust term: bridge the electrical transient after each Va step and low-pass.

    A step input (Va piecewise constant within its noise, as on the rig where Va follows the duty) is first
    replaced by its per-step median. Va and Ia then get the same linear treatment (bridging, zero-phase low-pass),
    so that Va - R Ia, continuous in truth, is treated consistently for any R.
    """
    steps = detect_steps(armature_voltage, sample_time)
    stepped = piecewise_constant(armature_voltage, steps)
    if stepped is not None:
        armature_voltage = stepped
    settling = settling_samples(sample_time)
    voltage = bridge_steps(armature_voltage, steps, settling)
    current = bridge_steps(armature_current, steps, settling)
    cutoff_hz = INPUT_CUTOFF_HZ if cutoff_hz is None else cutoff_hz
    nyquist = 0.5 / sample_time
    if cutoff_hz < nyquist and voltage.size > 60:
        sos = butter_lowpass_sos(cutoff_hz / nyquist)
        voltage = sosfiltfilt(sos, voltage)
        current = sosfiltfilt(sos, current)
    return ConditionedInputs(voltage, current, steps)


#: Sample time [s] above which a duty step is taken to land anywhere between two samples (a logger printing one line
#: every N PWM periods changes the duty at any period); at the rig's 490 Hz it lands on a sample.
BETWEEN_SAMPLES_TIME = 1.5 / 490.0


def step_switches(step_indices: np.ndarray, n: int, sample_time: float) -> np.ndarray:
    """Where inside each sample interval the duty (Va) changes [fraction of the interval], for the motor observer.

    At a low rate (sample time above :data:`BETWEEN_SAMPLES_TIME`) a step first seen at sample k landed somewhere in
    (t_k-1, t_k]: the observer holds the old level over the first half of interval k-1 and the new one over the
    second half (the expected step time for a step time uniform over the interval). Unlike holding the mean of the two
    levels over the whole interval, this keeps the modelled current right at both samples: the armature current
    follows Va within ~2 ms (La/Ra), so at t_k it has the new level's value and at t_k-1 the old one's, and holding
    the mean put a modelled current off by dVa / (2 R) (~0.5 A against ~17 mA of noise) at one sample per step,
    which bent the observer's fit (Rm -4.5 % at 98 Hz; no adequate observer at all at 49 and 24.5 Hz).

    Parameters
    ----------
    step_indices : ndarray of int [-]
        Samples where a Va step is first seen.
    n : int [-]
        Number of samples.
    sample_time : float [s]

    Returns
    -------
    ndarray, shape (n,) [1]
        0.5 in the interval before each step at a low rate, 1 (held over the whole interval) elsewhere.
    """
    out = np.ones(int(n))
    if sample_time <= BETWEEN_SAMPLES_TIME:
        return out
    for k in np.asarray(step_indices, dtype=int):
        if 1 <= k < n:
            out[k - 1] = 0.5
    return out
