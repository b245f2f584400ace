"""A small thrust lag with the angle sensor's measurement chain known or not (issue #11, item 4).

Data with known truth: 60 s of LHC duty steps simulated with the full model, a thrust lag hidden, Gaussian noise at
40 dB and 10-bit quantisation; only the measured columns reach the diagnosis. "Chain known" is what a user passes:
``--fix angle_filter=0`` (the simulated rig has no angle filter). Seeds are used by no bench and no other test.
"""
from __future__ import annotations

import json
import re

import pytest

from aeropend_core.cli import main as aeropend
from aeropend_core.model.parameters import DEFAULT_PARAMETERS


def _record(tmp_path, name: str, effects: dict, psnr: float, seed: int):
    from aeropend_core.io.recording import write_csv
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import simulate
    duty = lhc_schedule(60.0, duty_range=(0.0, 0.7), duty_cap=0.7, seed=seed).duty(duration=60.0)
    run = simulate(duty, effects=effects, noise=MeasurementNoise(psnr, True), seed=seed + 1)
    path = tmp_path / name
    write_csv(str(path), run.columns(with_truth=False))
    return path


def _diagnose(capsys, *argv) -> dict:
    assert aeropend(['diagnose', *map(str, argv), '--json', '--quiet', '--no-drift']) == 0
    return json.loads(capsys.readouterr().out)


def test_a_19_ms_lag_is_named_when_the_chain_is_known_and_never_confidently_when_not(capsys, tmp_path):
    """19 ms (the smallest size bench/robustness.py --known-chain names in 4 of 4 seeds at 40 dB): with
    ``--fix angle_filter=0`` the lag is named alone, within 15 %; the same record with the chain unknown is never a
    confident thrust lag (a lag of 19 ms and a 19 ms angle filter differ by (w d)^2/9 = 0.6 % at the rod's 1.9 Hz)."""
    truth = 0.019
    data = _record(tmp_path, 'lag.csv', {'thrust_lag': truth}, 40.0, 8301)
    known = _diagnose(capsys, data, '--fix', 'angle_filter=0')
    assert known['fixed'] == {'filter_delay': 0.0} and known['fixed_from'] == {'filter_delay': '--fix'}
    assert known['verdict'] == 'effect_found' and known['add'] == ['thrust_lag'], known['message']
    assert known['missing_effects'][0]['parameters']['time_constant'] == pytest.approx(truth, rel=0.15)
    unknown = _diagnose(capsys, data)
    assert not (unknown['verdict'] == 'effect_found' and 'thrust_lag' in unknown['add']), unknown['message']
    assert unknown['verdict'] in ('confounded', 'nothing_missing'), unknown['message']
    if unknown['verdict'] == 'confounded':
        lag = next(f for f in unknown['missing_effects'] if 'thrust_lag' in [f['effect'], *f['confounded_with']])
        assert {lag['effect'], *lag['confounded_with']} == {'thrust_lag', 'angle_filter'}
        assert any('fix the filter at its hardware value' in note for note in unknown['notes'])


@pytest.mark.parametrize('seed', [8311, 8312])
def test_a_10_ms_lag_is_named_or_reported_as_a_near_miss_with_the_parameter_doubt(capsys, tmp_path, seed):
    """10 ms with the chain known: at 40 dB the lag passes every statistical test but, most of it absorbed by the
    nominal parameters (a thrust lag d looks like a rod 1 + (c/J) d heavier), it removes about as much held-out
    error as the noise-power spread, so it is named in some records and not in others (seeds 8311-8317: named in
    5 of 7; bench seeds at 9.4 ms: 1 of 4). Either way it must not be silent: named within 15 %, or the verdict
    "nothing missing" carries a note with the lag's estimate (within 15 %) and how far the nominal parameters move
    with it -- and they do move: without the lag mgd/J fits >= 5 % low, with it within 3 % of the truth. Seed 8311
    is a record where it is named, 8312 one where it is a near miss: both branches are checked. With the chain
    unknown the same record is never a confident thrust lag."""
    truth = 0.010
    data = _record(tmp_path, 'small-lag.csv', {'thrust_lag': truth}, 40.0, seed)
    unknown = _diagnose(capsys, data)        # the same record, chain unknown: never a confident thrust lag
    assert not (unknown['verdict'] == 'effect_found' and 'thrust_lag' in unknown['add']), unknown['message']
    result = _diagnose(capsys, data, '--fix', 'angle_filter=0')
    assert result['verdict'] == {8311: 'effect_found', 8312: 'nothing_missing'}[seed], result['message']
    if result['verdict'] == 'effect_found':
        assert result['add'] == ['thrust_lag'], result['message']
        assert result['missing_effects'][0]['parameters']['time_constant'] == pytest.approx(truth, rel=0.15)
        return
    notes = [note for note in result['notes'] if note.startswith('thrust_lag is supported by the statistics')]
    assert len(notes) == 1, result['notes']
    estimate = float(re.search(r'time_constant = ([0-9.e-]+) \+-', notes[0]).group(1))
    assert estimate == pytest.approx(truth, rel=0.15)
    before, after = map(float, re.search(r'gravity_stiffness ([0-9.]+) -> ([0-9.]+) 1/s\^2', notes[0]).groups())
    stiffness = DEFAULT_PARAMETERS.gravity_stiffness
    assert result['parameters']['gravity_stiffness'] == pytest.approx(before, rel=1e-3)
    assert before < 0.95 * stiffness and after == pytest.approx(stiffness, rel=0.03)
    assert 'free-decay segments' in notes[0]


def test_no_near_miss_note_on_a_clean_record(capsys, tmp_path):
    """Nothing hidden, chain known: nothing is missing and no candidate is reported as supported-but-not-named."""
    data = _record(tmp_path, 'clean.csv', {}, 40.0, 8321)
    result = _diagnose(capsys, data, '--fix', 'angle_filter=0')
    assert result['verdict'] == 'nothing_missing', result['message']
    assert not [note for note in result['notes'] if 'supported by the statistics' in note], result['notes']


def test_a_lag_named_with_the_chain_unknown_says_it_may_hold_the_filter(capsys, tmp_path):
    """75 ms lag read through the rig's 14.1 ms filter, 40 dB. Chain unknown: whatever is named, a thrust lag named
    alone carries the note that it includes any angle filter (its estimate does: ~96 ms in the bench). Chain known
    (``--fix angle_filter=0.0141``): the lag is named within 15 % and there is no such note."""
    truth = 0.075
    data = _record(tmp_path, 'filtered-lag.csv', {'thrust_lag': truth, 'angle_filter': 0.0141}, 40.0, 8331)
    unknown = _diagnose(capsys, data)
    chain = [note for note in unknown['notes'] if note.startswith('the measurement chain was not given')]
    if unknown['verdict'] == 'effect_found' and 'angle_filter' not in unknown['add']:
        assert unknown['add'] == ['thrust_lag'], unknown['message']
        assert len(chain) == 1 and 'includes any angle_filter' in chain[0] and '--fix angle_filter' in chain[0]
    else:
        assert unknown['verdict'] in ('effect_found', 'confounded') and not chain, unknown['message']
    known = _diagnose(capsys, data, '--fix', 'angle_filter=0.0141')
    assert known['verdict'] == 'effect_found' and known['add'] == ['thrust_lag'], known['message']
    assert known['missing_effects'][0]['parameters']['time_constant'] == pytest.approx(truth, rel=0.15)
    assert not [note for note in known['notes'] if note.startswith('the measurement chain was not given')]
