"""A joint diagnosis's record boundaries are new records, never lost samples (issue #26); a record's own lost
samples stay gaps inside it. Cheap: two short simulated records prepared jointly, no fit."""
from __future__ import annotations

import numpy as np

from aeropend_core.diagnosis.joint import joint_recording, prepare_joint
from aeropend_core.io.recording import from_columns
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate


def record(seed: int, lose: slice | None = None):
    duty = lhc_schedule(22.0, seed=seed).duty(duration=22.0)
    columns = simulate(duty, noise=MeasurementNoise(50.0, True), seed=seed).columns(with_truth=False)
    if lose is not None:
        keep = np.ones(len(columns['t']), dtype=bool)
        keep[lose] = False
        columns = {name: values[keep] for name, values in columns.items()}
    return from_columns(columns, source=f'seed {seed}')


def test_record_joins_are_not_lost_samples_and_a_real_gap_stays_one():
    first, second = record(1), record(2)
    prepared = prepare_joint([first, second])
    gaps = prepared.gaps
    assert (gaps.count, gaps.lost, gaps.records) == (0, 0, 4)      # A-train | B-train | A-held | B-held
    assert gaps.describe() == '' and gaps.to_dict()['lost_samples'] == 0
    assert prepared.valid is not None and not prepared.valid.all()     # the joins still give no residuals
    assert not any(f.code == 'lost_samples' for f in prepared.findings)
    # every training segment and held-out piece lies inside one record: none spans a join
    joins = np.flatnonzero(gaps.joins)
    for a, b in list(zip(prepared.train.seg_start, prepared.train.seg_stop)) + prepared.gaps.pieces(
            prepared.split, len(prepared.time)):
        assert not np.any((joins >= a) & (joins < b))
    # 25 lost samples inside the second record's training part: one gap of 25, said as lost inside the records
    lossy = record(2, slice(4000, 4025))
    prepared = prepare_joint([first, lossy])
    gaps = prepared.gaps
    assert (gaps.count, gaps.lost, gaps.records) == (1, 25, 4)
    note = gaps.describe()
    assert note.startswith('the record has 1 gap(s) of lost samples inside the records (25 samples'), note
    lost = [f for f in prepared.findings if f.code == 'lost_samples']
    assert len(lost) == 1 and lost[0].count == 25, prepared.findings
    # the joined recording keeps the lost samples missing where they were (not closed up)
    joined, split = joint_recording([first, lossy])
    steps = np.rint(np.diff(joined.time) / np.median(np.diff(joined.time))).astype(int)
    assert sorted(steps[steps > 1] - 1)[0] == 25


def test_the_motor_search_is_not_run_across_record_joins():
    """The motor equation's search simulates one observer state through the record; across a join it would run the
    first record's motor fit over the second record (its switch positions one record long: the compiled observer
    read past their end and `aeropend run --until-decided` died of a segmentation fault in round 2)."""
    from aeropend_core.diagnosis.motor_discovery import _simulate, discover_motor
    prepared = prepare_joint([record(1), record(2)])
    found = discover_motor(prepared)
    assert found.terms == [] and 'one record at a time' in found.note, found.note
    n = 50
    try:
        _simulate(np.zeros(8), -1, np.zeros(n), np.zeros(n), np.zeros(n - 1), 1 / 490)
    except ValueError as error:
        assert 'differ in length' in str(error)
    else:
        raise AssertionError('a switch array shorter than Va must be refused, not read past its end')
