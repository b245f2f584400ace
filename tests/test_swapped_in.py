"""The fit of a term in a catalog set's place is judged as before when the model with both is fitted only where it
can change the answer (:func:`aeropend_core.diagnosis.discovery._swapped_in`, issue 41: on a 600 s record that
fit ran to its 60-evaluation cap for a term whose errors were already too far from the set's to be confounded).

The former rule is written out here and both are run on every combination of the evidence (significance of the
term alone, of the set on top of the term, of the term on top of the set; errors close, apart either way; may
replace or not) with stand-ins for the fits."""
from __future__ import annotations

import itertools
import math
from types import SimpleNamespace

import pytest

from aeropend_core.diagnosis import discovery
from aeropend_core.diagnosis.compare import excess_error
from aeropend_core.diagnosis.discovery import CONFOUNDING_FACTOR, find_term

NOISE = 0.01
#: (set's rms error, term's rms error) [rad]: errors alike, the term's far worse, the term's far better
ERRORS = [(0.0110, 0.0111), (0.0110, 0.0200), (0.0200, 0.0110)]


def _comparison(rms, parameters):
    fit = SimpleNamespace(standard_errors={k: 0.1 for k in parameters}, initial_states=None, success=True)
    return SimpleNamespace(rms_error=rms, parameters=dict(parameters), fit=fit)


def _former(alone_significant, set_on_term, term_on_set, set_error, term_error, may_replace):
    """The rule before the change: the model with both always fitted, then judged."""
    if not alone_significant or set_on_term:
        return None
    floor = 0.2 * NOISE
    if term_on_set:
        if not may_replace or term_error > set_error:
            return None
        return 'proven'
    if not (term_error <= CONFOUNDING_FACTOR * max(set_error, floor)
            and set_error <= CONFOUNDING_FACTOR * max(term_error, floor)):
        return None
    return 'confounded'


@pytest.mark.parametrize('alone_significant,set_on_term,term_on_set,errors,may_replace',
                         list(itertools.product([False, True], [False, True], [False, True], ERRORS, [False, True])))
def test_the_judgement_is_the_former_one_and_the_fit_with_both_is_made_only_where_it_decides(
        monkeypatch, alone_significant, set_on_term, term_on_set, errors, may_replace):
    set_rms, term_rms = errors
    term = find_term('angle^3')
    name = discovery.term_effect(term)
    base = _comparison(set_rms, {'gravity_stiffness': 100.0, 'cable_stiffness': 20.0})
    without = _comparison(0.05, {'gravity_stiffness': 110.0})
    swapped = _comparison(term_rms, {'gravity_stiffness': 130.0, f'{name}_coefficient': -5.0})
    both = _comparison(min(set_rms, term_rms), {'gravity_stiffness': 120.0})
    fitted = []

    def compare(prep, effects, start=None, fixed=None, initial_states=None):
        fitted.append(tuple(effects))
        return swapped if 'cable_torque' not in effects else both

    def assess(prep, first, second, effect):
        significant = {(id(without), id(swapped)): alone_significant, (id(swapped), id(both)): set_on_term,
                       (id(base), id(both)): term_on_set}[(id(first), id(second))]
        return SimpleNamespace(significant=significant, parameters=second.parameters, standard_errors={},
                               excess_before=excess_error(first.rms_error, NOISE), share_removed=0.5,
                               t_statistic=3.0, delta_bic=-10.0, dm_statistic=2.0)

    monkeypatch.setattr(discovery, 'compare', compare)
    monkeypatch.setattr(discovery, 'assess', assess)
    prep = SimpleNamespace(noise_rms=NOISE)
    entry = discovery._swapped_in(prep, base, ('cable_torque',), {}, ('cable_torque',), without, term, -4.0,
                                  math.nan, may_replace)
    expected = _former(alone_significant, set_on_term, term_on_set, excess_error(set_rms, NOISE),
                       excess_error(term_rms, NOISE), may_replace)
    assert (entry.status if entry is not None else None) == expected
    if expected is not None:
        assert len(fitted) == 2
    close = errors == ERRORS[0]
    if not alone_significant or not (close or (may_replace and term_rms <= set_rms)):
        assert len(fitted) == 1, fitted          # the answer was already None: the model with both not fitted
