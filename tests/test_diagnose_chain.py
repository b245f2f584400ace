"""A small thrust lag with the angle sensor's measurement chain known or not (issue #11, item 4).

Data with known truth: 60 s of LHC duty steps simulated with the full model, a thrust lag hidden, Gaussian noise at
40 dB and 10-bit quantisation; only the measured columns reach the diagnosis. "Chain known" is what a user passes:
``--fix angle_filter=0`` (the simulated rig has no angle filter). Seeds are used by no bench and no other test.
"""
from __future__ import annotations

import json
import re

import numpy as np
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


@pytest.mark.slow
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


@pytest.mark.slow
@pytest.mark.parametrize('seed', [8311, 8312])
def test_a_10_ms_lag_is_named_or_reported_as_a_near_miss_with_the_parameter_doubt(capsys, tmp_path, seed):
    """10 ms with the chain known, 40 dB: the lag passes the parameter t and the held-out test; most of it is
    absorbed by the nominal parameters (a thrust lag d looks like a rod 1 + (c/J) d heavier), so what it removes is
    small. Either way it must not be silent: named within 15 %, or the verdict "nothing missing" carries a note with
    the lag's estimate (within 15 %) and how far the nominal parameters move with it -- and they do move: without
    the lag mgd/J fits >= 5 % low, with it within 3 % of the truth. (With the share-of-the-error rule, dropped in the
    third pass, 8311 was named and 8312 a near miss; both are named now.) With the chain unknown the same record is
    never a confident thrust lag."""
    truth = 0.010
    data = _record(tmp_path, 'small-lag.csv', {'thrust_lag': truth}, 40.0, seed)
    unknown = _diagnose(capsys, data)        # the same record, chain unknown: never a confident thrust lag
    assert not (unknown['verdict'] == 'effect_found' and 'thrust_lag' in unknown['add']), unknown['message']
    result = _diagnose(capsys, data, '--fix', 'angle_filter=0')
    assert result['verdict'] in ('effect_found', 'nothing_missing'), result['message']
    if result['verdict'] == 'effect_found':
        assert result['add'] == ['thrust_lag'], result['message']
        assert result['missing_effects'][0]['parameters']['time_constant'] == pytest.approx(truth, rel=0.15)
        return
    notes = [note for note in result['notes'] if note.startswith('a small thrust_lag cannot be ruled out')]
    assert len(notes) == 1, result['notes']
    estimate = float(re.search(r'time_constant = ([0-9.e-]+) \+-', notes[0]).group(1))
    assert estimate == pytest.approx(truth, rel=0.15)
    before, after = map(float, re.search(r'gravity_stiffness ([0-9.]+) -> ([0-9.]+) 1/s\^2', notes[0]).groups())
    stiffness = DEFAULT_PARAMETERS.gravity_stiffness
    assert result['parameters']['gravity_stiffness'] == pytest.approx(before, rel=1e-3)
    assert before < 0.95 * stiffness and after == pytest.approx(stiffness, rel=0.03)
    assert 'free-decay segments' in notes[0]


@pytest.mark.slow
def test_no_near_miss_note_on_a_clean_record(capsys, tmp_path):
    """Nothing hidden, chain known: nothing is missing and no candidate is reported as a near miss."""
    data = _record(tmp_path, 'clean.csv', {}, 40.0, 8321)
    result = _diagnose(capsys, data, '--fix', 'angle_filter=0')
    assert result['verdict'] == 'nothing_missing', result['message']
    assert not [note for note in result['notes'] if 'cannot be ruled out' in note], result['notes']


@pytest.mark.slow
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


def test_near_miss_note_names_the_rule_that_kept_a_supported_candidate_out():
    """A candidate with t and Diebold-Mariano above the thresholds but a held-out gain below the materiality floor
    gets one note naming that floor (in mrad^2, from the record's noise) and its estimate; a candidate that fails the
    t test, or one that is significant, gets none."""
    from types import SimpleNamespace

    from aeropend_core.diagnosis import diagnose as rules
    from aeropend_core.diagnosis.diagnose import Candidate
    from aeropend_core.diagnosis.doubts import near_miss_notes

    noise = 0.01                                                   # rad
    prep = SimpleNamespace(noise_rms=noise, heldout=SimpleNamespace(residual_index=np.arange(3700)), gaps=None,
                           angle=np.zeros(29400))
    current = SimpleNamespace(rms_error=0.0102, parameters={'gravity_stiffness': 110.0})
    floor = (rules.MATERIAL * noise) ** 2

    def candidate(t, gain, significant=False):
        comparison = SimpleNamespace(parameters={'gravity_stiffness': 117.0})
        return Candidate('thrust_lag', comparison, {'time_constant': 0.0101}, {'time_constant': 0.0007}, -50.0,
                         0.0, 0.0, significant, t_statistic=t, dm_statistic=3.0, mse_gain=gain, share_removed=0.3)

    notes = near_miss_notes([candidate(14.0, 0.5 * floor), candidate(1.0, 0.5 * floor),
                             candidate(14.0, 2 * floor, significant=True)], current, prep)
    assert len(notes) == 1, notes
    assert notes[0].startswith('a small thrust_lag cannot be ruled out (time_constant = 0.0101 +- 0.0007 s')
    assert 'too small to name' in notes[0] and 'supported by the statistics' not in notes[0]
    assert f'less than ({rules.MATERIAL:g} x the noise RMS)^2 = {floor * 1e6:.3f} mrad^2' in notes[0]
    assert 'gravity_stiffness 110 -> 117' in notes[0] and '+6.4 %' in notes[0]


def test_a_near_miss_that_changes_nothing_is_not_noted_beside_nothing_missing():
    """Issue #42 item 3: after "nothing significant is missing" a note said "dead_zone is supported by the statistics
    ... but not named" for a candidate with BIC +0 that gained 0.000 mrad^2 on a model already within the noise. A
    near miss is noted only when it matters: a nominal parameter moves beyond +-2 of its standard errors, or it
    removes at least MATERIAL_SHARE of the error beyond the noise."""
    from types import SimpleNamespace

    from aeropend_core.diagnosis import diagnose as rules
    from aeropend_core.diagnosis.diagnose import Candidate
    from aeropend_core.diagnosis.doubts import MATERIAL_SHARE, near_miss_notes

    noise = 0.01                                                   # rad
    prep = SimpleNamespace(noise_rms=noise, heldout=SimpleNamespace(residual_index=np.arange(3700)), gaps=None,
                           angle=np.zeros(29400))
    within = SimpleNamespace(rms_error=0.0099, parameters={'gravity_stiffness': 127.2},
                             fit=SimpleNamespace(standard_errors={'gravity_stiffness': 1.8}))

    def candidate(stiffness, excess_before=0.0, share=0.0):
        comparison = SimpleNamespace(parameters={'gravity_stiffness': stiffness})
        return Candidate('dead_zone', comparison, {'threshold_voltage': 0.0535}, {'threshold_voltage': 0.031}, 0.0,
                         excess_before, excess_before, False, t_statistic=rules.T_MIN + 1, dm_statistic=3.9,
                         mse_gain=0.0, share_removed=share)

    assert near_miss_notes([candidate(127.2 + 3.0)], within, prep) == []     # within +-2 sigma, nothing to remove
    moved = near_miss_notes([candidate(127.2 + 5.0)], within, prep)                  # 2.8 sigma: the +- is too small
    assert len(moved) == 1 and 'gravity_stiffness 127.2 -> 132.2' in moved[0] and 'within the noise' in moved[0]
    removes = near_miss_notes([candidate(127.2, 0.004, MATERIAL_SHARE + 0.01)], within, prep)
    assert len(removes) == 1 and removes[0].startswith('a small dead_zone cannot be ruled out')
