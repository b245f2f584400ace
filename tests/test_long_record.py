"""The long-record paths give the short path's answers on records where both apply (issue 15): the sparse
Jacobian with LSMR steps (taken above ``SPARSE_SEGMENTS`` segments), the coarse-to-fine ranking of dead-zone
thresholds (above ``PROFILE_GRID`` input levels), the CSV read block by block, and ``diagnose --start/--stop``."""
from __future__ import annotations

import json

import numpy as np
import pytest

from aeropend_core.diagnosis import compare as compare_module
from aeropend_core.diagnosis import output_error
from aeropend_core.diagnosis.compare import fit_model, gate_thresholds, prepare
from aeropend_core.diagnosis.diagnose import diagnose
from aeropend_core.io import recording as recording_module
from aeropend_core.io.recording import from_columns, load_csv, write_csv
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate
from aeropend_core.present.summary import format_summary


def _record(effects: dict, seed: int, duration: float = 60.0):
    duty = lhc_schedule(duration, seed=seed).duty(duration=duration)
    return simulate(duty, effects=effects, noise=MeasurementNoise(40.0, True), seed=seed)



def _assert_same_friction_verdict(reference, long) -> None:
    """Both name coulomb_friction alone, and `long`'s size is within 1 % and 3 of `reference`'s standard errors."""
    assert (long.verdict, long.missing_effects) == (reference.verdict, reference.missing_effects) == \
        ('effect_found', ['coulomb_friction']), format_summary(long)
    sd = reference.found[0].standard_errors['friction_acceleration']
    a, b = reference.found[0].parameters['friction_acceleration'], long.found[0].parameters['friction_acceleration']
    assert b == pytest.approx(a, rel=0.01) and abs(b - a) < 3 * sd, (a, b, sd)

@pytest.mark.slow
def test_diagnosis_on_the_long_record_path_gives_the_short_paths_answer(monkeypatch):
    """Coulomb friction (4 rad/s^2) hidden in 60 s: every fit forced onto the sparse LSMR path and the dead-zone
    ranking onto the coarse-to-fine one gives the same verdict, the same effect, and its size within 1 % (and within
    3 of its standard errors) of the short path's."""
    recording = from_columns(_record({'coulomb_friction': 4.0}, seed=4).columns(with_truth=False))
    short = diagnose(recording)
    monkeypatch.setattr(output_error, 'SPARSE_SEGMENTS', 0)
    monkeypatch.setattr(compare_module, 'PROFILE_GRID', 4)
    long = diagnose(recording)
    _assert_same_friction_verdict(short, long)
    assert [r['drifting'] for r in long.drift] == [r['drifting'] for r in short.drift]


def test_coarse_to_fine_dead_zone_ranking_finds_the_full_rankings_threshold(monkeypatch):
    """A 0.6 V dead zone: ranked coarse to fine (grid of 4) the profile scores fewer thresholds and refits the
    same best one, to the same parameters, as ranking every threshold."""
    prep = prepare(from_columns(_record({'dead_zone': 0.6}, seed=281).columns(with_truth=False)))
    levels = gate_thresholds(prep)
    assert levels.size > 8          # enough input levels for the coarse path to differ from the full one
    full = fit_model(prep, ['dead_zone'])
    scored = []
    original = compare_module.initial_guess

    def counting(prep_, threshold_voltage=None):
        if threshold_voltage is not None:
            scored.append(threshold_voltage)
        return original(prep_, threshold_voltage)
    monkeypatch.setattr(compare_module, 'initial_guess', counting)
    monkeypatch.setattr(compare_module, 'PROFILE_GRID', 4)
    coarse = fit_model(prep, ['dead_zone'])
    assert len(set(scored)) < levels.size
    assert coarse.parameters['threshold_voltage'] == full.parameters['threshold_voltage']
    for name, value in full.parameters.items():
        assert coarse.parameters[name] == pytest.approx(value, rel=1e-9, abs=1e-12), name


def test_csv_read_block_by_block_is_the_same_table(tmp_path, monkeypatch):
    """Blocks of 7 rows give the table one block gives; a ragged row is still named (before a bad value earlier)."""
    rng = np.random.default_rng(3)
    columns = {'t': np.arange(100) / 490.0, 'armature_voltage': rng.normal(size=100),
               'armature_current': rng.normal(size=100), 'angle': rng.normal(size=100)}
    path = tmp_path / 'run.csv'
    write_csv(str(path), columns)
    whole = load_csv(path)
    monkeypatch.setattr(recording_module, 'CSV_BLOCK_ROWS', 7)
    blocks = load_csv(path)
    for name in ('armature_voltage', 'armature_current', 'angle'):
        np.testing.assert_array_equal(blocks.signals[name], whole.signals[name])
    np.testing.assert_array_equal(blocks.time, whole.time)
    lines = path.read_text().splitlines()
    good = lines[10]
    lines[10] = lines[10].replace(lines[10].split(',')[1], 'abc', 1)       # data row 10: not a number
    lines[50] = lines[50] + ',1.0'                                          # data row 50: a field too many
    path.write_text('\n'.join(lines) + '\n')
    from aeropend_core.errors import AeropendError
    with pytest.raises(AeropendError, match=r"non-numeric value .*'abc', data row 10"):      # the first one in the file
        load_csv(path)
    lines[10] = good
    path.write_text('\n'.join(lines) + '\n')
    with pytest.raises(AeropendError, match='data row 50 has 5 fields, the header has 4'):
        load_csv(path)


@pytest.mark.slow
def test_diagnose_start_stop_selects_the_range_and_says_so(tmp_path, capsys):
    """`diagnose --start/--stop` takes identify's code path: the JSON states the range; a bad range is exit 2."""
    from aeropend_core.cli import main
    path = tmp_path / 'run.csv'
    write_csv(str(path), _record({}, seed=5, duration=50.0).columns(with_truth=False))
    assert main(['diagnose', str(path), '--start', '5', '--stop', '45', '--json', '--quiet', '--no-drift']) == 0
    out = json.loads(capsys.readouterr().out)
    assert out['time_range']['start_s'] == 5 and out['time_range']['stop_s'] == 45
    assert 5.0 <= out['time_range']['samples_start_s'] < 5.01 and 44.99 < out['time_range']['samples_stop_s'] < 45
    assert main(['diagnose', str(path), '--start', '30', '--stop', '10']) == 2
    assert '--start 30 s must be before --stop 10 s' in capsys.readouterr().err
    assert main(['diagnose', str(path), '--start', '100']) == 2
    assert 'no samples with --start 100 s; the recording spans 0 s to' in capsys.readouterr().err


def test_sample_time_from_rounded_stamps_keeps_every_sample_on_the_grid():
    """Stamps written with 12 significant digits far from zero (t from 100,000 s: 0.1 us steps) carry a rounding
    that the median step keeps; over the record it would put the last samples more than a quarter sample off the
    grid (refused as unevenly spaced). The span over the step count is the clock's step."""
    from aeropend_core.model.parameters import SAMPLE_TIME
    columns = _record({}, seed=6).columns(with_truth=False)
    columns['t'] = np.array([float(f'{1e5 + k * SAMPLE_TIME:.12g}') for k in range(len(columns['t']))])
    steps = np.diff(columns['t'])
    drift = abs(np.median(steps) - SAMPLE_TIME) * len(steps) / SAMPLE_TIME
    assert drift > 0.25             # the median step alone would be off by more than a quarter sample at the end
    prep = prepare(from_columns(columns))
    assert prep.sample_time == pytest.approx(SAMPLE_TIME, rel=1e-8)      # the end stamps' rounding over 60 s
    assert prep.gaps.count == 0 and len(prep.time) == len(columns['t'])


@pytest.mark.slow
def test_long_record_search_on_a_subset_gives_the_full_paths_verdict(monkeypatch):
    """Coulomb friction (4 rad/s^2) hidden in 60 s: with the long-record limit lowered to 20 s of training data the
    candidates are compared on an evenly spread half of the training segments, the chosen model fitted on all of
    them. Same verdict and effect as the full path; the size within 1 % and 3 of its standard errors of the full
    path's (it is fitted on the same data); the subset stated in the notes; the drift test on every stretch."""
    from aeropend_core.diagnosis import long_record

    recording = from_columns(_record({'coulomb_friction': 4.0}, seed=4).columns(with_truth=False))
    full = diagnose(recording)
    assert not any(note.startswith('long record') for note in full.notes)
    monkeypatch.setattr(long_record, 'SEARCH_SECONDS', 20.0)
    prep = prepare(recording)
    search, subset = long_record.search_record(prep)
    assert subset is not None and 1 < len(subset.chosen) < subset.total == len(prep.train.segments)
    assert len(search.train.segments) == len(subset.chosen) and search.heldout is prep.heldout
    assert subset.seconds_used < subset.seconds_total
    long = diagnose(recording)
    _assert_same_friction_verdict(full, long)
    # the reported model is the one fitted on every training segment
    assert long.final.fit.n_residuals == full.final.fit.n_residuals
    assert long.found[0].standard_errors['friction_acceleration'] == pytest.approx(
        full.found[0].standard_errors['friction_acceleration'], rel=0.2)
    notes = [note for note in long.notes if note.startswith('long record')]
    assert len(notes) == 1 and f'on {len(subset.chosen)} of {subset.total} training segments' in notes[0], long.notes
    assert [len(r['values']) for r in long.drift] == [len(r['values']) for r in full.drift]
    assert [r['drifting'] for r in long.drift] == [r['drifting'] for r in full.drift]


def test_regime_masks_time_since_step_is_the_direct_definition():
    """The since-step regimes (one sorted search, linear in the record) equal the direct definition: the time since
    the latest input step at or before each sample, no regime before the first step."""
    from types import SimpleNamespace

    from aeropend_core.diagnosis.compare import regime_masks
    rng = np.random.default_rng(5)
    n, sample_time = 5000, 1 / 490.0
    steps = np.array([3000, 17, 1200, 1201, 4999])          # unsorted, adjacent, the last sample
    prep = SimpleNamespace(smoothed_angle=rng.normal(size=n), smoothed_rate=rng.normal(size=n),
                           step_indices=steps, sample_time=sample_time, armature_voltage=rng.uniform(0, 6, n))
    since = np.full(n, np.inf)
    for k in steps:
        since[k:] = np.minimum(since[k:], (np.arange(k, n) - k) * sample_time)
    masks = regime_masks(prep)
    np.testing.assert_array_equal(masks['within 0.5 s after an input step'], since < 0.5)
    np.testing.assert_array_equal(masks['steady input (> 0.5 s after a step)'], since >= 0.5)
    assert not masks['within 0.5 s after an input step'][:17].any()
    prep.step_indices = np.array([], dtype=int)
    assert not regime_masks(prep)['within 0.5 s after an input step'].any()
