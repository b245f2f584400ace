"""Look-alikes (issue #40, the last "Done when"): where a catalog effect and a term outside the catalog explain a
record alike, the effect is not named as present beside a remainder, and the parameters the two explanations
disagree on are said."""

import math
from dataclasses import dataclass, field

import pytest

from aeropend_core.diagnosis.discovery import DiscoveredTerm, Discovery, find_term
from aeropend_core.diagnosis.evidence import DIFFER_SIGMA, differing_parameters
from aeropend_core.diagnosis.model_doubt import beside_lookalikes
from aeropend_core.present.discovery_text import differing_text


def test_parameters_further_apart_than_their_combined_sigma_differ_and_the_rest_do_not():
    with_set = {'gravity_stiffness': 120.0, 'damping': 6.0, 'angle_offset': 0.03}
    with_term = {'gravity_stiffness': 60.0, 'damping': 6.1, 'term_constant_coefficient': 5.0}
    errors_set = {'gravity_stiffness': 3.0, 'damping': 0.2, 'angle_offset': 0.001}
    errors_term = {'gravity_stiffness': 4.0, 'damping': 0.2, 'term_constant_coefficient': 0.3}
    differing = differing_parameters(with_set, errors_set, with_term, errors_term)
    # 60 apart against sqrt(3^2 + 4^2) = 5 combined: differs; 0.1 against 0.28: does not; unshared ones are not compared
    assert differing == {'gravity_stiffness': (120.0, 3.0, 60.0, 4.0)}
    edge = 0.99 * DIFFER_SIGMA * math.hypot(3.0, 4.0)
    assert differing_parameters({'g': 100.0}, {'g': 3.0}, {'g': 100.0 + edge}, {'g': 4.0}) == {}
    assert differing_parameters({'g': 100.0}, {'g': math.nan}, {'g': 0.0}, {'g': 1.0}) == {}


@dataclass
class _Found:
    effect: str
    confounded_with: list = field(default_factory=list)


def _term(expression, status, confounded_with=(), differing=None):
    return DiscoveredTerm(term=find_term(expression), status=status, weak_coefficient=1.0, weak_sigma=0.1,
                          excess_after=0.004, confounded_with=list(confounded_with), differing=differing or {})


def test_an_effect_a_term_explains_as_well_beside_a_remainder_is_not_named_and_the_note_says_why():
    discovery = Discovery([_term('1', 'confounded', ['angle_offset']), _term('angle^3', 'not_proven')])
    kept, notes = beside_lookalikes([_Found('angle_offset'), _Found('coulomb_friction')], discovery)
    assert [f.effect for f in kept] == ['coulomb_friction']
    assert len(notes) == 1 and 'angle_offset is not named' in notes[0] and 'confounded' in notes[0]
    # no confounded term: nothing changes
    kept, notes = beside_lookalikes([_Found('angle_offset')], Discovery([_term('1', 'not_proven')]))
    assert [f.effect for f in kept] == ['angle_offset'] and notes == []
    assert beside_lookalikes([_Found('angle_offset')], None) == ([_Found('angle_offset')], [])


def test_the_differing_parameters_are_said_with_both_values():
    term = _term('angle^3', 'confounded', ['cable_torque'],
                 {'gravity_stiffness': (62.0, 2.0, 118.0, 3.0)})
    text = differing_text(term)
    assert 'gravity_stiffness 62 +- 2 with cable_torque, 118 +- 3 with the term' in text, text
    assert differing_text(_term('angle^3', 'confounded', ['cable_torque'])) == ''
    assert term.to_dict()['differing_parameters']['gravity_stiffness'] == pytest.approx(
        {'with_catalog_set': 62.0, 'with_catalog_set_sigma': 2.0, 'with_term': 118.0, 'with_term_sigma': 3.0})
