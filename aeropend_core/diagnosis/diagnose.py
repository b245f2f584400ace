"""Which physical effects are missing? Search the catalog for the set that the data supports.

For the current model (nominal + the effects already added with ``--add``/``--fix``) every catalog effect not yet
in it is tried as an augmentation: the model is fitted on the training part (output error,
:mod:`aeropend_core.diagnosis.compare`) and judged on the held-out part. The evidence is valid under correlated
residuals (:mod:`aeropend_core.diagnosis.evidence`). A candidate is **significant** when all of these hold:

* its parameter is nonzero by more than ``T_MIN`` standard errors of the sandwich (HAC) covariance plus what the
  thrust input's own estimation error (the motor observer's) and an angle ADC that does not dither can move it by
  (:func:`~aeropend_core.diagnosis.output_error.fit_output_error`) (a profiled threshold: inside the input range);
* the training BIC, computed with the effective number of independent residuals (from the long-run variance),
  falls by more than ``BIC_MARGIN``;
* the held-out prediction improves: Diebold--Mariano statistic of the squared-error difference with a HAC
  variance above ``DM_MIN`` (above ``DM_WEAK`` when the candidate removes at least ``MAJOR_SHARE`` of the held-out
  error beyond the noise: a short held-out part with slow errors holds few independent pieces of evidence), and
  the held-out mean-square error falls by more than (``MATERIAL`` x noise RMS)^2. A small share of the error
  beyond the noise is no reason to refuse: the nominal model's own misfit that used to pass as an angle offset came
  from the observer and the ADC, which the standard errors now carry (bench/results/2026-11-24-diagnosis-3/offset).

The share is also reported of the error beyond the noise that is measurable: less one standard deviation of the
sampling spread of the two noise powers it is the difference of (:func:`beyond_spread`; at 40 dB with 3,700
held-out residuals about 2.6 % of the noise variance, as much as a 3 mrad offset's whole contribution). It is
reported, not decided on: deciding on it named a 3 mrad offset at 40 dB reliably but also the nominal model's own
misfit on clean records (5 false alarms in 140 against 2 in 140 with the raw share; bench/results/
2026-11-24-diagnosis-2/README.md).

There is no "the model is already within the noise" override: a small effect that the data support strongly is
found and reported with its size and the share of the error it removes ("significant, within the noise").

**Several effects at once** -- forward selection with backward elimination, scored by the same evidence: the
strongest significant candidate (largest BIC drop) is added, the others are tried again on top of it, an effect
that a later one makes redundant is dropped again, until nothing significant remains. Two candidates are reported
as **confounded** only when they are interchangeable on this data (adding either one makes the other
insignificant), with the experiment or hardware value that separates them. When the best set still leaves error
beyond the noise, the verdict says so with the size of the remainder and the residual's structure (outside the
catalog). Nominal parameters are also fitted per segment and tested for a trend (**drift**,
:mod:`aeropend_core.diagnosis.drift`).
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from aeropend_core.diagnosis.candidates import (  # noqa: F401  (re-exported: the evidence's thresholds)
    BIC_MARGIN, CORRELATION_LIMIT, DM_MIN, DM_WEAK, MAJOR_SHARE, MATERIAL, NOISE_ESTIMATE_VARIANCE, T_MIN, Candidate,
    _effect_parameters, _try, assess, beyond_spread)
from aeropend_core.diagnosis.compare import Comparison, PreparedRecord, compare, excess_error, prepare
from aeropend_core.diagnosis.checks import check_diagnosis, misfit_doubt
from aeropend_core.diagnosis.doubts import doubt_notes, rate_doubts, rate_notes, residual_structure, unresolvable
from aeropend_core.errors import AeropendError, InsufficientDataError
from aeropend_core.io.recording import Recording
from aeropend_core.model.effects import CATALOG, THRUST_LAG, get_effect
from aeropend_core.model.effects import separating_experiment as record_experiment
from aeropend_core.model.names import NOMINAL_PARAMETERS

#: "Unexplained" (the best set leaves error no catalog effect explains) is claimed beyond this multiple of the
#: noise RMS: a smaller excess can come from the noise estimate itself (quantisation that does not dither is partly
#: a slow bias).
UNEXPLAINED_NOISE = 0.5
#: Angle [rad] above which the record is flagged: the rod went above the horizontal, towards the unstable upright.
UPRIGHT_WARNING = math.radians(95.0)
#: A significant runner-up is tested for interchangeability with the best when its held-out error beyond the noise
#: is within this factor of the best's.
CONFOUNDING_FACTOR = 1.3
#: Candidates set aside in the first round (no training evidence) are tried again once, on top of the effects found,
#: while the error beyond the noise exceeds this multiple of the noise RMS (an effect masked by others).
RETRY_NOISE = 0.25
#: The discovery stage runs when the best set leaves more than this multiple of the noise RMS beyond the noise (or the
#: set is suspect); its terms must pass the catalog's evidence to be proposed, so running it adds no false alarm.
DISCOVERY_NOISE = 0.25
#: At most this many effects are added by the search.
MAX_EFFECTS = 4
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
class Found:
    """One effect of the selected set, with what it contributes and whether the data can pin it."""

    effect: str
    parameters: dict[str, float]
    standard_errors: dict[str, float]
    excess_before: float
    excess_after: float
    share_removed: float
    t_statistic: float
    dm_statistic: float
    confounded_with: list[str] = field(default_factory=list)
    #: Share of the measurable error beyond the noise it removes (see :func:`beyond_spread`).
    share_measurable: float = float('nan')

    def to_dict(self) -> dict:
        return {'effect': self.effect, 'parameters': self.parameters, 'standard_errors': self.standard_errors,
                'error_beyond_noise_before': _finite(self.excess_before),
                'error_beyond_noise_after': _finite(self.excess_after),
                'share_of_error_removed': _finite(self.share_removed), 't_statistic': _finite(self.t_statistic),
                'dm_statistic': _finite(self.dm_statistic), 'confounded_with': self.confounded_with,
                'share_of_measurable_error_removed': _finite(self.share_measurable)}


@dataclass(frozen=True)
class VerdictFacts:
    """What the verdict says, as typed numbers: the diagnosis decides, :mod:`aeropend_core.present.verdict_text`
    words it (``verdict_of(diagnosis)``). Angles in rad.

    Attributes
    ----------
    verdict : str
        The decision (as :attr:`Diagnosis.verdict` before a failed physical check overrides it).
    found : tuple of Found
        The selected set of catalog effects, in the order the search added them.
    noise_rms, excess_current, excess_final, within_noise, explained_below : float [rad]
        The angle's noise; the held-out error beyond it of the model as given and with the set; an error beyond the
        noise below `within_noise` is "within the noise"; a proven term that leaves more than `explained_below`
        explains only part of the error.
    structure : tuple of dict
        The residual's strongest signatures (``signature``, ``correlation`` [-]).
    drift_text : str
        The drift test's sentence (:func:`aeropend_core.diagnosis.drift.drift_message`), verdict ``'drift'``.
    heldout_only : tuple of Candidate
        Candidates that explain the held-out part without training evidence.
    heldout_advice : str
        The experiment that shows the first of them (the catalog's record).
    discovery, motor : Discovery, MotorDiscovery or None
        The discovery stage's results (pendulum and motor equations).
    reduced_rate_hz : float or None [Hz]
        The rate of a reduced-model record whose own error at that rate is unmeasured.
    prefix : str
        Put before the words: a failed physical check's line (:mod:`aeropend_core.diagnosis.checks`).
    """

    verdict: str
    found: tuple = ()
    noise_rms: float = math.nan
    excess_current: float = math.nan
    excess_final: float = math.nan
    within_noise: float = math.nan
    structure: tuple = ()
    drift_text: str = ''
    heldout_only: tuple = ()
    heldout_advice: str = ''
    discovery: object = None
    explained_below: float = math.inf
    reduced_rate_hz: float | None = None
    motor: object = None
    prefix: str = ''


@dataclass
class Diagnosis:
    """Outcome of :func:`diagnose`. Angles in rad; parameters SI. Its verdict's words:
    :func:`aeropend_core.present.verdict_text.verdict_of` (from :attr:`facts`)."""

    effects: tuple[str, ...]
    current: Comparison
    candidates: list[Candidate]
    missing_effect: str | None
    verdict: str                     # 'nothing_missing' | 'effect_found' | 'confounded' | 'unexplained' | ...
    facts: VerdictFacts
    notes: list[str]
    before: Comparison | None = None
    residual_structure: list[dict[str, float | str]] = field(default_factory=list)
    prepared: PreparedRecord | None = None
    seconds: float = 0.0
    #: The selected set of missing effects, in the order the search added them (confounded ones included).
    found: list[Found] = field(default_factory=list)
    #: The model with the selected set (None when nothing was selected).
    selected: Comparison | None = None
    #: Per-segment drift test of the nominal parameters (:func:`aeropend_core.diagnosis.drift.drift_test`).
    drift: list[dict] = field(default_factory=list)
    #: Parameters held at given values (``--fix``, a calibration file), SI.
    fixed: dict[str, float] = field(default_factory=dict)
    #: Where each held parameter's value came from (``'--fix'``, ``'calibration file PATH'``).
    fixed_from: dict[str, str] = field(default_factory=dict)
    #: Parameters that fail a physical check -> the warning (:mod:`aeropend_core.diagnosis.checks`).
    parameter_warnings: dict[str, str] = field(default_factory=dict)
    independent: object = None      #: the free-oscillation estimate (aeropend_core.identify.plausibility)
    #: The discovery stage's result (:class:`aeropend_core.diagnosis.discovery.Discovery`; None when it did not run).
    discovery: object = None
    #: The motor equation's discovery (:class:`aeropend_core.diagnosis.motor_discovery.MotorDiscovery`; None when the
    #: discovery stage was off).
    motor_discovery: object = None

    @property
    def message(self) -> str:
        """Not here: the diagnosis returns typed results (:attr:`facts`); the words are
        ``aeropend_core.present.verdict_text.verdict_of(diagnosis)``."""
        raise AttributeError('Diagnosis.message: the verdict\'s words are made in present/: use '
                             'aeropend_core.present.verdict_text.verdict_of(diagnosis) (the JSON form: diagnosis_dict)')

    @property
    def missing_effects(self) -> list[str]:
        """Names of the selected effects (those the data pins, then the confounded ones)."""
        return [f.effect for f in self.found]

    @property
    def add_arguments(self) -> str:
        """The single "add these" step for the command line."""
        return ' '.join(f'--add {f.effect}' for f in self.found if not f.confounded_with)

    @property
    def findings(self) -> tuple:
        """The data-quality gate's findings on the record (:mod:`aeropend_core.signals.quality`)."""
        return tuple(self.prepared.findings) if self.prepared is not None else ()

    @property
    def noise_rms(self) -> float:
        return self.current.noise_rms

    def reported_parameters(self, comparison: Comparison) -> dict[str, float]:
        """Fitted parameters in SI; with the motor observer, `armature_resistance` is the observer's fitted Rm; the
        reduced model has none and adds its motor map (:mod:`aeropend_core.signals.reduced`)."""
        return self.reported_errors(comparison, values=True)

    def reported_errors(self, comparison: Comparison, values: bool = False) -> dict[str, float]:
        """1σ of :meth:`reported_parameters` (SI); ``values=True``: the parameters themselves."""
        prep = self.prepared
        if prep is not None and prep.reduced:
            from aeropend_core.diagnosis.reduced_fit import reduced_parameters
            return reduced_parameters(prep, comparison)[0 if values else 1]
        out = dict(comparison.parameters if values else comparison.fit.standard_errors)
        if prep is not None and prep.motor is not None:     # a value from the motor observer carries the observer's σ
            out['armature_resistance'] = (prep.motor.parameters if values else prep.motor.standard_errors).get(
                'motor_resistance', math.nan)
        return out

    @property
    def final(self) -> Comparison:
        """The model with the selected set (the current model when nothing was selected)."""
        return self.selected if self.selected is not None else self.current

    def estimators(self, comparison: Comparison) -> dict[str, str]:
        """Which estimator gave each reported parameter (``output_error``, or ``motor_observer`` for R)."""
        estimators = dict.fromkeys(comparison.parameters, 'output_error')
        if self.prepared is not None and self.prepared.motor is not None:
            estimators['armature_resistance'] = 'motor_observer'
        return estimators

    def to_dict(self) -> dict:
        """The machine-readable numbers of ``aeropend diagnose --json`` (the verdict's words are added by
        :func:`aeropend_core.present.verdict_text.diagnosis_dict`)."""
        current = self.current
        result = {
            'model_effects': list(self.effects),
            'fit_percent': _finite(current.fit_percent),
            'fit_definition': 'held-out free-run simulation of the angle, NRMSE fit % as MATLAB compare',
            'rms_error': _finite(current.rms_error), 'noise_rms': _finite(current.noise_rms),
            'error_beyond_noise': _finite(excess_error(current.rms_error, current.noise_rms)),
            'prediction_rms_error': _finite(current.evaluation.prediction_rms),
            'prediction_horizon': current.evaluation.prediction_horizon,
            'parameters': self.reported_parameters(current),
            'standard_errors': self.reported_errors(current), 'parameter_warnings': self.parameter_warnings,
            'parameters_doubt': misfit_doubt(self),
            'model': 'reduced' if self.prepared is not None and self.prepared.reduced else 'full',
            'not_identifiable': _not_identifiable(self.prepared),
            'motor_map': getattr(self.prepared, 'motor_map', None),
            'free_oscillation': self.independent.to_dict() if self.independent is not None else None,
            'estimator': 'output_error', 'estimators': self.estimators(current),
            'parameter_rate_doubts': rate_doubts(getattr(self.prepared, 'sample_time', None),
                                                 getattr(self.prepared, 'reduced', False)),
            'missing_effect': self.missing_effect,
            'verdict': self.verdict,
            'notes': self.notes,
            'missing_effects': [f.to_dict() for f in self.found],
            'add': [f.effect for f in self.found if not f.confounded_with],
            'remaining_error_beyond_noise': _finite(excess_error(self.final.rms_error, self.final.noise_rms)),
            'discovered_terms': [t.to_dict() for t in self.discovery.proven] if self.discovery is not None else [],
            'discovery': self.discovery.to_dict() if self.discovery is not None else None,
            'discovered_motor_terms': ([t.to_dict() for t in self.motor_discovery.proven]
                                       if self.motor_discovery is not None else []),
            'motor_discovery': self.motor_discovery.to_dict() if self.motor_discovery is not None else None,
            'drift': self.drift,
            'gaps': self.prepared.gaps.to_dict() if self.prepared is not None and self.prepared.gaps is not None
            else None,
            'fixed': self.fixed,
            'fixed_from': self.fixed_from,
            'candidates': [_candidate_dict(c) for c in self.candidates],
            'regimes': current.evaluation.regimes,
            'worst_windows': current.evaluation.worst_windows,
            'residual_structure': self.residual_structure,
            'seconds': round(self.seconds, 2),
            'warnings': [finding.to_dict() for finding in self.findings],
        }
        if self.prepared is not None:        # a time constant below one sample is marked, not taken as a size
            for entry in result['candidates']:
                entry['not_resolvable_at_this_rate'] = unresolvable(entry['effect'], entry['parameters'] or {},
                                                                    self.prepared.sample_time)
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


def _not_identifiable(prep) -> dict[str, str]:
    """What the model of `prep` cannot identify (the reduced model's list; empty for the full model)."""
    from aeropend_core.signals.reduced import NOT_IDENTIFIABLE
    return dict(NOT_IDENTIFIABLE) if prep is not None and prep.reduced else {}


def _finite(value: float) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


def _candidate_dict(candidate: Candidate) -> dict:
    return {'effect': candidate.effect, 'parameters': candidate.parameters,
            'standard_errors': candidate.standard_errors, 'fit_percent': _finite(candidate.fit_percent),
            'rms_error': _finite(candidate.rms_error), 'error_beyond_noise': _finite(candidate.excess_after),
            'delta_bic': _finite(candidate.delta_bic), 'significant': candidate.significant,
            'confounded_with': candidate.confounded_with, 'evidence': candidate.evidence,
            'explanation': candidate.explanation, 'error': candidate.error,
            'heldout_only': candidate.heldout_only, 't_statistic': _finite(candidate.t_statistic),
            'dm_statistic': _finite(candidate.dm_statistic), 'mse_gain': _finite(candidate.mse_gain),
            'share_of_error_removed': _finite(candidate.share_removed),
            'share_of_measurable_error_removed': _finite(candidate.share_measurable)}


def _interchangeable(prep: PreparedRecord, model: tuple[str, ...], best: Candidate, rival: Candidate,
                     fixed: Mapping[str, float]) -> bool:
    """True when adding either one makes the other insignificant (on this data they explain the same thing)."""
    try:
        both = compare(prep, model + (best.effect, rival.effect), start={**rival.comparison.parameters,
                                                                          **best.comparison.parameters},
                       fixed=dict(fixed))
    except InsufficientDataError:
        return True
    rival_over_best = assess(prep, best.comparison, both, rival.effect)
    best_over_rival = assess(prep, rival.comparison, both, best.effect)
    return not rival_over_best.significant and not best_over_rival.significant


def _judge_pair(prep: PreparedRecord, model: tuple[str, ...], final: Comparison, chosen: str, rival: str,
                fixed: Mapping[str, float]) -> str:
    """On the final model (which holds `chosen`): 'interchangeable' (adding both adds nothing over either),
    'both' (the rival is significant on top of it) or 'chosen' (the data prefer the chosen one)."""
    try:
        both = compare(prep, model + (rival,), start=final.parameters, fixed=dict(fixed))
        swapped = compare(prep, tuple(n for n in model if n != chosen) + (rival,), start=final.parameters,
                          fixed=dict(fixed))
    except InsufficientDataError:
        return 'interchangeable'
    if assess(prep, final, both, rival).significant:
        return 'both'
    if assess(prep, swapped, both, chosen).significant:
        return 'chosen'
    return 'interchangeable'


def diagnose(recording: Recording | PreparedRecord, effects: Sequence[str] = (),
             candidates: Sequence[str] | None = None,
             progress: Callable[[str], None] | None = None,
             fixed: Mapping[str, Mapping[str, float] | float] | None = None,
             drift: bool = True, fixed_from: Mapping[str, str] | None = None, discovery: bool = True) -> Diagnosis:
    """Diagnose which effects are missing from nominal + `effects`, using only Va, Ia and the angle.

    Parameters
    ----------
    recording : Recording or PreparedRecord [-]
        At least 20 s of samples with ``armature_voltage`` [V], ``armature_current`` [A], ``angle`` [rad].
    effects : sequence of str [-]
        Effects already in the model (``--add``). The result also compares with the model without them.
    candidates : sequence of str, optional [-]
        Effects to try (default: every catalog effect not in `effects`, users' registered ones included).
    progress : callable, optional [-]
        Called with a short message before each fit.
    fixed : mapping of str -> float or mapping, optional [SI unit of each parameter]
        Effects with known parameter values (``--fix``): ``{effect: value}`` or ``{effect: {parameter: value}}``.
        They join the model with those values held.
    drift : bool [-]
        Also fit the nominal parameters per segment and test them for a trend.
    fixed_from : mapping of str -> str, optional [-]
        Where each fixed effect's values came from (``{effect: 'calibration file PATH'}``), reported next to the
        numbers; default ``'--fix'``.
    discovery : bool [-]
        Run the discovery stage (:mod:`aeropend_core.diagnosis.discovery`) when the best catalog set leaves error
        beyond the noise or is suspect: a term outside the catalog, proven by the same evidence.

    Returns
    -------
    Diagnosis
        The current model's comparison, every candidate (best first) and the verdict: ``missing_effects`` (the
        set to add), ``verdict``, ``facts`` (the verdict's numbers, worded by
        :func:`aeropend_core.present.verdict_text.verdict_of`) and ``notes``; angles in rad, parameters SI.
    """
    from aeropend_core.diagnosis.drift import drift_message, drift_test
    from aeropend_core.diagnosis.long_record import fit_on_all, search_record
    from aeropend_core.model.effects import resolve_effects
    started = time.perf_counter()
    say = progress or (lambda message: None)
    fixed_effects = resolve_effects(fixed)
    effects = tuple(effects) + tuple(name for name in fixed_effects if name not in effects)
    for name in effects:
        get_effect(name)
    if len(set(effects)) != len(effects):
        raise AeropendError(f'an effect is listed twice in {list(effects)}')
    held = {parameter: value for values in fixed_effects.values() for parameter, value in values.items()}
    held_from = {parameter: (fixed_from or {}).get(name, '--fix') for name, values in fixed_effects.items()
                 for parameter in values}
    say('preparing the data (input conditioning, motor observer)')
    prep = recording if isinstance(recording, PreparedRecord) else prepare(recording)
    search, subset = search_record(prep)       # a long record: the search on a subset of segments (module doc)
    say(f'fitting the current model: nominal{"".join(" + " + e for e in effects)}')
    current = compare(search, effects, fixed=held)
    before = None
    if effects:
        say('fitting the model without the added effects (for before -> after)')
        before = compare(search, ())
    noise = prep.noise_rms
    pool = [name for name in (candidates if candidates is not None else CATALOG) if name not in effects
            and (candidates is not None or not name.startswith('term_'))     # discovered terms: the discovery's
            and not (prep.reduced and get_effect(name).kind == THRUST_LAG)]   # the motor map's lag carries it
    for name in pool:
        get_effect(name)
    # ---- forward selection with backward elimination, scored by the same evidence
    def masking_possible(comparison: Comparison) -> bool:
        # set-aside candidates are tried again only while error beyond the noise remains to be explained
        return excess_error(comparison.rms_error, noise) > RETRY_NOISE * noise

    model, base = effects, current
    steps: list[tuple[Candidate, list[str]]] = []     # (the added candidate, what it is confounded with)
    first_round: list[Candidate] = []
    hopeless: set[str] = set()
    interchangeable: set[str] = set()
    retried = False
    notes: list[str] = []
    for round_index in range(2 * MAX_EFFECTS):
        if len(steps) >= MAX_EFFECTS:
            break
        remaining = [n for n in pool if n not in model and n not in hopeless]
        if not remaining and steps and not retried and hopeless - interchangeable and masking_possible(base):
            retried = True          # an effect can be masked while others are missing: try the set-aside again
            hopeless = set(interchangeable)
            remaining = [n for n in pool if n not in model and n not in hopeless]
        if not remaining:
            break
        tried: list[Candidate] = []
        for index, name in enumerate(remaining, 1):
            say(f'[round {round_index + 1}, {index}/{len(remaining)}] trying {name}')
            tried.append(_try(search, base, model, name, held))
        if round_index == 0:
            first_round = tried
        # a candidate without training evidence (BIC not lower by the margin) is not tried again in later rounds
        hopeless.update(c.effect for c in tried if not (np.isfinite(c.delta_bic) and c.delta_bic < -BIC_MARGIN))
        significant = sorted((c for c in tried if c.significant), key=lambda c: -c.strength)
        if not significant:
            # An effect can be masked while others are missing: once, try the set-aside candidates again.
            if steps and not retried and hopeless - interchangeable and masking_possible(base):
                retried = True
                hopeless = set(interchangeable)
                continue
            break
        best = significant[0]
        confounded = []
        for rival in significant[1:]:
            close = rival.excess_after <= CONFOUNDING_FACTOR * max(best.excess_after, 0.2 * noise)
            if close and _interchangeable(search, model, best, rival, held):
                confounded.append(rival.effect)
        say(f'adding {best.effect}')
        model, base = model + (best.effect,), best.comparison
        steps.append((best, confounded))
        hopeless.update(confounded)     # interchangeable with one in the model: adds nothing over it
        interchangeable.update(confounded)
        # backward elimination: an effect added earlier that the new one makes redundant is dropped
        for earlier, _ in list(steps[:-1]):
            if earlier.effect not in model:
                continue
            reduced_model = tuple(n for n in model if n != earlier.effect)
            say(f'checking {earlier.effect} is still needed')
            try:
                reduced = compare(search, reduced_model, start=base.parameters, fixed=dict(held))
            except InsufficientDataError:
                continue
            if not assess(search, reduced, base, earlier.effect).significant:
                notes.append(f'{earlier.effect} was dropped again: with {best.effect} in the model it adds nothing '
                             f'significant.')
                model, base = reduced_model, reduced
                steps = [(c, g) for c, g in steps if c.effect != earlier.effect]
    # Confounding judged in an early round, with other effects still missing, is judged again on the final model.
    for position, (chosen, rivals) in enumerate(steps):
        still = []
        for rival_name in rivals:
            if rival_name in model:
                continue
            say(f'checking whether {chosen.effect} and {rival_name} are interchangeable')
            verdict = _judge_pair(search, model, base, chosen.effect, rival_name, held)
            if verdict == 'interchangeable':
                still.append(rival_name)
            elif verdict == 'both':
                rival = _try(search, base, model, rival_name, held)
                model, base = model + (rival_name,), rival.comparison
                steps.append((rival, []))
        steps[position] = (chosen, still)
    if prep.reduced and steps:      # the motor map was profiled on the nominal model: again with the effects found
        from aeropend_core.diagnosis.reduced_fit import reprofile_and_recheck
        say(f'profiling the motor map again with {", ".join(model)}')
        prep, search, subset, model, base, dropped = reprofile_and_recheck(prep, model, base, held, search_record)
        steps, notes = [(c, g) for c, g in steps if c.effect in model], notes + dropped
    results = first_round
    results.sort(key=lambda c: (not np.isfinite(c.rms_error), c.rms_error if np.isfinite(c.rms_error) else 0.0))
    if subset is not None:
        say('fitting the chosen model on every training segment')
        base = fit_on_all(prep, subset, model, base, held)
        current = current if steps else base
        notes.append(subset.note(' + '.join(('nominal',) + model)))
    selected = base if steps else None
    final = base
    found: list[Found] = []
    for candidate, confounded in steps:
        values, errors = _effect_parameters(final, candidate.effect)
        found.append(Found(candidate.effect, values, errors, candidate.excess_before, candidate.excess_after,
                           candidate.share_removed, candidate.t_statistic, candidate.dm_statistic,
                           confounded_with=list(confounded), share_measurable=candidate.share_measurable))
    # ---- drift of the nominal parameters (per segment, trend test)
    drift_rows: list[dict] = []
    if drift:
        say('testing the nominal parameters for drift (per-segment fits)')
        try:
            drift_rows = drift_test(prep, final)
        except InsufficientDataError as error:
            notes.append(f'drift not tested: {error}')
    drifting = [row for row in drift_rows if row['drifting']]
    # ---- verdict
    excess_final = excess_error(final.rms_error, noise)
    # quantisation without dither (a slow signal, little noise) leaves an error up to step/sqrt(12) that the noise
    # estimate does not see: the remainder must exceed that too
    # (counted on top of the noise estimate: conservative for the claim that something is missing), and an error
    # within half an encoder count is no evidence: the reference is at least half a count
    quantisation = prep.angle_step ** 2 / 12.0
    reference = max(noise, 0.5 * prep.angle_step)
    remainder = final.rms_error ** 2 - noise ** 2 - quantisation > (UNEXPLAINED_NOISE * reference) ** 2
    structure: list[dict] = []
    found_terms = None
    # ---- discovery: a term outside the catalog, when the best set leaves error beyond the noise or is suspect
    suspect = any(f.confounded_with for f in found) or any(n for c, _ in steps for n in c.confounded_with)
    if discovery and (excess_final > DISCOVERY_NOISE * reference or suspect):
        from aeropend_core.diagnosis.discovery import discover
        catalog_set = tuple(f.effect for f in found)
        found_terms = discover(prep, final, model, held, catalog_set, current if catalog_set else None, say)
    # ---- discovery in the motor equation, where the armature current is measured (records without it: said so)
    motor_terms = None
    if discovery:
        from aeropend_core.diagnosis.motor_discovery import discover_motor
        motor_terms = discover_motor(prep, say)
        if motor_terms.proven:
            from aeropend_core.diagnosis.motor_discovery import pendulum_with_term
            say('discovery: refitting the pendulum with the thrust input of the corrected motor observer')
            pendulum_with_term(prep, motor_terms.proven[0], model, held, excess_final)
    proven = found_terms.proven if found_terms is not None else []
    # a proven term is the verdict only when it explains the error (what it leaves is within the noise's reach)
    proven = [t for t in proven if t.excess_after <= UNEXPLAINED_NOISE * reference]
    pinned = [f for f in found if not f.confounded_with]
    unsure = [f for f in found if f.confounded_with]
    missing = pinned[0].effect if pinned else None
    heldout_only: list[Candidate] = []
    # the decision; its wording is aeropend_core.present.verdict_text's
    if drifting:
        verdict = 'drift'
    elif proven and (remainder or not found or proven[0].replaces):
        verdict = 'term_discovered'
    elif found and remainder:
        verdict = 'unexplained'
        structure = residual_structure(prep, final)
        missing = None
    elif unsure:
        verdict = 'confounded'
        for f in unsure:
            for other in f.confounded_with:
                notes.append(f'{f.effect} and {other} are interchangeable on this data (adding either makes the other '
                             f'insignificant); {separating_experiment(f.effect, other)}.')
    elif found:
        verdict = 'effect_found'
    elif not remainder:
        verdict = 'nothing_missing'
    else:
        verdict = 'unexplained'
        structure = residual_structure(prep, current)
        heldout_only = [c for c in results if c.heldout_only]
        for other in heldout_only[1:]:
            notes.append(f'{other.effect} would also explain the held-out error ({other.excess_after * 1e3:.2f} '
                         f'mrad beyond the noise) without training evidence.')
    motor_best = motor_terms.proven[0] if motor_terms is not None and motor_terms.proven else None
    if motor_best is not None and (verdict == 'nothing_missing' or (
            verdict == 'unexplained' and motor_best.pendulum_excess_after <= UNEXPLAINED_NOISE * reference)):
        # the motor equation misses a term, and with it the pendulum is within the noise (or was already)
        verdict, missing = 'term_discovered', None
    if found_terms is not None and verdict == 'effect_found' and any(t.status == 'confounded'
                                                                   for t in found_terms.terms):
        verdict = 'confounded'      # a term outside the catalog explains the data as well as the set chosen
    reduced_rate = (1.0 / prep.sample_time if verdict == 'unexplained' and getattr(prep, 'reduced', False)
                    and rate_doubts(prep.sample_time, True) else None)
    facts = VerdictFacts(
        verdict, found=tuple(found), noise_rms=noise, excess_current=excess_error(current.rms_error, noise),
        excess_final=excess_final, within_noise=UNEXPLAINED_NOISE * noise, structure=tuple(structure),
        drift_text=drift_message(drifting, final) if drifting else '', heldout_only=tuple(heldout_only),
        heldout_advice=excitation_advice(heldout_only[0].effect) if heldout_only else '', discovery=found_terms,
        explained_below=UNEXPLAINED_NOISE * reference, reduced_rate_hz=reduced_rate, motor=motor_terms)
    if found and verdict in ('effect_found', 'confounded'):
        for f in found:
            step = next(c for c, _ in steps if c.effect == f.effect)
            for nominal in step.confounded_with:
                notes.append(f'the {f.effect} parameter is correlated with {nominal} in this data (correlation '
                             f'> {CORRELATION_LIMIT}), so its value is uncertain; '
                             f'{separating_experiment(f.effect, nominal)}.')
    highest = float(np.max(np.abs(prep.smoothed_angle)))
    if highest > UPRIGHT_WARNING:
        notes.append(f'the rod went {math.degrees(highest):.0f} deg from hanging (above the horizontal'
                     f'{"; past the upright it went over the top" if highest > math.pi else ""}): near the upright '
                     f'position tiny model errors decide which way the rod falls, so the free-run comparison is '
                     f'unreliable there; keep the duty steps below the level that holds the rod at ~85 deg.')
    # Effects not seen at all in this data (only when none was found: the first round was tried on this model).
    for candidate in results if not found else ():
        if candidate.confounded_with and not candidate.significant and candidate.effect not in model:
            for nominal in candidate.confounded_with:
                notes.append(f'{candidate.effect} cannot be told apart from {nominal} in this data; '
                             f'{separating_experiment(candidate.effect, nominal)}.')
    notes += doubt_notes(results, found, current, prep, model)     # near misses, an unstated measurement chain
    notes += rate_notes(found, prep.sample_time)                  # what this sample rate cannot resolve
    if getattr(prep, 'gaps', None) is not None and prep.gaps.count:
        notes.append(prep.gaps.describe())
    return check_diagnosis(Diagnosis(
        effects=effects, current=current, candidates=results, missing_effect=missing, verdict=verdict,
        facts=facts, notes=notes, before=before, residual_structure=structure, prepared=prep,
        seconds=time.perf_counter() - started, found=found, selected=selected, drift=drift_rows, fixed=held,
        fixed_from=held_from, discovery=found_terms, motor_discovery=motor_terms))

