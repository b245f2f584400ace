"""Where the model fails in the state space (issue #40 item 2): the missing acceleration binned by angle, direction
of motion and thrust names the region a local effect acts in, and nothing on a clean record."""
import json
import math

import numpy as np
import pytest

from aeropend_core.diagnosis.compare import compare, prepare
from aeropend_core.diagnosis.state_map import ANGLE_BAND, state_map
from aeropend_core.io.recording import from_columns
from aeropend_core.model.effects import CATALOG, EffectParameter, register_effect
from aeropend_core.present.state_map_text import state_map_html, state_map_sentence
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate

#: The band the test torque acts in [rad]: 28 to 38 degrees.
BAND = (math.radians(28.0), math.radians(38.0))


@pytest.fixture
def band_torque():
    """A torque of -level rad/s^2 inside BAND only (a cable touching a stop): outside the catalog."""
    @register_effect('test_band_torque', 'a torque inside one band of angles', replace=True,
                     parameters=[EffectParameter('test_band_level', 'rad/s^2', 'level', 2.5, -100.0, 100.0)])
    def torque(angle, angular_rate, test_band_level):
        return -test_band_level * ((angle > BAND[0]) & (angle < BAND[1]))
    yield 'test_band_torque'
    CATALOG.pop('test_band_torque', None)


def record(effects, seed):
    duty = lhc_schedule(60.0, duty_range=(0.0, 0.7), duty_cap=0.7, seed=seed).duty(duration=60.0)
    trajectory = simulate(duty, effects=effects, noise=MeasurementNoise(psnr_db=40.0, quantise=True), seed=seed + 1)
    return from_columns(trajectory.columns(with_truth=False), source=f'seed {seed}')


@pytest.mark.slow
def test_the_map_names_the_band_of_angles_a_local_torque_acts_in(band_torque):
    prep = prepare(record({band_torque: 2.5}, seed=21))
    mapped = state_map(prep, compare(prep))
    angle = mapped.axis('angle')
    assert mapped.significant and angle.localised, [(b.label, round(b.mean, 2), round(b.z, 1)) for b in angle.bins]
    # the region's edges within +-5 degrees of the band's (the bins are 5 degrees wide)
    assert abs(angle.low - BAND[0]) <= ANGLE_BAND + 1e-9 and abs(angle.high - BAND[1]) <= ANGLE_BAND + 1e-9
    inside = [b for b in angle.bins if b.label in angle.region]
    assert all(b.mean < 0 for b in inside if abs(b.z) >= 4)      # the torque pulls down: the model lacks -2.5 there
    sentence = state_map_sentence(mapped)
    assert f'between {math.degrees(angle.low):.0f} and {math.degrees(angle.high):.0f} deg' in sentence
    # the band is named; since the motor observer runs on every record (session 19) the middle thrust tercile, which
    # this band's steady states share, can lead the sentence (93 % of its axis), the band then 'Also confined'
    assert 'rad/s^2' in sentence and ('at these angles' in sentence or 'Also confined: between' in sentence), sentence
    document = mapped.to_dict()
    assert json.loads(json.dumps(document))['axes'][0]['localised'] is True
    assert document['unit'] == 'rad/s^2'


@pytest.mark.slow
def test_a_clean_record_has_no_region_and_says_so():
    prep = prepare(record(None, seed=25))
    mapped = state_map(prep, compare(prep))
    assert not mapped.localised, [(a.axis, a.region) for a in mapped.localised]
    assert not mapped.significant
    assert 'nowhere in particular' in state_map_sentence(mapped)
    # the map's cells are finite and the report's picture is drawn from them
    assert mapped.cells and all(np.isfinite(c['mean_missing_acceleration']) for c in mapped.cells)

    class Shown:
        state_map, state_map_selected = mapped, None
    assert '<svg' in state_map_html(Shown())
