"""A look-alike judgement that rests on an output-error fit stopped at its evaluation cap says so (issue 41, "never
silently wrong"): on the bench's 600 s record the imitator of the dry friction, ``exp(-(angular_rate/0.4)^2) *
sign(angular_rate)``, ran to its 60-evaluation cap and the check's "no look-alike" stood on that unfinished fit
without a word. Now :func:`aeropend_core.diagnosis.discovery._swapped_in` lists such fits, the check
(:func:`aeropend_core.diagnosis.lookalike_check.named_lookalikes`) returns them even when it finds no look-alike, and
the JSON, the summary's lines, the verdict's sentence and the report say it. Stand-ins for the fits (the judgement
itself is tests/test_swapped_in.py's)."""
from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from aeropend_core.diagnosis import discovery, lookalike_check
from aeropend_core.diagnosis.compare import excess_error
from aeropend_core.diagnosis.discovery import find_term
from aeropend_core.present.discovery_text import discovery_html, discovery_lines, discovery_sentence

NOISE = 0.01


def _comparison(rms, parameters, success=True):
    fit = SimpleNamespace(standard_errors={k: 0.1 for k in parameters}, initial_states=None, success=success)
    return SimpleNamespace(rms_error=rms, parameters=dict(parameters), fit=fit)


def _judge(monkeypatch, swapped_finished: bool, both_finished: bool, term_rms: float):
    """_swapped_in on stand-ins: the set's error 0.011 rad, the term's `term_rms`; (entry, at_cap, fits made)."""
    term = find_term('angle^3')
    name = discovery.term_effect(term)
    base = _comparison(0.0110, {'gravity_stiffness': 100.0, 'cable_stiffness': 20.0})
    without = _comparison(0.05, {'gravity_stiffness': 110.0})
    swapped = _comparison(term_rms, {'gravity_stiffness': 130.0, f'{name}_coefficient': -5.0}, swapped_finished)
    both = _comparison(0.0110, {'gravity_stiffness': 120.0}, both_finished)
    fitted = []

    def compare(prep, effects, start=None, fixed=None, initial_states=None):
        fitted.append(tuple(effects))
        return swapped if 'cable_torque' not in effects else both

    def assess(prep, first, second, effect):
        significant = first is without          # the term alone counts; neither adds to the other
        return SimpleNamespace(significant=significant, parameters=second.parameters, standard_errors={},
                               excess_before=excess_error(first.rms_error, NOISE), share_removed=0.5,
                               t_statistic=3.0, delta_bic=-10.0, dm_statistic=2.0)

    monkeypatch.setattr(discovery, 'compare', compare)
    monkeypatch.setattr(discovery, 'assess', assess)
    at_cap: list[dict] = []
    entry = discovery._swapped_in(SimpleNamespace(noise_rms=NOISE), base, ('cable_torque',), {}, ('cable_torque',),
                                  without, term, -4.0, math.nan, False, at_cap)
    return entry, at_cap, fitted


def test_an_imitator_fit_stopped_at_its_cap_is_listed_with_both_errors(monkeypatch):
    entry, at_cap, fitted = _judge(monkeypatch, swapped_finished=False, both_finished=True, term_rms=0.0200)
    assert entry is None and len(fitted) == 1          # errors apart: no look-alike, as before
    assert len(at_cap) == 1
    row = at_cap[0]
    assert row['term'] == 'angle^3' and row['in_place_of'] == ['cable_torque']
    assert row['fit'] == 'term in place of the set'
    assert row['term_excess_error'] == pytest.approx(excess_error(0.0200, NOISE))
    assert row['set_excess_error'] == pytest.approx(excess_error(0.0110, NOISE))


def test_finished_fits_list_nothing_and_a_capped_fit_with_both_is_listed(monkeypatch):
    entry, at_cap, _ = _judge(monkeypatch, swapped_finished=True, both_finished=True, term_rms=0.0200)
    assert entry is None and at_cap == []
    entry, at_cap, fitted = _judge(monkeypatch, swapped_finished=True, both_finished=False, term_rms=0.0111)
    assert entry is not None and entry.status == 'confounded' and len(fitted) == 2
    assert [row['fit'] for row in at_cap] == ['term beside the set']


def test_the_check_says_when_its_no_lookalike_rests_on_a_fit_at_its_cap(monkeypatch):
    row = {'term': 'exp(-(angular_rate/0.4)^2)*sign(angular_rate)', 'in_place_of': ['coulomb_friction'],
           'fit': 'term in place of the set', 'term_excess_error': 0.00452, 'set_excess_error': 0.00181}

    def beside(prep, final, without, model, fixed, effect, say, at_cap):
        at_cap.append(row)
        return None                                     # no look-alike: before, the check returned None, silent

    monkeypatch.setattr(lookalike_check, '_beside', beside)
    found = lookalike_check.named_lookalikes(None, None, SimpleNamespace(), ('coulomb_friction',), {},
                                             ('coulomb_friction',))
    assert found is not None and found.terms == [] and found.at_cap == [row]
    assert found.to_dict()['fits_stopped_at_cap'] == [row]
    for text in ('\n'.join(discovery_lines(found)), discovery_sentence(found, 0.005), discovery_html(found, 0.005)):
        assert 'evaluation cap' in text and 'coulomb_friction' in text and '4.52 mrad' in text and '1.81' in text
    assert 'no term of the vocabulary stands out' not in '\n'.join(discovery_lines(found))
    assert 'sparse regression' not in discovery_sentence(found, 0.005)     # the discovery stage did not run


def test_the_check_stays_silent_when_every_fit_finished(monkeypatch):
    monkeypatch.setattr(lookalike_check, '_beside', lambda *args: None)
    assert lookalike_check.named_lookalikes(None, None, SimpleNamespace(), ('coulomb_friction',), {},
                                            ('coulomb_friction',)) is None
