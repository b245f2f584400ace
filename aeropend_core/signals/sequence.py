"""Accounting of a sample counter (the rig's sequence numbers): gaps, duplicates and order."""
from __future__ import annotations

import numpy as np


def sequence_report(sequence: np.ndarray, expected: int) -> dict:
    """Gaps, duplicates and order of a recorded sample counter against the `expected` samples 0..expected-1."""
    unique = np.unique(sequence)
    in_range = unique[(unique >= 0) & (unique < expected)]
    steps = np.diff(sequence)
    return {'recorded': int(sequence.size), 'published': int(expected), 'unique': int(unique.size),
            'duplicates': int(sequence.size - unique.size), 'missing': int(expected - in_range.size),
            'gaps': int(np.sum(np.diff(unique) > 1)) + int(unique.size > 0 and unique[0] > 0)
            + int(unique.size > 0 and unique[-1] < expected - 1),
            'out_of_order': int(np.sum(steps < 0)), 'first': int(sequence.min()) if sequence.size else None,
            'last': int(sequence.max()) if sequence.size else None}


__all__ = ['sequence_report']
