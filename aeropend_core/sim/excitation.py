"""Excitation design: a true Latin hypercube over (step amplitude, dwell time), as in section 5.2 of the paper
"Data-Driven System Identification of an Aeropendulum".

scipy's :class:`scipy.stats.qmc.LatinHypercube` draws `n_strata` points so that each of the `n_strata` equal
intervals of amplitude and of dwell holds exactly one point. Each point is one duty step: hold the amplitude for
the dwell time. Longer records chain independent hypercubes (each seeded from the first seed).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import qmc

from aeropend_core.errors import AeropendError
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, SAMPLE_TIME, RigParameters

#: The paper's ranges: duty up to 70 % (eq 8: 1.89 V; 2.5 V is beyond duty 1 = 2.32 V), dwell 0.6-2 s, 10 strata.
DEFAULT_DUTY_RANGE = (0.0, 0.7)
DEFAULT_DWELL_RANGE = (0.6, 2.0)
DEFAULT_STRATA = 10


@dataclass(frozen=True)
class StepSchedule:
    """A sequence of duty steps.

    Attributes
    ----------
    amplitudes : ndarray, shape (n_steps,)
        Duty of each step (fraction 0..1).
    dwells : ndarray, shape (n_steps,)
        How long each step is held [s].
    design_points : ndarray, shape (n_steps, 2)
        The unit-cube Latin-hypercube points (amplitude, dwell) behind the steps, for plotting the design.
    """

    amplitudes: np.ndarray
    dwells: np.ndarray
    design_points: np.ndarray

    @property
    def duration(self) -> float:
        """Total length [s]."""
        return float(np.sum(self.dwells))

    def duty(self, sample_time: float = SAMPLE_TIME, duration: float | None = None) -> np.ndarray:
        """Duty per sample (zero-order hold at `sample_time` [s]), cut or zero-padded to `duration` [s]."""
        counts = np.round(np.cumsum(self.dwells) / sample_time).astype(int)
        lengths = np.diff(np.concatenate(([0], counts)))
        duty = np.repeat(self.amplitudes, lengths)
        if duration is not None:
            n = int(round(duration / sample_time))
            duty = duty[:n] if duty.size >= n else np.concatenate((duty, np.zeros(n - duty.size)))
        return duty

    def step_times(self) -> np.ndarray:
        """Start time [s] of each step."""
        return np.concatenate(([0.0], np.cumsum(self.dwells)[:-1]))


def latin_hypercube_steps(n_strata: int = DEFAULT_STRATA, duty_range: tuple[float, float] = DEFAULT_DUTY_RANGE,
                          dwell_range: tuple[float, float] = DEFAULT_DWELL_RANGE,
                          seed: int | None = None, duty_cap: float = 0.7) -> StepSchedule:
    """One Latin hypercube of `n_strata` steps over duty (fraction) x dwell [s]."""
    if n_strata < 1:
        raise AeropendError(f'n_strata must be at least 1, got {n_strata}')
    low, high = duty_range
    if not 0.0 <= low <= high <= 1.0:
        raise AeropendError(f'duty range must satisfy 0 <= low <= high <= 1, got {duty_range}')
    if not 0.0 < dwell_range[0] <= dwell_range[1]:
        raise AeropendError(f'dwell range must be positive and ordered, got {dwell_range} s')
    points = qmc.LatinHypercube(d=2, seed=seed).random(n_strata)
    scaled = qmc.scale(points, [low, dwell_range[0]], [high, dwell_range[1]]) if high > low or \
        dwell_range[1] > dwell_range[0] else np.tile([low, dwell_range[0]], (n_strata, 1))
    amplitudes = np.minimum(scaled[:, 0], duty_cap)
    return StepSchedule(amplitudes=amplitudes, dwells=scaled[:, 1], design_points=points)


def voltage_range_to_duty(voltage_range: tuple[float, float],
                          parameters: RigParameters = DEFAULT_PARAMETERS) -> tuple[float, float]:
    """The duty range (eq 8 inverted) that gives the armature-voltage range [V]."""
    low, high = (float(parameters.duty_from_voltage(v)) for v in voltage_range)
    return min(low, 1.0), min(high, 1.0)


def lhc_schedule(duration: float, n_strata: int = DEFAULT_STRATA,
                 duty_range: tuple[float, float] = DEFAULT_DUTY_RANGE,
                 dwell_range: tuple[float, float] = DEFAULT_DWELL_RANGE,
                 seed: int | None = None, duty_cap: float = 0.7) -> StepSchedule:
    """Chain Latin hypercubes of `n_strata` steps until `duration` [s] is covered.

    The first hypercube uses `seed`; the next ones use seeds spawned from it, so the schedule is reproducible.

    Parameters
    ----------
    duration : float [s]
        Length to cover; the last hypercube may run past it (cut with ``StepSchedule.duty(duration=...)``).
    n_strata : int [-]
        Steps per hypercube: each of the `n_strata` intervals of amplitude and of dwell holds exactly one step.
    duty_range : (float, float), dimensionless
        Lowest and highest step duty, fractions 0..1 (the paper's 0-0.7).
    dwell_range : (float, float) [s]
        Shortest and longest dwell of a step (the paper's 0.6-2 s).
    seed : int or None [-]
        Seed of the first hypercube; None draws a fresh one.
    duty_cap : float, dimensionless
        Safety cap applied to every step (duty fraction; 0.7 keeps the rod below 90 deg).

    Returns
    -------
    StepSchedule
        Amplitudes (duty fractions), dwells [s] and the unit-cube design points.

    Examples
    --------
    >>> from aeropend_core import lhc_schedule
    >>> duty = lhc_schedule(20, seed=4).duty(duration=20)            # duty (fraction 0..1) per sample at 490 Hz
    >>> len(duty), bool(0.0 <= duty.min() and duty.max() <= 1.0)
    (9800, True)
    """
    if not duration > 0:
        raise AeropendError(f'duration must be positive, got {duration!r} s')
    seeds = np.random.SeedSequence(seed)
    parts = []
    total = 0.0
    while total < duration:
        child = seeds.spawn(1)[0]
        part = latin_hypercube_steps(n_strata, duty_range, dwell_range, seed=child.generate_state(1)[0],
                                     duty_cap=duty_cap)
        parts.append(part)
        total += part.duration
    return StepSchedule(amplitudes=np.concatenate([p.amplitudes for p in parts]),
                        dwells=np.concatenate([p.dwells for p in parts]),
                        design_points=np.concatenate([p.design_points for p in parts]))


def staircase_schedule(step: float = 0.05, dwell: float = 2.0, top: float = 0.7, rest: float = 2.0) -> StepSchedule:
    """The paper's staircase: duty steps of `step` (fraction) held `dwell` [s] up to `top` and back down to 0,
    with `rest` [s] at duty 0 first and last (60 s for the defaults: 5 % steps of 2 s up to 70 % and down)."""
    count = int(round(top / step))
    up = step * np.arange(1, count + 1)
    amplitudes = np.concatenate(([0.0], up, up[-2::-1], [0.0]))
    dwells = np.concatenate(([rest], np.full(2 * count - 1, dwell), [rest]))
    return StepSchedule(amplitudes, dwells, np.zeros((0, 2)))
