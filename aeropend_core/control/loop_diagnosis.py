"""Diagnosis of a closed-loop record: models judged by the closed loop simulated from the reference with the known
controller (the indirect method of closed-loop identification).

Under feedback the duty depends on the measured angle's noise, so a fit that takes the measured Va as an open-loop
input is biased; the controller is known exactly here (the record carries its gains and the feedforward it played),
so each model is simulated *in closed loop* from the logged reference and compared with the measured angle:

1. **Replay check** before physics: the declared law run on the logged reference, feedforward and angle must give
   the logged duty (one sample later). A mismatch is an implementation fault (gains, latency, clamp), not a missing
   effect, and is said first.
2. **Fits**: the nominal model (gravity, damping and thrust scale free) and the nominal model plus each catalog
   effect the compiled loop runs, by least squares on the first ``TRAIN_SHARE`` of the record; scored on the rest
   (held-out RMS error of the angle, the error beyond the measurement noise).
3. **Evidence**: an effect is named when it is the best held-out candidate, its BIC gain on the training part is
   decisive (< ``-10`` with the sample count divided by the residual's correlation length; or any gain with every
   parameter of the effect ``SIGNIFICANT`` sigmas from zero: a limit cycle leaves few effective samples) and it
   removes at least half of the held-out error beyond the noise. Effects that give the same closed loop within
   ``TIE`` of that error are said to be confounded, with the record that would separate them (in closed loop a
   thrust lag and the sensor's filter give the same loop gain: the current, or an open-loop segment, separates
   them).

The loop is simulated with the record's own angle noise fed to the law (:func:`fed_back_noise`: the measured angle
minus its 15 Hz zero-phase low-pass), not noise-free: the law feeds that noise to the duty, and where the duty's jitter
crosses a nonlinearity (the dead zone's gate, the duty clamp, a lag's oscillation) the noise-free loop is biased
(s25: gravity and the thrust gain x1.37 on a dead-zone record with d = 0.13; s26: 131.74 and 141.39 for 131.75 and
142.00 with the noise fed back). The compared output is the simulated angle without that noise, so the residual keeps
the whole measurement noise and "beyond the noise" means what it did.

The ± of each parameter is the local least-squares standard error, inflated by the residual's correlation length,
widened (in quadrature) by half the spread of refits with the noise estimated at :data:`FED_BACK_SPREAD` Hz.
A threshold that gates samples (the dead zone's) gets none in what is reported: the cost steps where it gates a sample,
so its local standard error measures no doubt (a fit of 1.196 ± 0.0099 V for a 0.933 V truth, s24); the decisions
still read it. Where the controller's model already holds that threshold (an added effect with its value, from the
open-loop diagnosis), the fits **hold** it there (:data:`HELD_NOTE`).
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import butter, sosfiltfilt

from aeropend_core.control.law import PidGains, law_step, new_state
from aeropend_core.control.loop import simulate_loop
from aeropend_core.control.metrics import noise_sigma
from aeropend_core.control.model_source import motor_rates
from aeropend_core.errors import AeropendError
from aeropend_core.model.effects import CATALOG, get_effect, resolve_effects
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, SAMPLE_TIME, RigParameters

#: Share of the record the fits use; the rest scores them.
TRAIN_SHARE = 0.7
#: Decisive BIC gain (on the correlation-corrected sample count).
DECISIVE_BIC = -10.0
#: Share of the held-out error beyond the noise a named effect must remove.
MATERIAL_SHARE = 0.5
#: Candidates within this share of the best one's held-out error beyond the noise are confounded with it.
TIE = 0.15
#: Pairs of kernel kinds that the closed loop cannot tell apart, and what would.
SEPARATED_BY = {frozenset({'thrust_lag_time', 'measured_lowpass'}):
                'in closed loop a thrust lag and the angle sensor\'s filter give the same loop gain; the armature '
                'current (motor side) or an open-loop segment (duty steps with the loop open) separates them'}
#: The shortest lag a fit may reach [s]: the closed loop's integrator needs a lag above a few samples.
SHORTEST_LAG = 0.005
#: Cut-off [Hz] of the zero-phase low-pass whose residue estimates the measurement noise the law fed back
#: (:func:`fed_back_noise`): above the closed loop's motion on this rig (the pendulum's natural frequency ~1.8 Hz, a
#: 2 s settling template, loop bandwidths of a few Hz, the motor pole ~5-10 Hz) so the motion stays in the low-pass, and
#: low against the 245 Hz Nyquist frequency so the residue holds ~94 % of a white noise's power.
FED_BACK_CUTOFF = 15.0
#: Order of that Butterworth low-pass.
FED_BACK_ORDER = 4
#: Other cut-offs [Hz] the reported models are refitted at: half the range of the three fits is added (in
#: quadrature) to each parameter's sigma, the doubt of the noise estimate (the noise below the cut-off is not fed
#: back; on one test record the thrust gain moved 0.5 % between 10 and 25 Hz, 4 local sigmas).
FED_BACK_SPREAD = (10.0, 25.0)


def fed_back_noise(angle: np.ndarray, sample_time: float = SAMPLE_TIME,
                   cutoff: float = FED_BACK_CUTOFF) -> np.ndarray | None:
    """The measurement noise a closed-loop record's law read [rad per sample], estimated as the measured angle
    [rad] minus its zero-phase Butterworth low-pass at `cutoff` [Hz] (order :data:`FED_BACK_ORDER`): the fits
    feed it to the simulated law (:func:`~aeropend_core.control.loop.simulate_loops`' ``law_noise``) so the
    simulated duty carries the rig's jitter. None where the Nyquist frequency is under twice the cut-off (the
    loop's motion and the noise are not apart) or the record is too short to filter."""
    angle = np.asarray(angle, dtype=float)
    nyquist = 0.5 / sample_time
    if nyquist < 2.0 * cutoff or angle.size <= 6 * (FED_BACK_ORDER + 1):
        return None
    sections = butter(FED_BACK_ORDER, cutoff, fs=1.0 / sample_time, output='sos')
    return angle - sosfiltfilt(sections, angle)


def catalog_candidates() -> tuple[str, ...]:
    """The catalog effects the closed-loop diagnosis tries: every one the compiled loop runs (kernel terms)."""
    return tuple(name for name, effect in CATALOG.items() if effect.compiled and effect.kernel_terms)


def _kinds(name: str) -> frozenset[str]:
    return frozenset(kind for kind, _ in get_effect(name).kernel_terms)


def _separation(a: str, b: str) -> str | None:
    for pair, why in SEPARATED_BY.items():
        if any(pair == frozenset({x, y}) for x in _kinds(a) for y in _kinds(b)):
            return why
    return None
#: The pendulum parameters a closed-loop fit may free. A feedback loop holds the rod near its references, so the
#: record pins the static balance (thrust per unit of gravity) far better than gravity and damping apart: by
#: default the thrust scale and gravity are fitted within BASE_BOUNDS of the controller's model and the damping
#: stays the model's (an identified model, ideally: `aeropend diagnose` of an open-loop record).
BASE_PARAMETERS = ('gravity_stiffness', 'damping', 'lever_per_inertia')
DEFAULT_FREE = ('gravity_stiffness', 'lever_per_inertia')
#: Bounds of the free pendulum parameters relative to the controller's model.
BASE_BOUNDS = (0.6, 1.6)


@dataclass
class LoopFit:
    """One model fitted in closed loop."""

    effects: dict[str, dict[str, float]]
    parameters: RigParameters
    values: dict[str, float]
    sigmas: dict[str, float]
    train_rss: float
    test_rms: float
    beyond_noise: float
    n_parameters: int
    delta_bic: float = 0.0
    #: effect parameters held at a given value, not fitted (:data:`HELD_NOTE`)
    held: dict[str, float] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return ' + '.join(self.effects) or 'nominal'


@dataclass
class LoopDiagnosis:
    """The outcome (see the module docstring); angles [rad]."""

    base: LoopFit
    candidates: list[LoopFit]
    noise_rms: float
    replay_max_error: float
    replay_mismatches: int
    added: tuple[str, ...]
    verdict: str
    named: str | None
    confounded_with: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def best_model(self) -> LoopFit:
        if self.named:
            return next(fit for fit in self.candidates if fit.name.endswith(self.named))
        return self.base

    def to_dict(self) -> dict:
        model = self.best_model() if self.named else self.base
        parameters = _reported(self.base)
        return {'schema': 'aeropend.loop_diagnosis/1', 'closed_loop': True, 'verdict': self.verdict,
                'missing_effect': self.named, 'missing_effects': [self.named] if self.named else [],
                'add': [self.named] if self.named else [], 'model_effects': list(self.added),
                'parameters': parameters, 'standard_errors': _reported_sigmas(self.base),
                # the controller model's motor (held in the fit): a design on this JSON keeps it
                'motor_observer': motor_rates(self.base.parameters),
                'with_missing_effect': ({'parameters': _reported(model), 'standard_errors': _reported_sigmas(model)}
                                        if self.named else None),
                'noise_rms': self.noise_rms, 'rms_error': self.base.test_rms,
                'error_beyond_noise': self.base.beyond_noise,
                'replay': {'max_duty_error': self.replay_max_error, 'mismatched_samples': self.replay_mismatches},
                'candidates': [{'effect': fit.name, 'parameters': dict(fit.values),
                                'standard_errors': _shown_sigmas(fit), 'rms_error': fit.test_rms,
                                'error_beyond_noise': fit.beyond_noise, 'delta_bic': fit.delta_bic}
                               for fit in self.candidates],
                'confounded_with': list(self.confounded_with), 'notes': list(self.notes),
                'units': {'angles': 'rad', 'errors': 'rad', 'parameters': 'SI (see aeropend effects)'}}

    def as_text(self) -> str:
        lines = ['Closed-loop record: models judged by the closed loop simulated from the reference with the '
                 'known controller (not by taking the fed-back Va as an input)']
        if self.replay_mismatches:
            lines.append(f'Replay check: FAILED: the declared law on the logged angle gives another duty at '
                         f'{self.replay_mismatches} sample(s) (largest difference {self.replay_max_error:.3g}): the '
                         'controller that ran is not the one declared (gains, latency or clamp); fix that first')
        else:
            lines.append(f'Replay check: the declared law on the logged reference and angle gives the logged duty '
                         f'(largest difference {self.replay_max_error:.2g})')
        base = self.base
        lines.append(f'Model: {base.name if not self.added else "nominal + " + " + ".join(self.added)}: held-out '
                     f'RMS error {1e3 * base.test_rms:.2f} mrad, measurement noise {1e3 * self.noise_rms:.2f} mrad, '
                     f'error beyond noise {1e3 * base.beyond_noise:.2f} mrad')
        lines.append('Parameters (SI, +- 1 sigma): ' + ', '.join(
            f'{name} = {value:.4g} {_pm(base, name)}' for name, value in base.values.items()))
        if self.candidates:
            lines.append('Candidates (best first, held-out error beyond noise, BIC gain on the training part):')
            for fit in self.candidates:
                extra = ', '.join(f'{name} = {value:.4g} {_pm(fit, name)}'
                                  for name, value in fit.values.items() if name not in BASE_PARAMETERS)
                lines.append(f'  {fit.name:<28} beyond noise {1e3 * fit.beyond_noise:6.2f} mrad  dBIC '
                             f'{fit.delta_bic:9.1f}  {extra}')
        lines.append(f'Verdict: {self.verdict_text()}')
        lines.extend(f'Note: {note}' for note in self.notes)
        return '\n'.join(lines)

    def verdict_text(self) -> str:
        if self.verdict == 'missing_effect':
            fit = self.best_model()
            values = ', '.join(f'{name} = {value:.4g} {_pm(fit, name)}'
                               for name, value in fit.values.items() if name not in BASE_PARAMETERS)
            removed = 100 * (1 - fit.beyond_noise / self.base.beyond_noise) if self.base.beyond_noise > 0 else 0.0
            text = (f'missing effect: {self.named} ({values}; removes {removed:.0f} % of the held-out error beyond '
                    f'the noise in closed loop). Add it (--add {self.named}), then design on that diagnosis: '
                    f'aeropend control design --model DIAGNOSIS.json')
            if self.confounded_with:
                text += (f'. Confounded with {", ".join(self.confounded_with)} in this record (they give the same '
                         'closed loop): the design is the same either way, the physics is not decided')
            return text
        if self.verdict == 'nothing_missing':
            return (f'nothing significant is missing in closed loop: the error beyond the noise is '
                    f'{1e3 * self.base.beyond_noise:.2f} mrad against {1e3 * self.noise_rms:.2f} mrad of noise')
        return (f'unexplained: {1e3 * self.base.beyond_noise:.2f} mrad beyond the noise remain and no catalog effect '
                'removes half of it in closed loop')


def _reported(fit: LoopFit) -> dict[str, float]:
    """A diagnosis JSON's parameter names (what `control design --model` reads): thrust as the lumped gain."""
    values = {'gravity_stiffness': fit.parameters.gravity_stiffness, 'damping': fit.parameters.damping,
              'thrust_gain': fit.parameters.thrust_gain, 'armature_resistance': fit.parameters.armature_resistance}
    values.update({name: value for name, value in fit.values.items() if name not in BASE_PARAMETERS})
    return values


#: Kernel terms whose parameter gates samples: the closed loop's least-squares cost steps in it, so the local
#: standard error is no measure of its doubt and is not reported (NaN: null in JSON, "+- not given" in text).
STEP_COST_TERMS = frozenset({'thrust_threshold'})


def _step_cost_parameters(fit: LoopFit) -> set[str]:
    return {parameter for name in fit.effects for kind, parameter in get_effect(name).kernel_terms
            if kind in STEP_COST_TERMS}


def _shown_sigmas(fit: LoopFit) -> dict[str, float]:
    """`fit.sigmas` as reported: NaN for a gating threshold (:data:`STEP_COST_TERMS`)."""
    hidden = _step_cost_parameters(fit)
    return {name: (math.nan if name in hidden else sigma) for name, sigma in fit.sigmas.items()}


def _pm(fit: LoopFit, name: str) -> str:
    if name in fit.held:
        return '(held at the controller model\'s value: see the notes)'
    sigma = _shown_sigmas(fit).get(name, math.nan)
    return f'+- {sigma:.2g}' if math.isfinite(sigma) else '(+- not given: see the notes)'


STEP_COST_NOTE = ('{names}: no +- is given: in closed loop the fit\'s cost steps wherever the threshold gates a '
                  'sample, so its local least-squares error is no measure of doubt (on a simulated dead zone held '
                  'at 30-50 deg one fit gave 1.196 +- 0.0099 V for a 0.933 V truth); a loop held away from the '
                  'threshold trades it against the thrust gain: an open-loop record with steps through the '
                  'threshold decides it')


#: Said when a gating threshold is held at the controller model's value (s25, bench/results/2026-12-07-s25-loop).
HELD_NOTE = ('{names}: held at the controller model\'s value ({values}; its doubt is that model\'s, from the record '
             'it was identified on), not fitted here: the closed loop\'s cost steps wherever the threshold gates a '
             'sample, and a fit of it stays near where it starts (s25: with the record\'s noise fed back, a fit '
             'started at 0.6 V stayed there for a 0.9 V truth; without it, the noise-free loop fitted 1.196 V for '
             '0.933 V): an open-loop record with steps through the threshold decides it')


def _held_values(effects: Mapping[str, Mapping[str, float]], add: Sequence[str]) -> dict[str, dict[str, float]]:
    """The gating thresholds (:data:`STEP_COST_TERMS`) of the added effects whose value the controller's model
    gives: {effect: {parameter: value}}."""
    held = {}
    for name in add:
        values = effects.get(name) or {}
        for kind, parameter in get_effect(name).kernel_terms:
            value = values.get(parameter)
            if kind in STEP_COST_TERMS and value is not None and math.isfinite(float(value)):
                held.setdefault(name, {})[parameter] = float(value)
    return held


def _reported_sigmas(fit: LoopFit) -> dict[str, float]:
    """The standard errors under the reported names (the thrust gain's from L/J's: same relative doubt)."""
    sigmas = {name: value for name, value in _shown_sigmas(fit).items() if name != 'lever_per_inertia'}
    if 'lever_per_inertia' in fit.sigmas:
        sigmas['thrust_gain'] = fit.sigmas['lever_per_inertia'] / fit.parameters.lever_per_inertia \
            * fit.parameters.thrust_gain
    return sigmas


def replay(gains: PidGains, reference: np.ndarray, feedforward: np.ndarray, angle: np.ndarray, duty: np.ndarray,
           duty_limit: float, sample_time: float = SAMPLE_TIME) -> tuple[float, int]:
    """(largest |duty difference|, samples differing by more than 1e-4) between the logged duty and the declared
    law run on the logged reference, feedforward and angle (its answer applies one sample later)."""
    c = gains.coefficients(sample_time)
    state = new_state()
    computed = np.empty(angle.size)
    for k in range(angle.size):
        computed[k] = min(max(law_step(c, state, reference[k], feedforward[k], angle[k]), 0.0), duty_limit)
    difference = np.abs(computed[:-1] - duty[1:])
    return (float(difference.max()) if difference.size else 0.0), int(np.count_nonzero(difference > 1e-4))


def _correlation_length(residual: np.ndarray) -> float:
    """Samples to the first zero of the residual's autocorrelation (>= 1)."""
    centred = residual - residual.mean()
    n = centred.size
    spectrum = np.fft.rfft(centred, 2 * n)
    autocorrelation = np.fft.irfft(spectrum * np.conj(spectrum))[:n]
    if autocorrelation[0] <= 0:
        return 1.0
    below = np.flatnonzero(autocorrelation <= 0)
    return float(max(1, below[0])) if below.size else float(n)


class _Problem:
    """The closed-loop output-error problem of one record."""

    def __init__(self, gains, reference, feedforward, angle, duty_limit, sample_time, parameters, free,
                 law_noise=None):
        self.free = tuple(free)
        self.law_noise = law_noise
        self.gains, self.reference, self.feedforward, self.angle = gains, reference, feedforward, angle
        self.duty_limit, self.sample_time, self.parameters = duty_limit, sample_time, parameters
        self.split = int(TRAIN_SHARE * angle.size)
        self.initial_angle = float(np.median(angle[:max(5, int(0.05 / sample_time))]))

    def simulate(self, parameters, effects) -> np.ndarray:
        run = simulate_loop(self.gains, self.reference, self.feedforward, parameters, effects, None, None,
                            self.initial_angle, self.sample_time, self.duty_limit, method='compiled',
                            law_noise=self.law_noise)
        return run.angle

    def fit(self, effects: Mapping[str, Mapping[str, float]], noise: float,
            held: Mapping[str, Mapping[str, float]] | None = None, multistart: bool = True,
            start: RigParameters | None = None) -> LoopFit:
        """Fit the free pendulum parameters and `effects`' parameters, those in `held` ({effect: {parameter:
        value}}) kept at their value; `multistart` False: from the given start only (:func:`_starts`' first).
        `start`: the pendulum parameters to start from and bound around (default: the problem's)."""
        held = {name: dict(values) for name, values in (held or {}).items() if name in effects}
        effects = resolve_effects({name: {parameter.name: values.get(parameter.name, parameter.start_value)
                                          for parameter in get_effect(name).parameters}
                                   for name, values in effects.items()})
        names = list(self.free)
        start_parameters = start if start is not None else self.parameters
        starts = [getattr(start_parameters, name) for name in names]
        lower = [BASE_BOUNDS[0] * value for value in starts]
        upper = [BASE_BOUNDS[1] * value for value in starts]
        scales = list(starts)
        effect_slots = []
        typical = []
        for effect_name, values in effects.items():
            effect = get_effect(effect_name)
            for parameter in effect.parameters:
                if parameter.name in held.get(effect_name, {}):
                    continue
                names.append(parameter.name)
                start = values[parameter.name]
                low, high = parameter.lower, min(parameter.upper, 1e6)
                if ('thrust_lag_time', parameter.name) in get_effect(effect_name).kernel_terms:
                    low = max(low, SHORTEST_LAG)
                start = min(max(start, low + 1e-9 * (high - low)), high - 1e-9 * (high - low))
                starts.append(start)
                lower.append(low)
                upper.append(high)
                scales.append(parameter.scale if parameter.scale else max(abs(start), 0.01))
                effect_slots.append((effect_name, parameter.name))
                typical.append(parameter.typical)
        split = self.split

        n_free = len(self.free)

        def model(x):
            parameters = start_parameters.replace(**dict(zip(self.free, x[:n_free])))
            chosen = {name: dict(held.get(name, {})) for name in effects}
            for (effect_name, parameter_name), value in zip(effect_slots, x[n_free:]):
                chosen[effect_name][parameter_name] = float(value)
            return parameters, chosen

        def residual(x):
            parameters, chosen = model(x)
            simulated = self.simulate(parameters, chosen)
            difference = simulated[:split] - self.angle[:split]
            return np.where(np.isfinite(difference), difference, 10.0)

        result = None
        for start in (_starts(starts, effect_slots, n_free, lower, upper, typical) if multistart
                      else [np.array(starts)]):
            trial = least_squares(residual, start, bounds=(lower, upper), x_scale=np.array(scales),
                                  diff_step=1e-3, max_nfev=80, method='trf')
            if result is None or trial.cost < result.cost:
                result = trial
        parameters, chosen = model(result.x)
        simulated = self.simulate(parameters, chosen)
        test = simulated[split:] - self.angle[split:]
        test_rms = float(np.sqrt(np.mean(test ** 2))) if test.size else math.nan
        train_residual = result.fun
        rss = float(np.sum(train_residual ** 2))
        correlation = _correlation_length(train_residual)
        sigmas = {}
        try:
            jacobian = result.jac
            dof = max(1, train_residual.size - len(names))
            covariance = np.linalg.pinv(jacobian.T @ jacobian) * rss / dof * correlation
            sigmas = {name: float(math.sqrt(max(covariance[i, i], 0.0))) for i, name in enumerate(names)}
        except (np.linalg.LinAlgError, ValueError):
            sigmas = dict.fromkeys(names, math.nan)
        values = dict(zip(names, map(float, result.x)))
        held_values = {parameter: value for values_ in held.values() for parameter, value in values_.items()}
        values.update(held_values)
        sigmas.update(dict.fromkeys(held_values, math.nan))
        beyond = math.sqrt(max(0.0, test_rms ** 2 - noise ** 2))
        return LoopFit(chosen, parameters, values, sigmas, rss, test_rms, beyond, len(names), held=held_values)


#: What the +- of a closed-loop fit has been measured to mean (bench/closed_loop.py, 2026-12-06): said with every
#: closed-loop diagnosis until a coverage benchmark of its own says better.
COVERAGE_NOTE = ('the loop is simulated from the reference with the record\'s own angle noise fed to the law (the '
                 'measured angle minus its 15 Hz zero-phase low-pass), so the simulated duty carries the jitter the '
                 'rig\'s did; the +- are local (the least-squares Jacobian, inflated by the residual\'s correlation '
                 'length), widened by the spread of refits with the noise estimated at 10 and 25 Hz. On 50 '
                 'simulated 40 dB loops (s26, '
                 'parameters +-15 %, the structure told) they were more accurate than the noise-free loop\'s (median '
                 'error of a 0.1-0.2 s lag 2.0 % for 5.9 %, of the thrust gain beside it 1.2 % for 3.7 %) but their '
                 '+- cover less: within 2 sigma 106 of 130 parameters (the '
                 'noise-free loop\'s 114, with +- up to 100 % of a lag); beside a dead zone gravity 5 and the thrust '
                 'gain 4 of 10 (the threshold\'s gate makes the cost step), an angle offset 3 of 10: read them as the '
                 'least doubt; an open-loop record decides gravity and the thrust gain')
#: Said when the loop is simulated without the record's noise (``feed_back_noise=False``, the method before s26).
NOISE_FREE_NOTE = ('the +- here are local (the least-squares Jacobian, inflated by the residual\'s correlation '
                   'length). The loop is simulated from the reference without the measurement noise the law feeds '
                   'back to the duty; where that noise moves the duty much (a large derivative gain), gravity and the '
                   'thrust gain can be biased beyond them (simulated 40 dB loops with a dead zone: both x1.37 with '
                   'd = 0.13; the thrust gain 4.2 sigma off on another): an open-loop record decides them')
#: Sigmas from zero every parameter of an effect must be for a BIC gain short of decisive to count.
SIGNIFICANT = 4.0


def _significant(fit: LoopFit, add: Sequence[str]) -> bool:
    names = [parameter.name for effect in set(fit.effects) - set(add) for parameter in get_effect(effect).parameters]
    sigmas = [fit.sigmas.get(name, math.nan) for name in names]
    return bool(names) and all(math.isfinite(sigma) and sigma > 0 and abs(fit.values[name]) >= SIGNIFICANT * sigma
                               for name, sigma in zip(names, sigmas))


def _starts(starts, effect_slots, n_free, lower, upper, typical):
    """The start, then for each effect parameter starts at its typical size and at twice it: the closed loop's
    cost has a basin per oscillation mode (a lag, a filter) and is flat around a threshold or a friction level
    that the loop never crosses."""
    yield np.array(starts)
    for index in range(len(effect_slots)):
        for value in (typical[index], 2.0 * typical[index]):
            other = np.array(starts)
            other[n_free + index] = min(max(value, lower[n_free + index]), upper[n_free + index])
            if not np.allclose(other, starts):
                yield other


def _widen_by_cutoff(fit: LoopFit, others: Sequence[_Problem], noise: float,
                     held: Mapping[str, Mapping[str, float]]) -> None:
    """Refit `fit`'s model with the noise estimated at the other cut-offs (:data:`FED_BACK_SPREAD`; `others`, each
    started at `fit`'s values) and add half the range of the fitted values to each sigma, in quadrature."""
    values = [fit.values]
    for other in others:
        values.append(other.fit(fit.effects, noise, held, multistart=False, start=fit.parameters).values)
    for name, sigma in fit.sigmas.items():
        if name in fit.held or not math.isfinite(sigma):
            continue
        spread = 0.5 * (max(v[name] for v in values) - min(v[name] for v in values))
        fit.sigmas[name] = math.hypot(sigma, spread)


def diagnose_loop(time: np.ndarray, angle: np.ndarray, duty: np.ndarray, reference: np.ndarray,
                  feedforward: np.ndarray, gains: PidGains, duty_limit: float,
                  parameters: RigParameters = DEFAULT_PARAMETERS, add: Sequence[str] = (),
                  candidates: Sequence[str] | None = None, sample_time: float = SAMPLE_TIME,
                  free: Sequence[str] = DEFAULT_FREE,
                  model_effects: Mapping[str, Mapping[str, float]] | None = None,
                  feed_back_noise: bool = True) -> LoopDiagnosis:
    """Diagnose a closed-loop record (arrays of shape (n,): time [s], measured angle [rad], applied duty, reference
    [rad], the feedforward played [duty]); `gains` the law that ran, `duty_limit` the duty cap it ran under;
    `model_effects` the effects of the model the controller was designed on ({effect: {parameter: value}}, SI): an
    added effect's gating threshold found there is held at its value (:data:`HELD_NOTE`). `feed_back_noise`: the
    simulated law reads the record's own noise (:func:`fed_back_noise`); False: the noise-free loop (before s26)."""
    angle = np.asarray(angle, dtype=float)
    if angle.size < int(10.0 / sample_time):
        raise AeropendError(f'the closed-loop record has {angle.size * sample_time:.1f} s; the closed-loop '
                            'diagnosis needs at least 10 s (two steps with their holds)')
    reference = np.ascontiguousarray(reference, dtype=float)
    feedforward = np.ascontiguousarray(feedforward, dtype=float)
    tried = candidates if candidates is not None else catalog_candidates()
    for name in add:
        if name not in tried:
            raise AeropendError(f'--add {name}: the closed-loop diagnosis runs the catalog effects '
                                f'{", ".join(tried)}')
    max_error, mismatches = replay(gains, reference, feedforward, angle, np.asarray(duty, dtype=float), duty_limit,
                                   sample_time)
    noise = noise_sigma(angle)
    law_noise = fed_back_noise(angle, sample_time) if feed_back_noise else None
    problem = _Problem(gains, reference, feedforward, angle, duty_limit, sample_time, parameters, free, law_noise)
    # the refits that widen the +- by the noise estimate's cut-off (none for the noise-free loop)
    others = [_Problem(gains, reference, feedforward, angle, duty_limit, sample_time, parameters, free, other)
              for other in (fed_back_noise(angle, sample_time, cutoff) for cutoff in FED_BACK_SPREAD)
              if other is not None] if law_noise is not None else []
    base_effects = {name: {} for name in add}
    held = _held_values(model_effects or {}, add)
    base = problem.fit(base_effects, noise, held)
    _widen_by_cutoff(base, others, noise, held)
    fits = []
    n_effective = problem.split / _correlation_length(
        problem.simulate(base.parameters, base.effects)[:problem.split] - angle[:problem.split])
    for name in tried:
        if name in add:
            continue
        fit = problem.fit({**base_effects, name: {}}, noise, held)
        fit.delta_bic = float(n_effective * math.log(max(fit.train_rss, 1e-300) / max(base.train_rss, 1e-300))
                              + (fit.n_parameters - base.n_parameters) * math.log(max(n_effective, 2.0)))
        fits.append(fit)
    fits.sort(key=lambda fit: fit.test_rms)
    notes = []
    named, confounded = None, []
    verdict = 'nothing_missing' if base.beyond_noise <= 0.5 * noise else 'unexplained'
    if fits and base.beyond_noise > 0:
        best = fits[0]
        # Decisive: the BIC gain, or (a limit cycle's residual is correlated for long: few effective samples) a
        # gain with every parameter of the effect SIGNIFICANT sigmas from zero.
        decisive = best.delta_bic < DECISIVE_BIC or (best.delta_bic < 0 and _significant(best, add))
        material = best.beyond_noise <= (1 - MATERIAL_SHARE) * base.beyond_noise
        if decisive and material:
            named = next(iter(set(best.effects) - set(add)))
            _widen_by_cutoff(best, others, noise, held)
            verdict = 'missing_effect'
            for other in fits[1:]:
                if other.test_rms - best.test_rms <= TIE * base.beyond_noise and other.delta_bic < DECISIVE_BIC:
                    confounded.append(next(iter(set(other.effects) - set(add))))
            for other in confounded:
                why = _separation(named, other)
                if why:
                    notes.append(why)
        elif decisive:
            notes.append(f'{best.name} is supported by the statistics but removes only '
                         f'{100 * (1 - best.beyond_noise / base.beyond_noise):.0f} % of the error beyond the noise '
                         '(half is needed to name it)')
    if mismatches:
        notes.insert(0, 'the replay check failed: judge the physics only after the controller matches its '
                        'declaration')
    notes.append('closed-loop data excite the rig only as much as the controller lets them: parameters the '
                 'loop holds still (the static thrust map near one angle) are less sure than in an open-loop '
                 'record of the same length')
    notes.append(COVERAGE_NOTE if law_noise is not None else NOISE_FREE_NOTE)
    if held:
        names = [parameter for values in held.values() for parameter in values]
        notes.append(HELD_NOTE.format(names=', '.join(names), values=', '.join(
            f'{parameter} = {value:.4g}' for values in held.values() for parameter, value in values.items())))
    gated = sorted(set().union(*(_step_cost_parameters(fit) for fit in (base, *fits))) - set(base.held))
    if gated:
        notes.append(STEP_COST_NOTE.format(names=', '.join(gated)))
    return LoopDiagnosis(base, fits, noise, max_error, mismatches, tuple(add), verdict, named, confounded, notes)
