"""The thrust doubt of an identified model from the rests of its open-loop record (control.hold_doubt)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from aeropend_core.control.hold_doubt import hold_doubt, rests, widened
from aeropend_core.control.model_source import ModelSource
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, SAMPLE_TIME
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate


def _record(rig, seed=3, psnr=40.0):
    duty = lhc_schedule(40.0, duty_range=(0.0, 0.6), duty_cap=0.6, seed=seed).duty(SAMPLE_TIME, 40.0)
    columns = simulate(duty, rig, None, noise=MeasurementNoise(psnr, True), seed=seed).columns(with_truth=False)
    return columns['t'], columns['angle'], columns['duty']


@pytest.mark.parametrize('factor', [0.9, 1.12])
def test_the_rests_measure_a_thrust_the_model_gets_wrong(factor):
    # known truth: the rig's L/J is `factor` x the model's, 40 dB and the 10-bit angle
    rig = DEFAULT_PARAMETERS.scaled(lever_per_inertia=factor)
    doubt = hold_doubt(*_record(rig), DEFAULT_PARAMETERS)
    assert doubt is not None and len(doubt.factors) >= 8
    assert abs(np.mean(doubt.factors) - factor) < 0.02 * factor          # the bias is measured within 2 %
    assert doubt.tolerance[0] < factor < doubt.tolerance[1]
    # the design's tolerance is widened to hold it; the fit's own doubt is kept
    tolerance, beyond = widened((0.95, 1.05), doubt)
    assert tolerance[0] <= min(0.95, factor) and tolerance[1] >= max(1.05, factor) and not beyond


def test_a_right_model_keeps_a_narrow_doubt():
    doubt = hold_doubt(*_record(DEFAULT_PARAMETERS, seed=5), DEFAULT_PARAMETERS)
    assert doubt is not None
    assert 0.97 < doubt.tolerance[0] and doubt.tolerance[1] < 1.03


def test_a_record_without_rests_says_so():
    time = np.arange(0.0, 5.0, SAMPLE_TIME)
    duty = 0.4 + 0.2 * np.sin(2 * math.pi * 3.0 * time)                  # never constant: no hold
    assert rests(time, np.zeros_like(time), duty) == []
    assert hold_doubt(time, np.zeros_like(time), duty, DEFAULT_PARAMETERS) is None
    model = ModelSource(thrust_tolerance=(0.95, 1.05)).with_hold_doubt(None)
    assert model.thrust_tolerance == (0.95, 1.05) and 'too few rests' in model.doubts[-1]


def test_cli_record_needs_the_model_it_checks(tmp_path):
    import subprocess
    import sys
    time, angle, duty = _record(DEFAULT_PARAMETERS)
    path = tmp_path / 'open.csv'
    np.savetxt(path, np.column_stack([time, duty, angle]), delimiter=',', header='t,duty,angle', comments='')
    command = [sys.executable, '-c', 'from aeropend_core.cli import main; raise SystemExit(main())', 'control',
               'design', '--record', str(path), '-o', str(tmp_path / 'g.yaml')]
    bad = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert bad.returncode != 0 and '--model' in bad.stderr and 'Traceback' not in bad.stderr


def _friction_record(rig, effects, seed):
    duty = lhc_schedule(60.0, duty_range=(0.0, 0.6), duty_cap=0.6, seed=seed).duty(SAMPLE_TIME, 60.0)
    columns = simulate(duty, rig, effects, noise=MeasurementNoise(40.0, True), seed=seed).columns(with_truth=False)
    return columns['t'], columns['angle'], columns['duty']


@pytest.mark.parametrize('seed', [3, 8])
def test_a_dry_friction_band_is_not_read_as_a_thrust_doubt(seed):
    """Known truth: the model is the rig (Coulomb friction 5 rad/s^2 included). A rest anywhere inside the band the
    friction holds is consistent with the model's thrust: the doubt stays narrow (s22: 0.81-1.22 on an identified
    model with the friction right, and the first design refused a template the rig can meet)."""
    friction = {'coulomb_friction': {'friction_acceleration': 5.0}}
    doubt = hold_doubt(*_friction_record(DEFAULT_PARAMETERS, friction, seed), DEFAULT_PARAMETERS, friction)
    assert doubt is not None and len(doubt.factors) >= 8
    assert 0.96 < doubt.tolerance[0] and doubt.tolerance[1] < 1.04


def test_a_thrust_error_beyond_the_friction_band_still_shows():
    """Known truth: the rig's thrust is 0.85 x the model's, both with the friction: every rest needs more thrust
    than the band explains."""
    friction = {'coulomb_friction': {'friction_acceleration': 5.0}}
    rig = DEFAULT_PARAMETERS.scaled(lever_per_inertia=0.85)
    doubt = hold_doubt(*_friction_record(rig, friction, 3), DEFAULT_PARAMETERS, friction)
    assert doubt is not None and doubt.tolerance[0] < 0.95
    # the factor within each band nearest the rests' consensus, not nearest 1 (that read 0.916 here: band edges)
    assert abs(float(np.mean(doubt.factors)) - 0.85) < 0.01


@pytest.mark.parametrize('friction', [3.0, 6.0])
def test_a_dry_friction_in_the_model_is_not_a_thrust_doubt(friction):
    """Known truth: the nominal rig with a Coulomb friction (rad/s^2). Its rests scatter within the friction's band:
    judged on a model without the friction the thrust looks +-8-25 % off, and on s22's benchmark the design refused
    a template the rig meets. With the friction in the model each rest allows a band of factors; the doubt is then
    the thrust's own (the rig's is the model's: 1), and the words say the band was used."""
    effects = {'coulomb_friction': {'friction_acceleration': friction}}
    duty = lhc_schedule(40.0, duty_range=(0.0, 0.6), duty_cap=0.6, seed=3).duty(SAMPLE_TIME, 40.0)
    columns = simulate(duty, DEFAULT_PARAMETERS, effects, noise=MeasurementNoise(40.0, True),
                       seed=3).columns(with_truth=False)
    record = columns['t'], columns['angle'], columns['duty']
    without = hold_doubt(*record, DEFAULT_PARAMETERS)
    within = hold_doubt(*record, DEFAULT_PARAMETERS, effects)
    assert not without.within_friction_band and within.within_friction_band
    width = within.tolerance[1] - within.tolerance[0]
    assert without.tolerance[1] - without.tolerance[0] > 0.15 and width < 0.05
    assert within.tolerance[0] - 0.01 < 1.0 < within.tolerance[1] + 0.01       # the rig's thrust is the model's
    said = ModelSource(thrust_tolerance=(0.95, 1.05)).with_hold_doubt(within)
    assert 'dry friction' in said.doubts[-1] and said.thrust_tolerance == (0.95, 1.05)
