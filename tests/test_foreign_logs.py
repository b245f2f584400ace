"""Logs from other rigs (issue 21 items 1, 2, 3, 6): any rate from 20 Hz, host time stamps, log profiles, and the
foreign-log generator, through the real command line (in-process: exits and messages are what a user sees).

Rates are made the way a logger makes them: one line every N periods of the simulated 490 Hz rig (samples
picked, not averaged), N = 2, 5, 10, 20 (245, 98, 49, 24.5 Hz).
"""
from __future__ import annotations

import hashlib
import json
import math

import numpy as np
import pytest
import yaml

from aeropend_core.cli import main as cli
from aeropend_core.io.log_profile import read_import_metadata
from aeropend_core.io.recording import from_columns, write_csv
from aeropend_core.signals.host_clock import ClockContradiction, regularise
from aeropend_core.signals.quality import DataQualityError, check_recording
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate
from aeropend_core.testing.foreign_logs import ForeignLogSpec, _host_stamps, generate, random_spec

COLUMNS = ('t', 'duty', 'armature_voltage', 'armature_current', 'angle')


@pytest.fixture(scope='module')
def record_490() -> dict[str, np.ndarray]:
    """22 s of the default rig at 490 Hz, 40 dB, 10-bit (diagnose needs 20 s)."""
    duty = lhc_schedule(22.0, seed=5).duty(duration=22.0)
    run = simulate(duty, noise=MeasurementNoise(40.0, True), seed=5)
    return {k: np.asarray(v, dtype=float) for k, v in run.columns(with_truth=False).items() if k in COLUMNS}


def run_cli(argv, capsys) -> tuple[int, str, str]:
    status = cli(argv)
    captured = capsys.readouterr()
    return status, captured.out, captured.err


@pytest.mark.slow
@pytest.mark.parametrize('every', [2, 5, 10, 20])
def test_decimated_records_complete_identify_and_diagnose(record_490, every, tmp_path, capsys):
    path = tmp_path / f'every{every}.csv'
    write_csv(str(path), {k: v[::every] for k, v in record_490.items()})
    rate = f'{490.0 / every:.10g}'
    status, out, err = run_cli(['identify', str(path), '--sample-rate', rate, '--json', str(tmp_path / 'i.json')],
                               capsys)
    assert status == 0, err
    parameters = json.loads((tmp_path / 'i.json').read_text())['parameters']
    assert math.isfinite(parameters['gravity_stiffness'])
    status, out, err = run_cli(['diagnose', str(path), '--sample-rate', rate, '--quiet', '--no-drift',
                                '--only', 'angle_offset', '--json', str(tmp_path / 'd.json')], capsys)
    assert status == 0, err
    assert 'internal error' not in err
    diagnosis = json.loads((tmp_path / 'd.json').read_text())
    # the output-error fit recovers the pendulum within a rate-dependent tolerance (bench/rate_sweep.py measures it)
    assert diagnosis['parameters']['gravity_stiffness'] == pytest.approx(131.75, rel=0.25)
    if every >= 10:          # below ~327 Hz the time constants a sample cannot resolve are said
        assert any('not resolvable at this rate' in note for note in diagnosis['notes'])
    assert all('not_resolvable_at_this_rate' in c for c in diagnosis['candidates'])


def test_quasi_static_observer_predicts_at_a_low_rate():
    """The numba TypingError of issue 21 (a (1, 1) initial state in the quasi-static branch) is gone."""
    from aeropend_core.signals.motor import _predict
    voltage = np.repeat([0.5, 1.5, 1.0], 30)
    current, emf = _predict('quasi_static', np.array([20.0, 0.5, 0.5, 1.1, 0.2]), voltage, 1.0 / 22.28)
    assert current.shape == emf.shape == voltage.shape
    assert np.all(np.isfinite(emf)) and emf[-1] < voltage[-1]


def stamped(seed: int, lines: int = 900, rate: float = 490.0 / 22) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return _host_stamps(np.arange(lines) / rate, ForeignLogSpec(stall_probability=0.04, stall_max=0.36), rng)


def test_host_stamps_are_regularised_with_the_residual_said():
    stamps = stamped(1)
    assert np.any(np.diff(stamps) == 0) and np.max(np.diff(stamps)) > 0.2      # bursts after stalls
    clock = regularise(stamps)                                                 # the rate fitted
    assert 1.0 / clock.period == pytest.approx(490.0 / 22, rel=2e-4)
    assert clock.delay_max > 0.1 and clock.delay_median < 0.01
    given = regularise(stamps, rate=490.0 / 22)
    assert given.rate_given and np.allclose(np.diff(given.time), 22 / 490.0)
    assert 'ms RMS' in given.describe()


@pytest.mark.parametrize('fault, cause', [('lost', 'lost'), ('rate_change', 'rate changed')])
def test_host_stamps_that_contradict_a_constant_rate_are_refused_with_the_cause(fault, cause):
    stamps = stamped(2)
    if fault == 'lost':
        stamps = np.delete(stamps, range(450, 454))
    else:
        stamps[450:] += np.arange(stamps.size - 450) * 0.003
    with pytest.raises(ClockContradiction, match=cause):
        regularise(stamps)


def test_gate_regularises_host_stamps_instead_of_asking_for_more_digits(record_490):
    every = 20
    columns = {k: v[::every] for k, v in record_490.items()}
    columns['t'] = stamped(3, lines=columns['t'].size, rate=490.0 / every)
    report = check_recording(from_columns(columns, source='host.csv'), sample_time=every / 490.0)
    codes = {f.code: f for f in report.findings}
    assert codes['host_stamps'].severity == 'repaired'
    assert 'regularised from the sample order' in codes['host_stamps'].message
    assert 'more digits' not in ' '.join(f.message for f in report.findings)
    assert np.allclose(np.diff(report.recording.time), every / 490.0)
    columns['t'] = np.delete(columns['t'], range(200, 204))           # lost lines: refused, the cause named
    with pytest.raises(DataQualityError, match='lost'):
        check_recording(from_columns({k: (v if k == 't' else np.delete(v, range(200, 204)))
                                      for k, v in columns.items()}, source='host.csv'), sample_time=every / 490.0)


def write_log(tmp_path, spec: ForeignLogSpec):
    log = generate(spec)
    log_path, profile_path = tmp_path / 'rig.log.csv', tmp_path / 'rig.yaml'
    log_path.write_text(log.text)
    profile_path.write_text(yaml.safe_dump(log.profile))
    return log, log_path, profile_path


def test_import_writes_our_record_with_profile_and_hash(tmp_path, capsys):
    log, log_path, profile_path = write_log(tmp_path, ForeignLogSpec(duration=8.0, seed=4))
    out = tmp_path / 'run.csv'
    status, stdout, err = run_cli(['import', str(log_path), '--profile', str(profile_path), '-o', str(out)], capsys)
    assert status == 0, err
    assert stdout == '' and 'wrote ' in err                 # progress on standard error, as in every verb
    # '-o -': the same record on standard output (no file named '-'); --quiet: nothing but warnings on stderr
    status, piped, quiet_err = run_cli(['import', str(log_path), '--profile', str(profile_path), '-o', '-',
                                        '--quiet'], capsys)
    assert status == 0 and piped == out.read_text() and not (tmp_path / '-').exists()
    assert 'wrote ' not in quiet_err and all('warning' in line for line in quiet_err.splitlines())
    metadata = read_import_metadata(out)
    assert metadata['source_sha256'] == hashlib.sha256(log_path.read_bytes()).hexdigest()
    assert metadata['profile'] == log.profile
    assert metadata['sample_rate_hz'] == pytest.approx(490.0 / 22, rel=3e-4)      # given, or fitted (8 s)
    assert any('regularised from the sample order' in note for note in metadata['notes'])
    from aeropend_core.io.recording import load_csv
    record = load_csv(out)
    assert np.allclose(np.diff(record.time), 1.0 / metadata['sample_rate_hz'])
    assert 0.0 <= record.signal('duty').min() and record.signal('duty').max() < 1.0
    angle = record.signal('angle')
    assert abs(np.median(angle[:10])) < 0.02          # the encoder's zero taken off: hanging reads ~0 rad
    assert np.ptp(angle) < math.pi                    # unwrapped: no jump of a turn
    assert record.signal('armature_current').max() < 3.0      # counts -> A


def test_the_in_pulse_current_falls_as_the_duty_rises():
    """The generator's physics: read inside the on-pulse, the current falls with the back-EMF as duty rises."""
    pulse = generate(ForeignLogSpec(duration=30.0, seed=6, current='in_pulse', stamps='none'))
    average = generate(ForeignLogSpec(duration=30.0, seed=6, current='average', stamps='none'))
    for log, sign in ((pulse, -1), (average, 1)):
        table = np.array([[float(x) for x in line.split(',')] for line in log.text.splitlines()[1:]])
        duty, current = table[:, 0], table[:, 1]
        on = duty > 0
        assert sign * np.corrcoef(duty[on], current[on])[0, 1] > 0.3


@pytest.mark.parametrize('edit, message', [
    (lambda p: p['columns']['angle'].update(column='encoder'), "does not have (did you mean 'enc'?)"),
    (lambda p: p['columns']['duty'].update(unit='blorps') or p['columns']['duty'].pop('scale'), 'unknown unit'),
    (lambda p: p['columns']['angle'].update(unit='mA'), 'not a unit of angle'),
    (lambda p: p['columns'].update(speed={'column': 'enc'}), "unknown quantity 'speed'"),
])
def test_profile_mistakes_are_refused_in_one_line(tmp_path, capsys, edit, message):
    log, log_path, profile_path = write_log(tmp_path, ForeignLogSpec(duration=4.0, seed=8, angle='counts'))
    profile = yaml.safe_load(profile_path.read_text())
    if message == 'not a unit of angle':
        for key in ('counts_per_turn', 'zero', 'wrap'):
            profile['columns']['angle'].pop(key)
    edit(profile)
    profile_path.write_text(yaml.safe_dump(profile))
    status, _, err = run_cli(['import', str(log_path), '--profile', str(profile_path), '-o', str(tmp_path / 'o.csv')],
                             capsys)
    assert status == 2
    assert message in err and 'Traceback' not in err
    assert len(err.strip().splitlines()) == 1


@pytest.mark.slow
@pytest.mark.parametrize('seed', [0, 1, 2, 3, 4])
def test_random_foreign_logs_never_end_in_an_internal_error(seed, tmp_path, capsys):
    spec = random_spec(seed, duration=(21.0, 23.0))
    log, log_path, profile_path = write_log(tmp_path, spec)
    status, _, err = run_cli(['identify', str(log_path), '--profile', str(profile_path)], capsys)
    assert status in (0, 2), err
    if status == 2:
        assert 'internal error' not in err and err.strip().splitlines()[-1].startswith('aeropend identify: error:')
    status, _, err = run_cli(['diagnose', str(log_path), '--profile', str(profile_path), '--quiet', '--no-drift',
                              '--only', 'angle_offset'], capsys)
    assert status in (0, 2), err
    assert 'internal error' not in err


def test_stalls_in_a_row_are_not_taken_for_lost_lines(tmp_path, capsys):
    """Stalls back to back can hold every line of an envelope block back (a bump that returns, not a step): the
    variant of the sweep that was refused as "about 6.1 line periods lost" although no line was lost."""
    log, log_path, profile_path = write_log(tmp_path, random_spec(184, duration=(21.0, 27.0)))
    status, _, err = run_cli(['import', str(log_path), '--profile', str(profile_path), '-o', str(tmp_path / 'o.csv')],
                             capsys)
    assert status == 0, err
    assert 'regularised from the sample order' in err


@pytest.mark.slow
def test_a_discovered_terms_refit_that_stops_short_of_the_model_without_it_is_restarted(tmp_path, monkeypatch):
    """Clean 22.3 Hz log (no hidden effect: every discovered term's truth is 0; the current readable, so the full
    model). A refit started at the weak form's screening coefficient can stop in another basin: on such a log
    cos(2*angle) started at c = -1244 1/s^2 stayed there (the angle 3.7 rad RMS off, the training residual far above
    the model without the term, which is the same model at c = 0) and reported -1244 +- 0.00007, 17 million sigma
    from 0. A refit that fits worse than the nested model is started again from c = 0 (here twice); every refitted
    term that is not a confounded lookalike must then cover 0 within 3 sigma.

    Which refit stops short depends on the CPU's rounding (on the machine that found it two of seed 701's did; on an
    AMD EPYC with AVX-512 none did), so every screening coefficient is moved far out (1e4 in the term's unit, its
    sign kept) before the refit: a start no basin near the nested optimum holds, on any machine."""
    from aeropend_core.diagnosis import discovery
    from aeropend_core.diagnosis.diagnose import diagnose
    from aeropend_core.io.log_profile import import_log, load_profile
    restarts = []
    short, prove = discovery._short_of_nested, discovery._prove

    def counted(augmented, base):
        if short(augmented, base):
            restarts.append(augmented.fit.residual_rms)
            return True
        return False

    recovered = []

    def far_start(prep, base, model, fixed, entry, *rest):
        entry.weak_coefficient = math.copysign(1e4, entry.weak_coefficient or 1.0)
        before = len(restarts)
        refit = prove(prep, base, model, fixed, entry, *rest)
        if len(restarts) > before and refit is not None:     # fell short, was started again and gave an estimate
            recovered.append(entry.term.expression)
        return refit
    monkeypatch.setattr(discovery, '_short_of_nested', counted)
    monkeypatch.setattr(discovery, '_prove', far_start)
    # seed 701: two refits restart here. Seed 708 did until s22, but only because the quality gate 'repaired' a
    # true sample of the current's decay after a duty step to 0 at 45.03 s (its message named the kept 1.19 A kick
    # at 1.03 s instead, fixed in s23); the gate now keeps it, and no refit falls short on that log.
    log = generate(ForeignLogSpec(seed=701, duration=72.0, current='average', current_offset_counts=200.0))
    (tmp_path / 'log.csv').write_text(log.text)
    (tmp_path / 'profile.yaml').write_text(yaml.safe_dump(log.profile))
    columns, _ = import_log(tmp_path / 'log.csv', load_profile(tmp_path / 'profile.yaml'))
    result = diagnose(from_columns(columns, source='log.csv'))
    assert restarts, 'no refit fell short of the nested model on this log: the test does not test the restart'
    assert recovered, 'no refit that fell short was started again to an estimate'
    refitted = [t for t in result.discovery.terms if t.refitted and t.status == 'not_proven']
    assert refitted, [t.to_dict() for t in result.discovery.terms]
    for term in refitted:
        assert abs(term.value) <= 3 * term.sigma, term.to_dict()
    assert not result.found


@pytest.mark.slow
def test_a_named_effect_and_a_remainder_below_the_rigs_rate_say_what_the_rate_does(tmp_path, capsys):
    """An effect named on a record below the rig's rate carries the rate's doubt (false alarms were measured at
    490 Hz: a clean 245 Hz log got a coulomb_friction); at 490 Hz the same record's verdict does not. A remainder
    left by the full model at a low rate is said to be possibly the model's own limit there (clean 22.3 Hz logs kept
    one in 11 of 16). Both words are checked through the command line, on a 0.05 rad angle offset."""
    from aeropend_core.present.verdict_text import verdict_message
    duty = lhc_schedule(22.0, seed=5).duty(duration=22.0)
    run = simulate(duty, effects={'angle_offset': {'angle_offset': 0.05}}, noise=MeasurementNoise(40.0, True), seed=5)
    columns = {k: np.asarray(v, dtype=float) for k, v in run.columns(with_truth=False).items() if k in COLUMNS}
    messages = {}
    for every in (1, 5):
        path = tmp_path / f'every{every}.csv'
        write_csv(str(path), {k: v[::every] for k, v in columns.items()})
        status, _, err = run_cli(['diagnose', str(path), '--sample-rate', f'{490.0 / every:.10g}', '--quiet',
                                  '--no-drift', '--only', 'angle_offset', '--json', str(tmp_path / 'd.json')], capsys)
        assert status == 0, err
        diagnosis = json.loads((tmp_path / 'd.json').read_text())
        assert 'angle_offset' in [f['effect'] for f in diagnosis['missing_effects']], diagnosis['message']
        messages[every] = diagnosis['message']
    assert 'At 98 Hz a named effect is less sure than at the rig\'s 490 Hz' in messages[5], messages[5]
    assert 'a named effect is less sure' not in messages[1], messages[1]
    words = verdict_message('unexplained', found=(), noise_rms=3e-3, excess_current=9e-3, excess_final=9e-3,
                            within_noise=1.5e-3, structure=({'signature': 'angle', 'correlation': 0.3},),
                            low_rate_hz=22.27)
    assert 'At 22.27 Hz part or all of this remainder can be the model\'s own limit at this rate' in words
    assert 'can be the model' not in verdict_message('unexplained', found=(), noise_rms=3e-3, excess_current=9e-3,
                                                     excess_final=9e-3, within_noise=1.5e-3,
                                                     structure=({'signature': 'angle', 'correlation': 0.3},))
