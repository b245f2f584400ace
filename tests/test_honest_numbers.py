"""Honest numbers (issue 22, items 1-3): no standard error of 0, the thrust lag's global basin, one answer per record.

Records are simulated with known truth; seeds fixed up front. The coverage sweeps themselves are benches
(bench/sigma_coverage.py, bench/lag_basins.py).
"""
import json
import math
import re

import numpy as np
import pytest

from aeropend_core.cli import main as cli_main
from aeropend_core.io.recording import from_columns
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate


def _record(seed, duration, effects=None, psnr=40.0, parameters=None):
    duty = lhc_schedule(duration, seed=seed).duty(duration=duration)
    kwargs = {} if parameters is None else {'parameters': parameters}
    trajectory = simulate(duty, effects=effects, noise=MeasurementNoise(psnr, True), seed=seed + 1, **kwargs)
    return trajectory.columns(with_truth=False)


def _csv(path, columns):
    names = list(columns)
    np.savetxt(path, np.column_stack([columns[n] for n in names]), delimiter=',', header=','.join(names),
               comments='')
    return path


def test_every_reported_parameter_has_a_positive_sigma_in_text_and_json():
    """armature_resistance came from the motor observer with sigma 0.0 in every diagnosis."""
    from aeropend_core.diagnosis.diagnose import diagnose
    from aeropend_core.present.summary import format_summary
    found = diagnose(from_columns(_record(3, 30.0), source='clean'), candidates=(), drift=False)
    assert found.prepared.motor is not None           # the case that printed 0: R from the observer
    out = found.to_dict()
    for name in out['parameters']:
        sigma = out['standard_errors'][name]
        assert sigma is not None and math.isfinite(sigma) and sigma > 0, (name, sigma)
    line = next(x for x in format_summary(found).splitlines() if x.strip().startswith('armature_resistance'))
    sigma = float(re.search(r'\+-\s*([0-9.eE+-]+)', line).group(1))
    assert sigma > 0, line
    # the observer's sigma is of the size of its actual error (truth 1.08 ohm): not 0, not absurd
    assert abs(out['parameters']['armature_resistance'] - 1.08) < 6 * sigma < 0.2


def _lag_record(seed):
    """bench/lag_basins.py's record `seed`: moved rig, lag U(0.05, 0.3) s, 60 s LHC, 40 dB (same draws)."""
    from aeropend_core.model.parameters import DEFAULT_PARAMETERS
    rng = np.random.default_rng(seed)
    moved = ('armature_resistance', 'back_emf_constant', 'motor_inertia', 'propeller_torque_coefficient',
             'thrust_coefficient', 'gravity_stiffness', 'damping', 'lever_per_inertia')
    parameters = DEFAULT_PARAMETERS.scaled(**{name: float(rng.uniform(0.8, 1.2)) for name in moved})
    tau = float(rng.uniform(0.05, 0.3))
    cap = 0.7       # bench/false_alarms.duty_cap: the largest duty holding the rod below 80 deg
    while cap > 0.3 and not parameters.steady_state(parameters.voltage_from_duty(cap))['angle'] < math.radians(80):
        cap -= 0.05
    duty = lhc_schedule(60.0, duty_range=(0.0, cap), duty_cap=cap, seed=seed).duty(duration=60.0)
    trajectory = simulate(duty, parameters, {'thrust_lag': {'time_constant': tau}},
                          noise=MeasurementNoise(40.0, True), seed=seed + 1)
    return trajectory.columns(with_truth=False), tau, parameters


@pytest.mark.slow
def test_thrust_lag_is_found_in_its_global_basin_or_reported_ambiguous():
    """A 0.23 s lag whose fit from the default start stopped at 0.084 s (bench/lag_basins.py seed 52001)."""
    from aeropend_core.diagnosis.compare import compare
    columns, truth, parameters = _lag_record(52001)
    fit = compare(from_columns(columns, source='lag'), ('thrust_lag',)).fit
    assert abs(fit.extra['local_start']['time_constant'] / truth - 1) > 0.15     # the trap is really there
    estimate, sigma = fit.parameters['time_constant'], fit.standard_errors['time_constant']
    ambiguity = fit.extra.get('ambiguity')
    if ambiguity is None:
        assert abs(estimate / truth - 1) < 0.15 and abs(estimate - truth) < 3 * sigma
        assert fit.parameters['gravity_stiffness'] == pytest.approx(parameters.gravity_stiffness, rel=0.1)
    else:
        assert any(abs(b['time_constant'] / truth - 1) < 0.15 for b in ambiguity['basins'])


def test_identify_states_held_out_fit_and_disagreement_with_the_command(tmp_path, capsys):
    """Dry friction (no weak form): identify's numbers differ from the output-error fit and it must say so."""
    path = _csv(tmp_path / 'friction.csv', _record(5, 30.0, {'coulomb_friction': 4.0}))
    assert cli_main(['identify', str(path)]) == 0
    text = capsys.readouterr().out
    assert 'Held-out free-run fit of the weak-form model' in text and 'error beyond the noise' in text
    assert 'DISAGREE' in text and f'aeropend diagnose {path}' in text
    assert cli_main(['identify', str(path), '--json']) == 0
    out = json.loads(capsys.readouterr().out)
    assert out['cross_check']['agree'] is False and out['cross_check']['disagreeing']
    assert math.isfinite(out['cross_check']['heldout_fit_percent'])


@pytest.mark.slow
def test_hidden_dry_friction_comes_back_within_its_sigma():
    """The issue's case: coulomb_friction 3.0 came back 2.88 +- 0.027 (z -4.4 on this record) while the output-error
    kernel smoothed the friction law more sharply than the catalog's tanh(W / 0.01 rad/s)."""
    from aeropend_core.diagnosis.compare import compare
    columns = _record(7001, 60.0, {'coulomb_friction': 3.0})
    fit = compare(from_columns(columns, source='friction'), ('coulomb_friction',)).fit
    value, sigma = fit.parameters['friction_acceleration'], fit.standard_errors['friction_acceleration']
    assert 0 < sigma < 0.1
    assert abs(value - 3.0) < 2.5 * sigma, (value, sigma)


def test_an_ambiguous_fit_is_reported_with_both_basins():
    """A second basin within the margin is printed with both basins (the diagnosis's notes), not hidden."""
    from types import SimpleNamespace

    from aeropend_core.diagnosis.doubts import ambiguity_notes
    basins = [{'parameters': {'time_constant': 0.03, 'gravity_stiffness': 70.0}, 'residual_rms': 0.0091},
              {'parameters': {'time_constant': 0.15, 'gravity_stiffness': 148.0}, 'residual_rms': 0.0092}]
    fit = SimpleNamespace(extra={'ambiguity': {'parameter': 'time_constant', 'basins': basins,
                                               'note': 'two basins fit nearly as well.'}})
    notes = ambiguity_notes([], [], SimpleNamespace(fit=fit))
    assert len(notes) == 1 and 'AMBIGUOUS' in notes[0]
    assert 'time_constant 0.03' in notes[0] and 'time_constant 0.15' in notes[0] and 'gravity_stiffness 148' in notes[0]
    assert ambiguity_notes([], [], SimpleNamespace(fit=SimpleNamespace(extra={}))) == []


#: Records of the coverage test: (seed, effect or None). Seeds used by no bench; fixed before the test was run.
COVERAGE_RECORDS = tuple((88000 + k, (None, 'cable_torque', 'quadratic_drag')[k % 3]) for k in range(12))


def _coverage_record(seed, effect, staircase=False):
    """A moved rig (every nominal parameter x 1 +- U(0.15, 0.25)), 45 s of LHC steps (or 60 s of the paper's
    staircase up to the duty cap and down), PSNR U(30, 50) dB."""
    from aeropend_core.model.effects import get_effect
    from aeropend_core.model.parameters import DEFAULT_PARAMETERS
    rng = np.random.default_rng(seed)
    moved = ('armature_resistance', 'armature_inductance', 'back_emf_constant', 'torque_constant', 'motor_inertia',
             'motor_friction', 'propeller_torque_coefficient', 'thrust_coefficient', 'gravity_stiffness', 'damping',
             'lever_per_inertia')
    parameters = DEFAULT_PARAMETERS.scaled(**{n: float(1 + rng.choice((-1, 1)) * rng.uniform(0.15, 0.25))
                                              for n in moved})
    psnr = float(rng.uniform(30.0, 50.0))
    effects = None
    truth = {'gravity_stiffness': parameters.gravity_stiffness, 'damping': parameters.damping,
             'thrust_gain': parameters.thrust_gain}
    if effect is not None:
        values = {p.name: float(rng.uniform(0.75, 1.5) * p.typical) for p in get_effect(effect).parameters}
        effects = {effect: values}
        truth.update(values)
    cap = 0.7       # bench/false_alarms.duty_cap: the largest duty holding the rod below 80 deg
    while cap > 0.3 and not parameters.steady_state(parameters.voltage_from_duty(cap))['angle'] < math.radians(80):
        cap -= 0.05
    if staircase:
        from aeropend_core.sim.excitation import staircase_schedule
        duty = staircase_schedule(step=cap / 14, top=cap).duty(duration=60.0)
    else:
        duty = lhc_schedule(45.0, duty_range=(0.0, cap), duty_cap=cap, seed=seed).duty(duration=45.0)
    trajectory = simulate(duty, parameters, effects, noise=MeasurementNoise(psnr, True), seed=seed + 1)
    return from_columns(trajectory.columns(with_truth=False), source=f'coverage {seed}'), truth


#: False-failure probability of each coverage check under honest sigmas.
CHECK_ALPHA = 0.002


def _coverage_bounds(n):
    """(fewest within 1 sigma, most outside 2 sigma) that n honest z-values pass with probability >= 1 - alpha."""
    from scipy.stats import binom
    fewest = max(k for k in range(n + 1) if binom.cdf(k - 1, n, 0.6827) <= CHECK_ALPHA) if n else 0
    most = min(m for m in range(n + 1) if binom.sf(m, n, 0.0455) <= CHECK_ALPHA)
    return fewest, most


@pytest.mark.slow
def test_error_bars_cover_the_truth_on_seeded_records():
    """Coverage of +-1 sigma and +-2 sigma over 12 moved rigs with the right model (clean, cable torque, drag).

    Per parameter (the three nominal ones over 12 records, the effects' over 8), with honest sigmas each count is
    binomial (p = 0.683 within 1 sigma, 0.954 within 2 sigma; the records are independent); the bounds
    (:func:`_coverage_bounds`) are the widest whose false-failure probability is <= 0.2 % each: for 12 values at
    least 3 within 1 sigma and at most 3 outside 2 sigma, for 8 at least 2 and at most 3. |mean z| <= 1.2 has
    a false-failure probability below 0.1 % for 8 N(0, 1) values. 12 checks: below 2.5 % for the whole test. A
    regression tripwire (the tails of z 3-15 seen before), not the measurement: that is bench/sigma_coverage.py.
    """
    from aeropend_core.diagnosis.compare import compare
    zs: dict[str, list[float]] = {}
    for seed, effect in COVERAGE_RECORDS:
        recording, truth = _coverage_record(seed, effect)
        fit = compare(recording, () if effect is None else (effect,)).fit
        for name, true in truth.items():
            sigma = fit.standard_errors[name]
            assert math.isfinite(sigma) and sigma > 0, (seed, name, sigma)
            key = name if name in ('gravity_stiffness', 'damping', 'thrust_gain') else 'effect parameter'
            zs.setdefault(key, []).append((fit.parameters[name] - true) / sigma)
    for name, values in zs.items():
        z = np.abs(np.asarray(values))
        fewest, most = _coverage_bounds(z.size)
        assert np.sum(z <= 1.0) >= fewest, (name, np.round(values, 2))
        assert np.sum(z > 2.0) <= most, (name, np.round(values, 2))
        assert abs(float(np.mean(values))) <= 1.2, (name, np.round(values, 2))


def test_weak_form_error_bars_cover_the_truth_on_clean_records():
    """identify's weak-form sigma on 12 clean moved rigs on the staircase (its model is right there): the same
    binomial bounds.

    Its covariance assumed white whitened residual rows while they are correlated (lag-1 0.2-0.4): 33 % within
    1 sigma and 58 % within 2 sigma on 25 clean bench records; on these 12 it gave 4 within 1 sigma, 6-8 outside
    2 sigma (z down to -8.6) and a sigma of exactly 0 on three (a compensated Gram matrix that is not positive
    definite), all rejected here. The sandwich over blocks of rows: 9-10 within 1 sigma, 1 outside 2 sigma.
    """
    from aeropend_core.identify.pendulum import identify_pendulum
    zs: dict[str, list[float]] = {}
    for seed in range(89000, 89012):
        recording, truth = _coverage_record(seed, None, staircase=True)
        weak = identify_pendulum(recording.time, recording.signal('armature_voltage'),
                                 recording.signal('armature_current'), recording.signal('angle'))
        for name, true in truth.items():
            sigma = weak.standard_errors[name]
            assert math.isfinite(sigma) and sigma > 0, (seed, name, sigma)
            zs.setdefault(name, []).append((weak.parameters[name] - true) / sigma)
    for name, values in zs.items():
        z = np.abs(np.asarray(values))
        fewest, most = _coverage_bounds(z.size)
        assert np.sum(z <= 1.0) >= fewest, (name, np.round(values, 2))
        assert np.sum(z > 2.0) <= most, (name, np.round(values, 2))
        assert abs(float(np.mean(values))) <= 1.2, (name, np.round(values, 2))


def test_a_dead_zone_threshold_has_no_share_in_the_nominal_sigma_inside_its_interval():
    """The threshold is pinned only to the interval between two input levels, sigma (high - low)/sqrt(12). Its
    uncertainty has no share to propagate into the nominal parameters: the gate compares the piecewise-constant
    Va with it, so anywhere inside the interval the model's free run is the same to the last bit (the Jacobian
    column of the threshold is exactly 0). The 300 s dead-zone misses of the coverage bench (z -5 to -16) were a
    timing error of the gate, not the held threshold (tests/test_output_error.py)."""
    from aeropend_core.diagnosis.compare import gate_thresholds, initial_guess, input_levels, prepare
    from aeropend_core.diagnosis.output_error import Structure, initial_states_from_data
    prep = prepare(from_columns(_record(17, 30.0, {'dead_zone': 0.6}), source='dead zone'))
    levels = input_levels(prep, prep.split)
    threshold = float(gate_thresholds(prep)[np.argmin(np.abs(gate_thresholds(prep) - 0.6))])
    low, high = float(levels[levels < threshold].max()), float(levels[levels > threshold].min())
    structure = Structure(('dead_zone',))
    values = {**initial_guess(prep, threshold), 'armature_resistance': 0.0}
    rows = np.array([structure.row({**values, 'threshold_voltage': low + fraction * (high - low)})
                     for fraction in (0.001, 0.5, 0.999)])
    initial = initial_states_from_data(prep.train, 0.0)
    simulated = prep.train.simulate(structure, rows, np.repeat(initial[None], 3, axis=0))[:, prep.train.residual_index]
    assert np.all(np.isfinite(simulated)) and np.ptp(simulated[1]) > 0.1
    assert np.array_equal(simulated[0], simulated[1]) and np.array_equal(simulated[1], simulated[2])
    # a threshold one level higher gates one more level: the free run changes (the check can fail)
    above = levels[levels > high]
    moved = structure.row({**values, 'threshold_voltage': 0.5 * (high + above.min())}) if above.size else rows[1]
    other = prep.train.simulate(structure, moved[None], initial[None])[0, prep.train.residual_index]
    assert not np.array_equal(other, simulated[1])
