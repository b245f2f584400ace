"""Discovery: the missing term when no catalog effect explains the error, found by sparse regression and proven.

A stage of the diagnosis (:mod:`aeropend_core.diagnosis.diagnose`), run when the best catalog set leaves error
beyond the noise or when its set is suspect. Steps:

1. **States from the model.** The output-error fit of the current best model gives the angle and its rate
   (the model's own smooth trajectory, sampled on the fit's integration grid) and the thrust's angular
   acceleration ``thrust_gain e|e|`` on every training segment. No derivative of noisy data is taken.
2. **Sparse regression of the discrepancy.** The output residual ``r = measured angle - model angle`` obeys,
   to first order, ``d^2r/dt^2 = -a cos(angle) r - b dr/dt + Σ (nominal sensitivities) + Σ c_k θ_k(states)``:
   the pendulum equation's discrepancy. It is regressed in weak form (the project's own WSINDy with its GLS noise
   model and MSTLS, :func:`aeropend_core.wsindy.weak_form.fit_weak_sindy`) with the sensitivities kept and a library
   of physically typed candidate terms θ_k (:data:`VOCABULARY`): angle harmonics and powers, rate sign and
   powers, Stribeck exp(-(W/v)^2) sign W, thrust x rate, thrust x angle, propeller speed x rate, the thrust
   through lags, slow functions of time and of the dissipated power. Each term has units, a readable expression
   and a physical reading.
3. **Proof.** Every surviving term that the simulator can carry is added to the model as a one-parameter effect
   (``dW/dt += c θ``), refitted by output error and judged by the same evidence as a catalog effect
   (:func:`aeropend_core.diagnosis.candidates.assess`: HAC t, BIC with the effective sample count, held-out
   Diebold--Mariano, materiality). A term that a catalog effect spans (its columns correlate beyond
   :data:`SPAN_CORRELATION` on these states) is reported as that catalog effect; a term that explains the data
   as well as the catalog set the search chose is reported as confounded with it. Terms of time, lags or heating
   are not simulated by the output-error model: they are reported as candidates, never as proven.

The discovered term is kept as ``--term EXPRESSION`` (:func:`term_effect` registers it on demand) or written as an
effects module (:func:`effect_module_text`).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from aeropend_core.diagnosis.candidates import Candidate, assess
from aeropend_core.diagnosis.compare import Comparison, PreparedRecord, compare, excess_error
from aeropend_core.diagnosis.evidence import TermEvidence, differing_parameters, finite_or_none, screening_doubt
from aeropend_core.diagnosis.output_error import STRIDE
from aeropend_core.errors import AeropendError, InsufficientDataError
from aeropend_core.signals.filters import first_order_lag
from aeropend_core.model.effects import (CATALOG, FRICTION_SMOOTHING, KERNEL_KINDS, PENDULUM, Effect, EffectParameter,
                                         add_effect)

#: A term and a catalog effect whose columns correlate beyond this on the model's states are the same term here.
SPAN_CORRELATION = 0.95
#: A term's evidence is compared with a catalog effect's held-out error with this factor (as the catalog's
#: confounding test, :data:`aeropend_core.diagnosis.diagnose.CONFOUNDING_FACTOR`).
CONFOUNDING_FACTOR = 1.3
#: At most this many surviving terms are refitted by output error (strongest weak-form evidence first).
MAX_REFITS = 3
#: Knee terms of the thrust curve, refitted beside a chosen catalog set whatever their rank (a lower thrust gain plus
#: an offset imitates a knee); beyond the rank they enter its model doubt only when significant (docs/diagnosis.md).
SHAPE_TERMS = ('thrust^2', 'thrust*angle')
#: Family-wise significance of the weak-form selection (Bonferroni over the free candidate terms).
SIGNIFICANCE = 0.01
#: Half-width of the weak-form test functions [s]: about a quarter of the pendulum's period (~0.55 s here).
TEST_HALF_WIDTH = 0.15
#: Prefix of the effect names that carry discovered terms.
PREFIX = 'term_'
#: Time constants [s] of the thrust lags and of the winding's heating in the library.
LAG_TIMES = (0.05, 0.15, 0.4)
HEATING_TIME = 30.0


@dataclass(frozen=True)
class Term:
    """One candidate term of the pendulum equation's discrepancy: ``dW/dt += coefficient * value``.

    Attributes
    ----------
    expression : str
        The term in the vocabulary's names (``angle`` [rad], ``angular_rate`` [rad/s], ``thrust`` [rad/s^2], the
        thrust's angular acceleration L f / J, ``time`` [s], ``heat`` [A^2]); it is also the ``--term`` argument.
    slug : str
        A short identifier (letters, digits, underscores) for effect and parameter names.
    unit : str
        SI unit of the coefficient.
    reading : str
        Its physical reading, for the verdict.
    function : callable
        ``function(angle, angular_rate, thrust, signals) -> ndarray`` with ``signals`` holding ``time``, ``heat``
        and the thrust lags (shape (n,) each).
    simulated : bool
        True when the output-error model can carry it (a function of angle, rate and thrust): it can be proven.
    catalog_kind : str or None
        The kernel kind (:data:`aeropend_core.model.effects.KERNEL_KINDS`) of the catalog effect it is.
    """

    expression: str
    slug: str
    unit: str
    reading: str
    function: Callable = field(repr=False, compare=False)
    simulated: bool = True
    catalog_kind: str | None = None


def _sign(rate):
    return np.tanh(rate / FRICTION_SMOOTHING)


def _state(expression, slug, unit, reading, f, catalog_kind=None):
    return Term(expression, slug, unit, reading, lambda y, w, u, s: f(y, w), True, catalog_kind)


def _vocabulary() -> tuple[Term, ...]:
    terms = [
        _state('1', 'constant', 'rad/s^2', 'a constant torque (a preloaded cable, a draught, a tilted pivot)',
               lambda y, w: np.ones_like(y)),
        _state('cos(angle)', 'cos_angle', 'rad/s^2', 'a zero offset of the angle sensor, or gravity tilted',
               lambda y, w: np.cos(y), 'measured_offset'),
        _state('angle', 'angle', '1/s^2', 'a linear spring at the pivot (cable)', lambda y, w: y, 'angle_linear'),
        _state('angle^2', 'angle_square', '1/(s^2 rad)', 'a spring stiffer on one side (asymmetric cable)',
               lambda y, w: y ** 2),
        _state('angle^3', 'angle_cube', '1/(s^2 rad^2)', 'a hardening spring (cable stiffening with twist)',
               lambda y, w: y ** 3),
        _state('sin(2*angle)', 'sin_2angle', 'rad/s^2', 'a torque periodic twice per turn (an eccentric magnet, '
               'the encoder\'s second-harmonic nonlinearity, an unbalanced pod)', lambda y, w: np.sin(2 * y)),
        _state('cos(2*angle)', 'cos_2angle', 'rad/s^2', 'a torque periodic twice per turn, phase-shifted',
               lambda y, w: np.cos(2 * y)),
        _state('sin(3*angle)', 'sin_3angle', 'rad/s^2', 'a torque periodic three times per turn',
               lambda y, w: np.sin(3 * y)),
        _state('sign(angular_rate)', 'rate_sign', 'rad/s^2', 'dry (Coulomb) friction', lambda y, w: _sign(w),
               'rate_sign'),
        _state('angular_rate*abs(angular_rate)', 'rate_square', '1/rad', 'aerodynamic drag',
               lambda y, w: w * np.abs(w), 'rate_square'),
    ]
    for power, unit, reading in (
            (0.5, 'rad^0.5/s^1.5', 'damping that grows with the square root of the speed (mixed dry/viscous)'),
            (1.5, '1/(rad^0.5 s^0.5)', 'damping between viscous and quadratic (a transitional air flow)'),
            (3.0, 's/rad^2', 'damping that grows with the cube of the speed')):
        terms.append(_state(f'abs(angular_rate)^{power:g}*sign(angular_rate)', f'rate_power_{power:g}'.replace(
            '.', 'p'), unit, reading, lambda y, w, p=power: np.abs(w) ** p * np.sign(w)))
    for speed in (0.05, 0.1, 0.2, 0.4):
        terms.append(_state(f'exp(-(angular_rate/{speed:g})^2)*sign(angular_rate)',
                            f'stribeck_{speed:g}'.replace('.', 'p'), 'rad/s^2',
                            f'breakaway friction above the Coulomb level that fades above {speed:g} rad/s '
                            '(Stribeck stiction)', lambda y, w, v=speed: np.exp(-(w / v) ** 2) * _sign(w)))
    terms += [
        Term('thrust*angular_rate', 'thrust_rate', 's/rad', 'thrust falls with the rod\'s speed through the air '
             '(propeller inflow)', lambda y, w, u, s: u * w),
        Term('sqrt(abs(thrust))*angular_rate', 'speed_rate', 'rad^0.5/s', 'thrust falls with the propeller speed '
             'times the rod\'s speed (inflow, momentum theory)', lambda y, w, u, s: np.sqrt(np.abs(u)) * w),
        Term('thrust*angle', 'thrust_angle', '1/rad', 'thrust changes with the rod\'s angle (ground or wall '
             'effect, a cable pulling on the pod)', lambda y, w, u, s: u * y),
        Term('thrust*cos(angle)', 'thrust_cos', '1', 'the thrust is not perpendicular to the rod',
             lambda y, w, u, s: u * np.cos(y)),
        Term('thrust^2', 'thrust_square', 's^2/rad', 'the thrust law is not quadratic in the motor speed',
             lambda y, w, u, s: u ** 2),
    ]
    for lag in LAG_TIMES:
        terms.append(Term(f'lag(thrust,{lag:g})-thrust', f'thrust_lag_{lag:g}'.replace('.', 'p'), '1',
                          f'the thrust follows the motor through a lag of about {lag:g} s', lambda y, w, u, s,
                          k=lag: s[f'lag_{k:g}'] - u, False, 'thrust_lag_time'))
    terms += [
        Term('time*thrust', 'time_thrust', '1/s', 'the thrust gain drifts (supply sag, battery)',
             lambda y, w, u, s: s['time'] * u, False),
        Term('time', 'time', 'rad/s^3', 'a torque that drifts with time', lambda y, w, u, s: s['time'], False),
        Term('heat*thrust', 'heat_thrust', '1/A^2', 'the thrust falls as the winding heats (resistance rising with '
             'the dissipated power)', lambda y, w, u, s: s['heat'] * u, False),
    ]
    return tuple(terms)


#: The library of candidate terms (module docstring).
VOCABULARY: tuple[Term, ...] = _vocabulary()


def find_term(text: str) -> Term:
    """The vocabulary term written `text` (its expression or slug, spaces ignored).

    Parameters
    ----------
    text : str [-]
        E.g. ``'thrust*angular_rate'`` or ``'thrust_rate'``.

    Returns
    -------
    Term
        The term.

    Raises
    ------
    AeropendError
        Not a term of the vocabulary (the message lists them).
    """
    key = text.replace(' ', '')
    for term in VOCABULARY:
        if key in (term.expression, term.slug, PREFIX + term.slug):
            if not term.simulated:
                raise AeropendError(f'term {text!r} cannot be simulated by the model (it needs time, a lag or '
                                    'heating); only terms of angle, angular_rate and thrust can be added')
            return term
    known = ', '.join(t.expression for t in VOCABULARY if t.simulated)
    raise AeropendError(f'unknown term {text!r}; the terms are: {known}')


def term_effect(term: Term | str) -> str:
    """Register `term` as a one-parameter pendulum effect ``dW/dt += coefficient * term`` and return its name.

    Parameters
    ----------
    term : Term or str [-]
        A vocabulary term, or its expression (:func:`find_term`).

    Returns
    -------
    str
        The effect's name, ``term_<slug>``; its parameter is ``term_<slug>_coefficient`` [the term's unit].
    """
    term = find_term(term) if isinstance(term, str) else term
    name = PREFIX + term.slug
    if name in CATALOG:
        return name
    base = term.function
    if 'thrust' in term.expression:
        def function(angle, angular_rate, thrust, **values):
            return next(iter(values.values())) * base(angle, angular_rate, thrust, None)
    else:
        def function(angle, angular_rate, **values):
            return next(iter(values.values())) * base(angle, angular_rate, 0.0, None)
    from aeropend_core.diagnosis.term_kernel import TERM_CODES
    function.term_code = TERM_CODES[term.slug]      # the compiled kernel runs it (same values as term.function)
    parameter = EffectParameter(f'{name}_coefficient', term.unit, f'coefficient of {term.expression}', 0.0,
                                -1e6, 1e6, start=0.0)
    add_effect(Effect(name, term.reading, f'residual ~ {term.expression}', PENDULUM, (parameter,), function,
                      f'eq (6): dW/dt = ... + c {term.expression}'))
    return name


def model_states(prep: PreparedRecord, comparison: Comparison) -> list[dict[str, np.ndarray]]:
    """The model's trajectory on each training segment, on the fit's integration grid (every STRIDE-th sample).

    Returns
    -------
    list of dict
        Per segment: ``time`` [s], ``residual`` (measured minus model angle) [rad], ``angle`` [rad] (the model's,
        without a sensor offset), ``angular_rate`` [rad/s] (the model's), ``thrust`` [rad/s^2] (the model's thrust
        acceleration), ``heat`` [A^2] (the armature current squared through a 30 s lag) and the thrust lags.
    """
    fit = comparison.fit
    values = fit.parameters
    structure = fit.structure
    simulated = comparison.evaluation.simulated
    e = prep.voltage - values.get('armature_resistance', 0.0) * prep.current
    thrust = values['thrust_gain'] * e * np.abs(e)
    if structure.gate_on:
        thrust = np.where(prep.gate_voltage < values[structure.gate_parameter], 0.0, thrust)
    from aeropend_core.model.effects import kernel_parameter
    lag = kernel_parameter(structure.effects, 'thrust_lag_time')
    if lag is not None and values[lag] > 0:
        thrust = _lagged(thrust, values[lag], prep.sample_time)
    offset = values.get(structure.offset_parameter, 0.0) if structure.offset_parameter else 0.0
    heat = _lagged(prep.armature_current ** 2, HEATING_TIME, prep.sample_time)
    lags = {f'lag_{k:g}': _lagged(thrust, k, prep.sample_time) for k in LAG_TIMES}
    middle = 0.5 * (prep.time[0] + prep.time[-1])
    segments = []
    step = STRIDE * prep.sample_time
    for start, stop in prep.train.segments:
        index = np.arange(start, stop, STRIDE)
        model = simulated[index]
        if index.size < 16 or not np.all(np.isfinite(model)):
            continue
        segment = {'time': prep.time[index] - middle, 'residual': prep.angle[index] - model,
                   'angle': model - offset, 'angular_rate': np.gradient(model, step), 'thrust': thrust[index],
                   'heat': heat[index]}
        segment.update({k: v[index] for k, v in lags.items()})
        segments.append(segment)
    return segments


def _lagged(signal: np.ndarray, time_constant: float, sample_time: float) -> np.ndarray:
    decay = math.exp(-sample_time / time_constant)
    return first_order_lag(signal, decay)


def _columns(term: Term, segment: Mapping[str, np.ndarray]) -> np.ndarray:
    return np.asarray(term.function(segment['angle'], segment['angular_rate'], segment['thrust'], segment), float)


def weak_discrepancy(segments: list[dict[str, np.ndarray]], terms: tuple[Term, ...], noise_rms: float,
                     sample_time: float):
    """Weak-form sparse regression of the discrepancy on `terms` (module docstring, step 2).

    Returns
    -------
    aeropend_core.wsindy.weak_form.EquationFit
        Selected terms by expression with coefficients [term units] and 1σ.
    """
    from aeropend_core.wsindy import library
    from aeropend_core.wsindy.weak_form import Equation, fit_weak_sindy
    kept = [library.Term('sin(angle)', ('angle',), lambda s: np.sin(s['angle']),
                         partial=lambda s, n: np.cos(s['angle'])),
            library.variable('angular_rate'), library.variable('thrust'),
            library.Term('residual*cos(angle)', ('residual', 'angle'), lambda s: s['residual'] * np.cos(s['angle']),
                         partial=lambda s, n: np.cos(s['angle']) if n == 'residual' else
                         -s['residual'] * np.sin(s['angle'])),
            library.derivative('residual')]
    free = [library.Term(t.expression, (t.slug,), lambda s, k=t.slug: s[k], partial=library._ones) for t in terms]
    signals = []
    for segment in segments:
        entry = {k: segment[k] for k in ('residual', 'angle', 'angular_rate', 'thrust')}
        entry.update({t.slug: _columns(t, segment) for t in terms})
        signals.append(entry)
    noise = {name: 0.0 for name in signals[0]}
    noise['residual'] = float(noise_rms)
    step = STRIDE * sample_time
    equation = Equation('residual', tuple(kept + free), order=2, keep=tuple(t.name for t in kept))
    result = fit_weak_sindy([s['time'] for s in segments], signals, [equation],
                            half_width=max(8, int(round(TEST_HALF_WIDTH / step))), noise_std=noise,
                            significance=SIGNIFICANCE, exhaustive_terms=2)
    return result.equations[0], {t.name for t in kept}


@dataclass(kw_only=True)
class DiscoveredTerm(TermEvidence):
    """One term the discovery stage proposes or reports, with its evidence (:class:`TermEvidence`, errors in rad).
    Parameters SI.

    ``status``: ``'proven'`` (significant by the catalog's evidence), ``'catalog'`` (a catalog effect spans it:
    ``catalog_effect``), ``'confounded'`` (it explains the data as well as the catalog set ``confounded_with``),
    ``'not_proven'`` (``why_not`` says why). A proven term may make the catalog set redundant (``replaces``).
    """

    term: Term
    catalog_effect: str | None = None
    confounded_with: list[str] = field(default_factory=list)
    #: Catalog effects the search chose that add nothing significant once the term is in the model (it explains
    #: more than they do: they were its shadow).
    replaces: list[str] = field(default_factory=list)
    #: Other proven terms that explain about as much on this data (within the confounding factor): lookalikes.
    alternatives: list[str] = field(default_factory=list)
    #: How far each parameter of the model [SI] moved when the term was refitted beside it (output error; empty when
    #: it was not refitted or the refit gave no estimate): what the remainder the term stands for does to them.
    parameter_shifts: dict[str, float] = field(default_factory=dict)
    #: The 1-sigma [SI] of each parameter of the model in that refit (the term beside it): with
    #: ``parameter_shifts``, an effect's evidence against the remainder modelled by the term.
    parameter_sigmas: dict[str, float] = field(default_factory=dict)
    #: When confounded: the parameters the two explanations share and disagree on by more than their combined +-
    #: (name -> (value with the set, its sigma, value with the term, its sigma) [SI]).
    differing: dict[str, tuple[float, float, float, float]] = field(default_factory=dict)

    @property
    def effect(self) -> str:
        return PREFIX + self.term.slug

    @property
    def add(self) -> list[str]:
        """Command-line arguments that put the term (or its catalog effect) in the model."""
        if self.catalog_effect:
            return ['--add', self.catalog_effect]
        return ['--term', self.term.expression] if self.term.simulated else []

    def to_dict(self) -> dict:
        value, sigma = self.coefficient()
        return {'expression': self.term.expression, 'status': self.status, 'reading': self.term.reading,
                'equation': f'dW/dt = ... + c * {self.term.expression}',
                'parameters': {f'{self.effect}_coefficient': {'value': finite_or_none(value),
                                                              'sigma': finite_or_none(sigma),
                                                              'unit': self.term.unit}},
                'estimator': 'output_error' if self.refitted else 'weak_sindy',
                **self.evidence_dict(),
                'catalog_effect': self.catalog_effect, 'confounded_with': self.confounded_with,
                'replaces': self.replaces, 'alternatives': self.alternatives,
                'differing_parameters': {name: {'with_catalog_set': a, 'with_catalog_set_sigma': sa,
                                                'with_term': b, 'with_term_sigma': sb}
                                         for name, (a, sa, b, sb) in self.differing.items()},
                'why_not_proven': self.why_not, 'add': self.add}


@dataclass
class Discovery:
    """Outcome of :func:`discover`: the terms tried (best first) and the ones proven."""

    terms: list[DiscoveredTerm]
    selected: tuple[str, ...] = ()
    note: str = ''
    #: Look-alike judgements resting on an output-error fit stopped at its evaluation cap (:func:`_swapped_in`).
    at_cap: list[dict] = field(default_factory=list)

    @property
    def proven(self) -> list[DiscoveredTerm]:
        return [t for t in self.terms if t.status == 'proven']

    def to_dict(self) -> dict:
        return {'weak_form_selected': list(self.selected), 'note': self.note,
                'terms': [t.to_dict() for t in self.terms],
                **({'fits_stopped_at_cap': self.at_cap} if self.at_cap else {})}     # said where it happens


def _span(term: Term, segments, model_effects: tuple[str, ...]) -> str | None:
    """The catalog effect (not in the model) whose term this one is, by kind or by correlation on the states."""
    kinds = {kind: name for name, effect in CATALOG.items() if effect.builtin and name not in model_effects
             for kind, _ in effect.kernel_terms}
    if term.catalog_kind:
        return kinds.get(term.catalog_kind)
    column = np.concatenate([_columns(term, s) for s in segments])
    if not np.std(column) > 0:           # a constant: no correlation to speak of
        return None
    for other in VOCABULARY:
        if other.catalog_kind in kinds and other is not term:
            reference = np.concatenate([_columns(other, s) for s in segments])
            if np.std(reference) > 0 and abs(np.corrcoef(column, reference)[0, 1]) > SPAN_CORRELATION:
                return kinds[other.catalog_kind]
    return None


def discover(prep: PreparedRecord, base: Comparison, model: tuple[str, ...], fixed: Mapping[str, float],
             catalog_set: tuple[str, ...] = (), without_set: Comparison | None = None,
             say: Callable[[str], None] = lambda message: None) -> Discovery:
    """Find, refit and judge terms outside the catalog that explain what `base` misses (module docstring).

    Parameters
    ----------
    prep : PreparedRecord [-]
        The record (the search's training and held-out parts).
    base : Comparison [-]
        The current best model (nominal + `model`), fitted by output error.
    model : tuple of str [-]
        Its effects.
    fixed : mapping of str -> float [SI]
        Parameters held at given values.
    catalog_set : tuple of str [-]
        The effects the catalog search added (part of `model`); a term that explains as much without them is
        reported as confounded with them.
    without_set : Comparison, optional [-]
        The model without `catalog_set` (needed to test confounding).
    say : callable [-]
        Progress messages.

    Returns
    -------
    Discovery
        The terms, best first, each with its status and evidence.
    """
    segments = model_states(prep, base)
    if not segments:
        return Discovery([], note='no training segment with a finite model trajectory')
    in_model = {kind for name in model for kind, _ in CATALOG[name].kernel_terms}
    terms = tuple(t for t in VOCABULARY if not (t.catalog_kind and t.catalog_kind in in_model))
    say('discovery: sparse regression of the pendulum equation\'s discrepancy (weak form)')
    try:
        fit, kept = weak_discrepancy(segments, terms, prep.noise_rms, prep.sample_time)
    except (InsufficientDataError, AeropendError, np.linalg.LinAlgError) as error:
        return Discovery([], note=f'the weak-form regression failed: {error}')
    # ranked by the model-based sigma, as the weak form's significance guard selects terms: the sandwich sigma of a
    # discrepancy regression, dominated by its structured residual, ranks erratically (it is the one reported)
    chosen = [(name, (value, fit.model_standard_errors.get(name, math.nan), fit.standard_errors.get(name, math.nan)))
              for name, value in fit.coefficients.items() if name not in kept]
    # Each term alone (with the sensitivities kept): nearly collinear terms split the evidence in the joint
    # selection, so a true term can lose there to a combination of lookalikes; alone it shows its own strength.
    screened = {}
    for term in terms:
        if term.simulated and not term.catalog_kind:
            alone, _ = weak_discrepancy(segments, (term,), prep.noise_rms, prep.sample_time)
            if term.expression in alone.coefficients:
                screened[term.expression] = _screened(alone, term.expression)
    order = dict(chosen)
    for name, row in screened.items():
        order.setdefault(name, row)
    # terms that stand out alone first (by their own t), then the joint selection's others (collinearity artefacts)
    ranked = sorted(order.items(), key=lambda kv: (kv[0] not in screened,
                                                   -_strength(*screened.get(kv[0], kv[1])[:2])))
    by_expression = {t.expression: t for t in terms}
    shape = [name for name in SHAPE_TERMS if catalog_set and name in by_expression]     # refitted whatever their rank
    ranked += [(name, (math.nan, math.nan, math.nan)) for name in shape if name not in order]   # not screened
    found: list[DiscoveredTerm] = []
    excess_now = excess_error(base.rms_error, prep.noise_rms)
    doubt = screening_doubt(excess_now, prep.noise_rms, 'mrad', 1e3)
    refits = 0
    for name, (value, _, sigma) in ranked:
        term = by_expression[name]
        entry = DiscoveredTerm(term=term, status='not_proven', weak_coefficient=float(value),
                               weak_sigma=float(sigma), weak_doubt=doubt, excess_before=excess_now)
        found.append(entry)
        if term.catalog_kind:
            entry.catalog_effect = _span(term, segments, model)
            entry.status = 'catalog'
            entry.why_not = f'it is the catalog effect {entry.catalog_effect}\'s own term'
            continue
        if not term.simulated:
            entry.why_not = ('a term of time, a lag or heating: the output-error model cannot simulate it, so it is '
                             'not proven; see the drift test and the catalog\'s thrust-lag effect')
            continue
        beyond = name in shape and (refits >= MAX_REFITS or name not in order)      # refitted beyond the rank
        if refits >= MAX_REFITS and not beyond:
            entry.why_not = f'not refitted: weaker weak-form evidence than the {MAX_REFITS} terms refitted before it'
            continue
        refits += 1
        say(f'discovery: refitting {term.expression} by output error')
        augmented = _prove(prep, base, model, fixed, entry, catalog_set, without_set)
        if (entry.status == 'not_proven' and refits == 1 and augmented is not None and catalog_set
                and without_set is not None):
            # adds nothing on top of the catalog set: does it explain as much *instead of* the set? (a lookalike
            # the set absorbs: an encoder's harmonic passing as an offset, |W|^1.5 damping as quadratic drag)
            say(f'discovery: {term.expression} in place of {" + ".join(catalog_set)}')
            _instead_of_set(prep, base, model, fixed, entry, catalog_set, without_set, augmented)
        lookalike = _span(term, segments, model) if entry.status == 'proven' else None
        if lookalike:
            _against_catalog(prep, base, model, fixed, entry, lookalike)
        if beyond and entry.status == 'not_proven':     # no evidence for this shape: not part of the model doubt
            entry.parameter_shifts, entry.parameter_sigmas = {}, {}
    at_cap: list[dict] = []
    if catalog_set and without_set is not None and not any(f.status in ('proven', 'confounded') for f in found):
        lookalike = _set_lookalike(prep, base, model, fixed, catalog_set, without_set, say, at_cap=at_cap)
        if lookalike is not None:
            found.insert(0, lookalike)
        elif len(catalog_set) > 1:
            found[:0] = _effect_lookalikes(prep, base, model, fixed, catalog_set, say, at_cap)
    found.sort(key=lambda f: (f.status != 'proven', f.excess_after if math.isfinite(f.excess_after) else math.inf))
    if found and found[0].status == 'proven':
        # other proven terms that explain about as much: the data cannot tell them from the best (a quasi-static rig
        # ties the thrust to sin(angle), so thrust and angle terms can be lookalikes) -- said, not hidden
        best = found[0]
        floor = max(best.excess_after, 0.2 * prep.noise_rms)
        best.alternatives = [f.term.expression for f in found[1:] if f.status == 'proven'
                             and f.excess_after <= CONFOUNDING_FACTOR * floor]
    return Discovery(found, selected=tuple(name for name, _ in chosen), at_cap=at_cap)


#: A refit with one term more whose training residual RMS exceeds the base's by more than this factor has not
#: converged: with the term at 0 it is the base model, so its least-squares optimum is at least as good.
NESTED_TOLERANCE = 1.05


def _short_of_nested(augmented: Comparison, base: Comparison) -> bool:
    """True when `augmented` (the base plus a term) fits its training part worse than `base` (NESTED_TOLERANCE)."""
    return not augmented.fit.residual_rms <= NESTED_TOLERANCE * base.fit.residual_rms


def _strength(value: float, sigma: float) -> float:
    return abs(value) / sigma if sigma > 0 and math.isfinite(sigma) else 0.0


def _screened(fit, expression: str) -> tuple[float, float, float]:
    """(coefficient, ranking sigma, reported sigma) [term unit] of `expression` in a weak-form fit: the noise-only
    sigma ranks terms as the weak form's significance guard selects them; the sandwich sigma is the one reported."""
    return (float(fit.coefficients[expression]), float(fit.model_standard_errors[expression]),
            float(fit.standard_errors[expression]))


def _against_catalog(prep, base, model, fixed, entry: DiscoveredTerm, effect: str) -> None:
    """A proven term that correlates with a catalog effect's term: the catalog effect, if it explains as much."""
    try:
        rival = compare(prep, model + (effect,), start=base.parameters, fixed=dict(fixed),
                        initial_states=base.fit.initial_states)
    except InsufficientDataError:
        return
    after = excess_error(rival.rms_error, prep.noise_rms)
    if after <= CONFOUNDING_FACTOR * max(entry.excess_after, 0.2 * prep.noise_rms):
        entry.status = 'catalog'
        entry.catalog_effect = effect
        entry.why_not = (f'the catalog effect {effect} explains as much ({after * 1e3:.2f} mrad beyond the noise '
                         f'against {entry.excess_after * 1e3:.2f}): their terms correlate beyond {SPAN_CORRELATION} '
                         'on these states')


def _set_lookalike(prep, base, model, fixed, catalog_set, without_set, say, may_replace: bool = False,
                   tries: int = 1, at_cap: list[dict] | None = None) -> DiscoveredTerm | None:
    """A term outside the catalog that explains the data as well as the catalog set the search chose.

    The discrepancy of the model *without* the set is screened (each term alone, weak form); the strongest term that
    is not the set's own (nor correlated beyond SPAN_CORRELATION with it on these states) is fitted in place of the
    set. It is returned as 'confounded' with the set when it is significant there, explains as much (within
    CONFOUNDING_FACTOR), and neither adds anything significant on top of the other; with `may_replace`, as 'proven'
    replacing the set when it adds to the set, the set adds nothing to it and it explains more; else None. The
    `tries` strongest terms are fitted in turn until one qualifies.
    """
    segments = model_states(prep, without_set)
    if not segments:
        return None
    own = {kind for name in catalog_set for kind, _ in CATALOG[name].kernel_terms}
    columns = [np.concatenate([_columns(t, s) for s in segments]) for t in VOCABULARY if t.catalog_kind in own]
    screened = []
    for term in VOCABULARY:
        if not term.simulated or term.catalog_kind:
            continue
        column = np.concatenate([_columns(term, s) for s in segments])
        if np.std(column) > 0 and any(np.std(c) > 0 and abs(np.corrcoef(column, c)[0, 1]) > SPAN_CORRELATION
                                      for c in columns):
            continue                    # the set's own term here: the catalog effect, not a lookalike
        try:
            alone, _ = weak_discrepancy(segments, (term,), prep.noise_rms, prep.sample_time)
        except (InsufficientDataError, AeropendError, np.linalg.LinAlgError):
            continue
        if term.expression in alone.coefficients:
            value, ranking, sigma = _screened(alone, term.expression)
            screened.append((_strength(value, ranking), term, value, sigma))
    screened.sort(key=lambda row: -row[0])
    for _, term, value, sigma in screened[:tries]:
        say(f'discovery: {term.expression} in place of {" + ".join(catalog_set)}')
        entry = _swapped_in(prep, base, model, fixed, catalog_set, without_set, term, value, sigma, may_replace, at_cap)
        if entry is not None:
            return entry
    return None


def _swapped_in(prep, base, model, fixed, catalog_set, without_set, term: Term, value: float, sigma: float,
                may_replace: bool, at_cap: list[dict] | None = None) -> DiscoveredTerm | None:
    """`term` (screening value `value`, sigma `sigma`) fitted in place of `catalog_set` and judged
    (:func:`_set_lookalike`). A judgement resting on a fit stopped at its evaluation cap (scipy's status 0, the one
    unsuccessful end of 'trf') is appended to `at_cap`: term, set, which fit, errors beyond the noise [rad]."""
    name = term_effect(term)
    parameter = f'{name}_coefficient'
    kept = tuple(n for n in model if n not in catalog_set)
    try:
        swapped = compare(prep, kept + (name,), start={**without_set.parameters, parameter: value}, fixed=dict(fixed))
    except InsufficientDataError:
        return None
    noise = prep.noise_rms
    term_error, set_error = excess_error(swapped.rms_error, noise), excess_error(base.rms_error, noise)
    capped = {'term': term.expression, 'in_place_of': list(catalog_set), 'term_excess_error': term_error,
              'set_excess_error': set_error}
    if at_cap is not None and not swapped.fit.success:
        at_cap.append({**capped, 'fit': 'term in place of the set'})
    alone = assess(prep, without_set, swapped, name)
    if not alone.significant:
        return None
    floor = 0.2 * noise
    alike = (term_error <= CONFOUNDING_FACTOR * max(set_error, floor)
             and set_error <= CONFOUNDING_FACTOR * max(term_error, floor))
    if not (alike or (may_replace and term_error <= set_error)):
        # neither confounded (errors apart) nor proven (not allowed, or it explains less), whatever the model with
        # both would say: that fit is skipped (a 600 s record's ran to its 60-evaluation cap, ~15 s of CPU)
        return None
    try:
        both = compare(prep, model + (name,), start={**base.parameters, **swapped.parameters}, fixed=dict(fixed))
    except InsufficientDataError:
        return None
    if at_cap is not None and not both.fit.success:
        at_cap.append({**capped, 'fit': 'term beside the set'})
    if assess(prep, swapped, both, catalog_set[0]).significant:
        return None
    status, replaces = 'confounded', []
    if assess(prep, base, both, name).significant:
        if not may_replace or term_error > set_error:
            return None
        # the term adds to the set, the set adds nothing to the term, and in its place the term explains more:
        # the effect was the term's shadow (an encoder harmonic read as an angle offset beside a friction)
        status, replaces = 'proven', list(catalog_set)
    elif not alike:
        return None
    return DiscoveredTerm(term=term, status=status, replaces=replaces, weak_coefficient=float(value),
                          weak_sigma=float(sigma),
                          weak_doubt=screening_doubt(excess_error(without_set.rms_error, noise), noise, 'mrad', 1e3),
                          value=alone.parameters.get(parameter, math.nan),
                          sigma=alone.standard_errors.get(parameter, math.nan), excess_before=alone.excess_before,
                          excess_after=term_error, share_removed=alone.share_removed, t_statistic=alone.t_statistic,
                          delta_bic=alone.delta_bic, dm_statistic=alone.dm_statistic,
                          confounded_with=list(catalog_set) if status == 'confounded' else [],
                          differing=_differing(base, swapped) if status == 'confounded' else {})


def _differing(with_set: Comparison, with_term: Comparison) -> dict[str, tuple[float, float, float, float]]:
    """The parameters the catalog set's fit and the term's fit in its place share and disagree on
    (:func:`~aeropend_core.diagnosis.evidence.differing_parameters`)."""
    return differing_parameters(with_set.parameters, with_set.fit.standard_errors, with_term.parameters,
                                with_term.fit.standard_errors)


#: Terms fitted in place of one effect of a selected set (strongest screening first) before it is judged to have none.
LOOKALIKE_TRIES = 3


def model_without(prep: PreparedRecord, fitted: Comparison, model: tuple[str, ...], fixed: Mapping[str, float],
                  effect: str) -> Comparison | None:
    """`model` without `effect`, refitted from `fitted`'s parameters and initial states (None: too little data)."""
    rest = tuple(n for n in model if n != effect)
    try:
        return compare(prep, rest, start=fitted.parameters, fixed=dict(fixed), initial_states=fitted.fit.initial_states)
    except InsufficientDataError:
        return None


def _effect_lookalikes(prep, base, model, fixed, catalog_set, say, at_cap=None) -> list[DiscoveredTerm]:
    """Each effect of a selected set of two or more judged against the strongest term outside the catalog in its
    place (:func:`_set_lookalike` on the model without that effect alone): the whole set's swap cannot see one
    effect of it standing in for a remainder beside a real one (an angle offset of -0.008 rad, z = 14, named beside a
    true dry friction for a torque rippling twice per turn)."""
    found = []
    for effect in catalog_set:
        without = model_without(prep, base, model, fixed, effect)
        if without is None:
            continue
        entry = _set_lookalike(prep, base, model, fixed, (effect,), without, say, may_replace=True,
                               tries=LOOKALIKE_TRIES, at_cap=at_cap)
        if entry is not None:
            found.append(entry)
    return found


def _instead_of_set(prep, base, model, fixed, entry: DiscoveredTerm, catalog_set, without_set,
                    augmented: Comparison) -> None:
    """`entry` (not significant on top of `catalog_set`) is 'confounded' with the set when, in place of it, the term
    is significant against the model without the set, explains as much as the set (within CONFOUNDING_FACTOR), and
    the set adds nothing significant on top of it: the data cannot tell the two apart."""
    name = term_effect(entry.term)
    parameter = f'{name}_coefficient'
    kept = tuple(n for n in model if n not in catalog_set)
    try:
        swapped = compare(prep, kept + (name,), start={**without_set.parameters, parameter: entry.refit_start},
                          fixed=dict(fixed))
    except InsufficientDataError:
        return
    alone = assess(prep, without_set, swapped, name)
    if not alone.significant or assess(prep, swapped, augmented, catalog_set[0]).significant:
        return
    noise = prep.noise_rms
    term_error, set_error = excess_error(swapped.rms_error, noise), excess_error(base.rms_error, noise)
    floor = 0.2 * noise
    if term_error <= CONFOUNDING_FACTOR * max(set_error, floor) and set_error <= CONFOUNDING_FACTOR * max(term_error,
                                                                                                        floor):
        entry.status, entry.confounded_with, entry.why_not = 'confounded', list(catalog_set), ''
        entry.differing = _differing(base, swapped)
        entry.value = alone.parameters.get(parameter, math.nan)
        entry.sigma = alone.standard_errors.get(parameter, math.nan)
        entry.excess_before, entry.excess_after = alone.excess_before, term_error
        entry.share_removed, entry.t_statistic = alone.share_removed, alone.t_statistic
        entry.delta_bic, entry.dm_statistic = alone.delta_bic, alone.dm_statistic


def _prove(prep, base, model, fixed, entry: DiscoveredTerm, catalog_set, without_set) -> Comparison | None:
    """Refit with the term and judge it (sets `entry`); returns the refitted model (None: not testable)."""
    name = term_effect(entry.term)
    parameter = f'{name}_coefficient'
    start = {**base.parameters, parameter: entry.refit_start}
    try:
        augmented = compare(prep, model + (name,), start=start, fixed=dict(fixed),
                            initial_states=base.fit.initial_states)
        if _short_of_nested(augmented, base) and entry.refit_start != 0.0:
            # the model with the term at c = 0 is the base: a refit that fits the training part worse than the base
            # stopped in another basin (a screening coefficient of -1244 1/s^2 kept, sigma 7e-5, the angle 3.7 rad
            # off), so its coefficient and sigma are no estimate; started from the base, it finds the nested optimum
            start = {**base.parameters, parameter: 0.0}
            augmented = compare(prep, model + (name,), start=start, fixed=dict(fixed),
                                initial_states=base.fit.initial_states)
    except InsufficientDataError as error:
        entry.why_not = f'not testable on this data: {error}'
        return None
    if _short_of_nested(augmented, base):
        entry.why_not = (f'refitted by output error (c = {augmented.parameters.get(parameter, math.nan):.3g}), the '
                         f'model with it fits the training part worse than the model without it (residual '
                         f'{augmented.fit.residual_rms * 1e3:.3g} against {base.fit.residual_rms * 1e3:.3g} mrad RMS): '
                         'the refit did not converge, so it gives no estimate and no evidence')
        return None
    if augmented.evaluation.diverged:
        # the refit's coefficient makes the model run away: neither it nor its sigma is an estimate (the JSON and the
        # text then show the weak form's coefficient, with the estimator said)
        entry.why_not = (f'refitted by output error (c = {augmented.parameters.get(parameter, math.nan):.3g}), the '
                         'model with it does not simulate this record: its angle grows without bound, so the refit '
                         'gives no estimate and no evidence')
        return None
    candidate: Candidate = assess(prep, base, augmented, name)
    entry.parameter_shifts = {k: float(augmented.parameters[k] - v) for k, v in base.parameters.items()
                              if k in augmented.parameters and math.isfinite(augmented.parameters[k] - v)}
    entry.parameter_sigmas = {k: float(augmented.fit.standard_errors.get(k, math.nan)) for k in entry.parameter_shifts}
    entry.value = candidate.parameters.get(parameter, math.nan)
    entry.sigma = candidate.standard_errors.get(parameter, math.nan)
    entry.excess_after, entry.share_removed = candidate.excess_after, candidate.share_removed
    entry.t_statistic, entry.delta_bic = candidate.t_statistic, candidate.delta_bic
    entry.dm_statistic = candidate.dm_statistic
    if not candidate.significant:
        reasons = []
        from aeropend_core.diagnosis.candidates import BIC_MARGIN, T_MIN
        if not candidate.t_statistic >= T_MIN:
            reasons.append(f'its coefficient is only {candidate.t_statistic:.1f} HAC standard errors from zero '
                           f'(needs {T_MIN:g})')
        if not candidate.delta_bic < -BIC_MARGIN:
            reasons.append(f'the training BIC changes by {candidate.delta_bic:+.1f} (needs < -{BIC_MARGIN:g})')
        if not reasons:
            reasons.append(f'the held-out prediction does not improve enough (Diebold-Mariano '
                           f'{candidate.dm_statistic:+.1f}, {candidate.share_removed * 100:.0f} % of the error '
                           'beyond the noise removed)')
        entry.why_not = '; '.join(reasons)
        return augmented
    entry.status = 'proven'
    if catalog_set and without_set is not None:
        # the term in place of the catalog set: does the set still add anything significant on top of the term?
        kept = tuple(n for n in model if n not in catalog_set)
        try:
            swapped = compare(prep, kept + (name,), start=start, fixed=dict(fixed))
        except InsufficientDataError:
            return augmented
        if assess(prep, swapped, augmented, catalog_set[0]).significant:
            return augmented            # both are needed: the term is proven alongside the set
        noise = prep.noise_rms
        alone, chosen = excess_error(swapped.rms_error, noise), excess_error(base.rms_error, noise)
        floor = 0.2 * noise
        if alone <= CONFOUNDING_FACTOR * max(chosen, floor) and chosen <= CONFOUNDING_FACTOR * max(alone, floor):
            entry.status = 'confounded'         # they explain the data equally
            entry.confounded_with = list(catalog_set)
            entry.differing = _differing(base, swapped)
        else:
            entry.replaces = list(catalog_set)  # the term explains more, and with it the set adds nothing
    return augmented


__all__ = ['VOCABULARY', 'Term', 'DiscoveredTerm', 'Discovery', 'discover', 'find_term', 'term_effect',
           'model_states', 'weak_discrepancy', 'KERNEL_KINDS']
