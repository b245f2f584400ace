"""Samples missing from the uniform grid: lost samples inside a record, and the joins between several records.

A record whose link dropped frames is put on its uniform sample grid with the lost samples filled by linear
interpolation (:func:`split_at_gaps`); the filled samples give no residual and the fits restart after each gap
(:class:`Gaps`). A joint diagnosis of several records (:mod:`aeropend_core.diagnosis.joint`) puts them on one grid
with a few filler samples between them: those are **record joins**, not lost data. Each record after a join starts
with its own initial state exactly as after a gap, but the joins are counted and described apart from the lost
samples (``Gaps.joins``), so that a joint diagnosis never reports its record boundaries as a faulty link.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aeropend_core.diagnosis.output_error import STRIDE
from aeropend_core.errors import AeropendError, InsufficientDataError

#: A piece between gaps shorter than this [s] is not used for fitting (too short for its own initial state).
SHORTEST_PIECE = 0.5
#: More than this fraction of the record lost: refused.
MAX_LOST_FRACTION = 0.3


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First index and length of every run of True in `mask`."""
    edges = np.diff(np.concatenate(([0], mask.astype(int), [0])))
    starts = np.flatnonzero(edges == 1)
    return starts, np.flatnonzero(edges == -1) - starts


@dataclass
class Gaps:
    """Samples of the uniform grid that were not measured: lost samples and joins between records.

    Attributes
    ----------
    valid : ndarray of bool, shape (n,)
        False where no sample was measured (a lost sample, or filler between two records), filled by linear
        interpolation only to keep the grid; such samples give no residuals, and the multiple-shooting segments and
        the held-out part restart after each run of them.
    sample_time : float [s]
        Ts of the grid.
    source : str
        What the lost samples were detected from (``'time stamps'``, ``'sequence counter'``).
    joins : ndarray of bool, shape (n,), or None
        True on the filler samples between two records of a joint diagnosis (a record boundary: the next record
        starts with its own initial state). They are not lost samples: ``count``, ``lost`` and :meth:`describe`
        leave them out. None: a single record.
    """

    valid: np.ndarray
    sample_time: float
    source: str = 'time stamps'
    joins: np.ndarray | None = None

    @property
    def _lost_mask(self) -> np.ndarray:
        lost = ~np.asarray(self.valid, dtype=bool)
        return lost & ~np.asarray(self.joins, dtype=bool) if self.joins is not None else lost

    @property
    def starts(self) -> np.ndarray:
        """First lost sample of each gap (record joins excluded) [-]."""
        return _runs(self._lost_mask)[0]

    @property
    def lengths(self) -> np.ndarray:
        """Lost samples per gap (record joins excluded) [-]."""
        return _runs(self._lost_mask)[1]

    @property
    def count(self) -> int:
        """Gaps of lost samples (record joins excluded) [-]."""
        return int(self.starts.size)

    @property
    def lost(self) -> int:
        """Lost samples (record joins excluded) [-]."""
        return int(np.count_nonzero(self._lost_mask))

    @property
    def records(self) -> int:
        """Records on the grid (1 plus the joins between them) [-]."""
        return 1 + (int(_runs(np.asarray(self.joins, dtype=bool))[0].size) if self.joins is not None else 0)

    @property
    def complete(self) -> bool:
        """True when every sample of the grid was measured (no lost sample, no join) [-]."""
        return bool(np.all(self.valid))

    @property
    def longest_seconds(self) -> float:
        """Longest gap of lost samples [s] (0 without gaps)."""
        return float(self.lengths.max() * self.sample_time) if self.count else 0.0

    @property
    def measured_seconds(self) -> float:
        """Time covered by measured samples [s]."""
        return float(np.count_nonzero(self.valid) * self.sample_time)

    @property
    def lost_text(self) -> str:
        """' of measured samples (12 lost in 1 gap(s))', or '' without lost samples."""
        return f' of measured samples ({self.lost} lost in {self.count} gap(s))' if self.count else ''

    def pieces(self, start: int, stop: int) -> list[tuple[int, int]]:
        """[start, stop) without the gaps and joins, as runs of measured samples at least SHORTEST_PIECE long."""
        shortest = max(4 * STRIDE + 1, int(round(SHORTEST_PIECE / self.sample_time)))
        starts, lengths = _runs(np.asarray(self.valid[start:stop], dtype=bool))
        return [(start + int(a), start + int(a + n)) for a, n in zip(starts, lengths) if n >= shortest]

    def to_dict(self) -> dict:
        """The JSON form: gaps of lost samples (record joins apart) and the number of records."""
        return {'count': self.count, 'lost_samples': self.lost, 'longest_seconds': self.longest_seconds,
                'detected_from': self.source, 'records': self.records}

    def describe(self) -> str:
        """The note of a diagnosis on the lost samples ('' without any; record joins are not lost samples)."""
        if not self.count:
            return ''
        within = ' inside the records' if self.records > 1 else ''
        return (f'the record has {self.count} gap(s) of lost samples{within} ({self.lost} samples, the longest '
                f'{self.longest_seconds * 1e3:.0f} ms, detected from the {self.source}): they were filled by '
                f'interpolation only to keep the sample grid; no residual is taken there and the fitted segments '
                f'restart after each gap.')


def split_at_gaps(time: np.ndarray, columns: dict[str, np.ndarray], sample_time: float, source: str,
                  sequence: np.ndarray | None = None) -> tuple[np.ndarray, dict[str, np.ndarray], Gaps]:
    """Put samples with lost ones (gaps in the time stamps or the sequence counter) on the uniform grid.

    Parameters
    ----------
    time : ndarray, shape (n,) [s]
        Acquisition stamps.
    columns : dict of str -> ndarray, shape (n,) [SI]
        The signals.
    sample_time : float [s]
        Ts.
    source : str
        The record's name in messages.
    sequence : ndarray, shape (n,), optional [-]
        The device's sample counter (preferred over the stamps when strictly increasing).

    Returns
    -------
    time : ndarray [s]
        The grid times.
    columns : dict of str -> ndarray [SI]
        The columns on the grid (lost samples linearly interpolated, never used as data).
    gaps : Gaps
        The lost samples.

    Raises
    ------
    AeropendError
        Spacing that is not a whole number of samples.
    InsufficientDataError
        More than MAX_LOST_FRACTION of the record lost.
    """
    if sequence is not None and np.all(np.isfinite(sequence)) and np.all(np.diff(sequence) > 0):
        index = np.rint(np.asarray(sequence, dtype=float) - float(sequence[0])).astype(np.int64)
        detected = 'sequence counter'
    else:
        offsets = (time - time[0]) / sample_time
        index = np.rint(offsets).astype(np.int64)
        if np.max(np.abs(offsets - index)) > 0.25 or np.any(np.diff(index) <= 0):
            steps = np.diff(time)
            k = int(np.argmax(np.abs(steps - sample_time * np.maximum(np.rint(steps / sample_time), 1))))
            raise AeropendError(f'{source}: samples are not evenly spaced (step of {steps[k]:.4f} s at t = '
                                f'{time[k]:.3f} s, not a whole number of {sample_time:.4f} s samples); the time '
                                f'stamps must be the acquisition clock (sample counter x Ts)')
        detected = 'time stamps'
    n = int(index[-1]) + 1
    valid = np.zeros(n, dtype=bool)
    valid[index] = True
    gaps = Gaps(valid, sample_time, detected)
    if gaps.lost == 0:
        return time, columns, gaps
    if gaps.lost > MAX_LOST_FRACTION * n:
        raise InsufficientDataError(f'{source}: {gaps.lost} of {n} samples are lost ({gaps.count} gaps, the '
                                    f'longest {gaps.longest_seconds:.3f} s); too little remains to diagnose: '
                                    f'record again with a reliable link')
    grid = np.arange(n)
    filled = {name: np.interp(grid, index, values) for name, values in columns.items()}
    return time[0] + grid * sample_time, filled, gaps


__all__ = ['Gaps', 'split_at_gaps', 'SHORTEST_PIECE', 'MAX_LOST_FRACTION']
