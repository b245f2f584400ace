"""Diagnose several recordings of the same rig together: shared parameters, per-record initial states.

The records are put on one sample grid separated by a few filler samples, marked as *record joins*
(:class:`aeropend_core.diagnosis.gaps.Gaps` ``joins``), so the existing diagnosis treats them as one record whose
pieces restart: no multiple-shooting segment spans two records (each piece has its own fitted initial angle and
rate); a join is a new record with its own initial state, never counted or described as lost samples (a record's
own lost samples stay gaps inside it), every model's parameters are shared, and the noise
is estimated over all of them. The training / held-out split is taken *within each record*: the first 75 % of
every record goes to the training part and the last 25 % to the held-out part (the pieces are ordered
``A-train, B-train, ..., A-held, B-held, ...``), so a separating experiment's evidence enters both the fit and the
held-out judgement.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from aeropend_core.errors import AeropendError

#: Lost samples put between two pieces [s] (a gap: the segments restart after it; too short to matter otherwise).
GAP_SECONDS = 0.2
#: Sample times of the records may differ by at most this fraction.
SAMPLE_TIME_TOLERANCE = 0.01


def joint_recording(recordings: Sequence, train_fraction: float | None = None):
    """One recording from several of the same rig, pieces separated by record joins, and the index of the split.

    Parameters
    ----------
    recordings : sequence of Recording [-]
        At least two records with ``armature_voltage`` [V], ``angle`` [rad] and, in every one or none,
        ``armature_current`` [A]; the same sample time.
    train_fraction : float, optional [-]
        Fraction of each record that goes to the training part (default: the diagnosis's 0.75).

    Returns
    -------
    recording : Recording
        The pieces on one grid (time [s] from 0; no samples at the joins between pieces, and each record's own lost
        samples stay missing where they were).
    split : int
        The grid index where the held-out pieces start.

    Raises
    ------
    AeropendError
        Fewer than two records, different sample times, or the current in some records only.
    """
    recording, split, _, _ = _joined(recordings, train_fraction)
    return recording, split


def _joined(recordings: Sequence, train_fraction: float | None):
    """:func:`joint_recording`, plus the record joins on the grid (bool, True between pieces) and the records' own
    lost-sample findings."""
    from aeropend_core.diagnosis.compare import TRAIN_FRACTION
    from aeropend_core.diagnosis.gaps import split_at_gaps
    from aeropend_core.io.recording import from_columns
    from aeropend_core.signals.quality import check_recording
    fraction = TRAIN_FRACTION if train_fraction is None else float(train_fraction)
    if len(recordings) < 2:
        raise AeropendError('a joint diagnosis needs at least two recordings')
    sample_times = [float(np.median(np.diff(r.time))) for r in recordings]
    reference = sample_times[0]
    for recording, sample_time in zip(recordings, sample_times):
        if abs(sample_time - reference) > SAMPLE_TIME_TOLERANCE * reference:
            raise AeropendError(f'{recording.source or "a recording"} is sampled every {sample_time * 1e3:.3f} ms, '
                                f'the first every {reference * 1e3:.3f} ms: record the same rig at the same rate')
    has_current = ['armature_current' in r.signals for r in recordings]
    if any(has_current) and not all(has_current):
        raise AeropendError('some recordings have the armature current and some do not; diagnose records of the same '
                            'kind together')
    names = ['armature_voltage', 'angle'] + (['armature_current'] if all(has_current) else [])
    spans, findings = [], []            # (record's measured grid index, columns, grid start, grid stop)
    for number, recording in enumerate(recordings):
        checked = check_recording(recording)
        findings += [f for f in checked.findings if f.code == 'lost_samples']
        record = checked.recording
        time = np.asarray(record.time, dtype=float)
        source = record.source or f'record {number + 1}'
        # each record on its own grid: a sample it lost stays a gap inside it (never closed up)
        _, _, own = split_at_gaps(time, {}, reference, source, record.signals.get('sequence'))
        index = np.flatnonzero(own.valid)
        columns = {name: np.asarray(record.signals[name], dtype=float) for name in names}
        spans.append((index, columns, fraction))
    gap = max(1, int(round(GAP_SECONDS / reference)))
    pieces = []
    for index, columns, _ in spans:
        cut = int(round(fraction * (index[-1] + 1)))
        pieces.append((index, columns, 0, cut))
    for index, columns, _ in spans:
        cut = int(round(fraction * (index[-1] + 1)))
        pieces.append((index, columns, cut, int(index[-1]) + 1))
    grid, parts, position, split = [], {name: [] for name in names}, 0, 0
    joins = []
    for order, (index, columns, start, stop) in enumerate(pieces):
        if order:
            joins.append(np.arange(position, position + gap))
            position += gap
        if order == len(spans):
            split = position
        inside = (index >= start) & (index < stop)
        grid.append(position + index[inside] - start)
        for name in names:
            parts[name].append(columns[name][inside])
        position += stop - start
    mask = np.zeros(position, dtype=bool)
    mask[np.concatenate(joins)] = True
    columns = {'t': np.concatenate(grid) * reference, **{name: np.concatenate(parts[name]) for name in names}}
    sources = ' + '.join(r.source or f'record {i + 1}' for i, r in enumerate(recordings))
    return from_columns(columns, source=f'{sources} (joint)'), split, mask, tuple(findings)


def prepare_joint(recordings: Sequence, train_fraction: float | None = None):
    """A :class:`~aeropend_core.diagnosis.compare.PreparedRecord` of several records (module docstring).

    Each record is prepared alone first (input conditioning, noise, the motor observer: the observer's back-EMF,
    the thrust voltage, starts from each record's own beginning and runs through it without a break; the motor's
    parameters are then refitted to all records at once, :func:`aeropend_core.signals.motor.refit_shared`), then the
    prepared signals are joined in the order ``A-train, B-train, ..., A-held, B-held, ...`` with gaps between the
    pieces. Run over the joined record instead, the observer carried one piece's motor state across a 0.2 s gap
    into the next (its time constant is ~0.4 s): a designed record whose offset it named alone lost it in the
    joint diagnosis, and a record cut in two gave friction 3 % off (6 sigma, bench/results/2026-11-27-s8-loop2).

    Parameters
    ----------
    recordings : sequence of Recording [-]
        Records of the same rig (see :func:`joint_recording`).
    train_fraction : float, optional [-]
        Fraction of each record in the training part (default 0.75).

    Returns
    -------
    PreparedRecord
        Ready for :func:`aeropend_core.diagnosis.diagnose.diagnose`; its training part holds the first part of
        every record, its held-out part the rest of every record.
    """
    from aeropend_core.diagnosis.compare import TRAIN_FRACTION, Gaps, PreparedRecord, prepare
    joint_recording(recordings, train_fraction)         # the same checks (rate, current in all or none)
    fraction = TRAIN_FRACTION if train_fraction is None else float(train_fraction)
    preps = [prepare(recording) for recording in recordings]
    observers = {p.motor is not None for p in preps}
    members = {None if p.voltage_ensemble is None else p.voltage_ensemble.shape[0] for p in preps}
    if any(p.reduced for p in preps) or len(observers) > 1 or len(members) > 1 or any(
            p.gaps is not None and p.gaps.count for p in preps):
        return _prepare_joined(recordings, train_fraction)      # mixed kinds or lost samples: one preparation
    sample_time = preps[0].sample_time
    if all(p.motor is not None for p in preps):     # one motor: its observer's parameters fitted to all records
        from aeropend_core.signals.motor import refit_shared
        shared = refit_shared([p.motor for p in preps], [p.gate_voltage for p in preps],
                              [p.armature_current for p in preps], [p.step_indices for p in preps], sample_time)
        if shared is not None:
            preps = [dataclasses.replace(p, voltage=fit.back_emf, motor=fit) for p, fit in zip(preps, shared)]
    gap = max(1, int(round(GAP_SECONDS / sample_time)))
    names = ('armature_voltage', 'armature_current', 'angle', 'voltage', 'current', 'gate_voltage')
    pieces = []
    for prep in preps:
        cut = int(round(fraction * len(prep.time)))
        pieces.append((prep, 0, cut))
    for prep in preps:
        cut = int(round(fraction * len(prep.time)))
        pieces.append((prep, cut, len(prep.time)))
    parts = {name: [] for name in names}
    ensemble, valid, steps = [], [], []
    position, split = 0, 0
    for order, (prep, start, stop) in enumerate(pieces):
        if order == len(preps):
            split = position
        if order:
            for name in names:          # lost samples between pieces: linear, never used as data
                before, after = parts[name][-1][-1], getattr(prep, name)[start]
                parts[name].append(np.linspace(before, after, gap + 2)[1:-1])
            if prep.voltage_ensemble is not None:
                ensemble.append(np.zeros((prep.voltage_ensemble.shape[0], gap)))
            valid.append(np.zeros(gap, dtype=bool))
            position += gap
        for name in names:
            parts[name].append(np.asarray(getattr(prep, name), dtype=float)[start:stop])
        if prep.voltage_ensemble is not None:
            ensemble.append(prep.voltage_ensemble[:, start:stop])
        valid.append(np.ones(stop - start, dtype=bool))
        inside = prep.step_indices[(prep.step_indices >= start) & (prep.step_indices < stop)]
        steps.append(inside - start + position)
        position += stop - start
    columns = {name: np.concatenate(parts[name]) for name in names}
    counts = np.array([len(p.time) for p in preps], dtype=float)
    noise = float(np.sqrt(np.sum(counts * np.array([p.noise_rms for p in preps]) ** 2) / counts.sum()))
    findings = tuple(f for p in preps for f in p.findings)
    return PreparedRecord(
        time=np.arange(position) * sample_time, armature_voltage=columns['armature_voltage'],
        armature_current=columns['armature_current'], angle=columns['angle'], sample_time=sample_time,
        voltage=columns['voltage'], current=columns['current'], step_indices=np.concatenate(steps).astype(int),
        noise_rms=noise, split=int(split), motor=preps[0].motor, gate_voltage=columns['gate_voltage'],
        findings=findings, gaps=Gaps(np.concatenate(valid), sample_time, joins=~np.concatenate(valid)),
        angle_step=max(p.angle_step for p in preps),
        voltage_ensemble=np.concatenate(ensemble, axis=1) if ensemble else None)


def _prepare_joined(recordings: Sequence, train_fraction: float | None = None):
    """The joined record prepared as one (records with lost samples, or of different kinds): the joins between the
    records are marked as such (not lost samples), each record's own lost samples stay gaps."""
    from aeropend_core.diagnosis.compare import prepare
    recording, split, joins, own_findings = _joined(recordings, train_fraction)
    prepared = prepare(recording)
    if len(joins) != len(prepared.time):        # never: the grid is built from the same sample time
        raise AeropendError('internal check: the grid of the joint record does not match its joins')
    gaps = dataclasses.replace(prepared.gaps, joins=joins)
    # the joined record's lost-sample finding counts the joins: the records' own findings say what was lost
    findings = tuple(f for f in prepared.findings if f.code != 'lost_samples') + own_findings
    # the split between the records' training and held-out pieces, exactly at the join (prepare placed it by share)
    return dataclasses.replace(prepared, split=int(split), findings=findings, gaps=gaps)


def diagnose_joint(recordings: Sequence, **options):
    """Diagnose several records of the same rig together (shared parameters, per-record initial states).

    Parameters
    ----------
    recordings : sequence of Recording [-]
        At least two records (see :func:`joint_recording`).
    **options
        Passed to :func:`aeropend_core.diagnosis.diagnose.diagnose` (``effects``, ``fixed``, ``progress``, ...).

    Returns
    -------
    Diagnosis
        As :func:`~aeropend_core.diagnosis.diagnose.diagnose`; a note names the records.
    """
    from aeropend_core.diagnosis.diagnose import diagnose
    prepared = prepare_joint(recordings)
    diagnosis = diagnose(prepared, **options)
    diagnosis.notes.append(f'joint diagnosis of {len(recordings)} recordings of the same rig (shared parameters, '
                           'each record with its own initial states; the first 75 % of each record trains, the rest '
                           'is held out).')
    return diagnosis


__all__ = ['joint_recording', 'prepare_joint', 'diagnose_joint']
