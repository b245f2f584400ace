"""Corrupt a clean recording the ways real logs get corrupted (for the data-quality gate's tests).

Each fault is a function ``(columns) -> columns`` on a dict of equal-length arrays (``t`` [s], ``duty``,
``armature_voltage`` [V], ``armature_current`` [A], ``angle`` [rad], optional ``sequence``), returning new arrays;
:data:`FAULTS` names them. ``expected`` says what the gate must do: the finding code and its severity.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

Columns = dict[str, np.ndarray]


def _copy(columns: Columns) -> Columns:
    return {k: np.array(v, dtype=float) for k, v in columns.items()}


def _index(columns: Columns, t: float) -> int:
    return int(np.searchsorted(columns['t'], columns['t'][0] + t))


def degrees(c: Columns) -> Columns:
    c = _copy(c)
    c['angle'] = np.degrees(c['angle'])
    return c


def milliamps(c: Columns) -> Columns:
    c = _copy(c)
    c['armature_current'] = c['armature_current'] * 1e3
    return c


def milliseconds(c: Columns) -> Columns:
    c = _copy(c)
    c['t'] = c['t'] * 1e3
    return c


def wrapped_0_2pi(c: Columns) -> Columns:
    c = _copy(c)
    c['angle'] = np.mod(c['angle'], 2 * math.pi)
    return c


def wrapped_pm_pi(c: Columns) -> Columns:
    c = _copy(c)
    c['angle'] = np.mod(c['angle'] + math.pi, 2 * math.pi) - math.pi
    return c


def glitch_2pi(c: Columns, start: float = 20.0, seconds: float = 0.5) -> Columns:
    c = _copy(c)
    a = _index(c, start)
    c['angle'][a:a + round(seconds / np.median(np.diff(c['t'])))] += 2 * math.pi
    return c


def jump_2pi(c: Columns, start: float = 30.0) -> Columns:
    c = _copy(c)
    c['angle'][_index(c, start):] += 2 * math.pi
    return c


def outlier(c: Columns, value: float = 100.0, at: float = 15.0, name: str = 'angle') -> Columns:
    c = _copy(c)
    c[name][_index(c, at)] = value
    return c


def stuck(c: Columns, start: float = 20.0, seconds: float = 6.0, name: str = 'angle') -> Columns:
    c = _copy(c)
    a = _index(c, start)
    b = _index(c, start + seconds)
    c[name][a:b] = c[name][a]
    return c


def decimated(c: Columns, factor: int = 5) -> Columns:
    return {k: np.array(v[::factor], dtype=float) for k, v in c.items()}


def nan_sample(c: Columns, at: float = 12.0, name: str = 'angle') -> Columns:
    c = _copy(c)
    c[name][_index(c, at)] = np.nan
    return c


def lost_samples(c: Columns, start: float = 25.0, seconds: float = 1.0) -> Columns:
    a, b = _index(c, start), _index(c, start + seconds)
    keep = np.ones(len(c['t']), dtype=bool)
    keep[a:b] = False
    return {k: np.array(v[keep], dtype=float) for k, v in c.items()}


def coarse_time(c: Columns, offset: float = 1e5, digits: int = 9) -> Columns:
    """Stamps offset by `offset` s and written with `digits` significant digits (``%.9g`` of a long record)."""
    c = _copy(c)
    c['t'] = np.array([float(f'{v:.{digits}g}') for v in c['t'] + offset])
    return c


@dataclass(frozen=True)
class Fault:
    name: str
    apply: Callable[[Columns], Columns]
    code: str
    severity: str
    #: When in a recording's life it happens (faults of a pair are applied in this order): 0 the sensor or the
    #: physics, 1 the encoder's range, 2 the units it is logged in, 3 the logging and its clock, 4 the file.
    stage: int = 0


#: The faults of issue 12 with what the gate must answer (code, severity).
FAULTS = [
    Fault('angle_in_degrees', degrees, 'angle_in_degrees', 'repaired', 2),
    Fault('current_in_milliamps', milliamps, 'current_in_milliamps', 'repaired', 2),
    Fault('angle_wrapped_0_2pi', wrapped_0_2pi, 'angle_wrapped', 'repaired', 1),

    Fault('glitch_2pi', glitch_2pi, 'angle_jump', 'repaired'),
    Fault('jump_2pi', jump_2pi, 'angle_jump', 'repaired'),
    Fault('outlier_100rad', outlier, 'outlier', 'repaired'),
    Fault('outlier_1e300', lambda c: outlier(c, 1e300, at=16.0), 'absurd_value', 'repaired', 4),
    Fault('outlier_1e308', lambda c: outlier(c, 1e308, at=17.0), 'absurd_value', 'repaired', 4),
    Fault('current_outlier', lambda c: outlier(c, 50.0, at=18.0, name='armature_current'), 'outlier', 'repaired'),
    Fault('angle_stuck_6s', stuck, 'stuck_sensor', 'refused'),
    Fault('current_stuck_6s', lambda c: stuck(c, name='armature_current'), 'stuck_sensor', 'refused'),
    Fault('logged_at_98hz', decimated, 'sample_rate_mismatch', 'refused', 3),
    Fault('nan_sample', nan_sample, 'non_finite', 'repaired', 4),
    Fault('lost_1s', lost_samples, 'lost_samples', 'warning', 3),
    Fault('time_rounded_1e5s', coarse_time, 'time_precision', 'repaired', 3),
    Fault('time_in_milliseconds', milliseconds, 'time_in_milliseconds', 'repaired', 3),
]
