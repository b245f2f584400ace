"""Step-response metrics of the closed loop and the performance template they are judged against.

Defined once, for predicted and measured transients alike (docs/control.md):

* the step goes from ``initial`` (the reference before it, as MATLAB's ``stepinfo`` ``yinit``; not the data's
  first sample) to ``target`` (the new reference); ``step = target - initial``;
* ``final`` is the measured mean over the hold's last 20 %;
* **steady-state error** = (final - target) / |step|, in % of the step;
* **overshoot** = the largest excursion beyond ``final`` in the direction of the step, in % of |step| (0 if none);
* **rise time** = from the first crossing of initial + 10 % to initial + 90 % of (final - initial) [s];
* **settling time** = from the step to the last sample outside the band around ``final`` [s]; the band's half width
  is max(2 % of |step|, 3 angle counts, 3 noise sigma) (2 % of a 10 deg step is below one 10-bit count);
  a step that never enters the band reports its hold (not settled);
* **peak duty** = the largest duty during the step (fraction 0..1).

Overshoot, rise and settling are read on the angle averaged over a centred 50 ms window (``SMOOTHING_TIME``, cut
to the samples the step has at its two ends): on the rig's 10-bit angle at 40 dB the raw samples' noise alone
(0.9 deg) would put a 3-sigma excursion in every hold of a few seconds and read as overshoot; the window is ten
times shorter than the pendulum's period (0.55 s) and takes about 1 % off a peak. The noise sigma of the band is
that of the averaged angle.

python-control's ``step_info`` takes the band and the rise limits as fractions of the final value, not of the step,
and has no ``yinit``: it is not used here.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from aeropend_core.errors import AeropendError
from aeropend_core.sim.noise import ANGLE_LSB

#: Share of the hold over which the final value and the steady-state error are measured.
FINAL_SHARE = 0.2
#: The settling band: at least this share of the step, this many angle counts, this many noise sigmas.
BAND_STEP_SHARE = 0.02
BAND_COUNTS = 3
BAND_SIGMAS = 3
#: Length of the centred moving average the transient metrics read [s].
SMOOTHING_TIME = 0.05


@dataclass(frozen=True)
class Template:
    """A performance template: each item None when not asked for.

    settling : float [s]         settling time at most this
    overshoot : float [%]        overshoot at most this, in % of the step
    error : float [%]            |steady-state error| below this, in % of the step
    duty : float [fraction]      peak duty at most this
    """

    settling: float | None = 2.0
    overshoot: float | None = 10.0
    error: float | None = 5.0
    duty: float | None = 0.8

    ITEMS = ('settling', 'overshoot', 'error', 'duty')
    UNITS = {'settling': 's', 'overshoot': '%', 'error': '%', 'duty': ''}

    @classmethod
    def parse(cls, text: str) -> Template:
        """``'settling=2,overshoot=10,error=5,duty=0.8'`` (items left out are not judged).

        >>> Template.parse('settling=2,overshoot=10')
        Template(settling=2.0, overshoot=10.0, error=None, duty=None)
        """
        values: dict[str, float | None] = dict.fromkeys(cls.ITEMS)
        for part in filter(None, (piece.strip() for piece in text.split(','))):
            name, _, value = part.partition('=')
            name = name.strip()
            if name not in cls.ITEMS:
                raise AeropendError(f'--template: unknown item {name!r}; items: {", ".join(cls.ITEMS)} '
                                    '(e.g. settling=2,overshoot=10,error=5,duty=0.8)')
            try:
                number = float(value.strip().rstrip('%s'))
            except ValueError:
                raise AeropendError(f'--template: {name}={value!r} is not a number') from None
            if not math.isfinite(number) or number <= 0:
                raise AeropendError(f'--template: {name} must be a positive number, got {value!r}')
            values[name] = number
        if all(value is None for value in values.values()):
            raise AeropendError('--template: no item given (e.g. settling=2,overshoot=10,error=5,duty=0.8)')
        if values['duty'] is not None and values['duty'] > 1:
            raise AeropendError(f'--template: duty is a fraction 0..1, got {values["duty"]} (80 % is duty=0.8)')
        return cls(**values)

    def as_dict(self) -> dict[str, float | None]:
        return {name: getattr(self, name) for name in self.ITEMS}

    def text(self) -> str:
        return ', '.join(f'{name} <= {value:g}{self.UNITS[name] and " " + self.UNITS[name]}'
                         for name, value in self.as_dict().items() if value is not None)


@dataclass(frozen=True)
class StepMetrics:
    """Metrics of one step (see the module docstring); angles [rad], times [s], percentages of |step|."""

    start: float
    initial: float
    target: float
    final: float
    rise_time: float
    overshoot: float
    settling_time: float
    settled: bool
    steady_state_error: float
    peak_duty: float
    band: float
    hold: float

    @property
    def step(self) -> float:
        return self.target - self.initial

    def value(self, item: str) -> float:
        """The metric a template item judges: settling [s], overshoot [%], |error| [%], duty [fraction]."""
        return {'settling': self.settling_time, 'overshoot': self.overshoot,
                'error': abs(self.steady_state_error), 'duty': self.peak_duty}[item]

    def misses(self, template: Template) -> dict[str, float]:
        """Template items missed and by how much (in the item's unit); empty when every item is met."""
        missed = {}
        for item, limit in template.as_dict().items():
            if limit is None:
                continue
            value = self.value(item)
            if item == 'settling' and not self.settled:
                missed[item] = math.inf
            elif not value <= limit:
                missed[item] = value - limit
        return missed

    def as_dict(self) -> dict:
        return asdict(self)


def moving_mean(values: np.ndarray, window: int, ends: str = 'nearest') -> np.ndarray:
    """The mean over `window` samples around each sample (samples i - window//2 .. i + (window - 1)//2), in the
    unit of `values`; numpy only (scipy's ndimage cost ~0.2-0.5 s of import in `control check`).

    `ends`: ``'nearest'``, the ends held (scipy.ndimage's ``uniform_filter1d`` with ``mode='nearest'``: the last
    sample weighs window//2 + 1 of the window in the last mean); ``'shrink'``, the window cut at the ends (the mean
    of the samples there are), what the step metrics read: with the ends held, one noisy sample at a hold's end
    moved the last smoothed value by half its noise and read as "not settled" (s23)."""
    values = np.asarray(values, dtype=float)
    if window <= 1 or values.size == 0:
        return values.copy()
    if ends == 'shrink':
        n = values.size
        sums = np.concatenate(([0.0], np.cumsum(values)))
        index = np.arange(n)
        low = np.maximum(index - window // 2, 0)
        high = np.minimum(index + (window - 1) // 2 + 1, n)
        return (sums[high] - sums[low]) / (high - low)
    if ends != 'nearest':
        raise ValueError(f"ends must be 'nearest' or 'shrink', got {ends!r}")
    padded = np.concatenate((np.full(window // 2, values[0]), values, np.full((window - 1) // 2, values[-1])))
    sums = np.cumsum(np.concatenate(([0.0], padded)))
    return (sums[window:] - sums[:-window]) / window


def noise_sigma(angle: np.ndarray) -> float:
    """White-noise sigma [rad] of an angle record: the RMS of its first differences over sqrt(2), the differences
    beyond 5 robust sigmas (steps, glitches) left out (0 if too short). Not the MAD alone: on a 10-bit angle the
    differences take few values and their median rounds to a count (40 dB read as 0.0129 rad for 0.0157)."""
    angle = np.asarray(angle, dtype=float)
    if angle.size < 8:
        return 0.0
    differences = np.diff(angle)
    centred = differences - np.median(differences)
    spread = 1.4826 * np.median(np.abs(centred))
    kept = centred[np.abs(centred) <= 5.0 * spread] if spread > 0 else centred
    return float(np.sqrt(np.mean(kept ** 2)) / math.sqrt(2.0)) if kept.size else 0.0


def step_metrics(time: np.ndarray, angle: np.ndarray, duty: np.ndarray, start: float, end: float,
                 initial: float, target: float, angle_count: float = ANGLE_LSB,
                 sigma: float | None = None, sample_time: float | None = None) -> StepMetrics:
    """Metrics of the step from `initial` to `target` [rad] at `start` [s], held until `end` [s].

    `time` [s], `angle` [rad], `duty` [fraction] are the record's samples (at least the step's). `sigma` [rad] is
    the raw angle's noise (default: measured on the hold's last 20 %); `angle_count` [rad] one count of the angle
    sensor; `sample_time` [s] the median spacing of `time` (given by :func:`schedule_metrics`, which computes it
    once for all its steps; None: computed here).
    """
    time = np.asarray(time, dtype=float)
    inside = (time >= start - 1e-9) & (time < end - 1e-9)
    if inside.sum() < 10:
        raise AeropendError(f'the step at {start:.2f} s has {int(inside.sum())} samples; it needs at least 10')
    t = time[inside] - start
    y = np.asarray(angle, dtype=float)[inside]
    u = np.asarray(duty, dtype=float)[inside]
    hold = end - start
    if sample_time is None:
        sample_time = float(np.median(np.diff(time))) if time.size > 1 else 0.0
    window = max(1, int(round(SMOOTHING_TIME / sample_time))) if sample_time > 0 else 1
    raw = y
    y = moving_mean(raw, window, ends='shrink')
    tail = t >= (1.0 - FINAL_SHARE) * hold
    if tail.sum() < 2:
        tail = np.zeros_like(t, dtype=bool)
        tail[-2:] = True
    final = float(np.mean(y[tail]))
    step = target - initial
    size = abs(step)
    if size <= 0:
        raise AeropendError(f'the step at {start:.2f} s does not change the reference')
    direction = math.copysign(1.0, step)
    if sigma is None:
        sigma = noise_sigma(raw[tail])
    sigma = sigma / math.sqrt(window)
    band = max(BAND_STEP_SHARE * size, BAND_COUNTS * angle_count, BAND_SIGMAS * sigma)
    excursion = direction * (y - final)
    overshoot = 100.0 * max(0.0, float(excursion.max())) / size
    # Rise 10-90 % of the way from the initial value to the final one.
    progress = direction * (y - initial) / max(abs(final - initial), 1e-12)
    low = np.flatnonzero(progress >= 0.1)
    high = np.flatnonzero(progress >= 0.9)
    rise = float(t[high[0]] - t[low[0]]) if low.size and high.size else math.inf
    outside = np.flatnonzero(np.abs(y - final) > band)
    if outside.size == 0:
        settling, settled = 0.0, True
    elif outside[-1] == y.size - 1:
        settling, settled = hold, False
    else:
        settling, settled = float(t[outside[-1] + 1]), True
    return StepMetrics(start=float(start), initial=float(initial), target=float(target), final=final,
                       rise_time=rise, overshoot=overshoot, settling_time=settling, settled=settled,
                       steady_state_error=100.0 * (final - target) / size, peak_duty=float(u.max()),
                       band=float(band), hold=float(hold))


def schedule_metrics(time: np.ndarray, angle: np.ndarray, duty: np.ndarray, schedule,
                     angle_count: float = ANGLE_LSB, sigma: float | None = None) -> list[StepMetrics]:
    """Metrics of every step of a :class:`~aeropend_core.control.reference.ReferenceSchedule` that the record
    covers completely (time [s] from the schedule's start)."""
    time = np.asarray(time, dtype=float)
    if time.size == 0:
        return []
    results = []
    sample_time = float(np.median(np.diff(time))) if time.size > 1 else 0.0     # once, not once a step
    for start, end, before, after in schedule.step_times():
        if end > time[-1] + 1.5 * (time[1] - time[0] if time.size > 1 else 0.0) or before == after:
            continue
        results.append(step_metrics(time, angle, duty, start, end, before, after, angle_count, sigma, sample_time))
    return results
