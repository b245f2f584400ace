"""Physics of the simulator against independent results: equilibria, small-angle analytic response, energy."""
import warnings

import numpy as np
import pytest

from aeropend_core.errors import AeropendError, UnknownEffectError
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, PAPER_TABLE1, SAMPLE_TIME
from aeropend_core.sim.noise import MeasurementNoise, psnr
from aeropend_core.sim.simulate import RigSimulator, simulate

P = DEFAULT_PARAMETERS


def test_default_parameters_give_a_large_deflection_below_90_degrees_at_duty_0p7():
    steady = P.steady_state(P.voltage_from_duty(0.7))
    assert np.radians(45) < steady['angle'] < np.radians(85)
    assert 0.2 < steady['armature_current'] < 2.0          # inside the 2 A current-sense range
    assert P.electrical_time_constant == pytest.approx(2.04e-3, rel=0.02)   # the paper's La/Ra


def test_eq8_matches_the_paper_and_inverts():
    assert P.voltage_from_duty(0.7) == pytest.approx(1.894, abs=2e-3)
    assert P.voltage_from_duty(1.0) == pytest.approx(2.319, abs=2e-3)
    assert P.voltage_from_duty(0.005) == 0.0                  # dead band implied by eq (8)
    duty = np.linspace(0.05, 1.0, 20)
    assert np.allclose(P.duty_from_voltage(P.voltage_from_duty(duty)), duty)


def test_paper_table1_is_kept_literally():
    assert PAPER_TABLE1.torque_constant == 0.235 and PAPER_TABLE1.thrust_coefficient == 1e-4
    assert PAPER_TABLE1.motor_inertia == 5.2e-5


def test_simulation_settles_at_the_analytic_equilibrium():
    duty = np.full(int(8 / SAMPLE_TIME), 0.5)
    trajectory = simulate(duty)
    steady = P.steady_state(P.voltage_from_duty(0.5))
    assert trajectory.truth['angle'][-1] == pytest.approx(steady['angle'], rel=1e-4)
    assert trajectory.truth['motor_speed'][-1] == pytest.approx(steady['motor_speed'], rel=1e-4)
    assert trajectory.armature_current[-1] == pytest.approx(steady['armature_current'], rel=1e-4)


def test_small_angle_free_response_matches_the_linear_solution():
    # No thrust: y'' = -a y - b y' for a small initial angle; compare with the closed form.
    angle0 = 0.01
    trajectory = simulate(np.zeros(int(2 / SAMPLE_TIME)), initial_angle=angle0)
    a, b = P.gravity_stiffness, P.damping
    wd = np.sqrt(a - b * b / 4)
    t = trajectory.time
    expected = angle0 * np.exp(-b * t / 2) * (np.cos(wd * t) + b / (2 * wd) * np.sin(wd * t))
    assert np.max(np.abs(trajectory.angle - expected)) < 1e-3 * angle0 + 1e-7


def test_energy_balance_without_damping():
    # With c/J = 0 and no thrust, mechanical energy W^2/2 + a (1 - cos y) is conserved.
    params = P.replace(damping=0.0)
    trajectory = simulate(np.zeros(int(3 / SAMPLE_TIME)), parameters=params, initial_angle=1.0)
    energy = trajectory.truth['angular_rate'] ** 2 / 2 + params.gravity_stiffness * (1 - np.cos(trajectory.angle))
    assert np.ptp(energy) < 1e-4 * energy[0]


def test_streaming_in_blocks_equals_one_batch_and_is_deterministic():
    duty = lhc_schedule(6, seed=3).duty(duration=6)
    whole = simulate(duty, effects={'coulomb_friction': 3.0, 'thrust_lag': 0.1})
    simulator = RigSimulator(effects={'coulomb_friction': 3.0, 'thrust_lag': 0.1})
    blocks = [simulator.run(chunk) for chunk in np.array_split(duty, 37)]
    streamed = np.concatenate([block.angle for block in blocks])
    assert np.allclose(streamed, whole.angle, atol=1e-6)
    assert np.allclose(np.concatenate([b.time for b in blocks]), whole.time)
    noisy = [simulate(duty, noise=MeasurementNoise(40, True), seed=5).angle for _ in range(2)]
    assert np.array_equal(noisy[0], noisy[1])


@pytest.mark.parametrize('effect, values, check', [
    ('coulomb_friction', 4.0, lambda base, eff: eff.truth['angle'].max() < base.truth['angle'].max()),
    ('cable_torque', 20.0, lambda base, eff: eff.truth['angle'][-1] < base.truth['angle'][-1] - 0.01),
    ('angle_offset', 0.05, lambda base, eff: np.allclose(eff.angle - base.angle, 0.05)),
    ('dead_zone', 1.0, lambda base, eff: np.all(eff.truth['thrust'] == 0.0)),
    ('thrust_lag', 0.2, lambda base, eff: eff.truth['angle'][100] < base.truth['angle'][100]),
    ('quadratic_drag', 2.0,
     lambda base, eff: eff.truth['angular_rate'].max() < 0.95 * base.truth['angular_rate'].max()),
])
def test_each_effect_changes_the_response_the_way_its_physics_says(effect, values, check):
    # Duty 0.4 (1.37 V); for the dead zone duty 0.15 (0.73 V), below its 1 V threshold.
    duty = np.full(int(3 / SAMPLE_TIME), 0.15 if effect == 'dead_zone' else 0.4)
    base = simulate(duty)
    with_effect = simulate(duty, effects={effect: values})
    assert check(base, with_effect)


def test_noise_has_the_stated_psnr_and_quantisation_steps():
    duty = lhc_schedule(20, seed=1).duty(duration=20)
    clean = simulate(duty)
    noisy = simulate(duty, noise=MeasurementNoise(psnr_db=40.0), seed=2)
    for name in ('armature_current', 'angle'):
        assert psnr(getattr(clean, name), getattr(noisy, name)) == pytest.approx(40.0, abs=0.3)
    quantised = simulate(duty, noise=MeasurementNoise(quantise=True))
    counts = quantised.angle / (2 * np.pi / 1024)
    assert np.allclose(counts, np.round(counts))


def test_bad_inputs_raise_clear_errors():
    with pytest.raises(UnknownEffectError, match='known effects'):
        simulate(np.zeros(10), effects={'magic_friction': 1.0})
    with pytest.raises(AeropendError, match='duty'):
        simulate(np.array([0.2, np.nan]))
    with pytest.raises(AeropendError, match='outside'):
        simulate(np.zeros(10), effects={'coulomb_friction': -1.0})


@pytest.mark.parametrize('effects', [None, {'coulomb_friction': 4.0, 'thrust_lag': 0.15, 'angle_offset': 0.05},
                                     {'dead_zone': 0.6, 'quadratic_drag': 4.0, 'cable_torque': 20.0}])
def test_compiled_and_reference_integrators_agree(effects):
    duty = lhc_schedule(20, seed=9).duty(duration=20)
    compiled = simulate(duty, effects=effects, method='compiled')
    reference = simulate(duty, effects=effects, method='lsoda')
    assert np.max(np.abs(compiled.angle - reference.angle)) < 2e-5                      # rad
    assert np.max(np.abs(compiled.armature_current - reference.armature_current)) < 2e-5  # A
    assert np.max(np.abs(compiled.truth['motor_speed'] - reference.truth['motor_speed'])) < 0.05  # rad/s


@pytest.mark.parametrize('method', ['compiled', 'lsoda'])
def test_a_long_rest_in_small_blocks_stays_finite(method):
    # After minutes at duty 0 the state decays into subnormal numbers; LSODA used to return NaN then.
    simulator = RigSimulator(method=method)
    simulator.run(np.full(490, 0.5))
    for _ in range(420):                                   # 420 s of rest in 1 s blocks
        block = simulator.run(np.zeros(490))
        assert np.all(np.isfinite(block.angle)) and np.all(np.isfinite(simulator.state))


def test_a_simulation_that_diverges_is_refused_with_a_reason_not_a_math_error(scoped_catalog):
    """A softening cubic torque of 40 1/(s^2 rad^2) sends the rod off to infinity: the simulator says the equation
    diverged, from when, with which effects, and what to do, instead of the integrator's bare 'math domain error'."""
    from aeropend_core.diagnosis.discovery import VOCABULARY, term_effect
    name = term_effect(next(t for t in VOCABULARY if t.expression == 'angle^3'))
    with pytest.raises(AeropendError, match=r'diverged .* t = 0\.000 s.*term_angle_cube.*make an effect smaller'), \
            np.errstate(all='ignore'), warnings.catch_warnings():
        warnings.simplefilter('ignore', RuntimeWarning)
        simulate(np.full(2000, 0.7), effects={name: 40.0})


def test_rates_without_friction_skip_the_tanh_and_equal_the_full_formula_bit_for_bit():
    """s25: with no Coulomb friction the compiled rates skip its tanh (a quarter of the closed loop's time); the
    pendulum's rate equals the formula with the zero term, sign bits included, on states with zeros of both signs
    and rates of both signs (the damping is never 0 in a rig)."""
    import math

    from aeropend_core.model.parameters import DEFAULT_PARAMETERS as P
    from aeropend_core.sim.simulate import _rig_rates
    c = np.array([[P.armature_resistance, P.armature_inductance, P.back_emf_constant, P.torque_constant,
                   P.motor_inertia, P.motor_friction, P.propeller_torque_coefficient, P.gear_ratio,
                   P.thrust_coefficient, P.gravity_stiffness, P.damping, P.lever_per_inertia]])
    rng = np.random.default_rng(5)
    values = [0.0, -0.0, 1e-300, -1e-300, 0.3, -0.3, 2.0, -2.0]
    checked = 0
    for _ in range(400):
        angle, rate, speed, lagged = (values[k] if k < len(values) else rng.normal()
                                      for k in rng.integers(0, len(values) + 2, 4))
        for g, lag in ((0.0, 0.0), (1.0, 0.0), (1.0, 0.1)):
            rates = _rig_rates(c, 0, 3.0 * g, g, 0.1, speed * 300.0, angle, rate, lagged, 0.0, 0.0, 0.0, lag, 0.01)
            prop = speed * 300.0 / P.gear_ratio
            prop_sq = prop * abs(prop)
            thrust = lagged if lag > 0 else g * P.thrust_coefficient * prop_sq
            full = (-P.gravity_stiffness * math.sin(angle) - P.damping * rate + P.lever_per_inertia * thrust
                    - 0.0 * math.tanh(rate / 0.01) - 0.0 * rate * abs(rate) - 0.0 * angle)
            assert rates[3] == full and math.copysign(1.0, rates[3]) == math.copysign(1.0, full), (angle, rate)
            checked += 1
    assert checked == 1200
