"""The verdict in two layers (issue #42 item 3): one plain sentence a student reads first (what is missing, how big
with its unit, what to do next; no test names, equation numbers or paper symbols), then the evidence. Built from
typed facts as the diagnosis returns them (no fit here: the words are under test)."""
from __future__ import annotations

import math
import re
from types import SimpleNamespace

import pytest

from aeropend_core.present.plain_verdict import plain_verdict
from aeropend_core.present.verdict_text import verdict_message

#: Words a student should not meet in the first sentence (they belong to the evidence).
JARGON = re.compile(r'HAC|Diebold|BIC|eq \(\d\)|f_eq5|t = |DM = |dBIC|r = ', re.IGNORECASE)
#: The plain sentence stays short enough to read at a glance [characters].
PLAIN_MAX = 420


def facts(verdict, **given):
    base = dict(verdict=verdict, found=(), noise_rms=0.01078, excess_current=0.01121, excess_final=0.0,
                within_noise=0.0054, structure=(), drift_text='', heldout_only=(), heldout_advice='', discovery=None,
                explained_below=0.005, reduced_rate_hz=None, motor=None, motor_input_corrected=False,
                low_rate_hz=None, prefix='')
    base.update(given)
    return SimpleNamespace(**base)


def lag(confounded_with=()):
    return SimpleNamespace(effect='thrust_lag', parameters={'time_constant': 0.14}, standard_errors={
        'time_constant': 0.0036}, confounded_with=tuple(confounded_with), share_removed=1.0, share_measurable=1.0,
        excess_before=0.01121, excess_after=0.0)


def diagnosis(f, effects=()):
    return SimpleNamespace(facts=f, verdict=f.verdict, effects=list(effects))


def evidence(f) -> str:
    return verdict_message(f.verdict, found=f.found, noise_rms=f.noise_rms, excess_current=f.excess_current,
                           excess_final=f.excess_final, within_noise=f.within_noise, structure=f.structure,
                           low_rate_hz=f.low_rate_hz, reduced_rate_hz=f.reduced_rate_hz)


def check_plain(text: str) -> None:
    assert not JARGON.search(text), text
    assert len(text) <= PLAIN_MAX, (len(text), text)
    assert 'Next:' in text, text


def test_an_effect_found_says_what_how_big_with_its_unit_and_the_next_command():
    f = facts('effect_found', found=(lag(),))
    text = plain_verdict(diagnosis(f), 'lag.csv')
    check_plain(text)
    assert text.startswith('Missing: thrust_lag, time_constant 0.14 +- 0.0036 s (thrust builds up')
    assert 'from 11.21 to 0.00 mrad' in text and '10.78 mrad measurement noise' in text
    assert text.endswith('Next: aeropend diagnose lag.csv --add thrust_lag.')
    assert 'the held-out error beyond the noise falls from 11.21 to 0.00 mrad' in evidence(f)     # the evidence layer
    # without the record's name the next step is said in words; an --add given before is kept in the command
    assert 'Next: diagnose again with --add thrust_lag.' in plain_verdict(diagnosis(f))
    assert 'Next: aeropend diagnose lag.csv --add cable_torque --add thrust_lag --report after.html.' in plain_verdict(
        diagnosis(f, ['cable_torque']), 'lag.csv', report=True)


def test_nothing_missing_says_so_without_a_contradiction():
    f = facts('nothing_missing', excess_current=0.0)
    text = plain_verdict(diagnosis(f))
    check_plain(text)
    assert text.startswith('Nothing is missing') and 'within the 10.78 mrad measurement noise' in text
    assert 'supported' not in text and 'missing:' not in text


@pytest.mark.parametrize('rate', [None, 24.5])
def test_an_unexplained_error_at_a_low_rate_stays_plain_and_short(rate):
    """Issue #42: ~1,150 characters of jargon at a low rate. The first sentence says what is missing, how big and
    what to do, the rate's doubt in a clause; the statistics stay in the evidence."""
    f = facts('unexplained', excess_final=0.00331, noise_rms=0.00287, reduced_rate_hz=rate, low_rate_hz=rate,
              structure=({'signature': 'rate|rate| (quadratic drag)', 'correlation': -0.2},))
    text = plain_verdict(diagnosis(f))
    check_plain(text)
    assert '3.31 mrad beyond the 2.87 mrad noise' in text and 'rate|rate|' in text
    assert ('24.5 Hz' in text and "model's own limit" in text) == (rate is not None)
    assert len(evidence(f)) > len(text)


def test_confounded_names_both_and_the_experiment_as_next_step():
    f = facts('confounded', found=(lag(['angle_filter']),))
    text = plain_verdict(diagnosis(f))
    check_plain(text)
    assert 'One of thrust_lag or angle_filter is missing' in text and 'cannot tell which' in text
    assert '--until-decided' in text


def test_a_low_rate_effect_asks_for_a_record_at_the_rigs_rate():
    f = facts('effect_found', found=(lag(),), low_rate_hz=49.0)
    text = plain_verdict(diagnosis(f))
    check_plain(text)
    assert text.endswith("The record is at 49 Hz: confirm it on a record at the rig's 490 Hz.")
    assert math.isclose(f.low_rate_hz, 49.0)


def test_a_lookalike_term_puts_the_parameter_that_decides_first():
    """A cable spring and a hardening cubic stay alike at every rest the rig reaches once the thrust gain is refitted,
    yet their fits disagree in gravity by about the cable's size: the plain sentence sends the user to measure it."""
    term = SimpleNamespace(status='confounded', confounded_with=['cable_torque'],
                           term=SimpleNamespace(expression='angle^3'),
                           differing={'gravity_stiffness': (132.7, 2.0, 161.4, 0.64)})
    cable = SimpleNamespace(effect='cable_torque', parameters={'cable_stiffness': 28.65},
                            standard_errors={'cable_stiffness': 1.8}, confounded_with=(), share_removed=0.98,
                            share_measurable=1.0, excess_before=0.00211, excess_after=0.00027)
    f = facts('confounded', found=(cable,), discovery=SimpleNamespace(terms=[term]), excess_current=0.00211,
              excess_final=0.00027)
    text = plain_verdict(diagnosis(f), 'cable.csv')
    assert not JARGON.search(text) and 'Next:' in text, text
    assert 'measure gravity_stiffness independently (132.7 with the catalog effect, 161.4 1/s^2 with the term)' in text
    assert text.index('gravity_stiffness') < text.index('--until-decided')
    term.differing = {}
    assert 'Next: record an experiment that may separate them (aeropend run --until-decided)' in plain_verdict(
        diagnosis(f), 'cable.csv')


def test_a_lookalike_whose_size_reaches_zero_is_offered_only_as_a_stand_in():
    """Second-rig record 64098 (dry friction alone): the verdict said "quadratic_drag or the term
    abs(rate)^0.5*sign(rate)" with the drag 0.154 +- 0.20, yet advised the drag as "the model to use". The advice now
    carries the size, and one within 2 sigma of zero is said unmeasured and offered only as a stand-in."""
    term = SimpleNamespace(status='confounded', confounded_with=['quadratic_drag'],
                           term=SimpleNamespace(expression='abs(rate)^0.5*sign(rate)'), differing={})
    drag = SimpleNamespace(effect='quadratic_drag', parameters={'drag_coefficient': 0.154},
                           standard_errors={'drag_coefficient': 0.20}, confounded_with=(), share_removed=0.6,
                           share_measurable=1.0, excess_before=0.004, excess_after=0.001)
    f = facts('confounded', found=(drag,), discovery=SimpleNamespace(terms=[term]), excess_current=0.004,
              excess_final=0.001)
    text = plain_verdict(diagnosis(f), 'rig.csv')
    assert 'quadratic_drag drag_coefficient 0.154 +- 0.2' in text, text
    assert 'within 2 sigma of zero' in text and 'only as a stand-in' in text and 'model to use' not in text, text
    drag.standard_errors = {'drag_coefficient': 0.02}
    text = plain_verdict(diagnosis(f), 'rig.csv')
    assert 'is the model to use: aeropend diagnose rig.csv --add quadratic_drag' in text, text
    assert 'zero' not in text, text
