"""Which physical effect is missing? Test every catalog effect as an augmentation of the current model.

For the current model (nominal + the effects already added) and for each candidate effect not yet in it, the
model is fitted on the training part (output error,
:mod:`aeropend_core.diagnosis.compare`) and judged on the held-out part.
A candidate counts as **significant** only if all of these hold:

* the current model is not already within the noise (error beyond the noise above ``WITHIN_NOISE`` x noise RMS);
* it lowers the training BIC (computed with the effective number of independent residuals) by more than
  ``BIC_MARGIN``;
* it lowers the held-out model error beyond the noise, sqrt(rms^2 - noise^2), by at least ``MIN_IMPROVEMENT``
  (a fraction), and the held-out mean-square error by more than ``MIN_ABSOLUTE^2`` x the noise variance (so that
  a model already within the noise is not "improved" by fitting it);
* its parameter is nonzero by more than three standard errors.

Candidates are ranked by held-out error. The recommendation is the best significant candidate unless another
significant one explains the data about as well (then they are reported as confounded, with the experiment that
separates them). If the current model is already within the noise, nothing is reported missing; if it is not and
no candidate helps, the residual's structure is shown so a user can write a new effect.
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from aeropend_core.diagnosis.compare import Comparison, PreparedRecord, compare, excess_error, prepare
from aeropend_core.errors import AeropendError, InsufficientDataError
from aeropend_core.model.effects import CATALOG, find_parameter, get_effect
from aeropend_core.model.effects import separating_experiment as record_experiment
from aeropend_core.model.names import NOMINAL_PARAMETERS
from aeropend_core.io.recording import Recording

#: A candidate must lower the training BIC by more than this.
BIC_MARGIN = 10.0
#: ... and the held-out error beyond the noise by at least this fraction ...
MIN_IMPROVEMENT = 0.25
#: ... and the held-out mean-square error by more than (this x the noise RMS)^2.
MIN_ABSOLUTE = 0.25
#: The current model is "within the noise" when its error beyond the noise is below this multiple of the noise
#: (its RMS error is then within 5 % of the noise RMS): then no candidate is reported, whatever it absorbs.
WITHIN_NOISE = 0.3
#: "Unexplained" (no catalog effect helps) is claimed only beyond this multiple of the noise: a smaller excess can
#: come from the noise estimate itself (quantisation that does not dither is partly a slow bias).
UNEXPLAINED_NOISE = 0.5
#: Angle [rad] above which the record is flagged: the rod went above the horizontal, towards the unstable upright.
UPRIGHT_WARNING = math.radians(95.0)
#: Two significant candidates are confounded when the runner-up's excess error is within this factor of the best.
CONFOUNDING_FACTOR = 1.3
#: An effect parameter correlated beyond this with a nominal parameter is not separable from it in this data.
CORRELATION_LIMIT = 0.97

DEFAULT_EXPERIMENT = 'vary the step amplitudes and add rests at duty 0; longer records narrow the uncertainty'


def separating_experiment(a: str, b: str) -> str:
    """The experiment that separates `a` from `b` (effects or nominal parameters), from the catalog's records."""
    return record_experiment(a, b) or DEFAULT_EXPERIMENT


def excitation_advice(effect: str) -> str:
    """The experiment that shows `effect` best: the one separating it from a nominal parameter, if known."""
    for nominal in NOMINAL_PARAMETERS:
        advice = record_experiment(effect, nominal)
        if advice:
            return advice
    return DEFAULT_EXPERIMENT


@dataclass
class Candidate:
    """One catalog effect tried as an augmentation of the current model."""

    effect: str
    comparison: Comparison | None
    parameters: dict[str, float]
    standard_errors: dict[str, float]
    delta_bic: float
    excess_before: float
    excess_after: float
    significant: bool
    confounded_with: list[str] = field(default_factory=list)
    evidence: list[str] = field(default_factory=list)
    explanation: str = ''
    error: str = ''
    #: It explains the held-out error (enough improvement, parameter nonzero) but the training part shows no
    #: evidence for it (its BIC does not fall): the held-out part holds conditions the training part lacks.
    heldout_only: bool = False

    @property
    def fit_percent(self) -> float:
        return self.comparison.fit_percent if self.comparison else float('nan')

    @property
    def rms_error(self) -> float:
        return self.comparison.rms_error if self.comparison else float('nan')

    @property
    def improvement(self) -> float:
        """Fraction by which the held-out error beyond the noise falls."""
        if self.excess_before <= 0:
            return 0.0
        return 1.0 - self.excess_after / self.excess_before


@dataclass
class Diagnosis:
    """Outcome of :func:`diagnose`. Angles in rad; parameters SI."""

    effects: tuple[str, ...]
    current: Comparison
    candidates: list[Candidate]
    missing_effect: str | None
    verdict: str                     # 'nothing_missing' | 'effect_found' | 'confounded' | 'unexplained'
    message: str
    notes: list[str]
    before: Comparison | None = None
    residual_structure: list[dict[str, float | str]] = field(default_factory=list)
    prepared: PreparedRecord | None = None
    seconds: float = 0.0

    @property
    def noise_rms(self) -> float:
        return self.current.noise_rms

    def reported_parameters(self, comparison: Comparison) -> dict[str, float]:
        """Fitted parameters in SI; with the motor observer, `armature_resistance` is the observer's fitted Rm."""
        parameters = dict(comparison.parameters)
        if self.prepared is not None and self.prepared.motor is not None:
            parameters['armature_resistance'] = self.prepared.motor.parameters['motor_resistance']
        return parameters

    def estimators(self, comparison: Comparison) -> dict[str, str]:
        """Which estimator gave each reported parameter (``output_error``, or ``motor_observer`` for the
        armature resistance when the observer's back-EMF drives the thrust)."""
        estimators = dict.fromkeys(comparison.parameters, 'output_error')
        if self.prepared is not None and self.prepared.motor is not None:
            estimators['armature_resistance'] = 'motor_observer'
        return estimators

    def to_dict(self) -> dict:
        """The machine-readable form printed by ``aeropend diagnose --json``."""
        current = self.current
        result = {
            'model_effects': list(self.effects),
            'fit_percent': _finite(current.fit_percent),
            'fit_definition': 'held-out free-run simulation of the angle, NRMSE fit % as MATLAB compare',
            'rms_error': _finite(current.rms_error),
            'noise_rms': _finite(current.noise_rms),
            'error_beyond_noise': _finite(excess_error(current.rms_error, current.noise_rms)),
            'prediction_rms_error': _finite(current.evaluation.prediction_rms),
            'prediction_horizon': current.evaluation.prediction_horizon,
            'parameters': self.reported_parameters(current),
            'standard_errors': current.fit.standard_errors,
            'estimator': 'output_error',
            'estimators': self.estimators(current),
            'missing_effect': self.missing_effect,
            'verdict': self.verdict,
            'message': self.message,
            'notes': self.notes,
            'candidates': [_candidate_dict(c) for c in self.candidates],
            'regimes': current.evaluation.regimes,
            'worst_windows': current.evaluation.worst_windows,
            'residual_structure': self.residual_structure,
            'seconds': round(self.seconds, 2),
        }
        result['signal_errors'] = {'angle': {'rms_error': _finite(current.rms_error), 'unit': 'rad',
                                             'noise_rms': _finite(current.noise_rms)}}
        if self.prepared is not None and self.prepared.motor is not None:
            motor = self.prepared.motor
            result['motor_observer'] = motor.parameters
            result['signal_errors']['armature_current'] = {'rms_error': _finite(motor.current_rms_error),
                                                           'unit': 'A', 'noise_rms': _finite(motor.current_noise_rms)}
        if self.before is not None:
            result['before'] = {
                'model_effects': list(self.before.effects),
                'fit_percent': _finite(self.before.fit_percent),
                'rms_error': _finite(self.before.rms_error),
                'error_beyond_noise': _finite(excess_error(self.before.rms_error, self.before.noise_rms)),
                'parameters': self.reported_parameters(self.before),
                'regimes': self.before.evaluation.regimes,
            }
        return result

    def summary(self) -> str:
        """A person-readable report of the diagnosis (units stated)."""
        return format_summary(self)


def _finite(value: float) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


def _candidate_dict(candidate: Candidate) -> dict:
    return {'effect': candidate.effect, 'parameters': candidate.parameters,
            'standard_errors': candidate.standard_errors, 'fit_percent': _finite(candidate.fit_percent),
            'rms_error': _finite(candidate.rms_error), 'error_beyond_noise': _finite(candidate.excess_after),
            'delta_bic': _finite(candidate.delta_bic), 'significant': candidate.significant,
            'confounded_with': candidate.confounded_with, 'evidence': candidate.evidence,
            'explanation': candidate.explanation, 'error': candidate.error,
            'heldout_only': candidate.heldout_only}


def _effect_parameters(comparison: Comparison, effect: str) -> tuple[dict[str, float], dict[str, float]]:
    names = get_effect(effect).parameter_names
    values = {n: comparison.fit.parameters[n] for n in names}
    errors = {n: comparison.fit.standard_errors.get(n, float('nan')) for n in names}
    return values, errors


def _correlated_nominals(comparison: Comparison, effect: str) -> list[str]:
    """Nominal parameters whose estimate is correlated beyond CORRELATION_LIMIT with the effect's parameter."""
    fit = comparison.fit
    names = list(fit.free_names)
    confounded = []
    for parameter in get_effect(effect).parameter_names:
        if parameter not in names:
            continue
        i = names.index(parameter)
        for nominal in NOMINAL_PARAMETERS:
            if nominal in names:
                value = fit.correlation[i, names.index(nominal)]
                if np.isfinite(value) and abs(value) > CORRELATION_LIMIT:
                    confounded.append(nominal)
    return confounded


def _regime_evidence(before: Comparison, after: Comparison, count: int = 2) -> list[str]:
    """The regimes whose error fell the most (relative), as sentences with numbers in mrad."""
    changes = []
    for name, stats in before.evaluation.regimes.items():
        if name in after.evaluation.regimes:
            old, new = stats['rms_error'], after.evaluation.regimes[name]['rms_error']
            if old > 0:
                changes.append(((old - new) / old, name, old, new))
    changes.sort(reverse=True)
    return [f'{name}: {old * 1e3:.1f} -> {new * 1e3:.1f} mrad' for drop, name, old, new in changes[:count]
            if drop > 0.05]


def _explain(effect: str, values: dict[str, float], errors: dict[str, float], excess_before: float,
             excess_after: float, evidence: list[str]) -> str:
    entry = get_effect(effect)
    units = {p.name: p.unit for p in entry.parameters}
    estimates = ', '.join(f'{name} = {value:.4g} +- {errors.get(name, float("nan")):.2g} {units[name]}'
                          for name, value in values.items())
    text = (f'{entry.description} [{entry.equation}]. Estimated {estimates}. Held-out error beyond the noise '
            f'{excess_before * 1e3:.2f} -> {excess_after * 1e3:.2f} mrad.')
    if evidence:
        text += ' Improved most: ' + '; '.join(evidence) + '.'
    return text


def residual_structure(prep: PreparedRecord, comparison: Comparison, count: int = 5) -> list[dict]:
    """Correlation of the simulation residual with signatures of possible missing terms (best first).

    Gives a user writing a new effect a lead: e.g. a strong correlation with angle^3 suggests a cubic spring.
    """
    simulated = comparison.evaluation.simulated
    available = np.isfinite(simulated)
    residual = prep.angle - np.nan_to_num(simulated)
    angle, rate = prep.smoothed_angle, prep.smoothed_rate
    e = prep.voltage - comparison.parameters.get('armature_resistance', 0.0) * prep.current
    thrust = e * np.abs(e)
    delay = int(round(0.1 / prep.sample_time))
    delayed = np.concatenate([np.full(delay, thrust[0]), thrust[:-delay]])
    signatures = {
        'sign(rate) (dry friction)': np.sign(rate), 'rate|rate| (quadratic drag)': rate * np.abs(rate),
        'rate (viscous damping)': rate, 'angle (linear spring)': angle, 'angle^3 (hardening spring)': angle ** 3,
        'cos(angle) (offset / asymmetry)': np.cos(angle), 'sin(angle) (gravity)': np.sin(angle),
        'thrust input (gain)': thrust, 'thrust input 0.1 s earlier (lag)': delayed,
        'thrust input change (lag/lead)': thrust - delayed,
    }
    rows = []
    r = residual[available] - residual[available].mean()
    for name, signal in signatures.items():
        s = signal[available] - signal[available].mean()
        denominator = math.sqrt(float(np.dot(r, r) * np.dot(s, s))) or 1.0
        rows.append({'signature': name, 'correlation': float(np.dot(r, s) / denominator)})
    rows.sort(key=lambda row: -abs(row['correlation']))
    return rows[:count]


def diagnose(recording: Recording | PreparedRecord, effects: Sequence[str] = (),
             candidates: Sequence[str] | None = None,
             progress: Callable[[str], None] | None = None) -> Diagnosis:
    """Diagnose which effect is missing from nominal + `effects`, using only Va, Ia and the angle.

    Parameters
    ----------
    recording : Recording or PreparedRecord
        At least 20 s of samples with ``armature_voltage`` [V], ``armature_current`` [A], ``angle`` [rad].
    effects : sequence of str
        Effects already in the model (``--add``). The result also compares with the model without them.
    candidates : sequence of str, optional
        Effects to try (default: every catalog effect not in `effects`, users' registered ones included).
    progress : callable, optional
        Called with a short message before each fit.
    """
    started = time.perf_counter()
    say = progress or (lambda message: None)
    effects = tuple(effects)
    for name in effects:
        get_effect(name)
    if len(set(effects)) != len(effects):
        raise AeropendError(f'an effect is listed twice in {list(effects)}')
    say('preparing the data (input conditioning, motor observer)')
    prep = recording if isinstance(recording, PreparedRecord) else prepare(recording)
    say(f'fitting the current model: nominal{"".join(" + " + e for e in effects)}')
    current = compare(prep, effects)
    before = None
    if effects:
        say('fitting the model without the added effects (for before -> after)')
        before = compare(prep, ())
    noise = prep.noise_rms
    excess_now = excess_error(current.rms_error, noise)
    pool = [name for name in (candidates if candidates is not None else CATALOG) if name not in effects]
    results: list[Candidate] = []
    for index, name in enumerate(pool, 1):
        get_effect(name)
        say(f'[{index}/{len(pool)}] trying {name}')
        try:
            augmented = compare(prep, effects + (name,), start=current.parameters)
        except InsufficientDataError as error:
            results.append(Candidate(name, None, {}, {}, float('nan'), excess_now, float('nan'), False,
                                     error=str(error), explanation=f'not testable on this data: {error}'))
            continue
        values, errors = _effect_parameters(augmented, name)
        excess_after = excess_error(augmented.rms_error, noise)
        delta_bic = augmented.fit.bic - current.fit.bic
        nonzero = all(abs(v) > 3 * s for v, s in ((values[k], errors.get(k, 0.0)) for k in values)
                      if np.isfinite(s) and s > 0) if values else False
        gate = augmented.fit.structure.gate_parameter
        if gate in values:  # profiled, no standard error: require a threshold inside the data's range
            nonzero = values[gate] > 0.0
        improved = (excess_after <= (1.0 - MIN_IMPROVEMENT) * excess_now
                    and excess_now ** 2 - excess_after ** 2 >= (MIN_ABSOLUTE * noise) ** 2)
        relevant = improved and nonzero and excess_now > WITHIN_NOISE * noise
        significant = bool(delta_bic < -BIC_MARGIN and relevant)
        evidence = _regime_evidence(current, augmented)
        candidate = Candidate(name, augmented, values, errors, delta_bic, excess_now, excess_after, significant,
                              confounded_with=_correlated_nominals(augmented, name), evidence=evidence,
                              heldout_only=bool(relevant and not significant))
        candidate.explanation = _explain(name, values, errors, excess_now, excess_after, evidence)
        if gate in values and 'threshold_interval' in augmented.fit.extra:
            low, high = augmented.fit.extra['threshold_interval']
            candidate.explanation += (f' The threshold lies between the input levels {low:.3f} V and {high:.3f} V '
                                      f'present in the data.')
        results.append(candidate)
    results.sort(key=lambda c: (not np.isfinite(c.rms_error), c.rms_error if np.isfinite(c.rms_error) else 0.0))
    significant = [c for c in results if c.significant]
    notes: list[str] = []
    missing = None
    structure: list[dict] = []
    if significant:
        best = significant[0]
        rivals = [c for c in significant[1:] if c.excess_after <= CONFOUNDING_FACTOR * max(best.excess_after,
                                                                                               0.2 * noise)]
        if best.confounded_with:
            # Only this effect explains the error, but its parameter trades off against a nominal one here:
            # name the effect, say the value is uncertain, and which experiment would pin it.
            for nominal in best.confounded_with:
                notes.append(f'the {best.effect} parameter is correlated with {nominal} in this data (correlation '
                             f'> {CORRELATION_LIMIT}), so its value is uncertain; '
                             f'{separating_experiment(best.effect, nominal)}.')
        if rivals:
            verdict = 'confounded'
            names = [best.effect] + [c.effect for c in rivals]
            for rival in rivals:
                best.confounded_with.append(rival.effect)
                notes.append(f'{best.effect} and {rival.effect} explain the data about equally well '
                             f'({best.excess_after * 1e3:.2f} vs {rival.excess_after * 1e3:.2f} mrad beyond the '
                             f'noise); {separating_experiment(best.effect, rival.effect)}.')
            message = f'one of {", ".join(names)} is missing, but this data cannot tell which; see notes.'
        else:
            verdict = 'effect_found'
            missing = best.effect
            message = (f'missing effect: {best.effect}. Add it (--add {best.effect}): the held-out error beyond '
                       f'the noise falls from {best.excess_before * 1e3:.2f} to {best.excess_after * 1e3:.2f} mrad.')
    elif excess_now <= UNEXPLAINED_NOISE * noise:
        verdict = 'nothing_missing'
        message = (f'nothing significant is missing: the model error beyond the measurement noise is '
                   f'{excess_now * 1e3:.2f} mrad against {noise * 1e3:.2f} mrad of noise, and no catalog effect '
                   f'improves the held-out fit significantly.')
    else:
        verdict = 'unexplained'
        structure = residual_structure(prep, current)
        heldout_only = [c for c in results if c.heldout_only]
        if heldout_only:
            # Something explains the held-out error, but the training part cannot confirm it: name it, do not
            # recommend it, and say which data would decide.
            lead = heldout_only[0]
            message = (f'the model misses the held-out data by {excess_now * 1e3:.2f} mrad beyond the noise '
                       f'({noise * 1e3:.2f} mrad). {lead.effect} would explain it ({lead.excess_before * 1e3:.2f} '
                       f'-> {lead.excess_after * 1e3:.2f} mrad) but the training part shows no evidence for it '
                       f'(its BIC does not fall), so it is not recommended: the held-out part holds conditions '
                       f'the training part lacks; {excitation_advice(lead.effect)}.')
            for other in heldout_only[1:]:
                notes.append(f'{other.effect} would also explain the held-out error ({other.excess_after * 1e3:.2f} '
                             f'mrad beyond the noise) without training evidence.')
        else:
            message = (f'the model misses the data by {excess_now * 1e3:.2f} mrad beyond the noise '
                       f'({noise * 1e3:.2f} mrad), and no catalog effect explains it. The residual correlates most '
                       f'with: {structure[0]["signature"]} (r = {structure[0]["correlation"]:+.2f}); consider '
                       f'writing an effect with that signature (aeropend_core.model.effects.register_effect).')
    highest = float(np.max(np.abs(prep.smoothed_angle)))
    if highest > UPRIGHT_WARNING:
        notes.append(f'the rod went {math.degrees(highest):.0f} deg from hanging (above the horizontal'
                     f'{"; past the upright it went over the top" if highest > math.pi else ""}): near the upright '
                     f'position tiny model errors decide which way the rod falls, so the free-run comparison is '
                     f'unreliable there; keep the duty steps below the level that holds the rod at ~85 deg.')
    # Identifiability warnings for effects that could not be seen at all in this data.
    for candidate in results:
        if candidate.confounded_with and not candidate.significant:
            for nominal in candidate.confounded_with:
                notes.append(f'{candidate.effect} cannot be told apart from {nominal} in this data; '
                             f'{separating_experiment(candidate.effect, nominal)}.')
    return Diagnosis(effects=effects, current=current, candidates=results, missing_effect=missing, verdict=verdict,
                     message=message, notes=notes, before=before, residual_structure=structure, prepared=prep,
                     seconds=time.perf_counter() - started)


def format_summary(diagnosis: Diagnosis) -> str:
    """The text report printed by ``aeropend diagnose``."""
    current = diagnosis.current
    noise = current.noise_rms
    lines = []
    model = 'nominal' + ''.join(f' + {e}' for e in diagnosis.effects)
    lines.append(f'Model: {model}')
    lines.append(f'Held-out free-run simulation of the angle: fit {current.fit_percent:.2f} % (NRMSE, MATLAB '
                 f'compare), RMS error {current.rms_error * 1e3:.2f} mrad, measurement noise {noise * 1e3:.2f} mrad, '
                 f'error beyond noise {excess_error(current.rms_error, noise) * 1e3:.2f} mrad')
    lines.append(f'{current.evaluation.prediction_horizon:g} s-ahead prediction RMS error '
                 f'{current.evaluation.prediction_rms * 1e3:.2f} mrad')
    if diagnosis.prepared is not None and diagnosis.prepared.motor is not None:
        motor = diagnosis.prepared.motor
        lines.append(f'Armature current by the motor observer: RMS error {motor.current_rms_error * 1e3:.2f} mA, '
                     f'current noise {motor.current_noise_rms * 1e3:.2f} mA')
    lines.append('Parameters (SI, +- 1 sigma):')
    observer = diagnosis.prepared is not None and diagnosis.prepared.motor is not None
    for name, value in diagnosis.reported_parameters(current).items():
        error = current.fit.standard_errors.get(name, float('nan'))
        found = find_parameter(name)
        unit = NOMINAL_PARAMETERS[name][0] if name in NOMINAL_PARAMETERS else (found[1].unit if found else '')
        if name == 'armature_resistance' and observer:
            lines.append(f'  {name:24s} {value:12.5g} {unit} (from the motor observer fitted to Ia)')
            continue
        lines.append(f'  {name:24s} {value:12.5g} +- {error:9.2g} {unit}')
    if diagnosis.before is not None:
        before = diagnosis.before
        lines.append('Before -> after adding ' + ', '.join(diagnosis.effects) + ':')
        lines.append(f'  fit {before.fit_percent:.2f} % -> {current.fit_percent:.2f} %; error beyond noise '
                     f'{excess_error(before.rms_error, noise) * 1e3:.2f} -> '
                     f'{excess_error(current.rms_error, noise) * 1e3:.2f} mrad')
        for name in NOMINAL_PARAMETERS:
            if name in before.parameters and name in current.parameters and name != 'armature_resistance':
                old, new = before.parameters[name], current.parameters[name]
                lines.append(f'  {name:24s} {old:10.4g} -> {new:10.4g} ({(new - old) / old * 100:+.1f} %)')
        for name, stats in current.evaluation.regimes.items():
            if name in before.evaluation.regimes:
                lines.append(f'  {name}: {before.evaluation.regimes[name]["rms_error"] * 1e3:.1f} -> '
                             f'{stats["rms_error"] * 1e3:.1f} mrad')
    lines.append('Where the model fails (RMS error by regime, mrad; ratio to overall):')
    for name, stats in sorted(current.evaluation.regimes.items(), key=lambda kv: -kv[1]['ratio_to_overall']):
        lines.append(f'  {stats["rms_error"] * 1e3:7.2f}  x{stats["ratio_to_overall"]:.2f}  {name} '
                     f'({stats["fraction_of_samples"] * 100:.0f} % of samples)')
    lines.append('Worst 1-s windows:')
    for window in current.evaluation.worst_windows[:3]:
        lines.append(f'  t = {window["start"]:.1f}-{window["stop"]:.1f} s ({window["part"]}): '
                     f'{window["rms_error"] * 1e3:.2f} mrad, input {window["input"]}')
    lines.append('Candidates (best first):')
    for candidate in diagnosis.candidates:
        if candidate.comparison is None:
            lines.append(f'  {candidate.effect:18s} not testable: {candidate.error}')
            continue
        flag = 'SIGNIFICANT' if candidate.significant else ('held-out' if candidate.heldout_only else 'no')
        params = ', '.join(f'{k} = {v:.4g}' for k, v in candidate.parameters.items())
        lines.append(f'  {candidate.effect:18s} fit {candidate.fit_percent:6.2f} %  beyond noise '
                     f'{candidate.excess_after * 1e3:6.2f} mrad  dBIC {candidate.delta_bic:9.1f}  {flag:11s} '
                     f'{params}')
    lines.append('Verdict: ' + diagnosis.message)
    for note in diagnosis.notes:
        lines.append('Note: ' + note)
    for row in diagnosis.residual_structure:
        lines.append(f'  residual vs {row["signature"]}: r = {row["correlation"]:+.2f}')
    if diagnosis.missing_effect:
        best = next(c for c in diagnosis.candidates if c.effect == diagnosis.missing_effect)
        lines.append('Why: ' + best.explanation)
    lines.append(f'({diagnosis.seconds:.1f} s)')
    return '\n'.join(lines)
