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

:func:`diagnose` composes the stages of :mod:`aeropend_core.diagnosis.stages` (prepare -> compare -> catalog search ->
discovery -> drift -> verdict), each a function with a typed result (docs/pipeline.md). When the motor equation's
discovery proves a term, the compare, catalog-search and pendulum-discovery stages run again on the thrust input
rebuilt with it: a set chosen on the uncorrected input is the motor term's shadow.
"""
from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from aeropend_core.blas import single_blas_thread
from aeropend_core.diagnosis.candidates import (  # noqa: F401  (re-exported: the evidence's thresholds)
    BIC_MARGIN, CORRELATION_LIMIT, DM_MIN, DM_WEAK, MAJOR_SHARE, MATERIAL, NOISE_ESTIMATE_VARIANCE, T_MIN, Candidate,
    assess, beyond_spread)
from aeropend_core.diagnosis.checks import check_diagnosis, misfit_doubt
from aeropend_core.diagnosis.compare import Comparison, PreparedRecord, excess_error
from aeropend_core.diagnosis.doubts import rate_doubts, unresolvable
from aeropend_core.diagnosis.stages import (  # noqa: F401  (re-exported: the search's constants and Found)
    CONFOUNDING_FACTOR, DEFAULT_EXPERIMENT, DISCOVERY_NOISE, MAX_EFFECTS, RETRY_NOISE, UNEXPLAINED_NOISE,
    UPRIGHT_WARNING, Found, VerdictFacts, _finite, catalog_stage, compare_stage, discovery_stage, drift_stage,
    excitation_advice, prepare_stage, rerun_on_corrected_input, separating_experiment, verdict_stage)
from aeropend_core.diagnosis.friction_doubt import widen_for_friction_shape, widen_found
from aeropend_core.diagnosis.model_doubt import beside_lookalikes, beyond_doubt, widen_for_remainder
from aeropend_core.diagnosis.remainder import Remainder, remainder_of
from aeropend_core.diagnosis.remainder_doubt import remainder_dict, widen_for_slow_remainder
from aeropend_core.diagnosis.state_map import StateMap, state_map
from aeropend_core.diagnosis.verdicts import Verdict
from aeropend_core.io.recording import Recording
from aeropend_core.model.effects import catalog_scope, kernel_parameter

#: The ``schema`` key of a diagnosis's JSON (``aeropend diagnose --json``, ``aeropend run --json``'s
#: ``diagnosis``, the ``.diagnosis.json`` saved beside a bag): its name and version, raised when a key changes
#: meaning or goes away.
DIAGNOSIS_SCHEMA = 'aeropend.diagnosis/1'

if TYPE_CHECKING:       # annotations only (imported where their stage runs)
    from aeropend_core.diagnosis.discovery import Discovery
    from aeropend_core.diagnosis.motor_discovery import MotorDiscovery
    from aeropend_core.identify.plausibility import FreeOscillation


@dataclass
class Diagnosis:
    """Outcome of :func:`diagnose`. Angles in rad; parameters SI. Its verdict's words:
    :func:`aeropend_core.present.verdict_text.verdict_of` (from :attr:`facts`); its JSON form
    :func:`aeropend_core.present.verdict_text.diagnosis_dict`; its text
    :func:`aeropend_core.present.summary.format_summary`.

    Made by :func:`diagnose`, not by hand (the example of :mod:`aeropend_core` runs one).

    Parameters
    ----------
    effects : tuple of str [-]
        Effects in the model as given (``--add``).
    current : Comparison [-]
        That model fitted and judged on the held-out part (fit %, RMS error [rad]).
    candidates : list of Candidate [-]
        Every catalog effect tried, best first, with its evidence.
    missing_effect : str or None [-]
        The one effect to add, when the data pin exactly one.
    verdict : Verdict [-]
        What it concluded (a ``str`` too: ``'effect_found'``, ``'nothing_missing'``, ...).
    facts : VerdictFacts [-]
        The verdict's numbers (errors [rad], shares), worded in present/.
    notes : list of str [-]
        Notes said under the verdict.
    before : Comparison or None [-]
        The nominal model, when the model as given has effects.
    residual_structure : list of dict [-]
        Structure left in the residual (lags [s], correlations [-]) when the error is unexplained.
    prepared : PreparedRecord or None [-]
        The conditioned record (noise RMS [rad], sample time [s], training and held-out parts).
    seconds : float [s]
        Wall-clock time of the diagnosis.
    found : list of Found [-]
        The selected set of missing effects, in the order the search added them (confounded ones included).
    selected : Comparison or None [-]
        The model with the selected set (None when nothing was selected).
    drift : list of dict [-]
        Per-segment drift test of the nominal parameters (:func:`aeropend_core.diagnosis.drift.drift_test`).
    fixed : dict of str -> float [SI unit of each parameter]
        Parameters held at given values (``--fix``, a calibration file).
    fixed_from : dict of str -> str [-]
        Where each held parameter's value came from (``'--fix'``, ``'calibration file PATH'``).
    parameter_warnings : dict of str -> str [-]
        Parameters that fail a physical check -> the warning (:mod:`aeropend_core.diagnosis.checks`).
    parameter_doubts : dict of str -> str [-]
        Doubts on parameters the fit cannot check itself -> the text, said beside the number.
    independent : FreeOscillation or None [-]
        The free-oscillation estimate (:mod:`aeropend_core.identify.plausibility`; frequency [rad/s]).
    discovery : Discovery or None [-]
        The discovery stage's result: terms outside the catalog (None when it did not run).
    motor_discovery : MotorDiscovery or None [-]
        The motor equation's discovery (None when the discovery stage was off).
    state_map, state_map_selected : StateMap or None [-]
        Where the model given, and the model with the selected set, fail in the state space: the missing angular
        acceleration [rad/s^2] by angle band [rad], direction of motion and thrust (:mod:`.state_map`).
    remainder : Remainder or None [-]
        What the final model leaves unexplained: RMS beyond the noise [rad], correlation time [s], median
        frequency [Hz] (:mod:`.remainder`).
    """

    effects: tuple[str, ...]
    current: Comparison
    candidates: list[Candidate]
    missing_effect: str | None
    verdict: Verdict                 #: what it concluded (a str too: 'effect_found', 'nothing_missing', ...)
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
    #: Doubts on parameters the fit cannot check itself -> the text (a current's scale on Ra:
    #: :func:`aeropend_core.diagnosis.checks.scale_doubts`); said beside the number, not a failed check.
    parameter_doubts: dict[str, str] = field(default_factory=dict)
    independent: FreeOscillation | None = None      #: the free-oscillation estimate (identify/plausibility)
    #: The discovery stage's result (:class:`aeropend_core.diagnosis.discovery.Discovery`; None when it did not run).
    discovery: Discovery | None = None
    #: The motor equation's discovery (:class:`aeropend_core.diagnosis.motor_discovery.MotorDiscovery`; None when the
    #: discovery stage was off).
    motor_discovery: MotorDiscovery | None = None
    #: Where the model fails in the state space (:class:`aeropend_core.diagnosis.state_map.StateMap`): the missing
    #: acceleration of the model given, and of the model with the selected set (None when nothing was selected).
    state_map: StateMap | None = None
    state_map_selected: StateMap | None = None
    #: What the final model leaves unexplained: size, correlation time, spectrum
    #: (:class:`aeropend_core.diagnosis.remainder.Remainder`).
    remainder: Remainder | None = None

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
        if not values:      # a parameter on a bound of its range is not determined: no finite sigma to claim
            from aeropend_core.identify.plausibility import pinned_at_bound
            out.update({name: math.inf for name, value in comparison.parameters.items()
                        if name in out and pinned_at_bound(name, value)})
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

    # ---- the result presents itself: each method imports its words from present/ when called (present/ imports
    # this class for annotations only, so the import graph has no circle; docs/architecture.md)
    def summary(self) -> dict:
        """The diagnosis on one screen: verdict, plain sentence, model, held-out fit and errors.

        Returns
        -------
        dict
            ``verdict`` and ``plain`` [-], ``model`` [-], ``fit_percent`` [%], ``rms_error_rad``,
            ``noise_rms_rad``, ``error_beyond_noise_rad`` [rad], ``missing_effects`` and ``add`` [-] (the
            effects to add on the command line), ``parameters`` (SI) with ``standard_errors`` (1 sigma, SI).
            The package example (:mod:`aeropend_core`) runs it.
        """
        from aeropend_core.present.verdict_text import diagnosis_summary
        return diagnosis_summary(self)

    def as_text(self, source: str | None = None) -> str:
        """What ``aeropend diagnose`` prints (the text summary; `source`, the record's name, goes into the next
        command the verdict suggests). The package example (:mod:`aeropend_core`) runs it."""
        from aeropend_core.present.summary import format_summary
        return format_summary(self, source)

    def as_html(self, source: str | None = None, validation=None) -> str:
        """The self-contained HTML report (one page, plots and data embedded, no external link) as a string;
        :func:`aeropend_core.present.report.write_report` writes it to a file. `validation`: a
        :class:`~aeropend_core.diagnosis.validation.Validation` on a second record (its own section). The package
        example (:mod:`aeropend_core`) runs it."""
        from aeropend_core.present.report import render_report
        return render_report(self, source, validation)

    def to_dict(self) -> dict:
        """Exactly what ``aeropend diagnose --json`` prints (one record, no ``--start``/``--stop``/``--validate``):
        :meth:`numbers_dict` with the verdict's ``plain`` sentence and its ``message`` after ``verdict``. Plain
        Python types; NaN where a number is unknown (the CLI writes it as null). The package example runs it."""
        from aeropend_core.present.verdict_text import diagnosis_dict
        return diagnosis_dict(self)

    def numbers_dict(self) -> dict:
        """The machine-readable numbers of the diagnosis without the verdict's words (:meth:`to_dict` adds them;
        ``aeropend run --json``'s ``diagnosis`` is this)."""
        current = self.current
        result = {
            'schema': DIAGNOSIS_SCHEMA,
            'model_effects': list(self.effects),
            'fit_percent': _finite(current.fit_percent),
            'fit_definition': 'held-out free-run simulation of the angle, NRMSE fit % as MATLAB compare',
            'rms_error': _finite(current.rms_error), 'noise_rms': _finite(current.noise_rms),
            'error_beyond_noise': _finite(excess_error(current.rms_error, current.noise_rms)),
            'prediction_rms_error': _finite(current.evaluation.prediction_rms),
            'prediction_horizon': current.evaluation.prediction_horizon,
            'parameters': self.reported_parameters(current),
            'standard_errors': self.reported_errors(current), 'parameter_warnings': self.parameter_warnings,
            'parameters_doubt': misfit_doubt(self), 'parameter_doubts': self.parameter_doubts,
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
            'state_map': {'model': self.state_map.to_dict() if self.state_map is not None else None,
                          'with_selected': (self.state_map_selected.to_dict()
                                            if self.state_map_selected is not None else None)},
            'remainder': self.remainder.to_dict() if self.remainder is not None else None,
            'slow_remainder': {'model': remainder_dict(current), 'with_selected': remainder_dict(self.selected)},
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
            if motor.kept_against_fallback:     # beyond 1.5x the noise, kept as the better thrust voltage
                result['signal_errors']['armature_current']['kept_against_fallback'] = {
                    'observer_voltage_error_bound': _finite(motor.voltage_error_bound),
                    'fallback_voltage_error': _finite(motor.fallback_voltage_error), 'unit': 'V'}
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
        beyond the noise or is suspect: a term outside the catalog, proven by the same evidence; and the motor
        equation's (:mod:`aeropend_core.diagnosis.motor_discovery`), whose proven term rebuilds the thrust input
        the rest of the diagnosis is run on again.

    Returns
    -------
    Diagnosis
        The current model's comparison, every candidate (best first) and the verdict: ``missing_effects`` (the
        set to add), ``verdict``, ``facts`` (the verdict's numbers, worded by
        :func:`aeropend_core.present.verdict_text.verdict_of`) and ``notes``; angles in rad, parameters SI.
    """
    # small matrices: BLAS's own threads only wait on a busy machine; the discovery stage's term_* effects are
    # registered for this diagnosis only (its result carries what it found), so no analysis changes the next one's
    with single_blas_thread(), catalog_scope():
        return _diagnose(recording, effects, candidates, progress, fixed, drift, fixed_from, discovery)


def _widen_for_friction_shape(catalog, say):
    """(`catalog` with the current and selected models' ± widened by the dry-friction law's doubt, the notes):
    :mod:`aeropend_core.diagnosis.friction_doubt`, two refits per model that has dry friction."""
    if not any(kernel_parameter(c.effects, 'rate_sign') for c in (catalog.current, catalog.selected) if c):
        return catalog, []
    say('refitting with the dry-friction law\'s shape varied (its doubt joins the +-)')
    current, notes = widen_for_friction_shape(catalog.prep, catalog.current)
    selected, selected_notes = (current, []) if catalog.selected is catalog.current else \
        widen_for_friction_shape(catalog.prep, catalog.selected)
    return dataclasses.replace(
        catalog, current=current, selected=selected, final=selected if selected is not None else current,
        found=tuple(widen_found(list(catalog.found), selected))), notes + selected_notes

def _diagnose(recording, effects, candidates, progress, fixed, drift, fixed_from, discovery) -> Diagnosis:
    """The stages of :func:`diagnose` (same arguments), run in order."""
    started = time.perf_counter()
    say = progress or (lambda message: None)
    prepared = prepare_stage(recording, effects, candidates, fixed, fixed_from, say)
    compared = compare_stage(prepared, say)
    catalog = catalog_stage(prepared, compared, say)
    discovered = discovery_stage(prepared, catalog, discovery, say)
    rerun = rerun_on_corrected_input(prepared, catalog, discovered, say)
    if rerun is not None:       # a proven motor term: the stages again on the thrust input rebuilt with it
        prepared, compared, catalog, discovered = rerun.prepared, rerun.compared, rerun.catalog, rerun.discovered
    # with dry friction in the model, every +- carries how far the parameters move with the friction law's shape
    catalog, friction_notes = _widen_for_friction_shape(catalog, say)
    # beside a remainder the discovery stage refitted terms for, the selected effects' +- carry the model doubt
    widened, doubt_notes = widen_for_remainder(list(catalog.found), discovered.pendulum)
    if catalog.remainder:       # beside a remainder: an effect the doubt puts within T_MIN sigma of zero is not named
        widened, unnamed = beyond_doubt(widened, T_MIN, discovered.pendulum)
        widened, confounded = beside_lookalikes(widened, discovered.pendulum)
        doubt_notes += unnamed + confounded
    doubt_notes = friction_notes + doubt_notes
    catalog = dataclasses.replace(catalog, found=tuple(widened))
    drifted = drift_stage(catalog, drift, say)
    decided = verdict_stage(catalog, discovered, drifted, input_corrected=rerun is not None)
    # after every decision, the reported +- count a slow remainder of the residual (a note says so)
    catalog, slow_notes = widen_for_slow_remainder(catalog)
    decided = dataclasses.replace(decided, facts=dataclasses.replace(decided.facts, found=tuple(catalog.found)))
    doubt_notes = doubt_notes + slow_notes
    say('mapping the missing acceleration over angle, direction of motion and thrust')
    mapped = state_map(catalog.prep, catalog.current, prepared.effects)
    mapped_selected = (state_map(catalog.prep, catalog.selected, tuple(catalog.model))
                       if catalog.selected is not None else None)
    return check_diagnosis(Diagnosis(
        effects=prepared.effects, current=catalog.current, candidates=catalog.results,
        missing_effect=decided.missing, verdict=Verdict(decided.verdict), facts=decided.facts,
        notes=([rerun.note] if rerun is not None else []) + list(decided.notes) + doubt_notes,
        before=compared.before, residual_structure=list(decided.structure), prepared=catalog.prep,
        seconds=time.perf_counter() - started, found=list(catalog.found), selected=catalog.selected,
        drift=list(drifted.rows), fixed=prepared.held, fixed_from=prepared.held_from, discovery=discovered.pendulum,
        motor_discovery=discovered.motor, state_map=mapped, state_map_selected=mapped_selected,
        remainder=remainder_of(catalog.prep, catalog.final)))
