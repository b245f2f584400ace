"""The online window analysis and the excitation node's schedule input, without ROS traffic."""
from __future__ import annotations

import numpy as np
import pytest

from aeropend_core.errors import AeropendError, InsufficientDataError, UnknownEffectError
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, SAMPLE_TIME
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate
from aeropend_core.diagnosis.online import analyze_window
from aeropend_core.model.effects import check_effect_names


def test_effect_names_validated():
    assert check_effect_names(['', 'angle_offset', 'angle_offset', ' coulomb_friction ']) == \
        ('angle_offset', 'coulomb_friction')
    with pytest.raises(UnknownEffectError, match='known effects'):
        check_effect_names(['warp_drive'])
    with pytest.raises(AeropendError, match='names only'):
        check_effect_names(['coulomb_friction=4'])


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


@pytest.mark.parametrize('duration, method', [(18.0, 'window'), (25.0, 'compare')])
def test_window_with_dropped_frames_is_segmented_not_filled(duration, method):
    """Frames dropped as a USB link drops them (12 single losses, one burst of 0.4 s: 2.7 % / 1.6 % of the
    window), hidden 0.06 rad offset, 50 dB: the window is split at the gaps (nothing interpolated), says so
    (count, lost samples, longest), and recovers the truth as the gap-free window does (offset within 5 mrad,
    parameters within 8 %, held-out error near the noise). Given by sequence numbers and by time stamps alike."""
    duty = lhc_schedule(duration, seed=3).duty(duration=duration)
    run = simulate(duty, effects={'angle_offset': 0.06}, noise=MeasurementNoise(50, True), seed=2)
    n = run.time.size
    rng = np.random.default_rng(11)
    dropped = set(rng.choice(np.arange(50, n - 50), 12, replace=False).tolist())
    burst = int(0.4 / SAMPLE_TIME)
    dropped |= set(range(n // 3, n // 3 + burst))            # a long gap in the training part
    kept = np.array(sorted(set(range(n)) - dropped))
    sequence = kept + 1000                                   # the rig's counter does not start at 0
    columns = [run.armature_voltage[kept], run.armature_current[kept], run.angle[kept]]
    by_sequence = analyze_window(run.time[kept], *columns, effects=['angle_offset'], sequence=sequence)
    by_stamps = analyze_window(run.time[kept], *columns, effects=['angle_offset'])
    for result in (by_sequence, by_stamps):
        assert result.method == method
        assert result.lost_samples == len(dropped) and result.longest_gap_seconds == pytest.approx(
            burst * SAMPLE_TIME)
        assert 1 <= result.gap_count <= 13           # 13 unless two single losses happen to be neighbours
        assert any(f.code == 'lost_samples' for f in result.findings)   # and the data-quality finding says it
        p = result.parameters
        assert p['angle_offset'][0] == pytest.approx(0.06, abs=0.005)
        assert p['gravity_stiffness'][0] == pytest.approx(DEFAULT_PARAMETERS.gravity_stiffness, rel=0.08)
        assert p['thrust_gain'][0] == pytest.approx(DEFAULT_PARAMETERS.thrust_gain, rel=0.08)
        assert result.rms_error < 2 * result.noise_rms and result.fit_percent > 95
    assert by_sequence.parameters['angle_offset'][0] == pytest.approx(by_stamps.parameters['angle_offset'][0],
                                                                     abs=1e-9)


def test_window_with_too_much_lost_is_refused():
    """More than 30 % of the window lost: refused with the count, not analysed on interpolated data."""
    duty = lhc_schedule(25.0, seed=3).duty(duration=25.0)
    run = simulate(duty, noise=MeasurementNoise(50, True), seed=2)
    kept = np.flatnonzero((np.arange(run.time.size) // 500) % 2 == 0)      # every other quarter second lost
    with pytest.raises(InsufficientDataError, match='samples are lost'):
        analyze_window(run.time[kept], run.armature_voltage[kept], run.armature_current[kept], run.angle[kept])
