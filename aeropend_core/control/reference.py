"""Reference schedules of the closed loop: angle steps with holds, an optional small dither.

A schedule file (YAML; SI units, angles in rad or, spelt out, in degrees)::

    start_hold: 2.0          # s at the first angle (default 0 rad: the rod hanging) before the first step
    start_angle: 0.0         # rad (or start_angle_deg)
    steps:                   # each step: the new reference and how long it is held [s]
      - {angle_deg: 20, hold: 5}
      - {angle: 0.61, hold: 5}
    dither:                  # optional: a square wave added to the reference, for identifiability
      amplitude: 0.005       # rad (or amplitude_deg)
      period: 0.4            # s

Steps are judged on the reference without the dither (the metrics say when a dither was played).
"""
from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from aeropend_core.errors import AeropendError
from aeropend_core.model.parameters import SAMPLE_TIME


@dataclass(frozen=True)
class ReferenceStep:
    """One step of a schedule: the new reference `angle` [rad] held for `hold` [s]."""

    angle: float
    hold: float


@dataclass(frozen=True)
class ReferenceSchedule:
    """A start angle held `start_hold` [s], then `steps`; an optional square dither (`dither_amplitude` [rad],
    `dither_period` [s])."""

    steps: tuple[ReferenceStep, ...]
    start_angle: float = 0.0
    start_hold: float = 2.0
    dither_amplitude: float = 0.0
    dither_period: float = 0.4
    source: str = field(default='', compare=False)

    def __post_init__(self) -> None:
        if not self.steps:
            raise AeropendError(f'{self.source or "schedule"}: no steps; give at least one {{angle: RAD, hold: S}}')
        values = [self.start_angle, self.start_hold, self.dither_amplitude, self.dither_period]
        values += [number for step in self.steps for number in (step.angle, step.hold)]
        if not all(math.isfinite(value) for value in values):
            raise AeropendError(f'{self.source or "schedule"}: every angle and time must be a finite number')
        for index, step in enumerate(self.steps):
            if step.hold <= 0:
                raise AeropendError(f'{self.source or "schedule"}: step {index + 1} holds {step.hold} s; '
                                    'holds must be positive (seconds)')
            if abs(step.angle) > math.radians(100):
                raise AeropendError(f'{self.source or "schedule"}: step {index + 1} asks for '
                                    f'{math.degrees(step.angle):.0f} deg; this rig works between -100 and '
                                    '100 deg (did you give degrees as angle? write angle_deg)')
        if self.start_hold < 0 or self.dither_amplitude < 0 or self.dither_period <= 0:
            raise AeropendError(f'{self.source or "schedule"}: start_hold and dither amplitude must be >= 0 and '
                                'the dither period > 0')

    @property
    def duration(self) -> float:
        """Total length [s]."""
        return self.start_hold + sum(step.hold for step in self.steps)

    def step_times(self) -> list[tuple[float, float, float, float]]:
        """(start [s], end [s], reference before [rad], reference after [rad]) of every step."""
        spans, start, before = [], self.start_hold, self.start_angle
        for step in self.steps:
            spans.append((start, start + step.hold, before, step.angle))
            start += step.hold
            before = step.angle
        return spans

    def base_reference(self, n_samples: int, sample_time: float = SAMPLE_TIME) -> np.ndarray:
        """The stepped reference [rad] at samples 0..n-1 (the last step held beyond the end)."""
        time = np.arange(n_samples) * sample_time
        reference = np.full(n_samples, self.start_angle)
        for start, _end, _before, after in self.step_times():
            reference[time >= start - 1e-9] = after
        return reference

    def reference(self, n_samples: int | None = None, sample_time: float = SAMPLE_TIME) -> np.ndarray:
        """The reference [rad] played at each sample: the steps plus the dither (n defaults to the duration)."""
        if n_samples is None:
            n_samples = int(round(self.duration / sample_time))
        reference = self.base_reference(n_samples, sample_time)
        if self.dither_amplitude > 0:
            time = np.arange(n_samples) * sample_time
            reference = reference + self.dither_amplitude * np.where(
                np.floor(2.0 * time / self.dither_period) % 2 == 0, 1.0, -1.0)
        return reference

    def as_dict(self) -> dict:
        return {'start_angle': self.start_angle, 'start_hold': self.start_hold,
                'steps': [{'angle': step.angle, 'hold': step.hold} for step in self.steps],
                'dither': {'amplitude': self.dither_amplitude, 'period': self.dither_period}}

    @property
    def sha256(self) -> str:
        """Hash of the schedule's content (not of the file's spelling)."""
        return hashlib.sha256(json.dumps(self.as_dict(), sort_keys=True).encode()).hexdigest()

    @classmethod
    def from_mapping(cls, data: Mapping, source: str = 'schedule') -> ReferenceSchedule:
        """A schedule from the YAML layout in the module docstring."""
        if not isinstance(data, Mapping):
            raise AeropendError(f'{source}: expected a mapping with "steps", got {type(data).__name__}')
        known = {'steps', 'start_hold', 'start_angle', 'start_angle_deg', 'dither'}
        unknown = sorted(set(data) - known)
        if unknown:
            raise AeropendError(f'{source}: unknown key(s) {", ".join(map(str, unknown))}; known: '
                                f'{", ".join(sorted(known))}')
        raw_steps = data.get('steps')
        if not isinstance(raw_steps, list):
            raise AeropendError(f'{source}: "steps" must be a list of {{angle: RAD, hold: S}}')
        steps = tuple(ReferenceStep(_angle(item, 'angle', source, f'step {index + 1}'),
                                    _number(item, 'hold', source, f'step {index + 1}'))
                      for index, item in enumerate(raw_steps))
        dither = data.get('dither') or {}
        if not isinstance(dither, Mapping):
            raise AeropendError(f'{source}: "dither" must be a mapping {{amplitude: RAD, period: S}}')
        start_angle = _angle(data, 'start_angle', source, 'start', default=0.0)
        return cls(steps=steps, start_angle=start_angle,
                   start_hold=_number(data, 'start_hold', source, 'start', default=2.0),
                   dither_amplitude=_angle(dither, 'amplitude', source, 'dither', default=0.0),
                   dither_period=_number(dither, 'period', source, 'dither', default=0.4), source=source)

    @classmethod
    def steps_between(cls, angles_deg: list[float], hold: float = 5.0, start_hold: float = 2.0) -> ReferenceSchedule:
        """A schedule through `angles_deg` [deg], each held `hold` [s], from the rod hanging."""
        return cls(steps=tuple(ReferenceStep(math.radians(angle), hold) for angle in angles_deg),
                   start_hold=start_hold)


def _number(item, key: str, source: str, where: str, default: float | None = None) -> float:
    if not isinstance(item, Mapping):
        raise AeropendError(f'{source}: {where} must be a mapping like {{angle: 0.35, hold: 5}}')
    if key not in item:
        if default is None:
            raise AeropendError(f'{source}: {where} has no "{key}"')
        return default
    value = item[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise AeropendError(f'{source}: {where}: "{key}" must be a number, got {value!r}')
    return float(value)


def _angle(item, key: str, source: str, where: str, default: float | None = None) -> float:
    if isinstance(item, Mapping) and f'{key}_deg' in item:
        if key in item:
            raise AeropendError(f'{source}: {where} gives both "{key}" (rad) and "{key}_deg"; keep one')
        return math.radians(_number(item, f'{key}_deg', source, where))
    return _number(item, key, source, where, default)


#: Default design steps: +-SWING around the operating angle [deg], each held HOLD [s], after an approach of APPROACH
#: [s] from the hanging rod to the first angle (played, not judged).
SWING_DEG = 10.0
HOLD = 4.0
APPROACH = 4.0


def design_schedule(angle: float, swing_deg: float = SWING_DEG, hold: float = HOLD,
                    approach: float = APPROACH) -> ReferenceSchedule:
    """The default design schedule around `angle` [rad]: the approach to angle - swing (not judged), then steps to
    angle + swing, angle - swing and angle + swing."""
    at = math.degrees(angle)
    steps = tuple(ReferenceStep(math.radians(at + sign * swing_deg), hold) for sign in (1, -1, 1))
    return ReferenceSchedule(steps=steps, start_angle=math.radians(at - swing_deg), start_hold=approach)
