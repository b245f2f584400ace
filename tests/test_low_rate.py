"""Low sample rates (issue 21): a duty step that lands between two samples, the motor observer at 49 and 24.5 Hz,
and seeded low-rate records through ``aeropend diagnose`` with known truth.

Rates are made the way a logger makes them: one line every N periods of the simulated 490 Hz rig (samples picked).
Tolerances are the ones bench/rate_sweep.py states (gravity_stiffness and damping 15 % at 49 Hz, 25 % at 24.5 Hz;
thrust_gain twice those); the recovery tests' seeds are not the benches' (11-14).
"""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

from aeropend_core.cli import main as cli
from aeropend_core.diagnosis.compare import prepare
from aeropend_core.diagnosis.doubts import rate_doubts
from aeropend_core.io.recording import Recording, write_csv
from aeropend_core.model.parameters import DEFAULT_PARAMETERS as P
from aeropend_core.signals.motor import _predict
from aeropend_core.signals.preprocess import step_switches
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate

COLUMNS = ('t', 'duty', 'armature_voltage', 'armature_current', 'angle')
TOLERANCE = {10: 0.15, 20: 0.25}


@pytest.fixture(scope='module')
def rig_record() -> dict[str, np.ndarray]:
    """30 s of the default rig at 490 Hz, 40 dB, 10-bit, with its truth (seed 21)."""
    duty = lhc_schedule(30.0, seed=21).duty(duration=30.0)
    run = simulate(duty, noise=MeasurementNoise(40.0, True), seed=21)
    return {k: np.asarray(v, dtype=float) for k, v in run.columns(with_truth=True).items()}


def test_a_step_inside_a_sample_interval_is_integrated_as_if_sampled_finely():
    """The observer's Va changing at 30 % of a 24.5 Hz interval gives the back-EMF and current of the same input
    simulated ten times finer with the step on that fine sample."""
    sample_time = 1.0 / 24.5
    levels = np.repeat([0.4, 1.6, 0.9], 12)
    switch = step_switches(np.array([12, 24]), levels.size, sample_time)
    switch[switch < 1] = 0.3
    state = np.array([1.08, 2e-3, 2.9, 0.44, 2.6, 0.0, 0.0])      # R, La/R, q1, p2, p3, Ia0, e0
    current, emf = _predict('inductance', state, levels, sample_time, switch)
    fine = np.repeat(levels, 10)
    for k in (12, 24):      # the fine samples of interval k-1 from 30 % on hold the new level
        fine[(k - 1) * 10 + 3:k * 10] = levels[k]
    fine_current, fine_emf = _predict('inductance', state, fine, sample_time / 10)
    assert np.max(np.abs(emf - fine_emf[::10])) < 1e-9
    assert np.max(np.abs(current - fine_current[::10])) < 1e-9
    # holding the old level over the whole interval instead misses the current at the next sample by far more
    _, held_emf = _predict('inductance', state, levels, sample_time)
    assert np.max(np.abs(held_emf - fine_emf[::10])) > 1e-3


@pytest.mark.parametrize('every', [10, 20])
def test_motor_observer_gives_the_true_back_emf_at_a_low_rate(rig_record, every):
    """At 49 and 24.5 Hz the observer explains the current (adequate) and its thrust e|e| scales as the truth's
    within 3 %, Rm within 3 % (before the step-in-interval model: rejected at both rates)."""
    pick = slice(None, None, every)
    recording = Recording(rig_record['t'][pick], {k: rig_record[k][pick] for k in COLUMNS[1:]}, source='test')
    prep = prepare(recording)
    assert prep.motor is not None, 'the motor observer was rejected'
    assert prep.motor.parameters['motor_resistance'] == pytest.approx(P.armature_resistance, rel=0.03)
    true_emf = P.back_emf_constant * rig_record['true_motor_speed'][pick]
    late = slice(int(2.0 / prep.sample_time), None)       # after the motor's start from rest
    emf, true_emf = prep.motor.back_emf[late], true_emf[late]
    thrust, truth = emf * np.abs(emf), true_emf * np.abs(true_emf)
    assert float(thrust @ truth / (truth @ truth)) == pytest.approx(1.0, abs=0.03)


@pytest.mark.slow
@pytest.mark.parametrize('every', [10, 20])
def test_seeded_low_rate_record_recovers_the_pendulum_with_the_rate_said(rig_record, every, tmp_path, capsys):
    path = tmp_path / f'every{every}.csv'
    write_csv(str(path), {k: rig_record[k][::every] for k in COLUMNS})
    status = cli(['diagnose', str(path), '--sample-rate', f'{490.0 / every:.10g}', '--no-drift', '--only',
                  'angle_offset', '--json', str(tmp_path / 'd.json')])
    out = capsys.readouterr().out
    assert status == 0
    diagnosis = json.loads((tmp_path / 'd.json').read_text())
    limit = TOLERANCE[every]
    for name, truth, factor in (('gravity_stiffness', P.gravity_stiffness, 1), ('damping', P.damping, 1),
                                ('thrust_gain', P.thrust_gain, 2)):
        assert diagnosis['parameters'][name] == pytest.approx(truth, rel=limit * factor), name
        # the measured accuracy at this rate stands next to the number, in the JSON and in the text
        assert diagnosis['parameter_rate_doubts'][name].startswith('rate: at ')
        line = next(line for line in out.splitlines() if line.strip().startswith(name))
        assert '~ rate: at ' in line


def test_rate_doubts_are_said_only_below_the_rigs_rate():
    assert rate_doubts(1.0 / 490.0) == {}
    assert set(rate_doubts(1.0 / 49.0)) == {'gravity_stiffness', 'damping', 'thrust_gain'}
    slower = rate_doubts(1.0 / 20.0)['damping']
    assert 'slower than any rate measured' in slower
    assert 'not been measured' in rate_doubts(1.0 / 49.0, reduced=True)['damping']


def test_below_the_lowest_rate_the_analysis_refuses_in_one_line(rig_record, tmp_path, capsys):
    path = tmp_path / 'every30.csv'
    write_csv(str(path), {k: rig_record[k][::30] for k in COLUMNS})     # 16.3 Hz
    status = cli(['diagnose', str(path), '--sample-rate', f'{490.0 / 30:.10g}', '--quiet'])
    err = capsys.readouterr().err
    assert status == 2
    assert 'Traceback' not in err
    assert '19.5' in err


@pytest.mark.slow
def test_a_weak_form_model_that_diverges_at_a_low_rate_is_said_not_squared_into_an_overflow(tmp_path, capsys):
    """At 24.5 Hz the weak form's (biased) model can be unstable as a running model: its held-out free run grows
    without bound. identify says so in words, with no fit score, instead of an overflow warning (which, as an error,
    was an internal error) or an infinite rms; the output-error fit is still scored."""
    import warnings
    duty = lhc_schedule(30.0, seed=11).duty(duration=30.0)      # seed 11: a record whose weak-form model diverges
    run = simulate(duty, noise=MeasurementNoise(40.0, True), seed=11)
    columns = {k: np.asarray(v, dtype=float) for k, v in run.columns(with_truth=False).items() if k in COLUMNS}
    path = tmp_path / 'every20.csv'
    write_csv(str(path), {k: v[::20] for k, v in columns.items()})
    with warnings.catch_warnings():
        warnings.simplefilter('error', RuntimeWarning)
        status = cli(['identify', str(path), '--sample-rate', '24.5'])
    out = capsys.readouterr().out
    assert status == 0
    weak_line = next(line for line in out.splitlines() if 'free run' in line or 'free-run fit' in line)
    assert 'diverges' in weak_line or 'fit -' not in weak_line, weak_line
    assert 'inf' not in weak_line and 'nan' not in weak_line, weak_line
    assert re.search(r'Output-error fit of the same model .* held-out fit \d', out), out
