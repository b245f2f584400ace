"""Long records: the candidate search on an evenly spread subset of the training segments, the chosen model on all.

The output-error fits of a long record solve for hundreds of segment initial states besides the parameters; their
cost grows faster than the record (the sparse LSMR trust-region steps need more evaluations as the segments grow:
a 3600 s diagnosis took 96x the 60 s time). The search compares many candidate models, and which one explains the
data best does not need every segment: above :data:`SEARCH_SECONDS` of training data the search (every candidate,
the backward elimination, the confounding checks) fits the training segments picked evenly over the record
(:func:`search_record`), up to that much data, and evaluates each on the whole held-out part as before. The model
it chooses is then fitted on every training segment (:func:`fit_on_all`): the reported sizes, their standard
errors, the held-out error and the drift test use all data. The diagnosis says so in its notes
(:meth:`SearchSubset.note`), never silently. Records with up to :data:`SEARCH_SECONDS` of training data (a 600 s
record holds 420 s) take the full path unchanged.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np

from aeropend_core.diagnosis.compare import Comparison, PreparedRecord, compare
from aeropend_core.diagnosis.output_error import SegmentedData, initial_states_from_data

#: Training data [s] above which the candidate search runs on an evenly spread subset of the training segments
#: holding about this much data (the final model is fitted on all of them).
SEARCH_SECONDS = 600.0


@dataclass
class SearchSubset:
    """Which training segments the candidate search used.

    Parameters
    ----------
    chosen : ndarray of int [-]
        Indices of the used segments in the full record's training segments.
    total : int [-]
        Number of training segments in the record.
    seconds_used, seconds_total : float [s]
        Training data in the used segments and in all of them.
    """

    chosen: np.ndarray
    total: int
    seconds_used: float
    seconds_total: float

    def note(self, refitted: str) -> str:
        """The sentence the diagnosis reports (`refitted`: the model fitted on all segments, as text)."""
        return (f'long record: the candidate models were compared on {len(self.chosen)} of {self.total} training '
                f'segments ({self.seconds_used:.0f} of {self.seconds_total:.0f} s) spread evenly over the record '
                f'(above {SEARCH_SECONDS:g} s of training data); the chosen model ({refitted}) was then fitted on '
                f'all {self.total}: its sizes, standard errors, held-out error and the drift test use all data, the '
                f'candidates\' statistics the subset.')


def search_record(prep: PreparedRecord, limit_seconds: float | None = None
                  ) -> tuple[PreparedRecord, SearchSubset | None]:
    """The record the candidate search fits: `prep` itself, or above the limit a copy on a subset of segments.

    Parameters
    ----------
    prep : PreparedRecord
    limit_seconds : float, optional [s]
        Training data above which a subset is taken (default :data:`SEARCH_SECONDS`).

    Returns
    -------
    (PreparedRecord, SearchSubset or None)
        The record to search on (the held-out part and everything else shared with `prep`) and the subset taken
        (None: `prep` itself, the full path).
    """
    limit = SEARCH_SECONDS if limit_seconds is None else float(limit_seconds)
    train = prep.train
    lengths = (train.seg_stop - train.seg_start) * prep.sample_time
    total = float(np.sum(lengths))
    if total <= limit:
        return prep, None
    count = max(2, math.ceil(len(lengths) * limit / total))
    chosen = np.unique(np.round(np.linspace(0, len(lengths) - 1, count)).astype(int))
    search = copy.copy(prep)
    search.train = SegmentedData(prep.voltage, prep.current, prep.angle, [train.segments[i] for i in chosen],
                                 prep.sample_time, prep.gate_voltage, prep.valid, prep.voltage_ensemble,
                                 train.hold_starts, train.held_bias_rms)
    return search, SearchSubset(chosen, len(lengths), float(np.sum(lengths[chosen])), total)


def fit_on_all(prep: PreparedRecord, subset: SearchSubset, effects: tuple[str, ...], searched: Comparison,
               fixed: dict[str, float]) -> Comparison:
    """The searched model fitted on every training segment of `prep`.

    Starts from the subset fit's parameters and, on the subset's segments, its fitted initial states (the others
    from the data's line fits).

    Parameters
    ----------
    prep : PreparedRecord
        The whole record.
    subset : SearchSubset
        The segments the search used (:func:`search_record`).
    effects : tuple of str [-]
        The model's effects.
    searched : Comparison
        The model's comparison on the subset.
    fixed : dict of str -> float [SI unit of each parameter]
        Parameters held at given values.

    Returns
    -------
    Comparison
        Fitted on all training segments, evaluated on the held-out part.
    """
    offset_name = searched.fit.structure.offset_parameter
    initial = initial_states_from_data(prep.train, searched.parameters.get(offset_name, 0.0) if offset_name else 0.0)
    if np.shape(searched.fit.initial_states) == (len(subset.chosen), 2):
        initial[subset.chosen] = searched.fit.initial_states
    return compare(prep, effects, start=searched.parameters, fixed=dict(fixed), initial_states=initial)


__all__ = ['SEARCH_SECONDS', 'SearchSubset', 'search_record', 'fit_on_all']
