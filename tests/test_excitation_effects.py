"""Latin-hypercube excitation, the effect catalog and the core's independence from ROS."""
import subprocess
import sys

import numpy as np
import pytest

from aeropend_core.model.effects import EffectParameter, get_effect, parse_effect_assignments, register_effect
from aeropend_core.errors import AeropendError, UnknownEffectError
from aeropend_core.sim.excitation import latin_hypercube_steps, lhc_schedule, voltage_range_to_duty
from aeropend_core.sim.simulate import simulate


def test_latin_hypercube_has_one_point_per_stratum_in_each_dimension():
    schedule = latin_hypercube_steps(10, seed=4)
    for column in schedule.design_points.T:
        assert sorted(np.floor(column * 10).astype(int)) == list(range(10))
    assert np.all((0.6 <= schedule.dwells) & (schedule.dwells <= 2.0))
    assert np.all((0.0 <= schedule.amplitudes) & (schedule.amplitudes <= 0.7))


def test_schedule_is_seeded_and_covers_the_duration():
    a, b = lhc_schedule(60, seed=7), lhc_schedule(60, seed=7)
    assert np.array_equal(a.amplitudes, b.amplitudes)
    assert not np.array_equal(a.amplitudes, lhc_schedule(60, seed=8).amplitudes)
    assert a.duration >= 60 and len(a.duty(duration=60)) == round(60 * 490)
    assert np.allclose(a.step_times()[1:], np.cumsum(a.dwells)[:-1])


def test_voltage_range_maps_to_duty_with_cap():
    low, high = voltage_range_to_duty((0.0, 2.5))
    assert low == 0.0 and high == 1.0               # 2.5 V is beyond eq (8)'s reach at full duty


def test_catalog_has_the_required_effects_with_units_and_descriptions():
    for name in ('coulomb_friction', 'quadratic_drag', 'cable_torque', 'angle_offset', 'thrust_lag', 'dead_zone'):
        effect = get_effect(name)
        assert effect.description and effect.signature and effect.equation
        assert all(p.unit for p in effect.parameters)


def test_user_effect_is_one_small_function_and_enters_the_simulation(scoped_catalog):
    @register_effect('test_cubic_spring', 'hardening spring', replace=True,
                     parameters=[EffectParameter('stiffness', '1/(s^2 rad^2)', 'cubic spring', 50.0)])
    def cubic_spring(angle, angular_rate, stiffness):
        return -stiffness * angle ** 3

    duty = np.full(1500, 0.6)
    base, stiff = simulate(duty), simulate(duty, effects={'test_cubic_spring': 200.0})
    assert stiff.angle[-1] < base.angle[-1] - 0.05


def test_effect_assignments_parse_and_reject_mistakes():
    assert parse_effect_assignments(['coulomb_friction=3', 'thrust_lag.time_constant=0.2']) == {
        'coulomb_friction': {'friction_acceleration': 3.0}, 'thrust_lag': {'time_constant': 0.2}}
    with pytest.raises(UnknownEffectError):
        parse_effect_assignments(['stiction=1'])
    with pytest.raises(AeropendError, match='NAME=VALUE'):
        parse_effect_assignments(['coulomb_friction'])
    with pytest.raises(AeropendError, match='no parameter'):
        parse_effect_assignments(['coulomb_friction.mu=1'])


def test_core_imports_no_ros_serial_or_message_package():
    code = ('import sys, pkgutil, importlib, aeropend_core\n'
            'for m in pkgutil.walk_packages(aeropend_core.__path__, "aeropend_core."):\n'
            '    importlib.import_module(m.name)\n'
            'bad = [m for m in sys.modules if m.split(".")[0] in '
            '("rclpy", "rosidl_runtime_py", "sensor_msgs", "std_msgs", "diagnostic_msgs", "serial", "aeropend_ros")]\n'
            'print(bad); sys.exit(1 if bad else 0)\n')
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
