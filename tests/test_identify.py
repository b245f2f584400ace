"""Aeropendulum identification against the rig simulator (known truth), the CSV loader and the identify verb.

Tolerances are the ones the issue states; records and seeds are fixed up front (seeds 0, 1, 2), not chosen.
"""
import json

import numpy as np
import pytest

from aeropend_core.cli import main as cli_main
from aeropend_core.errors import (
    AeropendError,
    InsufficientDataError,
    UnknownEffectError,
)
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.identify.pendulum import (
    identify_full_state,
    identify_pendulum,
    interval_current,
)
from aeropend_core.model.parameters import DEFAULT_PARAMETERS as P
from aeropend_core.model.parameters import SAMPLE_TIME
from aeropend_core.sim.noise import MeasurementNoise, add_noise
from aeropend_core.io.recording import load_recording
from aeropend_core.sim.simulate import simulate

LIVE_TRUTH = {'gravity_stiffness': P.gravity_stiffness, 'damping': P.damping,
              'thrust_gain': P.thrust_gain}


def rig_record(seed, duration, noise=None, sample_time=SAMPLE_TIME):
    schedule = lhc_schedule(duration, seed=seed)
    return simulate(schedule.duty(sample_time, duration), noise=noise, seed=seed, sample_time=sample_time)


@pytest.fixture(scope='module')
def live_records():
    # 60 s records, PSNR 50 dB on Va, Ia and angle, then 10-bit angle (and current ADC) quantisation.
    return [rig_record(seed, 60.0, MeasurementNoise(50.0, True)) for seed in (0, 1, 2)]


@pytest.mark.parametrize('index', [0, 1, 2])
def test_live_rig_parameters_within_2_percent(live_records, index):
    tr = live_records[index]
    fit = identify_pendulum(tr.time, tr.armature_voltage, tr.armature_current, tr.angle, duty=tr.duty)
    for name, truth in LIVE_TRUTH.items():
        assert fit.parameters[name] == pytest.approx(truth, rel=0.02), name
    assert fit.parameters['armature_resistance'] == pytest.approx(P.armature_resistance, rel=0.02)
    assert fit.parameters['thrust_coefficient'] == pytest.approx(P.thrust_coefficient, rel=0.02)


@pytest.mark.parametrize('seed', [0, 1])
def test_live_rig_at_40_db_within_3_percent_and_3_sigma(seed):
    """Beyond the issue's 50 dB: at 40 dB + quantisation (60 s) the errors stay within 3 % and within 3 standard
    errors (the input-noise bias compensation and the standard errors are consistent)."""
    tr = rig_record(seed, 60.0, MeasurementNoise(40.0, True))
    fit = identify_pendulum(tr.time, tr.armature_voltage, tr.armature_current, tr.angle, duty=tr.duty)
    for name, truth in LIVE_TRUTH.items():
        assert fit.parameters[name] == pytest.approx(truth, rel=0.03), name
        assert abs(fit.parameters[name] - truth) < 3 * fit.standard_errors[name], name


def test_live_rig_step_kick_must_be_handled(live_records):
    """Without the La·dIa/dt handling the thrust kick at each step biases the fit far beyond 2 %."""
    tr = live_records[0]
    raw = identify_pendulum(tr.time, tr.armature_voltage, tr.armature_current, tr.angle, step_handling='none')
    assert abs(raw.parameters['thrust_gain'] / P.thrust_gain - 1) > 0.05


def test_interval_current_removes_the_kick():
    tr = rig_record(4, 10.0)
    raw = tr.armature_voltage - P.armature_resistance * tr.armature_current
    fixed = tr.armature_voltage[:-1] - P.armature_resistance * interval_current(
        tr.armature_current, SAMPLE_TIME, P.electrical_time_constant)
    true_emf = P.back_emf_constant * 0.5 * (tr.truth['motor_speed'][:-1] + tr.truth['motor_speed'][1:])
    assert np.max(np.abs(raw[:-1] - true_emf)) > 0.2  # volts: the kick
    assert np.max(np.abs(fixed - true_emf)) < 0.02


def test_live_rig_on_windows_with_segments(live_records):
    tr = live_records[1]
    n = len(tr.time) // 3
    pieces = [slice(0, n), slice(n, 2 * n)]
    fit = identify_pendulum([tr.time[s] for s in pieces], [tr.armature_voltage[s] for s in pieces],
                            [tr.armature_current[s] for s in pieces], [tr.angle[s] for s in pieces],
                            duty=[tr.duty[s] for s in pieces])
    # Two 20 s windows: 3 % tolerance (fewer data than the 60 s test).
    for name, truth in LIVE_TRUTH.items():
        assert fit.parameters[name] == pytest.approx(truth, rel=0.03), name


def test_live_rig_cable_torque_effect_is_found():
    tr = rig_record(5, 60.0, MeasurementNoise(50.0, True))
    tr = simulate(lhc_schedule(60.0, seed=5).duty(SAMPLE_TIME, 60.0), effects={'cable_torque': 20.0},
                  noise=MeasurementNoise(50.0, True), seed=5)
    fit = identify_pendulum(tr.time, tr.armature_voltage, tr.armature_current, tr.angle, duty=tr.duty,
                            effects=['cable_torque'])
    assert 'angle' in fit.equation.selected
    assert fit.parameters['cable_stiffness'] == pytest.approx(20.0, rel=0.2)


def test_unmodelled_friction_does_not_wipe_out_the_fit():
    """3 rad/s² of pivot friction (not in the weak-form model): the fit is biased (about -35 %) but keeps the
    physics' scale; with measurement-only whitening every coefficient collapsed to ~0 (-99 %)."""
    tr = simulate(lhc_schedule(20.0, seed=7).duty(SAMPLE_TIME, 20.0), effects={'coulomb_friction': 3.0},
                  noise=MeasurementNoise(50.0, False), seed=7)
    fit = identify_pendulum(tr.time, tr.armature_voltage, tr.armature_current, tr.angle)
    collapsed = identify_pendulum(tr.time, tr.armature_voltage, tr.armature_current, tr.angle, process_noise=False)
    assert fit.parameters['gravity_stiffness'] > 0.5 * P.gravity_stiffness
    assert collapsed.parameters['gravity_stiffness'] < 0.1 * P.gravity_stiffness


# --- edge cases ---------------------------------------------------------------------------------------------
def test_too_short_window_is_refused(live_records):
    tr = live_records[0]
    k = int(np.flatnonzero(np.diff(tr.duty))[1]) + 1
    window = slice(k - 40, k + 40)  # 80 samples around a duty step: excited, but too short
    with pytest.raises(InsufficientDataError, match='shorter than the test-function support'):
        identify_pendulum(tr.time[window], tr.armature_voltage[window], tr.armature_current[window],
                          tr.angle[window], half_width=100)


def test_constant_input_is_refused():
    tr = simulate(np.full(2000, 0.4))
    with pytest.raises(InsufficientDataError, match='no excitation'):
        identify_pendulum(tr.time, tr.armature_voltage, tr.armature_current, tr.angle)


def test_nan_is_refused(live_records):
    tr = live_records[0]
    angle = tr.angle.copy()
    angle[1234] = np.nan
    with pytest.raises(InsufficientDataError, match='angle has 1 NaN'):
        identify_pendulum(tr.time, tr.armature_voltage, tr.armature_current, angle)


def test_unknown_effect_name_is_refused(live_records):
    tr = live_records[0]
    with pytest.raises(UnknownEffectError, match='unknown effect'):
        identify_pendulum(tr.time, tr.armature_voltage, tr.armature_current, tr.angle, effects=['warp_drive'])
    with pytest.raises(AeropendError, match='cannot be written'):
        identify_pendulum(tr.time, tr.armature_voltage, tr.armature_current, tr.angle, effects=['thrust_lag'])


# --- full-state case (paper reproduction) ------------------------------------------------------------------
def full_state_record(seed, duration, psnr_db):
    tr = rig_record(seed, duration)
    rng = np.random.default_rng(1000 + seed)
    data = {'t': tr.time}
    for name in ('armature_voltage', 'armature_current', 'motor_speed', 'angle', 'angular_rate'):
        data[name] = add_noise(tr.truth[name], psnr_db, rng)
    return data


@pytest.mark.parametrize('seed', [0, 1])
def test_full_state_kq_at_50_db(seed):
    """Paper reproduction: Kq within 0.5 % at PSNR 50 dB (the paper got 3.7 %); 30 s records at 490 Hz."""
    fit = identify_full_state(full_state_record(seed, 30.0, 50.0))
    assert fit.parameters['thrust_coefficient'] == pytest.approx(P.thrust_coefficient, rel=0.005)
    assert fit.parameters['gravity_stiffness'] == pytest.approx(P.gravity_stiffness, rel=0.01)


@pytest.mark.parametrize('seed', [0, 1])
def test_full_state_kq_at_30_db(seed):
    """Kq within 5 % at PSNR 30 dB (the paper says its algorithm fails below 50 dB); 60 s records (on 30 s records
    a spurious Ia·ω1 term sometimes takes part of the thrust: -7.6 % for seed 1)."""
    fit = identify_full_state(full_state_record(seed, 60.0, 30.0))
    assert fit.parameters['thrust_coefficient'] == pytest.approx(P.thrust_coefficient, rel=0.05)


def true_full_state_support():
    return {'darmature_current/dt': {'armature_current', 'motor_speed', 'armature_voltage'},
            'dmotor_speed/dt': {'armature_current', 'motor_speed', 'motor_speed^2'},
            'dangle/dt': {'angular_rate'},
            'dangular_rate/dt': {'angular_rate', 'motor_speed^2', 'sin(angle)'}}


def test_full_state_support_at_40_db_in_19_of_20_seeds():
    """Correct support (no spurious, no missing term) in >= 19 of 20 seeds at 40 dB; 20 s records, seeds 0..19.

    All four equations. The armature equation dIa/dt (2 ms dynamics, barely resolved at 490 Hz) used to pick up
    one noise look-alike term (|w|/σ ≈ 2.5) in about 1 record of 10; identify_full_state's significance guard
    (5 % family-wise over the candidates) removes those without touching the true terms (|w|/σ > 30).
    """
    truth = true_full_state_support()
    mechanical = complete = 0
    for seed in range(20):
        fit = identify_full_state(full_state_record(seed, 20.0, 40.0))
        ok = {eq.name: set(eq.selected) == truth[eq.name] for eq in fit.result.equations}
        mechanical += all(v for k, v in ok.items() if k != 'darmature_current/dt')
        complete += all(ok.values())
    assert mechanical >= 19
    assert complete >= 19, f'all four equations correct in {complete}/20 seeds (target 19)'


# --- CSV and CLI -------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_identify_cli_json_and_errors(tmp_path, capsys, live_records):
    tr = live_records[2]
    path = tmp_path / 'run.csv'
    columns = tr.columns()
    np.savetxt(path, np.column_stack(list(columns.values())), delimiter=',', header=','.join(columns),
               comments='')
    rec = load_recording(path)
    assert rec.has('motor_speed') and len(rec) == len(tr.time)
    assert cli_main(['identify', str(path), '--json']) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) >= {'coefficients', 'standard_errors', 'parameters'}
    assert out['parameters']['damping'] == pytest.approx(P.damping, rel=0.02)
    assert cli_main(['identify', str(path)]) == 0
    text = capsys.readouterr().out
    assert 'd^2angle/dt^2' in text and 'rad/s^2' in text
    assert cli_main(['identify', str(tmp_path / 'missing.csv')]) == 2
    assert 'no such file' in capsys.readouterr().err
    bad = tmp_path / 'bad.csv'
    bad.write_text('t,angle\n0,1\n')
    assert cli_main(['identify', str(bad)]) == 2
    assert 'armature_voltage' in capsys.readouterr().err
