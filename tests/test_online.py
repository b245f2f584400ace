"""The online window analysis and the excitation node's schedule input, without ROS traffic."""
from __future__ import annotations

import numpy as np
import pytest

from aeropend_core.errors import AeropendError, InsufficientDataError, UnknownEffectError
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, SAMPLE_TIME
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate
from aeropend_core.diagnosis.online import analyze_window, fill_gaps
from aeropend_core.model.effects import check_effect_names


def test_effect_names_validated():
    assert check_effect_names(['', 'angle_offset', 'angle_offset', ' coulomb_friction ']) == \
        ('angle_offset', 'coulomb_friction')
    with pytest.raises(UnknownEffectError, match='known effects'):
        check_effect_names(['warp_drive'])
    with pytest.raises(AeropendError, match='names only'):
        check_effect_names(['coulomb_friction=4'])


def test_fill_gaps_interpolates_lost_samples():
    grid, filled, missing = fill_gaps(np.array([5, 6, 9]), {'angle': np.array([0.0, 1.0, 4.0])})
    assert missing == 2 and list(grid) == [5, 6, 7, 8, 9]
    assert np.allclose(filled['angle'], [0.0, 1.0, 2.0, 3.0, 4.0])


def test_constant_duty_is_insufficient_excitation():
    n = int(15 / SAMPLE_TIME)
    run = simulate(np.full(n, 0.4), seed=1)
    with pytest.raises(InsufficientDataError, match='excitation insufficient'):
        analyze_window(run.time, run.armature_voltage, run.armature_current, run.angle)


@pytest.mark.parametrize('duration, method', [(18.0, 'window'), (25.0, 'compare')])
def test_window_recovers_truth_and_hidden_offset(duration, method):
    """Hidden 0.06 rad offset, 50 dB noise, 10-bit quantisation: off the noise floor without the effect, on it with
    it; parameters within 8 % (their ratio 3 %), the offset within 5 mrad. Both held-out paths."""
    duty = lhc_schedule(duration, seed=3).duty(duration=duration)
    run = simulate(duty, effects={'angle_offset': 0.06}, noise=MeasurementNoise(50, True), seed=2)
    without = analyze_window(run.time, run.armature_voltage, run.armature_current, run.angle)
    with_offset = analyze_window(run.time, run.armature_voltage, run.armature_current, run.angle,
                                 effects=['angle_offset'])
    assert without.method == with_offset.method == method
    assert with_offset.fit_percent > 95 and with_offset.fit_percent > without.fit_percent
    assert with_offset.rms_error < 2 * with_offset.noise_rms < without.rms_error
    p = with_offset.parameters
    truth = DEFAULT_PARAMETERS
    assert p['angle_offset'][0] == pytest.approx(0.06, abs=0.005)
    assert p['gravity_stiffness'][0] == pytest.approx(truth.gravity_stiffness, rel=0.08)
    assert p['thrust_gain'][0] == pytest.approx(truth.thrust_gain, rel=0.08)
    assert p['thrust_gain'][0] / p['gravity_stiffness'][0] == pytest.approx(
        truth.thrust_gain / truth.gravity_stiffness, rel=0.03)
    assert 'sin(angle)' in with_offset.coefficients and 'cos(angle)' in with_offset.coefficients


def test_steps_file_and_flat_steps(tmp_path):
    from aeropend_ros.excitation_node import check_steps, read_steps_file
    path = tmp_path / 'steps.yaml'
    path.write_text('steps:\n  - [0.3, 1.5]\n  - [0.55, 2.0]\n')
    assert read_steps_file(path).tolist() == [[0.3, 1.5], [0.55, 2.0]]
    assert check_steps([0.1, 1.0, 0.2, 0.5], 'x').shape == (2, 2)
    with pytest.raises(AeropendError, match='fraction'):
        check_steps([[1.5, 1.0]], 'x')
    with pytest.raises(AeropendError, match='positive'):
        check_steps([[0.5, 0.0]], 'x')
    path.write_text('steps: 3\n')
    with pytest.raises(AeropendError, match='needs a list'):
        read_steps_file(path)
    with pytest.raises(AeropendError, match='cannot read'):
        read_steps_file(tmp_path / 'missing.yaml')


def test_window_refuses_non_finite_or_non_uniform_data():
    """The analysis itself refuses NaN/inf and a time axis off the sample grid (never a number from them)."""
    duty = lhc_schedule(8.0, seed=3).duty(duration=8.0)
    run = simulate(duty, seed=2)
    angle = run.angle.copy()
    angle[100] = np.nan
    with pytest.raises(AeropendError, match='angle has 1 NaN/inf'):
        analyze_window(run.time, run.armature_voltage, run.armature_current, angle)
    current = run.armature_current.copy()
    current[-1] = np.inf
    with pytest.raises(AeropendError, match='armature_current has 1 NaN/inf'):
        analyze_window(run.time, run.armature_voltage, current, run.angle)
    time = run.time.copy()
    time[500:] += 0.5 * SAMPLE_TIME                   # a stamp glitch that was not put on the grid
    with pytest.raises(AeropendError, match='not uniform'):
        analyze_window(time, run.armature_voltage, run.armature_current, run.angle)
    with pytest.raises(AeropendError, match='values for'):
        analyze_window(run.time, run.armature_voltage[:-1], run.armature_current, run.angle)


def test_window_passes_the_data_quality_gate():
    """analyze_window itself applies the gate: a one-turn glitch is unwrapped and listed with the result (the
    numbers are those of the clean window); a frozen angle is refused."""
    from aeropend_core.signals.quality import DataQualityError
    duty = lhc_schedule(8.0, seed=3).duty(duration=8.0)
    run = simulate(duty, noise=MeasurementNoise(50, True), seed=2)
    clean = analyze_window(run.time, run.armature_voltage, run.armature_current, run.angle)
    assert clean.findings == ()
    glitched = run.angle.copy()
    glitched[1500:1745] += 2 * np.pi
    result = analyze_window(run.time, run.armature_voltage, run.armature_current, glitched)
    assert [f.code for f in result.findings] == ['angle_jump']
    assert result.parameters['gravity_stiffness'][0] == pytest.approx(clean.parameters['gravity_stiffness'][0],
                                                                      rel=1e-6)
    frozen = run.angle.copy()
    frozen[1000:2500] = frozen[1000]
    with pytest.raises(DataQualityError, match='stuck'):
        analyze_window(run.time, run.armature_voltage, run.armature_current, frozen)


def test_parameter_trends_use_non_overlapping_windows_and_flag_a_sagging_gain():
    from aeropend_core.diagnosis.online import ParameterTrends
    trends = ParameterTrends(window_seconds=25.0)
    rng = np.random.default_rng(4)
    for k in range(60):                          # a window every 5 s for 300 s; the gain sags 15 % over it
        stop = 25.0 + 5.0 * k
        gain = 140.0 * (1 - 0.15 * (stop - 12.5) / 300.0) + rng.normal(scale=0.3)
        report = trends.add(stop, {'thrust_gain': (gain, 0.3), 'damping': (13.8 + rng.normal(scale=0.05), 0.05)})
    assert report['thrust_gain']['drifting'] and report['thrust_gain']['stretches'] == 12
    assert report['thrust_gain']['change'] == pytest.approx(-0.14, abs=0.03)
    assert not report['damping']['drifting']
    assert trends.add(330.0, {'thrust_gain': (120.0, 0.3)})['thrust_gain']['stretches'] == 1   # model changed


def test_parameter_trends_name_the_windows_they_tested():
    from aeropend_core.diagnosis.online import ParameterTrends
    trends = ParameterTrends(window_seconds=20.0)
    assert trends.tested_stops() == []
    for k in range(12):                          # a window every 5 s: 20, 25, ..., 75 s
        trends.add(20.0 + 5.0 * k, {'thrust_gain': (140.0, 0.3)})
    assert trends.tested_stops() == [35.0, 55.0, 75.0]      # the latest and every earlier one that does not overlap
    trends.reset(10.0)
    assert trends.tested_stops() == [] and trends.window_seconds == 10.0
