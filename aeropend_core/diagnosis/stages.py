"""The stages of a diagnosis, each a function with a typed result: prepare -> compare -> catalog search -> discovery
-> drift -> verdict.

:func:`aeropend_core.diagnosis.diagnose.diagnose` composes them (docs/pipeline.md); each stage takes the earlier
stages' results (frozen dataclasses) and returns its own:

* :func:`prepare_stage` -> :class:`Prepared`: the model as given (effects and held values), the record conditioned
  (:func:`aeropend_core.diagnosis.compare.prepare`), the record the search fits (a subset of a long record) and the
  candidates as catalog records (:class:`aeropend_core.model.effects.Effect`);
* :func:`compare_stage` -> :class:`Compared`: the model as given and the nominal model, fitted by output error;
* :func:`catalog_stage` -> :class:`CatalogResult`: forward selection with backward elimination over the catalog
  (:mod:`aeropend_core.diagnosis.diagnose`'s module docstring), the selected set and what it leaves;
* :func:`discovery_stage` -> :class:`Discovered`: terms outside the catalog in the pendulum equation
  (:mod:`aeropend_core.diagnosis.discovery`) and the motor's (:mod:`aeropend_core.diagnosis.motor_discovery`); when
  the motor's is proven, :func:`rerun_on_corrected_input` runs the compare, catalog and pendulum-discovery stages again
  on the thrust input rebuilt with that term (a catalog set chosen on the wrong input is the motor term's shadow);
* :func:`drift_stage` -> :class:`Drifted`: the nominal parameters per segment, tested for a trend;
* :func:`verdict_stage` -> :class:`Decided`: the decision and its typed facts (the words: ``present/verdict_text``).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from aeropend_core.diagnosis.candidates import (CORRELATION_LIMIT, BIC_MARGIN, Candidate, _effect_parameters, _try,
                                                assess)
from aeropend_core.diagnosis.compare import Comparison, PreparedRecord, compare, excess_error, prepare
from aeropend_core.diagnosis.thresholds import UNEXPLAINED_NOISE
from aeropend_core.diagnosis.doubts import (DEFAULT_EXPERIMENT, RATE_NOTE_TIME, doubt_notes, excitation_advice,
                                            rate_doubts, rate_notes, residual_structure)
from aeropend_core.errors import AeropendError, InsufficientDataError
from aeropend_core.model.effects import CATALOG, REDUCED_TWINS, THRUST_LAG, Effect, get_effect
from aeropend_core.model.effects import separating_experiment as record_experiment

if TYPE_CHECKING:       # annotations only (these modules are imported where their stage runs)
    from aeropend_core.diagnosis.discovery import Discovery
    from aeropend_core.diagnosis.long_record import SearchSubset
    from aeropend_core.diagnosis.motor_discovery import MotorDiscovery

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

Say = Callable[[str], None]


def separating_experiment(a: str, b: str) -> str:
    """The experiment that separates `a` from `b` (effects or nominal parameters), from the catalog's records."""
    return record_experiment(a, b) or DEFAULT_EXPERIMENT


def _finite(value: float) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


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
    #: Model doubt [SI] included in ``standard_errors`` (:mod:`aeropend_core.diagnosis.model_doubt`), by parameter.
    model_doubt: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {'effect': self.effect, 'parameters': self.parameters, 'standard_errors': self.standard_errors,
                'error_beyond_noise_before': _finite(self.excess_before),
                'error_beyond_noise_after': _finite(self.excess_after),
                'share_of_error_removed': _finite(self.share_removed), 't_statistic': _finite(self.t_statistic),
                'dm_statistic': _finite(self.dm_statistic), 'confounded_with': self.confounded_with,
                'share_of_measurable_error_removed': _finite(self.share_measurable),
                'model_doubt': self.model_doubt}


# ---------------------------------------------------------------------------------------------------- prepare
@dataclass(frozen=True)
class Prepared:
    """The prepare stage's result: the model as given and the record conditioned for it.

    Attributes
    ----------
    effects : tuple of str
        The model's effects (``--add``, then those held by ``--fix``).
    held, held_from : dict
        Held parameter values [SI] and where each came from.
    prep : PreparedRecord
        The record conditioned (input, motor observer, noise, split).
    search : PreparedRecord
        The record the search fits: `prep`, or for a long record a copy on a subset of segments.
    subset : SearchSubset or None
        That subset (None: the whole record).
    pool : tuple of Effect
        The candidates to try, as catalog records.
    """

    effects: tuple[str, ...]
    held: dict
    held_from: dict
    prep: PreparedRecord
    search: PreparedRecord
    subset: SearchSubset | None
    pool: tuple[Effect, ...]

    def on_input(self, prep: PreparedRecord) -> Prepared:
        """The same model and candidates on another conditioning of the record (a rebuilt thrust input)."""
        from aeropend_core.diagnosis.long_record import search_record
        search, subset = search_record(prep)
        return replace(self, prep=prep, search=search, subset=subset)


def prepare_stage(recording, effects: Sequence[str], candidates: Sequence[str] | None,
                  fixed: Mapping | None, fixed_from: Mapping[str, str] | None, say: Say) -> Prepared:
    """Check the model as given, condition the record and collect the candidates (module docstring)."""
    from aeropend_core.diagnosis.long_record import search_record
    from aeropend_core.model.effects import resolve_effects
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
    pool = tuple(get_effect(name) for name in (candidates if candidates is not None else CATALOG)
                 if name not in effects
                 and (candidates is not None or not name.startswith('term_')))    # discovered terms: the discovery's
    pool = tuple(entry for entry in pool if not (prep.reduced and entry.kind == THRUST_LAG))  # the map's lag has it
    return Prepared(effects, held, held_from, prep, search, subset, pool)


# ---------------------------------------------------------------------------------------------------- compare
@dataclass(frozen=True)
class Compared:
    """The compare stage's result: the model as given (`current`) and, when it has effects, the nominal model
    (`before`), fitted on the search's training part and judged on its held-out part."""

    current: Comparison
    before: Comparison | None


def compare_stage(prepared: Prepared, say: Say) -> Compared:
    """Fit the model as given and the nominal model (for before -> after)."""
    effects = prepared.effects
    say(f'fitting the current model: nominal{"".join(" + " + e for e in effects)}')
    current = compare(prepared.search, effects, fixed=prepared.held)
    before = None
    if effects:
        say('fitting the model without the added effects (for before -> after)')
        before = compare(prepared.search, ())
    return Compared(current, before)


# ---------------------------------------------------------------------------------------------- catalog search
@dataclass(frozen=True)
class CatalogResult:
    """The catalog search's result.

    Attributes
    ----------
    prep, search, subset : as :class:`Prepared`
        The record after the search (a reduced-model record's motor map is profiled again with the effects found).
    model : tuple of str
        The model's effects with the selected set.
    final : Comparison
        The model with the selected set (the current model when nothing was selected).
    current : Comparison
        The model as given (on every training segment of a long record when nothing was selected).
    steps : tuple of (Candidate, list of str)
        Each added candidate with the effects it is interchangeable with.
    results : list of Candidate
        The first round's candidates, best first.
    found : tuple of Found
        The selected set.
    selected : Comparison or None
        `final` when something was selected.
    notes : tuple of str
        What the search has to say (an effect dropped again, a long record's subset).
    excess_final, reference : float [rad]
        The error beyond the noise the set leaves; the noise, or half an encoder count when larger.
    remainder : bool
        The set leaves more than ``UNEXPLAINED_NOISE`` x `reference` beyond the noise and the quantisation.
    """

    prep: PreparedRecord
    search: PreparedRecord
    subset: SearchSubset | None
    model: tuple[str, ...]
    final: Comparison
    current: Comparison
    steps: tuple
    results: list
    found: tuple
    selected: Comparison | None
    notes: tuple
    excess_final: float
    reference: float
    remainder: bool


def _interchangeable(prep: PreparedRecord, model: tuple[str, ...], best: Candidate, rival: Candidate,
                     fixed: Mapping[str, float]) -> bool:
    """True when adding either one makes the other insignificant (on this data they explain the same thing)."""
    try:
        both = compare(prep, model + (best.effect, rival.effect), start={**rival.comparison.parameters,
                                                                          **best.comparison.parameters},
                       fixed=dict(fixed))
    except InsufficientDataError:
        return True
    rival_over_best = assess(prep, best.comparison, both, rival.effect, True)
    best_over_rival = assess(prep, rival.comparison, both, best.effect, True)
    return not rival_over_best.significant and not best_over_rival.significant


def _holding(both: Comparison, alone: Comparison) -> Comparison:
    """The better fit (training residual) of two models that hold an effect: with a second effect (`both`) or
    without it (`alone`).

    `both` nests `alone` only where the second effect can be switched off; a thrust lag cannot (its time constant
    is at least the integrator's 5 ms), so for a 20 ms angle filter the model with both settles near 16 ms of lag
    and 4 ms of filter, 0.3 % more training residual than the filter alone, and the filter judged through it did not
    look material over the lag (bench/results/2026-11-29-s16-loop7). The better of the two is the evidence for the
    effect."""
    return both if both.fit.residual_rms <= alone.fit.residual_rms else alone


def _judge_pair(prep: PreparedRecord, model: tuple[str, ...], final: Comparison, chosen: str, rival: str,
                fixed: Mapping[str, float]) -> tuple[str, Comparison | None]:
    """On the final model (which holds `chosen`): 'interchangeable' (neither adds to the other), 'both' (each
    adds to the other), 'chosen' (the data prefer the chosen one) or 'rival' (they prefer the rival: it takes the
    chosen one's place), with the fit of the model where the rival replaces the chosen one (None when it could not
    be fitted). Each side's evidence is the better-fitting model that holds it (:func:`_holding`): without that,
    a 20 ms angle filter chosen second to a thrust lag was reported with the lag as 'both' (the lag at its 5 ms
    bound)."""
    from aeropend_core.parallel import map_in_order, workers_for
    models = (tuple(n for n in model if n != chosen) + (rival,), model + (rival,))
    try:        # the two fits are independent (both start from the final model's values): side by side
        swapped, both = map_in_order(lambda effects: compare(prep, effects, start=final.parameters,
                                                             fixed=dict(fixed)), models, workers_for(len(prep.angle)))
    except InsufficientDataError:
        return 'interchangeable', None
    chosen_adds = assess(prep, swapped, _holding(both, final), chosen, True).significant
    rival_adds = assess(prep, final, _holding(both, swapped), rival, True).significant
    if chosen_adds and rival_adds:
        return 'both', swapped
    if chosen_adds or rival_adds:
        return ('chosen' if chosen_adds else 'rival'), swapped
    return 'interchangeable', swapped


def _try_round(search, base: Comparison, model: tuple[str, ...], names: list[str], held, say: Say,
               round_number: int) -> list[Candidate]:
    """Each of `names` tried on top of `model`, the fits side by side (:mod:`aeropend_core.parallel`);
    the candidates in the order of `names`, the same whatever the number of workers."""
    from aeropend_core.parallel import locked, map_in_order, workers_for
    say_one = locked(say)

    def attempt(numbered: tuple[int, str]) -> Candidate:
        index, name = numbered
        say_one(f'[round {round_number}, {index}/{len(names)}] trying {name}')
        return _try(search, base, model, name, held)
    return map_in_order(attempt, enumerate(names, 1), workers=workers_for(len(search.angle)))


def catalog_stage(prepared: Prepared, compared: Compared, say: Say) -> CatalogResult:
    """Forward selection with backward elimination over the candidates, scored by the catalog's evidence."""
    from aeropend_core.diagnosis.long_record import fit_on_all, search_record
    prep, search, subset, held = prepared.prep, prepared.search, prepared.subset, prepared.held
    current = compared.current
    noise = prep.noise_rms
    pool = prepared.pool

    def masking_possible(comparison: Comparison) -> bool:
        # set-aside candidates are tried again only while error beyond the noise remains to be explained
        return excess_error(comparison.rms_error, noise) > RETRY_NOISE * noise

    model, base = prepared.effects, current
    steps: list[tuple[Candidate, list[str]]] = []     # (the added candidate, what it is confounded with)
    first_round: list[Candidate] = []
    hopeless: set[str] = set()
    interchangeable: set[str] = set()
    retried = False
    notes: list[str] = []
    for round_index in range(2 * MAX_EFFECTS):
        if len(steps) >= MAX_EFFECTS:
            break
        remaining = [e for e in pool if e.name not in model and e.name not in hopeless]
        if not remaining and steps and not retried and hopeless - interchangeable and masking_possible(base):
            retried = True          # an effect can be masked while others are missing: try the set-aside again
            hopeless = set(interchangeable)
            remaining = [e for e in pool if e.name not in model and e.name not in hopeless]
        if not remaining:
            break
        tried = _try_round(search, base, model, [entry.name for entry in remaining], held, say, round_index + 1)
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
            if not assess(search, reduced, base, earlier.effect, True).significant:
                notes.append(f'{earlier.effect} was dropped again: with {best.effect} in the model it adds nothing '
                             f'significant.')
                model, base = reduced_model, reduced
                steps = [(c, g) for c, g in steps if c.effect != earlier.effect]
                # judged with other effects still missing: the replacement is judged again on the final model
                # (second-rig seed 64037: a filter replaced by a lag before a cable torque was added)
                steps[-1][1].append(earlier.effect)
    # A named effect is judged against each catalog neighbour it can be mistaken for (an effect whose record names
    # the experiment separating the two) on the final model, even when the neighbour was never a close rival in a
    # round (second-rig seed 64067: a cable torque named for an angle offset, the offset never close when tried).
    candidates_left = {entry.name for entry in pool} - set(model)
    for chosen, rivals in steps:
        rivals.extend(other for other in sorted(candidates_left) if other not in rivals
                      and other in CATALOG and chosen.effect in CATALOG
                      and (chosen.effect in CATALOG[other].separated_from
                           or other in CATALOG[chosen.effect].separated_from))
    # Confounding judged in an early round, with other effects still missing, is judged again on the final model.
    for position, (chosen, rivals) in enumerate(steps):
        still = []
        for rival_name in rivals:
            if rival_name in model or chosen.effect not in model:
                continue
            say(f'checking whether {chosen.effect} and {rival_name} are interchangeable')
            verdict, swapped = _judge_pair(search, model, base, chosen.effect, rival_name, held)
            if verdict == 'interchangeable':
                still.append(rival_name)
            elif verdict == 'both':
                rival = _try(search, base, model, rival_name, held)
                model, base = model + (rival_name,), rival.comparison
                steps.append((rival, []))
            elif verdict == 'rival':
                # the evidence of the rival in the chosen one's place, against the model that holds the chosen one
                steps.append((assess(search, base, swapped, rival_name, True), []))
                model, base = swapped.effects, swapped
                notes.append(f'{chosen.effect} was replaced by {rival_name}: judged against each other on the '
                             f'final model, the data prefer {rival_name}.')
        steps[position] = (chosen, still)
    steps = [(c, g) for c, g in steps if c.effect in model]
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
    found: list[Found] = []
    for candidate, confounded in steps:
        values, errors = _effect_parameters(base, candidate.effect)
        found.append(Found(candidate.effect, values, errors, candidate.excess_before, candidate.excess_after,
                           candidate.share_removed, candidate.t_statistic, candidate.dm_statistic,
                           confounded_with=list(confounded), share_measurable=candidate.share_measurable))
    excess_final = excess_error(base.rms_error, noise)
    # quantisation without dither (a slow signal, little noise) leaves an error up to step/sqrt(12) that the noise
    # estimate does not see: the remainder must exceed that too
    # (counted on top of the noise estimate: conservative for the claim that something is missing), and an error
    # within half an encoder count is no evidence: the reference is at least half a count
    quantisation = prep.angle_step ** 2 / 12.0
    reference = max(noise, 0.5 * prep.angle_step)
    remainder = base.rms_error ** 2 - noise ** 2 - quantisation > (UNEXPLAINED_NOISE * reference) ** 2
    return CatalogResult(prep, search, subset, model, base, current, tuple(steps), results, tuple(found),
                         base if steps else None, tuple(notes), excess_final, reference, remainder)


# ---------------------------------------------------------------------------------------------------- discovery
@dataclass(frozen=True)
class Discovered:
    """The discovery stage's result.

    Attributes
    ----------
    pendulum : Discovery or None
        Terms outside the catalog in the pendulum equation (None: not run).
    motor : MotorDiscovery or None
        Terms in the motor equation (None: the discovery stage was off).
    corrected : PreparedRecord or None
        The record with the thrust input rebuilt from the observer corrected by the proven motor term (None: no
        motor term proven, or the pendulum could not be refitted with it).
    """

    pendulum: Discovery | None = None
    motor: MotorDiscovery | None = None
    corrected: PreparedRecord | None = None


def pendulum_discovery(prepared: Prepared, catalog: CatalogResult, say: Say):
    """The pendulum equation's discovery when the best set leaves error beyond the noise or is suspect. Where effects
    were named and no remainder is left, each is also put beside the vocabulary's best imitator in its place
    (:func:`aeropend_core.diagnosis.lookalike_check.named_lookalikes`) when the discovery did not run or found no term
    proven or confounded: the discovery's own screening ranks by the discrepancy's weak form, where a cable's cubic
    look-alike ranked fifth. None when nothing ran or was found."""
    found, steps = catalog.found, catalog.steps
    suspect = any(f.confounded_with for f in found) or any(n for c, _ in steps for n in c.confounded_with)
    catalog_set = tuple(f.effect for f in found)
    discovery = None
    if catalog.excess_final > DISCOVERY_NOISE * catalog.reference or suspect:
        from aeropend_core.diagnosis.discovery import discover
        discovery = discover(catalog.prep, catalog.final, catalog.model, prepared.held, catalog_set,
                             catalog.current if catalog_set else None, say)
    if not catalog_set or catalog.remainder or (discovery is not None and any(
            t.status in ('proven', 'confounded') for t in discovery.terms)):
        return discovery
    from aeropend_core.diagnosis.lookalike_check import named_lookalikes
    say('discovery: each effect named beside the best imitator outside the catalog in its place')
    beside = named_lookalikes(catalog.prep, catalog.final, catalog.current, catalog.model, prepared.held, catalog_set,
                              say)
    if beside is None or discovery is None:
        return beside if beside is not None else discovery
    discovery.terms[:0] = beside.terms
    return discovery


def discovery_stage(prepared: Prepared, catalog: CatalogResult, enabled: bool, say: Say) -> Discovered:
    """Search the pendulum's and the motor's equations for terms outside the model (when `enabled`)."""
    if not enabled:
        return Discovered()
    from aeropend_core.diagnosis.motor_discovery import discover_motor, pendulum_with_term
    from aeropend_core.parallel import locked, map_in_order, workers_for
    say_one = locked(say)
    # the pendulum's equation and the motor's (where the armature current is measured; records without it: said so)
    # are searched independently: side by side on the cores (the same numbers)
    pendulum, motor = map_in_order(lambda search: search(), (lambda: pendulum_discovery(prepared, catalog, say_one),
                                                             lambda: discover_motor(catalog.prep, say_one)),
                                   workers_for(len(catalog.prep.angle)))
    corrected = None
    if motor.proven:
        say('discovery: refitting the pendulum with the thrust input of the corrected motor observer')
        corrected = pendulum_with_term(catalog.prep, motor.proven[0], catalog.model, prepared.held,
                                       catalog.excess_final)
    return Discovered(pendulum, motor, corrected)


@dataclass(frozen=True)
class Rerun:
    """The compare, catalog and pendulum-discovery stages again on the thrust input rebuilt with a motor term.

    Attributes
    ----------
    prepared, compared, catalog, discovered : the stages' results on the corrected input
        (`discovered` keeps the motor search's result).
    note : str
        What the catalog search chose on the input as first rebuilt (the motor term's shadow), for the notes.
    """

    prepared: Prepared
    compared: Compared
    catalog: CatalogResult
    discovered: Discovered
    note: str


def rerun_on_corrected_input(prepared: Prepared, catalog: CatalogResult, discovered: Discovered,
                             say: Say) -> Rerun | None:
    """Run the compare, catalog and pendulum-discovery stages again on ``discovered.corrected`` (None: nothing to
    run again on, or the rebuilt input leaves the pendulum further from the data). The corrected observer's current
    error is the motor term's refit's."""
    if discovered.corrected is None or discovered.motor is None or not discovered.motor.proven:
        return None
    term = discovered.motor.proven[0]
    if not term.pendulum_excess_after <= term.pendulum_excess_before:
        return None         # the term explains the current but not the speed: the pendulum keeps the first input
    corrected = discovered.corrected
    noise = discovered.motor.noise_rms
    if corrected.motor is not None and math.isfinite(noise) and math.isfinite(term.excess_after):
        corrected = replace(corrected, motor=replace(corrected.motor, current_noise_rms=float(noise),
                                                     current_rms_error=float(math.hypot(term.excess_after, noise))))
    say(f'the catalog search again, on the thrust input rebuilt with the motor term {term.term.expression}')
    again = prepared.on_input(corrected)
    try:
        compared = compare_stage(again, say)
        searched = catalog_stage(again, compared, say)
    except (InsufficientDataError, AeropendError) as error:
        say(f'the catalog search on the corrected input failed: {error}')
        return None
    pendulum = pendulum_discovery(again, searched, say)
    before = ' + '.join(f.effect for f in catalog.found) or 'nothing'
    note = (f'the thrust input was rebuilt with the motor term {term.term.expression} and the model compared and '
            f'searched again on it; on the input of the observer without it the catalog search chose {before}'
            + (' (what the motor term\'s error looked like to the pendulum)' if catalog.found else '') + '.')
    return Rerun(again, compared, searched, Discovered(pendulum, discovered.motor, discovered.corrected), note)


# ---------------------------------------------------------------------------------------------------- drift
@dataclass(frozen=True)
class Drifted:
    """The drift stage's result: per-segment rows (:func:`aeropend_core.diagnosis.drift.drift_test`), those
    drifting, and a note when it could not run."""

    rows: tuple = ()
    drifting: tuple = ()
    notes: tuple = ()


def drift_stage(catalog: CatalogResult, enabled: bool, say: Say) -> Drifted:
    """Fit the nominal parameters per segment on the final model and test them for a trend (when `enabled`)."""
    if not enabled:
        return Drifted()
    from aeropend_core.diagnosis.drift import drift_test
    say('testing the nominal parameters for drift (per-segment fits)')
    try:
        rows = drift_test(catalog.prep, catalog.final)
    except InsufficientDataError as error:
        return Drifted(notes=(f'drift not tested: {error}',))
    return Drifted(tuple(rows), tuple(row for row in rows if row['drifting']))


# ---------------------------------------------------------------------------------------------------- verdict
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
    motor_input_corrected : bool
        The model was fitted and searched on the thrust input rebuilt with the motor's proven term
        (:func:`rerun_on_corrected_input`).
    reduced_rate_hz : float or None [Hz]
        The rate of a reduced-model record whose own error at that rate is unmeasured.
    low_rate_hz : float or None [Hz]
        The rate of a record below the rig's (``RATE_NOTE_TIME``): what the model's own limit there can do to a
        remainder or a named effect is said.
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
    discovery: Discovery | None = None
    explained_below: float = math.inf
    reduced_rate_hz: float | None = None
    low_rate_hz: float | None = None
    motor: MotorDiscovery | None = None
    prefix: str = ''
    motor_input_corrected: bool = False


@dataclass(frozen=True)
class Decided:
    """The verdict stage's result: the decision, the effect to add first, the typed facts the words are made from,
    the notes and the residual's structure."""

    verdict: str
    missing: str | None
    facts: VerdictFacts
    notes: tuple
    structure: tuple


def _series_twins(found) -> list[str]:
    """Mark each found effect of a reduced-model record that has a twin there
    (:data:`aeropend_core.model.effects.REDUCED_TWINS`) as confounded with it (in place); the notes that say so."""
    notes = []
    for f in found:
        twin = REDUCED_TWINS.get(f.effect)
        if twin and twin not in f.confounded_with:
            f.confounded_with.append(twin)
            notes.append(f'{f.effect} can as well be a {twin.replace("_", " ")} in series with the motor\'s own lag: '
                         'without a usable armature current (the reduced model) the motor\'s lag carries a thrust lag '
                         'and cannot be fitted apart from it, and a lag on the angle acts on the data as a lag on the '
                         'thrust does; a record with the period-average armature current decides')
    return notes


def verdict_stage(catalog: CatalogResult, discovered: Discovered, drifted: Drifted,
                  input_corrected: bool = False) -> Decided:
    """Decide the verdict from the stages' results (the words: :mod:`aeropend_core.present.verdict_text`);
    `input_corrected`: they were run on the thrust input rebuilt with the motor's proven term."""
    from aeropend_core.diagnosis.drift import drift_message
    prep, final, current, found, steps = catalog.prep, catalog.final, catalog.current, catalog.found, catalog.steps
    model, results, reference, remainder = catalog.model, catalog.results, catalog.reference, catalog.remainder
    noise = prep.noise_rms
    reduced = getattr(prep, 'reduced', False)
    notes = list(catalog.notes) + list(drifted.notes)
    drifting = list(drifted.drifting)
    found_terms, motor_terms = discovered.pendulum, discovered.motor
    structure: list[dict] = []
    proven = found_terms.proven if found_terms is not None else []
    # a proven term is the verdict only when it explains the error (what it leaves is within the noise's reach)
    proven = [t for t in proven if t.excess_after <= UNEXPLAINED_NOISE * reference]
    if reduced:
        notes += _series_twins(found)
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
                if reduced and REDUCED_TWINS.get(f.effect) == other:
                    continue            # said by _series_twins
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
    reduced_rate = (1.0 / prep.sample_time if verdict == 'unexplained' and reduced
                    and rate_doubts(prep.sample_time, True) else None)
    low_rate = 1.0 / prep.sample_time if prep.sample_time > RATE_NOTE_TIME else None
    facts = VerdictFacts(
        verdict, found=tuple(found), noise_rms=noise, excess_current=excess_error(current.rms_error, noise),
        excess_final=catalog.excess_final, within_noise=UNEXPLAINED_NOISE * noise, structure=tuple(structure),
        drift_text=drift_message(drifting, final) if drifting else '', heldout_only=tuple(heldout_only),
        heldout_advice=excitation_advice(heldout_only[0].effect) if heldout_only else '', discovery=found_terms,
        explained_below=UNEXPLAINED_NOISE * reference, reduced_rate_hz=reduced_rate,
        low_rate_hz=low_rate, motor=motor_terms,
        motor_input_corrected=input_corrected)
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
    notes += doubt_notes(results, list(found), current, prep, model)     # near misses, an unstated measurement chain
    notes += rate_notes(list(found), prep.sample_time)                  # what this sample rate cannot resolve
    if getattr(prep, 'gaps', None) is not None and prep.gaps.count:
        notes.append(prep.gaps.describe())
    return Decided(verdict, missing, facts, tuple(notes), tuple(structure))


__all__ = ['VerdictFacts', 'Prepared', 'Compared', 'CatalogResult', 'Discovered', 'Rerun', 'Drifted', 'Decided',
           'Found', 'prepare_stage', 'compare_stage', 'catalog_stage', 'pendulum_discovery', 'discovery_stage',
           'rerun_on_corrected_input', 'drift_stage', 'verdict_stage', 'separating_experiment', 'excitation_advice']
