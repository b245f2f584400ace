"""Duty schedules as files: blocks (held duties, rests, sine sweeps, square waves) rendered as ``(duty, dwell_s)``
steps, written as the YAML step file the excitation node plays (its ``steps_file``; ``aeropend run --experiment``).

The file (SI units)::

    format: aeropend-duty-schedule-1
    units: {duty: fraction 0..1 of the PWM period, dwell: s}
    steps:                      # played in order from duty 0; the duty returns to 0 at the end
    - [0.0, 1.0]                # duty fraction, dwell [s]
    - [0.45, 2.5]
    experiment: {...}           # optional: what the schedule was designed for (ignored by the node)
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from aeropend_core.errors import AeropendError
from aeropend_core.model.parameters import SAMPLE_TIME

#: Hold time of the steps a sine sweep or square wave is rendered with [s] (20 holds per second).
SWEEP_HOLD = 0.05


@dataclass(frozen=True)
class Block:
    """One piece of a schedule: a held duty (``kind`` 'step', or 'rest' at duty 0), a sine sweep or a square wave
    whose frequency sweeps (``kind`` 'square': sharp full steps, which show a lag's shape best).

    Attributes
    ----------
    kind : str
        'step', 'rest', 'sweep' or 'square'.
    seconds : float [s]
        Length of the block.
    level : float, dimensionless
        Duty fraction of a step; mean duty of a sweep.
    amplitude : float, dimensionless
        Duty amplitude of a sweep or square wave (0 otherwise).
    start_hz, stop_hz : float [Hz]
        Frequencies at the start and end of a sweep (linear sweep).
    """

    kind: str
    seconds: float
    level: float = 0.0
    amplitude: float = 0.0
    start_hz: float = 0.0
    stop_hz: float = 0.0

    def steps(self) -> list[tuple[float, float]]:
        """The block as ``(duty, dwell_s)`` steps (a sweep or square wave in holds of SWEEP_HOLD seconds)."""
        if self.kind not in ('sweep', 'square'):
            return [(self.level if self.kind == 'step' else 0.0, self.seconds)]
        count = max(1, int(round(self.seconds / SWEEP_HOLD)))
        t = (np.arange(count) + 0.5) * SWEEP_HOLD
        rate = (self.stop_hz - self.start_hz) / max(self.seconds, 1e-9)
        phase = 2 * math.pi * (self.start_hz * t + 0.5 * rate * t ** 2)
        wave = np.sin(phase) if self.kind == 'sweep' else np.where(np.sin(phase) >= 0.0, 1.0, -1.0)
        duty = np.clip(self.level + self.amplitude * wave, 0.0, 1.0)
        return [(float(d), SWEEP_HOLD) for d in duty]

    def text(self) -> str:
        """The block in words, SI units."""
        if self.kind == 'rest':
            return f'rest at duty 0 for {self.seconds:.1f} s'
        if self.kind == 'step':
            return f'duty {self.level:.3f} for {self.seconds:.1f} s'
        if self.kind == 'square':
            return (f'square wave {self.start_hz:.2f}->{self.stop_hz:.2f} Hz between duty '
                    f'{self.level - self.amplitude:.3f} and {self.level + self.amplitude:.3f} for {self.seconds:.1f} s')
        return (f'sine sweep {self.start_hz:.2f}->{self.stop_hz:.2f} Hz around duty {self.level:.3f} '
                f'+- {self.amplitude:.3f} for {self.seconds:.1f} s')


@dataclass(frozen=True)
class DutySchedule:
    """A designed duty schedule: blocks rendered as ``(duty, dwell_s)`` steps (what the excitation node plays)."""

    blocks: tuple[Block, ...]

    @property
    def steps(self) -> np.ndarray:
        """Shape (n_steps, 2): duty fraction, dwell [s]; adjacent equal duties merged."""
        merged: list[list[float]] = []
        for block in self.blocks:
            for duty, dwell in block.steps():
                if merged and abs(merged[-1][0] - duty) < 1e-12:
                    merged[-1][1] += dwell
                else:
                    merged.append([duty, dwell])
        return np.array(merged, dtype=float).reshape(-1, 2)

    @property
    def duration(self) -> float:
        """Total length [s]."""
        return float(sum(b.seconds for b in self.blocks))

    def duty(self, sample_time: float = SAMPLE_TIME) -> np.ndarray:
        """Duty per sample (zero-order hold at `sample_time` [s]), shape (n,)."""
        return steps_to_duty(self.steps, sample_time)


def steps_to_duty(steps: np.ndarray, sample_time: float = SAMPLE_TIME) -> np.ndarray:
    """Duty per sample [fraction] from ``(duty, dwell_s)`` steps (rounded to whole samples at their ends)."""
    steps = np.asarray(steps, dtype=float).reshape(-1, 2)
    counts = np.round(np.cumsum(steps[:, 1]) / sample_time).astype(int)
    lengths = np.diff(np.concatenate(([0], counts)))
    return np.repeat(steps[:, 0], np.maximum(lengths, 0))


SCHEDULE_FORMAT = 'aeropend-duty-schedule-1'


def write_schedule(path: str | Path, steps: np.ndarray, experiment: Mapping | None = None) -> Path:
    """Write ``(duty, dwell_s)`` steps as the YAML step file the excitation node plays (``steps_file``).

    Parameters
    ----------
    path : str or Path [-]
        The file to write (its folder must exist).
    steps : ndarray, shape (n_steps, 2) [fraction, s]
        Duty fraction 0..1 and dwell of each step.
    experiment : mapping, optional [SI]
        What the schedule was designed for (written under ``experiment``; the node ignores it).

    Returns
    -------
    Path
        The written file.
    """
    import yaml
    path = Path(path)
    document = {'format': SCHEDULE_FORMAT,
                'units': {'duty': 'fraction 0..1 of the PWM period', 'dwell': 's'},
                'steps': [[round(float(d), 6), round(float(s), 6)] for d, s in np.asarray(steps).reshape(-1, 2)]}
    if experiment:
        document['experiment'] = dict(experiment)
    header = ('# aeropend duty schedule: each step is [duty fraction 0..1, dwell in s], played in order from duty 0\n'
              '# by the excitation node (aeropend run --experiment THIS_FILE); the duty returns to 0 at the end.\n')
    text = header + yaml.safe_dump(document, sort_keys=False, default_flow_style=None, width=110)
    try:
        path.write_text(text, encoding='utf-8')
    except OSError as error:
        raise AeropendError(f'cannot write the schedule file {path}: {error.strerror}; choose a writable '
                            'folder') from None
    return path


def read_schedule(path: str | Path, duty_limit: float = 1.0) -> tuple[np.ndarray, dict]:
    """Read a schedule file: its steps and its ``experiment`` section (empty when absent).

    Parameters
    ----------
    path : str or Path [-]
        A YAML file with ``steps: [[duty, dwell_s], ...]``.
    duty_limit : float, dimensionless
        Refuse steps above this duty fraction (the run's safety cap).

    Returns
    -------
    steps : ndarray, shape (n_steps, 2) [fraction, s]
        The steps.
    experiment : dict
        The file's ``experiment`` section (SI).

    Raises
    ------
    AeropendError
        An unreadable file, no valid steps, or a step above `duty_limit` (named).
    """
    import yaml

    from aeropend_core.io.inputs import load_yaml
    path = Path(path)
    try:
        document = load_yaml(path, 'the experiment file')        # a FIFO, device or a too deep YAML: refused
    except OSError as error:
        raise AeropendError(f'cannot read the experiment file {path}: {error.strerror}') from None
    except (yaml.YAMLError, UnicodeDecodeError) as error:
        raise AeropendError(f'experiment file {path} is not valid YAML ({type(error).__name__}); write '
                            '"steps: [[duty, dwell_s], ...]"') from None
    raw = document.get('steps') if isinstance(document, dict) else None
    try:
        steps = np.asarray(raw, dtype=float).reshape(-1, 2)
    except (TypeError, ValueError):
        steps = np.zeros((0, 2))
    if not isinstance(raw, list) or steps.size == 0:
        raise AeropendError(f'experiment file {path} needs a list "steps: [[duty fraction, dwell s], ...]"')
    if not np.all(np.isfinite(steps)) or np.any(steps[:, 0] < 0) or np.any(steps[:, 1] <= 0):
        raise AeropendError(f'experiment file {path}: every step needs a duty fraction >= 0 and a positive dwell [s]')
    above = np.flatnonzero(steps[:, 0] > duty_limit + 1e-9)
    if above.size:
        raise AeropendError(f'experiment file {path}: step {int(above[0]) + 1} asks for duty {steps[above[0], 0]:g}, '
                            f'above the duty cap {duty_limit:g}; design it again within the cap or raise --duty-cap')
    experiment = document.get('experiment') if isinstance(document.get('experiment'), dict) else {}
    return steps, experiment


__all__ = ['Block', 'DutySchedule', 'steps_to_duty', 'write_schedule', 'read_schedule', 'SCHEDULE_FORMAT',
           'SWEEP_HOLD']
