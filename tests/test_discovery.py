"""The discovery stage: a term outside the catalog, found in the discrepancy, proven and kept.

Data: 60 s of Latin-hypercube duty steps (duty <= 0.7: the rod stays below 70 deg) simulated with the full model,
PSNR 40 dB on Va, Ia and the angle plus 10-bit quantisation. The out-of-catalog effects live in an effects module
shared with the bench (bench/discovery_effects.py, loaded as ``--effects-module`` loads one): the simulator has
them, the catalog does not. Tolerances stated once:

* an out-of-catalog effect: a term is proven, its expression is one of the vocabulary's (readable, SI unit stated),
  and the error beyond the noise with it falls below HALF the noise RMS;
* a clean record proposes nothing; a catalog effect is still reported as the catalog effect (no discovered term).
"""
import json
import math

import numpy as np
import pytest

from aeropend_core.cli import main as cli_main
from aeropend_core.diagnosis.diagnose import diagnose
from aeropend_core.diagnosis.discovery import VOCABULARY, find_term, term_effect
from aeropend_core.errors import AeropendError
from aeropend_core.io.recording import from_columns
from aeropend_core.model.effects import CATALOG, catalog_scope, load_effects_module
from aeropend_core.present.discovery_text import effect_module_text
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate
from aeropend_core.present.verdict_text import verdict_of

HALF = 0.5
EFFECTS_MODULE = str(__import__('pathlib').Path(__file__).parents[1] / 'bench' / 'discovery_effects.py')


#: Effects registered here (the test-local module, `--term`) leave the catalog after each test (tests/conftest.py)
pytestmark = pytest.mark.usefixtures('scoped_catalog')


def measured_columns(effects=None, seed=11, duration=60.0):
    """Only the measured columns (t, duty, Va, Ia, angle) of a simulated, noisy, quantised record; the test-local
    effects are in the catalog only while simulating (the diagnosis must not have them as candidates)."""
    with catalog_scope():
        load_effects_module(EFFECTS_MODULE)
        schedule = lhc_schedule(duration, duty_range=(0.0, 0.7), duty_cap=0.7, seed=seed)
        trajectory = simulate(schedule.duty(duration=duration), effects=effects,
                              noise=MeasurementNoise(psnr_db=40.0, quantise=True), seed=seed + 1)
    return trajectory.columns(with_truth=False)


def recording(effects=None, seed=11, duration=60.0):
    return from_columns(measured_columns(effects, seed, duration), source=f'simulated seed {seed}')


# ---------------------------------------------------------------------------------------------------- fast checks
def test_every_term_has_a_readable_expression_a_unit_and_a_reading():
    names = set()
    for term in VOCABULARY:
        assert term.expression and term.unit and len(term.reading) > 10, term
        assert term.slug.replace('_', '').isalnum(), term.slug
        names.add(term.slug)
        signals = {'time': np.zeros(3), 'heat': np.ones(3), **{f'lag_{k:g}': np.ones(3) for k in (0.05, 0.15, 0.4)}}
        value = term.function(np.array([0.1, 0.5, 1.0]), np.array([-1.0, 0.0, 2.0]), np.array([10.0, 20, 30]),
                              signals)
        assert np.shape(value) == (3,) and np.all(np.isfinite(value)), term.expression
    assert len(names) == len(VOCABULARY)


def test_a_term_becomes_an_effect_and_a_module_that_loads(tmp_path):
    term = find_term('thrust*angular_rate')
    name = term_effect(term)
    assert name in CATALOG and CATALOG[name].parameters[0].unit == 's/rad'
    assert find_term(' thrust * angular_rate ') is term
    path = tmp_path / 'kept.py'
    path.write_text(effect_module_text([term, find_term('abs(angular_rate)^1.5*sign(angular_rate)')]))
    load_effects_module(str(path))
    kept = CATALOG['discovered_thrust_rate']
    assert kept.function(0.2, 1.5, discovered_thrust_rate_coefficient=-0.1, thrust=40.0) == pytest.approx(-6.0)
    power = CATALOG['discovered_rate_power_1p5']
    assert power.function(0.0, -4.0, discovered_rate_power_1p5_coefficient=2.0) == pytest.approx(-16.0, rel=1e-6)
    assert 'propeller inflow' in kept.description


def test_a_written_module_runs_compiled_and_equals_the_terms_kernel(tmp_path):
    """Vocabulary terms written by --write-discovered (one of each form the writer translates) compile with numba
    (the diagnosis runs them as fast as --term, not in Python) and give the term kernel's value times the
    coefficient: a kept term is the term that was proven (the power laws' true sign, the friction's smooth one)."""
    import warnings

    from aeropend_core.diagnosis.term_kernel import TERM_CODES, term_value
    from aeropend_core.diagnosis.user_kernel import compiled_user_terms
    terms = [find_term(text) for text in (
        '1', 'cos(2*angle)', 'angle^3', 'sign(angular_rate)', 'abs(angular_rate)^0.5*sign(angular_rate)',
        'exp(-(angular_rate/0.1)^2)*sign(angular_rate)', 'sqrt(abs(thrust))*angular_rate', 'thrust^2')]
    path = tmp_path / 'kept_terms.py'
    path.write_text(effect_module_text(terms))
    with warnings.catch_warnings():
        warnings.simplefilter('error')          # a term that fell back to Python would say so: fail
        load_effects_module(str(path))
        for term in terms:
            name = f'discovered_{term.slug}'
            extra = compiled_user_terms([(CATALOG[name].function, {f'{name}_coefficient': 0})])
            assert extra is not None, term.expression
            for y, w, u in ((0.3, -0.7, 12.0), (-1.1, 2.5, 0.4), (0.0, 0.002, 30.0), (0.5, -0.004, 3.0)):
                assert extra(y, w, u, np.array([-0.3])) == pytest.approx(
                    -0.3 * term_value(TERM_CODES[term.slug], y, w, u), rel=1e-12, abs=1e-15), term.expression


def test_unknown_or_unsimulable_terms_are_refused_with_the_list():
    with pytest.raises(AeropendError, match='the terms are'):
        find_term('angle^7')
    with pytest.raises(AeropendError, match='cannot be simulated'):
        find_term('time*thrust')


def test_cli_writes_the_module_and_refuses_bad_input(tmp_path, capsys):
    out = tmp_path / 'found.py'
    assert cli_main(['effects', '--write-discovered', str(out), '--term', 'sin(2*angle)']) == 0
    load_effects_module(str(out))
    assert 'discovered_sin_2angle' in CATALOG
    assert cli_main(['effects', '--write-discovered', str(out), '--term', 'angle^9']) == 2
    assert 'unknown term' in capsys.readouterr().err
    assert cli_main(['effects', '--write-discovered', str(tmp_path / 'x.txt'), '--term', 'angle^3']) == 2
    assert cli_main(['effects', '--write-discovered', str(out)]) == 2
    bad = tmp_path / 'bad.json'
    bad.write_text('{"verdict": "nothing"}')
    assert cli_main(['effects', '--write-discovered', str(out), '--from-json', str(bad)]) == 2


# ---------------------------------------------------------------------------------------------- slow: the physics
OUTSIDE = {
    'test_stribeck': ({'test_stribeck': {'test_stribeck_level': 5.0, 'test_stribeck_speed': 0.15}},
                      'exp(-(angular_rate/0.2)^2)*sign(angular_rate)'),
    'test_inflow': ({'test_inflow': 0.05}, 'thrust*angular_rate'),
    'test_second_harmonic': ({'test_second_harmonic': 6.0}, 'sin(2*angle)'),
}


@pytest.mark.slow
@pytest.mark.parametrize('effect', sorted(OUTSIDE))
def test_an_effect_outside_the_catalog_is_discovered_and_the_error_falls_below_half_the_noise(effect):
    truth, _expected = OUTSIDE[effect]
    found = diagnose(recording(truth), drift=False)
    assert not any(c.effect.startswith('test_') for c in found.candidates)      # outside the catalog indeed
    proven = found.discovery.proven if found.discovery is not None else []
    assert proven, (found.verdict, verdict_of(found))
    best = proven[0]
    assert best.term.expression in {t.expression for t in VOCABULARY}
    assert best.excess_after < HALF * found.noise_rms, (best.term.expression, best.excess_after, found.noise_rms)
    assert math.isfinite(best.value) and best.sigma > 0
    entry = found.to_dict()['discovered_terms'][0]
    assert entry['expression'] == best.term.expression and entry['add'][0] == '--term'
    (value,) = entry['parameters'].values()
    assert value['unit'] == best.term.unit and value['sigma'] > 0
    assert best.term.expression in verdict_of(found) and 'mrad' in verdict_of(found)


@pytest.mark.slow
def test_a_lookalike_the_catalog_set_absorbs_is_reported_as_confounded_with_the_experiment():
    """An encoder's second-harmonic nonlinearity (measured = angle + 0.04 sin(2 angle)) is absorbed by a catalog set
    (cable_torque + angle_offset); the term sin(2*angle) explains the data as well in its place: confounded, with the
    experiment that separates them (issue #25: a discovered term and a catalog set that explain the data equally)."""
    from aeropend_core.model.effects import MEASUREMENT, EffectParameter, register_effect

    with catalog_scope():       # in the catalog only while simulating: the diagnosis must not have it as a candidate
        register_effect('test_encoder_harmonic', 'encoder second-harmonic nonlinearity', kind=MEASUREMENT,
                        replace=True,
                        parameters=[EffectParameter('test_encoder_amplitude', 'rad', 'amplitude', 0.04, -1.0, 1.0)])(
            lambda angle, test_encoder_amplitude: angle + test_encoder_amplitude * np.sin(2.0 * angle))
        schedule = lhc_schedule(60.0, duty_range=(0.0, 0.7), duty_cap=0.7, seed=11)
        trajectory = simulate(schedule.duty(duration=60.0), effects={'test_encoder_harmonic': 0.04},
                              noise=MeasurementNoise(psnr_db=40.0, quantise=True), seed=12)
    found = diagnose(from_columns(trajectory.columns(with_truth=False)), drift=False)
    confounded = [t for t in found.discovery.terms if t.status == 'confounded'] if found.discovery else []
    assert confounded, (found.verdict, verdict_of(found))
    assert confounded[0].term.expression == 'sin(2*angle)' and confounded[0].confounded_with == found.missing_effects
    assert found.verdict == 'confounded'
    message = verdict_of(found)
    assert 'cannot tell them apart' in message and 'rests at several angles' in message, message


@pytest.mark.slow
def test_a_clean_record_proposes_nothing():
    found = diagnose(recording(None, seed=5), drift=False)
    assert found.to_dict()['discovered_terms'] == [], verdict_of(found)
    assert found.verdict == 'nothing_missing', verdict_of(found)


@pytest.mark.slow
def test_a_catalog_effect_is_still_reported_as_the_catalog_effect():
    found = diagnose(recording({'coulomb_friction': 4.0}, seed=7), drift=False)
    assert found.verdict == 'effect_found' and found.missing_effect == 'coulomb_friction', verdict_of(found)
    assert found.to_dict()['discovered_terms'] == []


@pytest.mark.slow
def test_the_cli_add_reproduces_the_fall(tmp_path, capsys):
    truth, _ = OUTSIDE['test_inflow']
    columns = measured_columns(truth, seed=11)
    path = tmp_path / 'inflow.csv'
    np.savetxt(path, np.column_stack(list(columns.values())), delimiter=',', header=','.join(columns), comments='')
    out, page = tmp_path / 'd.json', tmp_path / 'd.html'
    assert cli_main(['diagnose', str(path), '--no-drift', '--quiet', '--json', str(out), '--report', str(page)]) == 0
    first = json.loads(out.read_text())
    assert first['discovered_terms'], first['message']
    term = first['discovered_terms'][0]
    # the HTML report shows the term: expression, c +- sigma with its unit, the fall, the share, the add arguments
    html = page.read_text()
    section = html[html.index('<h2 id="discovery">'):]
    section = section[:section.index('<h2', 5)]
    (coefficient,) = term['parameters'].values()
    proven = section[section.index('PROVEN'):]
    assert term['expression'] in proven and f'{coefficient["value"]:.4g} &plusmn; {coefficient["sigma"]:.2g}' in proven
    assert coefficient['unit'] in proven and term['reading'].split(' (')[0].replace("'", '&#x27;') in proven
    assert (f'{term["error_beyond_noise_before"] * 1e3:.2f} &rarr; <b>{term["error_beyond_noise_after"] * 1e3:.2f}'
            in proven)
    assert f'{term["share_of_error_removed"] * 100:.0f}&nbsp;%' in proven
    assert f'{term["add"][0]} &#x27;{term["add"][1]}&#x27;' in proven and 'href="#discovery"' in html
    again = tmp_path / 'e.json'
    assert cli_main(['diagnose', str(path), '--no-drift', '--quiet', '--json', str(again), *term['add']]) == 0
    second = json.loads(again.read_text())
    assert second['error_beyond_noise'] == pytest.approx(term['error_beyond_noise_after'], rel=0.2, abs=2e-4)


def test_the_compiled_kernel_evaluates_every_simulated_term_as_the_vocabulary_does():
    from aeropend_core.diagnosis.term_kernel import TERM_CODES, term_value
    simulated = [t for t in VOCABULARY if t.simulated]
    assert {t.slug for t in simulated} == set(TERM_CODES)
    rng = np.random.default_rng(3)
    y, w, u = rng.uniform(-1.4, 1.4, 50), rng.uniform(-3, 3, 50), rng.uniform(0, 120, 50)
    for term in simulated:
        expected = term.function(y, w, u, None)
        got = np.array([term_value(TERM_CODES[term.slug], a, b, c) for a, b, c in zip(y, w, u)])
        np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-12, err_msg=term.expression)
