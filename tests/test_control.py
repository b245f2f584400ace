"""The closed loop's core: the law, the feedforward, the metrics, the linearisation, the design and the check."""
from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from aeropend_core.control.check import check_record
from aeropend_core.control.controller_file import Controller
from aeropend_core.control.design import TemplateNotMet, design, stable
from aeropend_core.control.feedforward import rest_thrust_torque, static_duty
from aeropend_core.control.law import PidController, PidGains, law_step, new_state
from aeropend_core.control.linear import linearise
from aeropend_core.control.loop import FeedforwardMap, simulate_loop
from aeropend_core.control.metrics import Template, schedule_metrics, step_metrics
from aeropend_core.control.reference import ReferenceSchedule
from aeropend_core.errors import AeropendError
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, SAMPLE_TIME
from aeropend_core.sim.noise import MeasurementNoise

TS = SAMPLE_TIME
#: the `aeropend` command of this interpreter
AEROPEND = [sys.executable, '-c', 'from aeropend_core.cli import main; raise SystemExit(main())']


# --- the law ------------------------------------------------------------------------------------------------------
def test_pure_proportional_law_is_p_times_error_plus_feedforward():
    controller = PidController(PidGains(p=0.8, i=0.0, d=0.0, u_clamp_max=1.0))
    assert controller.step(0.5, 0.2, 0.4) == pytest.approx(0.2 + 0.8 * 0.1)


def test_integral_accumulates_i_ts_error_and_derivative_acts_on_the_measurement_only():
    gains = PidGains(p=0.0, i=2.0, d=0.1, derivative_filter_time=0.0, feedforward_gain=0.0, u_clamp_max=1.0,
                     antiwindup='none')
    controller = PidController(gains)
    assert controller.step(0.3, 0.0, 0.1) == pytest.approx(0.0)      # first sample: no kick, integral still 0
    assert controller.integral == pytest.approx(2.0 * TS * 0.2)
    # A reference step does not move the derivative (no kick); a measured change does: -d (dy)/Ts.
    duty = controller.step(0.9, 0.0, 0.1)
    assert duty == pytest.approx(2.0 * TS * 0.2)
    duty = controller.step(0.9, 0.0, 0.11)
    assert duty == pytest.approx(max(0.0, 2.0 * TS * (0.2 + 0.8) - 0.1 * 0.01 / TS))


def test_back_calculation_bleeds_the_integral_while_saturated_and_conditional_integration_freezes_it():
    for strategy in ('back_calculation', 'conditional_integration', 'none'):
        gains = PidGains(p=2.0, i=5.0, d=0.0, u_clamp_max=0.5, i_clamp_max=10.0, i_clamp_min=-10.0,
                         antiwindup=strategy, tracking_time_constant=0.05, feedforward_gain=0.0)
        controller = PidController(gains)
        for _ in range(490):                        # one second saturated high: error 1 rad
            assert controller.step(1.0, 0.0, 0.0) == pytest.approx(0.5)
        if strategy == 'none':
            assert controller.integral == pytest.approx(5.0 * 1.0, rel=0.01)   # wound up over the second
        elif strategy == 'conditional_integration':
            assert controller.integral == 0.0
        else:
            # equilibrium of back-calculation: i e + (u - v)/Tt = 0 -> I = u - p e + i e Tt
            assert controller.integral == pytest.approx(0.5 - 2.0 + 5.0 * 0.05, abs=0.02)


def test_angle_limit_trips_to_zero_duty_latched_until_reset():
    controller = PidController(PidGains(angle_max=1.0))
    assert controller.step(0.5, 0.3, 0.4) > 0
    assert controller.step(0.5, 0.3, 1.01) == 0.0 and controller.tripped
    assert controller.step(0.5, 0.3, 0.4) == 0.0                     # latched
    controller.reset()
    assert controller.step(0.5, 0.3, 0.4) > 0


def test_law_compiled_by_numba_gives_the_same_duty_as_python():
    import numba
    compiled = numba.njit(law_step)
    rng = np.random.default_rng(3)
    gains = PidGains(p=1.1, i=0.7, d=0.08, antiwindup='conditional_integration')
    c = gains.coefficients()
    state_py, state_nb = new_state(), new_state()
    for _ in range(500):
        reference, angle = rng.uniform(0, 1.2), rng.uniform(0, 1.2)
        assert law_step(c, state_py, reference, 0.3, angle) == compiled(c, state_nb, reference, 0.3, angle)
    np.testing.assert_array_equal(state_py, state_nb)


def _law_before_setpoint_weighting(c, state, reference, feedforward_duty, angle):
    """law_step as it was before setpoint weighting (session 18), verbatim: the reference b = 1 must reproduce."""
    if state[4] != 0.0:
        return 0.0
    if angle < c[11] or angle > c[12]:
        state[4] = 1.0
        state[5] = 0.0
        return 0.0
    error = reference - angle
    if state[3] == 0.0:
        state[1] = 0.0
        state[3] = 1.0
    else:
        state[1] = c[2] * state[1] - c[3] * (angle - state[2])
    state[2] = angle
    unsaturated = c[10] * feedforward_duty + c[0] * error + state[0] + state[1]
    duty = unsaturated
    if duty > c[7]:
        duty = c[7]
    if duty < c[6]:
        duty = c[6]
    integral = state[0]
    if c[8] == 1.0:
        integral = integral + c[1] * error + c[9] * (duty - unsaturated)
    elif c[8] == 2.0:
        if not ((unsaturated > c[7] and error > 0.0) or (unsaturated < c[6] and error < 0.0)):
            integral = integral + c[1] * error
    else:
        integral = integral + c[1] * error
    if integral > c[5]:
        integral = c[5]
    if integral < c[4]:
        integral = c[4]
    state[0] = integral
    state[5] = unsaturated
    return duty


def test_setpoint_weight_one_reproduces_the_law_before_it_bit_for_bit_on_the_shared_vectors():
    from aeropend_core.control.law import SETPOINT_WEIGHT
    from aeropend_core.testing.law_vectors import generate
    vectors = generate(3000, seed=5)
    ones = vectors.coefficients[:, SETPOINT_WEIGHT] == 1.0
    assert 0.3 < ones.mean() < 0.9            # the vectors hold both b = 1 and b < 1
    changed = 0
    for k in range(vectors.count):
        c = vectors.coefficients[vectors.set_index[k]]
        args = (float(vectors.reference[k]), float(vectors.feedforward[k]), float(vectors.angle[k]))
        new, old = vectors.state[k].copy(), vectors.state[k].copy()
        duty_new, duty_old = law_step(c, new, *args), _law_before_setpoint_weighting(c, old, *args)
        if c[SETPOINT_WEIGHT] == 1.0:
            assert duty_new == duty_old and np.array_equal(new, old), k      # bit for bit
        else:
            changed += duty_new != duty_old
    assert changed > 0.3 * np.sum(~ones[vectors.set_index])        # and b < 1 is another law


def test_setpoint_weight_lowers_the_proportional_kick_of_a_step_by_p_one_minus_b_delta_r():
    """Same history, same gains but b: at a reference step the duties differ by exactly p (1 - b) delta_r; the
    integral (on r - y) and the derivative (on y) are the same in both."""
    p, b, step = 1.3, 0.35, 0.4
    duties = {}
    for weight in (1.0, b):
        controller = PidController(PidGains(p=p, i=0.8, d=0.05, setpoint_weight=weight, u_clamp_max=1.0,
                                            i_clamp_min=-1.0, i_clamp_max=1.0))
        before = [controller.step(0.3, 0.25, angle) for angle in (0.1, 0.12, 0.15)]
        kick = controller.step(0.3 + step, 0.25, 0.17) - before[-1]
        duties[weight] = (before, kick, controller.integral)
    # before the step the weighted law is lower by p (1 - b) r, constant: the step adds p (1 - b) delta_r to it
    assert np.allclose(np.subtract(duties[1.0][0], duties[b][0]), p * (1 - b) * 0.3, rtol=0, atol=1e-12)
    assert duties[1.0][1] - duties[b][1] == pytest.approx(p * (1 - b) * step, rel=1e-9)
    assert duties[1.0][2] == duties[b][2]                         # the integral does not see b


def test_setpoint_weight_keeps_zero_steady_state_error_and_tames_the_overshoot():
    """The nominal simulator, no noise: b < 1 still settles on the reference (the integral acts on r - y) and
    overshoots less than b = 1 with the same fast integral."""
    target = math.radians(40)
    reference = np.concatenate([np.full(int(2 / TS), math.radians(20)), np.full(int(8 / TS), target)])
    overshoot = {}
    for weight in (1.0, 0.3):
        gains = PidGains(p=1.0, i=1.5, d=0.08, setpoint_weight=weight, feedforward_gain=0.0, u_clamp_max=0.9,
                         i_clamp_min=-1.0, i_clamp_max=1.0)
        run = simulate_loop(gains, reference, duty_limit=0.9)
        tail = run.truth['angle'][-int(1 / TS):]
        assert abs(np.mean(tail) - target) < 1e-3, weight        # no steady-state error (1 mrad)
        overshoot[weight] = np.max(run.truth['angle'][int(2 / TS):]) - target
    assert overshoot[0.3] < overshoot[1.0], overshoot


@pytest.mark.parametrize('changes, message', [({'p': -1.0}, 'p must be >= 0'),
                                              ({'u_clamp_max': 1.5}, 'u_clamp_max <= 1'),
                                              ({'antiwindup': 'clamp'}, 'antiwindup must be one of'),
                                              ({'i': float('nan')}, 'finite'),
                                              ({'angle_min': 2.0}, 'angle_min'),
                                              ({'setpoint_weight': 1.2}, 'setpoint_weight must be between 0 and 1'),
                                              ({'setpoint_weight': -0.1}, 'setpoint_weight must be between')])
def test_bad_gains_are_refused_naming_the_problem(changes, message):
    with pytest.raises(AeropendError, match=message):
        PidGains(**changes)


# --- feedforward and linearisation ------------------------------------------------------------------------------
def test_static_duty_holds_the_angle_in_the_simulator():
    angle = math.radians(40)
    duty = static_duty(angle)
    trajectory = simulate_loop(PidGains(p=0, i=0, d=0, feedforward_gain=1.0), np.full(int(8 / TS), angle))
    assert np.mean(trajectory.truth['angle'][-490:]) == pytest.approx(angle, abs=2e-3)
    assert trajectory.duty[-1] == pytest.approx(duty)


def test_dead_zone_and_offset_enter_the_feedforward():
    assert rest_thrust_torque(0.05, effects={'dead_zone': 0.6}) == 0.0
    offset = 0.05
    assert static_duty(0.5 + offset, effects={'angle_offset': offset}) == pytest.approx(static_duty(0.5), rel=1e-6)
    with pytest.raises(AeropendError, match='no duty holds'):
        static_duty(math.radians(89), DEFAULT_PARAMETERS.scaled(lever_per_inertia=0.3))


def test_linearisation_dc_gain_matches_the_static_map_and_a_lag_adds_a_pole():
    angle = math.radians(35)
    lin = linearise(angle)
    numeric = 0.01 / (static_duty(angle + 0.005) - static_duty(angle - 0.005))
    assert lin.dc_gain == pytest.approx(numeric, rel=1e-3)
    lagged = linearise(angle, effects={'thrust_lag': 0.2})
    assert len(lagged.states) == len(lin.states) + 1
    assert np.any(np.isclose(np.linalg.eigvals(lagged.A), -1 / 0.2, rtol=1e-4))
    assert 'coulomb_friction' in linearise(angle, effects={'coulomb_friction': 2.0}).left_out


# --- metrics ----------------------------------------------------------------------------------------------------
def test_metrics_of_a_known_second_order_step():
    # y = 1 - exp(-z w t)(cos(wd t) + z/sqrt(1-z^2) sin(wd t)) from 0.2 to 0.6 rad: overshoot exp(-pi z/sqrt(1-z^2)).
    zeta, wn = 0.5, 8.0
    t = np.arange(0, 6, TS)
    wd = wn * math.sqrt(1 - zeta ** 2)
    unit = 1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta ** 2) * np.sin(wd * t))
    angle = 0.2 + 0.4 * unit
    m = step_metrics(t, angle, np.full(t.size, 0.5), 0.0, 6.0, 0.2, 0.6, angle_count=1e-6, sigma=0.0)
    assert m.overshoot == pytest.approx(100 * math.exp(-math.pi * zeta / math.sqrt(1 - zeta ** 2)), abs=0.5)
    assert m.steady_state_error == pytest.approx(0.0, abs=0.01)
    # 2 % settling of this response: about 4 / (zeta wn) = 1.0 s (the envelope's bound); the exact is below it.
    assert 0.6 < m.settling_time < 1.05 and m.settled
    assert m.misses(Template(settling=0.5, overshoot=10, error=5, duty=0.8)) .keys() == {'settling', 'overshoot'}


def test_the_metrics_smoothing_is_scipys_uniform_filter_without_scipy():
    """moving_mean (numpy, no scipy import in `control check`) equals scipy.ndimage's uniform_filter1d with
    mode='nearest' within 1e-9 of the signal on odd, even, 1 and longer-than-the-signal windows."""
    from scipy.ndimage import uniform_filter1d

    from aeropend_core.control.metrics import moving_mean
    rng = np.random.default_rng(5)
    for n, window in ((200, 5), (3000, 12), (7, 10), (50, 1), (10, 2)):
        values = np.cumsum(rng.normal(size=n)) + 0.7
        np.testing.assert_allclose(moving_mean(values, window), uniform_filter1d(values, window, mode='nearest'),
                                   rtol=0, atol=1e-9)


def test_template_parsing_refuses_mistakes():
    assert Template.parse('settling=2,overshoot=10,error=5,duty=0.8') == Template()
    for text, message in [('settle=2', 'unknown item'), ('duty=80', 'fraction'), ('overshoot=x', 'not a number')]:
        with pytest.raises(AeropendError, match=message):
            Template.parse(text)


def test_schedule_from_yaml_mapping_and_its_mistakes():
    schedule = ReferenceSchedule.from_mapping({'steps': [{'angle_deg': 20, 'hold': 3}, {'angle': 0.5, 'hold': 2}]})
    assert schedule.duration == pytest.approx(7.0)
    reference = schedule.reference()
    assert reference[0] == 0.0 and reference[-1] == 0.5
    assert reference[int(2.5 / TS)] == pytest.approx(math.radians(20))
    with pytest.raises(AeropendError, match='angle_deg'):
        ReferenceSchedule.from_mapping({'steps': [{'angle': 40, 'hold': 3}]})
    with pytest.raises(AeropendError, match='unknown key'):
        ReferenceSchedule.from_mapping({'stesp': []})


# --- design and check: the paper's story on the simulator -------------------------------------------------------
@pytest.fixture(scope='module')
def nominal_design():
    return design(Template(), math.radians(40))


def test_the_design_says_what_its_gains_do_at_the_edges_of_the_thrust_doubt(nominal_design):
    """Truth: the simulator with the model's thrust (L/J) scaled to each edge of the design's thrust doubt, the
    model's feedforward, the design's noise and seed. Where that rig misses an item, a note names the edge and the
    item (before s22 a note said the gains were designed to meet there, and they missed the error at 0.8 x)."""
    from aeropend_core.control.design import THRUST_TOLERANCE
    schedule = nominal_design.schedule
    template = nominal_design.template
    checked = []
    for factor in THRUST_TOLERANCE:
        run = simulate_loop(nominal_design.gains, schedule.reference(), FeedforwardMap(),
                            DEFAULT_PARAMETERS.scaled(lever_per_inertia=factor),
                            noise=MeasurementNoise(psnr_db=50.0, quantise=True), seed=0, duty_limit=0.8)
        missed = set().union(*(m.misses(template) for m in schedule_metrics(run.time, run.angle, run.duty,
                                                                              schedule)))
        assert set(nominal_design.tolerance_misses[factor]) == missed
        notes = ' '.join(nominal_design.notes)
        if missed:
            assert f'at {factor:g} x it misses' in notes and all(item in notes for item in missed), notes
        checked.append(bool(missed))
    if not any(checked):
        assert any('predicted to meet the template also on rigs' in note for note in nominal_design.notes)
    assert 'designed to meet the template also' not in ' '.join(nominal_design.notes)


@pytest.mark.slow
def test_nominal_design_meets_on_the_nominal_rig_and_misses_on_a_lagged_one(nominal_design):
    """Truth: the simulator; the design never saw the lag. The check's measured metrics decide."""
    controller = Controller(nominal_design.gains, template=Template())
    schedule = nominal_design.schedule
    noise = MeasurementNoise(psnr_db=50, quantise=True)
    for effects, should_meet in (({}, True), ({'thrust_lag': 0.15}, False)):
        run = simulate_loop(controller.gains, schedule.reference(), FeedforwardMap(), effects=effects, noise=noise,
                            seed=11, duty_limit=0.8)
        result = check_record(run.time, run.angle, run.duty, controller, schedule)
        assert result.met is should_meet, result.as_text()
        if not should_meet:
            assert result.verdict == 'misses the template where the model predicted it would meet it'
            assert any('overshoot' in step.measured_misses for step in result.steps)


@pytest.mark.slow
def test_a_design_on_the_lagged_model_meets_the_template_on_the_lagged_rig():
    """The redesign of the paper's story: designed on the model with the lag (an identified model: its thrust known
    within 5 %), checked on a lagged rig (another noise seed than the design's)."""
    lag = {'thrust_lag': {'time_constant': 0.15}}
    result = design(Template(), math.radians(40), effects=lag, thrust_tolerance=(0.95, 1.05))
    controller = Controller(result.gains, effects=lag, template=Template())
    run = simulate_loop(result.gains, result.schedule.reference(), FeedforwardMap(effects=lag), effects=lag,
                        noise=MeasurementNoise(psnr_db=50, quantise=True), seed=12, duty_limit=0.8)
    check = check_record(run.time, run.angle, run.duty, controller, result.schedule)
    assert stable(result.gains, result.linearisation)
    if any('less than 10 % to spare' in note for note in result.notes):
        # said to be thin: the rig may tip an item over, but the prediction holds (issue #39: +-3 pp, +-20 %)
        for step in check.steps:
            assert abs(step.measured.overshoot - step.predicted.overshoot) <= 3.0, check.as_text()
            assert abs(step.measured.settling_time - step.predicted.settling_time) <= \
                0.2 * step.measured.settling_time + 0.1, check.as_text()
    else:
        assert check.met, check.as_text()


@pytest.mark.parametrize('effects', [{}, {'thrust_lag': 0.12, 'angle_offset': 0.03},
                                     {'angle_filter': 0.0141, 'dead_zone': 0.6, 'coulomb_friction': 2.0,
                                      'cable_torque': 15.0, 'quadratic_drag': 3.0}])
def test_compiled_closed_loop_equals_the_streaming_simulator_sample_by_sample(effects):
    schedule = ReferenceSchedule.steps_between([30, 45], hold=2.0, start_hold=0.5)
    gains = PidGains(p=1.2, i=0.6, d=0.15)
    streaming = simulate_loop(gains, schedule.reference(), effects=effects, method='streaming', duty_limit=0.8)
    compiled = simulate_loop(gains, schedule.reference(), effects=effects, method='compiled', duty_limit=0.8)
    for name in ('angle', 'duty', 'armature_current', 'armature_voltage', 'integral'):
        np.testing.assert_allclose(getattr(compiled, name), getattr(streaming, name), rtol=0, atol=1e-9)


@pytest.mark.parametrize('effects', [{}, {'angle_filter': 0.0141, 'dead_zone': 0.6, 'thrust_lag': 0.12}])
def test_law_noise_reaches_the_law_only_as_the_loops_own_noise_does(effects):
    """`law_noise` (s26: a record's noise fed back in closed-loop fits) is what the law reads on top of the simulated
    measured angle, and nothing else: a noise-free loop given the very sequence a noisy loop drew (40 dB on the
    angle, no rounding) applies the same duties and moves the rod the same way, bit for bit; its recorded angle
    is the noisy loop's without that noise. A wrong shape or a NaN is refused."""
    from aeropend_core.control.loop import simulate_loops
    from aeropend_core.sim.noise import FULL_SCALE, sigma_for_psnr
    reference = ReferenceSchedule.steps_between([20, 50, 35], hold=1.5, start_hold=0.5).reference()
    gains = PidGains(p=1.2, i=0.6, d=0.15)
    noise = MeasurementNoise(psnr_db=40.0, signals=('angle',))
    noisy = simulate_loop(gains, reference, FeedforwardMap(), effects=effects, noise=noise, seed=5, duty_limit=0.8,
                          method='compiled')
    drawn = np.random.default_rng(5).normal(0.0, sigma_for_psnr(FULL_SCALE['angle'], 40.0), reference.size)
    fed = simulate_loop(gains, reference, FeedforwardMap(), effects=effects, seed=5, duty_limit=0.8,
                        method='compiled', law_noise=drawn)
    for name in ('duty', 'integral', 'unsaturated', 'armature_current'):
        np.testing.assert_array_equal(getattr(fed, name), getattr(noisy, name), err_msg=name)
    np.testing.assert_array_equal(fed.truth['angle'], noisy.truth['angle'])
    np.testing.assert_array_equal(fed.angle + drawn, noisy.angle)
    assert np.std(fed.duty - simulate_loop(gains, reference, FeedforwardMap(), effects=effects, duty_limit=0.8,
                                           method='compiled').duty) > 1e-3          # the noise did move the duty
    for bad in (drawn[:-1], np.where(np.arange(drawn.size) == 7, np.nan, drawn)):
        with pytest.raises(ValueError, match='law_noise'):
            simulate_loops([(gains, DEFAULT_PARAMETERS, 1)], reference, FeedforwardMap(), effects, law_noise=bad)


@pytest.mark.parametrize('effects', [{}, {'angle_filter': 0.0141, 'dead_zone': 0.6, 'coulomb_friction': 2.0,
                                         'thrust_lag': 0.12, 'angle_offset': 0.03}])
def test_loops_stepped_together_equal_each_loop_alone_bit_for_bit(effects):
    """simulate_loops (s25: the check's draws and the design's rigs in one compiled call, their arithmetic
    interleaved) gives each loop exactly what simulate_loop gives it alone: other gains, rigs and seeds side by side,
    noise and quantisation on, one loop saturating (p 6) and one tripping (an angle limit it crosses)."""
    from aeropend_core.control.loop import simulate_loops
    schedule = ReferenceSchedule.steps_between([20, 50, 35], hold=1.5, start_hold=0.5)
    reference = schedule.reference()
    noise = MeasurementNoise(psnr_db=45.0, quantise=True)
    runs = [(PidGains(p=1.2, i=0.6, d=0.15), DEFAULT_PARAMETERS, 3),
            (PidGains(p=6.0, i=2.0, d=0.4), DEFAULT_PARAMETERS.scaled(lever_per_inertia=0.8), 4),
            (PidGains(p=0.5, i=0.3, d=0.05, setpoint_weight=0.5), DEFAULT_PARAMETERS.scaled(lever_per_inertia=1.25), 3),
            (PidGains(p=1.2, i=0.6, d=0.15, angle_max=math.radians(40)), DEFAULT_PARAMETERS, 9)]
    together = simulate_loops(runs, reference, FeedforwardMap(), effects, noise, duty_limit=0.8)
    assert together[3].tripped.any() and together[1].duty.max() == 0.8
    for (gains, parameters, seed), run in zip(runs, together):
        alone = simulate_loop(gains, reference, FeedforwardMap(), parameters, effects, noise, seed, duty_limit=0.8,
                              method='compiled')
        for name in ('angle', 'duty', 'armature_current', 'armature_voltage', 'integral', 'unsaturated', 'tripped',
                     'feedforward'):
            np.testing.assert_array_equal(getattr(run, name), getattr(alone, name), err_msg=name)
        for name in alone.truth:
            np.testing.assert_array_equal(run.truth[name], alone.truth[name], err_msg=name)


def test_an_impossible_template_is_refused_naming_the_item():
    with pytest.raises(TemplateNotMet, match=r'settling: predicted .* against 0.2 s'):
        design(Template(settling=0.2, overshoot=None, error=None, duty=None), math.radians(40))


def test_a_design_every_round_missed_is_kept_when_half_its_noise_draws_meet_and_refused_when_fewer(nominal_design):
    """Truth: the nominal design's gains on the model's ten noise draws (seeds 0-9), their worst overshoot each.
    With the overshoot limit between the 5th and 6th smallest, 5 of 10 draws meet: the design is kept, its
    prediction the median draw (which meets), the note giving the count; between the 4th and 5th, 4 of 10: refused
    (None). (s23: at 40 dB on full scale the nominal model's design was refused by 1.1 pp of overshoot on the worse
    of two draws, while 7 of 10 draws of the same gains meet.)"""
    import dataclasses
    from concurrent.futures import ThreadPoolExecutor

    from aeropend_core.control.design import NOISE_EDGE_DRAWS, _at_the_noise_edge
    noise = MeasurementNoise(psnr_db=50.0, quantise=True)
    reference = nominal_design.schedule.reference(None, SAMPLE_TIME)
    feedforward = FeedforwardMap(DEFAULT_PARAMETERS, {})
    overshoots = []
    for seed in range(NOISE_EDGE_DRAWS):
        run = simulate_loop(nominal_design.gains, reference, feedforward, DEFAULT_PARAMETERS, {}, noise, seed,
                            sample_time=SAMPLE_TIME, duty_limit=0.8)
        overshoots.append(max(m.overshoot for m in schedule_metrics(run.time, run.angle, run.duty,
                                                                    nominal_design.schedule)))
    ordered = sorted(overshoots)
    with ThreadPoolExecutor(2) as pool:
        for limit, kept in ((0.5 * (ordered[4] + ordered[5]), True), (0.5 * (ordered[3] + ordered[4]), False)):
            template = Template(settling=None, overshoot=limit, error=None, duty=None)
            candidate = dataclasses.replace(nominal_design, template=template, notes=[])
            result = _at_the_noise_edge(candidate, pool, reference, feedforward, DEFAULT_PARAMETERS, {}, noise, 0,
                                        SAMPLE_TIME, 0.8)
            if not kept:
                assert result is None
                continue
            assert result is not None and not result.misses(), overshoots
            assert any(f'meets it in 5 of {NOISE_EDGE_DRAWS} noise draws' in note for note in result.notes)


@pytest.mark.slow
def test_a_design_the_doubt_weighted_search_misses_is_found_on_the_model_alone_and_its_edges_said():
    """Known truth: the rig is the model (a dead-zone rig, threshold 0.627 V, its parameters as an identified model
    gives them), so gains that meet the template on it exist: the search on it with no thrust doubt finds gains that
    meet. Under a 0.95-1.05 doubt the search's cost also weighs the rigs at the doubt's edges, and before s24 every
    round of that compromise missed the overshoot (by 0.12 pp) on the model: refused. A refusal must mean no gains
    meet on the model: the design is now found on the model alone, predicted to meet there, and the note says what
    it does at the doubt's edges."""
    parameters = DEFAULT_PARAMETERS.replace(
        armature_resistance=1.005514177944056, armature_inductance=0.0019251338148845519,
        motor_inertia=1.3349871558326622e-07, motor_friction=6.259576734794842e-08,
        propeller_torque_coefficient=5.512284087418227e-08, gravity_stiffness=112.61302630286987,
        damping=12.278306056014692, lever_per_inertia=452.1839868806605)
    effects = {'dead_zone': {'threshold_voltage': 0.62665}}
    noise = MeasurementNoise(psnr_db=39.93647621958069, quantise=True)
    result = design(Template(), math.radians(40), parameters, effects, noise=noise, thrust_tolerance=(0.95, 1.05))
    assert not result.misses()
    assert any('thrust doubt' in note for note in result.notes), result.notes
    assert set(result.tolerance_misses) == {0.95, 1.05}


def test_controller_file_round_trip_and_tamper_check(tmp_path, nominal_design):
    controller = Controller(nominal_design.gains, effects={'thrust_lag': {'time_constant': 0.1}},
                            template=Template())
    path = tmp_path / 'gains.yaml'
    controller.write(path)
    assert Controller.load(path) == controller
    path.write_text(path.read_text().replace(f'p: {nominal_design.gains.p}', 'p: 9.0'))
    with pytest.raises(AeropendError, match='sha256 does not match'):
        Controller.load(path)


def test_the_check_predicts_with_the_setpoint_weight_and_says_it():
    """A record of b = 0.5 (a fast integral that overshoots about 20 % with b = 1): the check's prediction runs the
    same b (overshoot within 3 percentage points of the measured, not the ~20 % of b = 1), its text and JSON name b."""
    schedule = ReferenceSchedule.steps_between([20, 40], hold=3.0, start_hold=1.0)
    controller = Controller(PidGains(p=1.0, i=1.5, d=0.08, setpoint_weight=0.5), template=Template())
    run = simulate_loop(controller.gains, schedule.reference(), FeedforwardMap(),
                        noise=MeasurementNoise(psnr_db=None, quantise=True), duty_limit=0.8)
    result = check_record(run.time, run.angle, run.duty, controller, schedule)
    assert len(result.steps) == 2
    for step in result.steps:
        assert step.measured.overshoot < 5.0
        assert abs(step.predicted.overshoot - step.measured.overshoot) <= 3.0, result.as_text()
    assert 'setpoint weight b = 0.5' in result.as_text().splitlines()[1]
    assert result.to_dict()['gains']['setpoint_weight'] == 0.5


def test_a_controller_file_without_setpoint_weight_loads_with_b_one_and_keeps_its_sha256(tmp_path):
    import hashlib

    import yaml
    controller = Controller(PidGains(p=0.7, i=0.4), template=Template())
    old = controller.to_dict()
    del old['gains']['setpoint_weight']            # as written before setpoint weighting existed
    old_gains = PidGains().as_dict() | {'p': 0.7, 'i': 0.4}
    del old_gains['setpoint_weight']
    old['sha256'] = hashlib.sha256(json.dumps({'gains': old_gains, 'model': controller.model_sha256},
                                              sort_keys=True).encode()).hexdigest()
    path = tmp_path / 'old.yaml'
    path.write_text(yaml.safe_dump(old))
    loaded = Controller.load(path)
    assert loaded.gains.setpoint_weight == 1.0 and loaded.sha256 == old['sha256']
    weighted = Controller(PidGains(p=0.7, i=0.4, setpoint_weight=0.5))
    assert weighted.sha256 != loaded.sha256                       # b < 1 is part of the hash
    weighted.write(path)
    assert Controller.load(path).gains.setpoint_weight == 0.5


@pytest.mark.slow
def test_cli_design_writes_gains_and_linearise_json(tmp_path):
    gains = tmp_path / 'gains.yaml'
    result = subprocess.run([*AEROPEND, 'control', 'design', '--at', '35deg', '-o',
                             str(gains), '--json', str(tmp_path / 'd.json')], capture_output=True, text=True,
                            timeout=300)
    assert result.returncode == 0, result.stderr
    assert 'meets the template' in result.stdout
    assert Controller.load(gains).gains == PidGains(**json.loads((tmp_path / 'd.json').read_text())['gains'])
    result = subprocess.run([*AEROPEND, 'control', 'linearise', '--at', '35deg',
                             '--json', '-'], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    data = json.loads(result.stdout[result.stdout.index('{'):])
    assert data['dc_gain'] > 0 and len(data['A']) == 4
    bad = subprocess.run([*AEROPEND, 'control', 'design', '--template', 'duty=80'],
                         capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2 and bad.stderr.count('\n') == 1 and 'fraction' in bad.stderr


# --- the diagnosis of a closed-loop record ------------------------------------------------------------------------
def _closed_loop_record(effects, seed, noise_db=50):
    gains = PidGains(p=1.2074, i=0.129, d=0.1255, derivative_filter_time=0.02, u_clamp_max=0.8)
    schedule = ReferenceSchedule.steps_between([20, 40, 60, 30], hold=5.0)
    run = simulate_loop(gains, schedule.reference(), FeedforwardMap(), effects=effects,
                        noise=MeasurementNoise(psnr_db=noise_db, quantise=True), seed=seed, duty_limit=0.7)
    return gains, run


@pytest.mark.slow
def test_closed_loop_diagnosis_names_a_hidden_thrust_lag_within_its_sigma():
    from aeropend_core.control.loop_diagnosis import diagnose_loop
    gains, run = _closed_loop_record({'thrust_lag': 0.15}, seed=21)
    result = diagnose_loop(run.time, run.angle, run.duty, run.reference, run.feedforward, gains, 0.7)
    assert result.replay_mismatches == 0
    assert result.named == 'thrust_lag', result.as_text()
    fit = result.best_model()
    assert abs(fit.values['time_constant'] - 0.15) <= 3 * fit.sigmas['time_constant'] + 0.01, result.as_text()


@pytest.mark.slow
def test_closed_loop_diagnosis_of_a_clean_rig_names_nothing():
    from aeropend_core.control.loop_diagnosis import diagnose_loop
    gains, run = _closed_loop_record({}, seed=22)
    result = diagnose_loop(run.time, run.angle, run.duty, run.reference, run.feedforward, gains, 0.7)
    assert result.named is None, result.as_text()
    assert result.verdict == 'nothing_missing', result.as_text()


@pytest.mark.slow
def test_a_closed_loop_threshold_is_reported_without_a_local_sigma():
    """A dead zone (0.9 V) in a loop held at 30-50 deg: the fit's cost steps in the threshold, so the local
    least-squares sigma is no doubt (s24: 1.196 +- 0.0099 V for 0.933 V). It is not reported (null in JSON, "not
    given" in text, a note says why); the thrust gain keeps its sigma; the decisions still read the local one."""
    from aeropend_core.control.loop_diagnosis import diagnose_loop
    from aeropend_core.present.json_output import finite_json
    gains = PidGains(p=1.2074, i=0.129, d=0.1255, derivative_filter_time=0.02, u_clamp_max=0.8)
    schedule = ReferenceSchedule.steps_between([30, 50, 40], hold=5.0)
    run = simulate_loop(gains, schedule.reference(), FeedforwardMap(), effects={'dead_zone': 0.9},
                        noise=MeasurementNoise(psnr_db=40, quantise=True), seed=24, duty_limit=0.7)
    result = diagnose_loop(run.time, run.angle, run.duty, run.reference, run.feedforward, gains, 0.7,
                           add=('dead_zone',), candidates=('dead_zone',))
    assert 'threshold_voltage' in result.base.sigmas          # the fit has one (the decisions read it) ...
    data = finite_json(result.to_dict())
    assert data['standard_errors']['threshold_voltage'] is None          # ... the report does not give it
    assert data['standard_errors']['thrust_gain'] is not None
    text = result.as_text()
    assert 'threshold_voltage = ' in text and '(+- not given: see the notes)' in text
    assert any(note.startswith('threshold_voltage: no +- is given') for note in result.notes), result.notes


@pytest.mark.slow
def test_a_closed_loop_threshold_the_design_model_holds_is_kept_not_refitted():
    """The same 0.9 V dead zone, the controller designed on a model that holds it (the open-loop diagnosis's value,
    here the truth): the closed-loop fits keep it (s24: the free fit gave 1.196 V for 0.933 V, and this record's
    0.18 V; the noise-free loop from the reference is biased where the fed-back noise moves the duty across the
    gate), say so in a note, give it no +-; gravity and the thrust scale are still fitted (with the same bias: on this
    record both x1.37, their ratio 4.5 % off, said in the note)."""
    from aeropend_core.control.loop_diagnosis import diagnose_loop
    from aeropend_core.present.json_output import finite_json
    gains = PidGains(p=1.2074, i=0.129, d=0.1255, derivative_filter_time=0.02, u_clamp_max=0.8)
    schedule = ReferenceSchedule.steps_between([30, 50, 40], hold=5.0)
    run = simulate_loop(gains, schedule.reference(), FeedforwardMap(), effects={'dead_zone': 0.9},
                        noise=MeasurementNoise(psnr_db=40, quantise=True), seed=24, duty_limit=0.7)
    result = diagnose_loop(run.time, run.angle, run.duty, run.reference, run.feedforward, gains, 0.7,
                           add=('dead_zone',), candidates=('dead_zone',),
                           model_effects={'dead_zone': {'threshold_voltage': 0.9}})
    data = finite_json(result.to_dict())
    assert data['parameters']['threshold_voltage'] == pytest.approx(0.9)
    assert data['standard_errors']['threshold_voltage'] is None
    assert result.base.n_parameters == 2                         # gravity and thrust scale: the threshold is held
    assert data['standard_errors']['thrust_gain'] is not None
    assert '(held at the controller model\'s value: see the notes)' in result.as_text()
    assert any(note.startswith('threshold_voltage: held at the controller model\'s value') for note in result.notes)
    assert not any(note.startswith('threshold_voltage: no +- is given') for note in result.notes)
    # an effect the model does not hold is fitted as before
    free = diagnose_loop(run.time, run.angle, run.duty, run.reference, run.feedforward, gains, 0.7,
                         add=('dead_zone',), candidates=('dead_zone',), model_effects={})
    assert free.base.n_parameters == 3 and not free.base.held


@pytest.mark.slow
def test_the_noise_fed_back_removes_the_closed_loop_bias_of_gravity_and_thrust():
    """The 0.9 V dead zone record above (40 dB, d = 0.13), the threshold held at the truth: with the loop simulated
    noise-free (before s26) gravity and the thrust gain came out x1.37, far beyond their +-; with the record's own
    noise fed to the simulated law (its measured angle minus a 15 Hz zero-phase low-pass) both lie within 2 sigma
    of the truth (131.75 1/s^2, 142.0 rad/s^2), and the sigma stays under 2 % of the value."""
    from aeropend_core.control.loop_diagnosis import diagnose_loop
    gains = PidGains(p=1.2074, i=0.129, d=0.1255, derivative_filter_time=0.02, u_clamp_max=0.8)
    schedule = ReferenceSchedule.steps_between([30, 50, 40], hold=5.0)
    run = simulate_loop(gains, schedule.reference(), FeedforwardMap(), effects={'dead_zone': 0.9},
                        noise=MeasurementNoise(psnr_db=40, quantise=True), seed=24, duty_limit=0.7)
    truth = {'gravity_stiffness': DEFAULT_PARAMETERS.gravity_stiffness, 'thrust_gain': DEFAULT_PARAMETERS.thrust_gain}
    for fed in (False, True):
        result = diagnose_loop(run.time, run.angle, run.duty, run.reference, run.feedforward, gains, 0.7,
                               add=('dead_zone',), candidates=('dead_zone',),
                               model_effects={'dead_zone': {'threshold_voltage': 0.9}}, feed_back_noise=fed)
        data = result.to_dict()
        z = {name: (data['parameters'][name] - value) / data['standard_errors'][name] for name, value in truth.items()}
        if fed:
            assert all(abs(value) <= 2.0 for value in z.values()), (z, result.as_text())
            assert all(data['standard_errors'][name] <= 0.02 * value for name, value in truth.items()), result.as_text()
            assert any('own angle noise fed to the law' in note for note in result.notes), result.notes
        else:
            assert all(abs(value) > 10.0 for value in z.values()), (z, result.as_text())


def test_replay_check_catches_a_controller_other_than_the_declared_one():
    from aeropend_core.control.loop_diagnosis import replay
    gains, run = _closed_loop_record({}, seed=23)
    assert replay(gains, run.reference, run.feedforward, run.angle, run.duty, 0.7) == (0.0, 0)
    other = gains.replace(p=gains.p * 1.1)
    largest, count = replay(other, run.reference, run.feedforward, run.angle, run.duty, 0.7)
    assert count > 100 and largest > 1e-3


@pytest.mark.slow
def test_simulate_runs_a_diagnosis_model_on_the_users_duty(tmp_path):
    """`aeropend simulate --model D.json --input duty.csv`: the JSON's fitted parameters and effects, the user's duty
    held between its stamps at 490 Hz; equal to the library's simulation of that model."""
    from aeropend_core.control.model_source import model_from_dict
    from aeropend_core.sim.simulate import simulate
    model_json = {'parameters': {'gravity_stiffness': 120.0, 'damping': 12.0, 'thrust_gain': 150.0,
                                 'time_constant': 0.12}, 'model_effects': ['thrust_lag'], 'verdict': 'nothing_missing'}
    (tmp_path / 'd.json').write_text(json.dumps(model_json))
    (tmp_path / 'duty.csv').write_text('t,duty\n0,0\n1,0.45\n2.5,0.3\n4,0.3\n')
    result = subprocess.run([*AEROPEND, 'simulate', '-o', str(tmp_path / 'out.csv'), '--model',
                             str(tmp_path / 'd.json'), '--input', str(tmp_path / 'duty.csv'), '--quiet'],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    table = np.genfromtxt(tmp_path / 'out.csv', delimiter=',', names=True)
    assert table['duty'][int(1.5 / TS)] == 0.45 and table['duty'][int(3 / TS)] == 0.3
    model = model_from_dict(model_json, 'd.json')
    assert model.parameters.thrust_gain == pytest.approx(150.0)
    expected = simulate(table['duty'], model.parameters, model.effects)
    np.testing.assert_allclose(table['angle'], expected.angle, atol=1e-6)
    bad = subprocess.run([*AEROPEND, 'simulate', '-o', str(tmp_path / 'x.csv'), '--input', str(tmp_path / 'd.json')],
                         capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2 and 'no "duty" column' in bad.stderr


def test_a_diagnosis_that_names_an_effect_is_a_model_with_a_doubt():
    """`diagnose --json` lists each found effect as an object: the model is read, and its doubt names the effect
    (it was a TypeError)."""
    from aeropend_core.control.model_source import model_from_dict
    data = {'parameters': {'gravity_stiffness': 120.0, 'damping': 12.0, 'thrust_gain': 150.0},
            'model_effects': [], 'verdict': 'missing_effect', 'missing_effect': 'thrust_lag',
            'missing_effects': [{'effect': 'thrust_lag', 'parameters': {'time_constant': 0.15}}]}
    model = model_from_dict(data, 'd.json')
    assert model.effects == {} and model.parameters.gravity_stiffness == 120.0
    assert any('missing_effect: thrust_lag' in doubt for doubt in model.doubts)


def test_a_diagnosis_model_takes_the_motor_its_observer_fitted():
    """A rig whose motor constants are off by up to 23 % (test_signals' moved rig, 42.8 dB): the diagnosis fits the
    thrust gain on the back-EMF of its motor observer, so the model to design on must carry that motor. With the
    observer's motor the model's static thrust at duty 0.3-0.7 is within 1.5 % of the rig's and its motor time
    constant within 3 % (the observer's rates are within 1-3 %); with the nominal motor (what the model took
    before) the static thrust is off by more than twice as much somewhere (3.7 % here): a miss the design's thrust
    doubt had to carry."""
    from aeropend_core.control.model_source import model_from_dict
    from aeropend_core.signals.motor import fit_motor
    from aeropend_core.signals.preprocess import detect_steps, piecewise_constant
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.simulate import simulate
    moved = DEFAULT_PARAMETERS.scaled(armature_resistance=0.9344, armature_inductance=0.8972,
                                      back_emf_constant=1.0515, torque_constant=0.885, motor_inertia=0.9072,
                                      motor_friction=0.7724, propeller_torque_coefficient=1.0673,
                                      thrust_coefficient=1.2105, gravity_stiffness=0.8946, damping=0.9099,
                                      lever_per_inertia=1.1154)
    duty = lhc_schedule(60.0, duty_range=(0.0, 0.7), duty_cap=0.7, seed=9006).duty(duration=60.0)
    record = simulate(duty, parameters=moved, noise=MeasurementNoise(42.77, True), seed=9007)
    steps = detect_steps(record.armature_voltage, record.sample_time)
    observer = fit_motor(piecewise_constant(record.armature_voltage, steps), record.armature_current, steps,
                         record.sample_time).parameters
    # the thrust gain and Ra as the diagnosis reports them (the true product, the observer's Rm)
    fitted = {'gravity_stiffness': moved.gravity_stiffness, 'damping': moved.damping,
              'armature_resistance': observer['motor_resistance'],
              'thrust_gain': moved.lever_per_inertia * moved.thrust_voltage_coefficient}
    with_motor_model = model_from_dict({'parameters': fitted, 'motor_observer': observer}, 'd.json')
    nominal_motor_model = model_from_dict({'parameters': fitted}, 'd.json')
    with_motor, nominal_motor = with_motor_model.parameters, nominal_motor_model.parameters
    # a model without the motor fit (an identify JSON) says that its motor is the nominal rig's
    assert not any('no motor fit' in doubt for doubt in with_motor_model.doubts)
    assert any('no motor fit' in doubt and 'nominal' in doubt for doubt in nominal_motor_model.doubts)

    def time_constant(parameters, duty):
        speed = parameters.steady_state(parameters.voltage_from_duty(duty))['motor_speed']
        slope = (parameters.torque_constant * parameters.back_emf_constant / parameters.armature_resistance
                 + parameters.motor_friction + 2 * parameters.propeller_torque_coefficient / parameters.gear_ratio ** 3
                 * speed)
        return parameters.motor_inertia / slope

    worst, worst_nominal = 0.0, 0.0
    for level in (0.3, 0.5, 0.7):
        truth = rest_thrust_torque(level, moved)
        assert rest_thrust_torque(level, with_motor) == pytest.approx(truth, rel=0.015), level
        assert time_constant(with_motor, level) == pytest.approx(time_constant(moved, level), rel=0.03), level
        worst = max(worst, abs(rest_thrust_torque(level, with_motor) / truth - 1.0))
        worst_nominal = max(worst_nominal, abs(rest_thrust_torque(level, nominal_motor) / truth - 1.0))
    assert worst_nominal > 2.0 * worst


def test_check_and_linearisation_pages_are_self_contained(tmp_path, nominal_design):
    from aeropend_core.control.report import check_report, linearisation_report
    controller = Controller(nominal_design.gains, template=Template())
    schedule = nominal_design.schedule
    run = simulate_loop(controller.gains, schedule.reference(), FeedforwardMap(), effects={'thrust_lag': 0.15},
                        noise=MeasurementNoise(psnr_db=50, quantise=True), seed=3, duty_limit=0.8)
    result = check_record(run.time, run.angle, run.duty, controller, schedule)
    for page in (check_report(result, run.time, run.angle, run.duty, run.reference, 'simulated'),
                 linearisation_report(linearise(math.radians(40)), 'nominal')):
        assert page.startswith('<!DOCTYPE html>') and '<svg' in page
        assert 'http://' not in page.replace('http://www.w3.org/2000/svg', '') and 'https://' not in page
    assert page.count('<figure') == 2                        # step response, Bode
    assert check_report(result, run.time, run.angle, run.duty, None, 's').count('<figure') == len(result.steps)
    # the result presents itself (issue #44): its short form agrees with its record, its fragment is its text
    summary, fragment = result.summary(), result.as_html()
    assert summary['verdict'] == result.to_dict()['verdict'] and summary['steps'] == len(result.steps)
    assert summary['missed'] == {s['step']: sorted(s['measured_misses']) for s in result.to_dict()['steps']
                                 if s['measured_misses']}
    assert fragment.startswith('<section class="aeropend-control-check">') and 'Verdict: ' in fragment
    assert 'http://' not in fragment and '<script' not in fragment


def test_schedule_metrics_equal_each_step_measured_alone():
    """schedule_metrics computes the record's sample spacing once for all its steps (s25; it was a median over the
    whole record per step): each step's metrics equal step_metrics' own, computed with nothing given."""
    schedule = ReferenceSchedule.steps_between([25, 45, 30], hold=2.0, start_hold=0.5)
    run = simulate_loop(PidGains(p=1.2, i=0.6, d=0.15), schedule.reference(), noise=MeasurementNoise(psnr_db=40.0),
                        seed=4, duty_limit=0.8)
    together = schedule_metrics(run.time, run.angle, run.duty, schedule)
    alone = [step_metrics(run.time, run.angle, run.duty, start, end, before, after)
             for start, end, before, after in schedule.step_times() if before != after]
    assert len(together) == len(alone) == 3
    assert [m.as_dict() for m in together] == [m.as_dict() for m in alone]
