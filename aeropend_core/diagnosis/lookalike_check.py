"""A named catalog effect beside the discovery vocabulary's best term in its place, when the discovery stage does not
run (issue #40, "a look-alike absorbed with confidence").

The discovery stage (:mod:`aeropend_core.diagnosis.discovery`) runs when the selected catalog set leaves error beyond
the noise or is suspect. A set that explains the record to the noise is then named with confidence, even where a
term outside the catalog explains it as well: a hardening cubic stiffness ``c angle^3`` of -4..-8 1/(s^2 rad^2) was
read as a cable torque of ~30 1/s^2 with gravity lowered, "with confidence", in 3 of 3 records
(bench/results/2026-12-07-s20-remainder). At these angles ``-Kc angle`` beside ``-g sin(angle)`` is ``-(g + Kc)
angle + g angle^3 / 6 + ...``, which gravity and a cubic write as well.

So each effect named is put beside the vocabulary's best imitator of it, at the same footing. Which term: for an
effect whose term is in the vocabulary (a cable's ``angle``, an offset's ``cos(angle)``, dry friction's
``sign(angular_rate)``, drag's ``angular_rate*abs(angular_rate)``), the term that, with the nominal parameters free
(gravity's ``sin(angle)``, damping's ``angular_rate``, the thrust gain's ``thrust``), writes most of the effect's
column on the model's states (least squares on the states, no fit): ``angle^3`` for the cable above, where the
weak-form screening of the discrepancy ranked it below ``thrust^2``, ``sin(3*angle)``, ``thrust*cos(angle)`` and
``sin(2*angle)``; for the others (lags, a filter, a dead zone) the strongest term of the weak-form screening of the
discrepancy of the model without the effect. That one term is fitted by output error in the effect's place and
judged by the same evidence as the discovery stage's look-alikes (:func:`aeropend_core.diagnosis.discovery._swapped_in`:
significant in the effect's place, neither adds anything significant on top of the other, held-out errors beyond the
noise within the confounding factor of each other). Where it qualifies the two are **confounded**; the parameters
their fits disagree on by more than 2 combined sigma are named (``DiscoveredTerm.differing``). One term per effect,
no full discovery round: two output-error fits per effect (three for an effect of a set of two or more, whose model
without it is fitted too).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping

import numpy as np

from aeropend_core.diagnosis.compare import Comparison, PreparedRecord
from aeropend_core.diagnosis.discovery import (SPAN_CORRELATION, VOCABULARY, Discovery, DiscoveredTerm, Term,
                                               _columns, _set_lookalike, _swapped_in, model_states, model_without)
from aeropend_core.model.effects import CATALOG

#: What :attr:`Discovery.note` says when only this check ran.
NOTE = ('the discovery stage did not run (the selected set explains the record to the noise); each effect named was '
        'put beside the vocabulary\'s strongest term fitted in its place')


def imitators(segments: list[dict], effect: str) -> list[tuple[float, Term]]:
    """The vocabulary's terms ranked by how much of `effect`'s own column they write beside the nominal columns.

    Parameters
    ----------
    segments : list of dict [-]
        The model's states (:func:`aeropend_core.diagnosis.discovery.model_states`).
    effect : str [-]
        A catalog effect.

    Returns
    -------
    list of (float, Term)
        (share [-] of the effect's column beyond the span of ``sin(angle)``, ``angular_rate`` and ``thrust`` that the
        term writes, the term), best first; empty when the vocabulary has no column for the effect (a lag, a filter,
        a dead zone) or the nominal columns already write all of it. Terms outside the vocabulary's simulated ones,
        catalog terms and terms correlated beyond SPAN_CORRELATION with the effect's own are left out (as the
        discovery stage does).
    """
    kinds = {kind for kind, _ in CATALOG[effect].kernel_terms}
    own = [t for t in VOCABULARY if t.catalog_kind in kinds and t.simulated]
    if not own or not segments:
        return []
    stack = lambda f: np.concatenate([np.asarray(f(s), float) for s in segments])     # noqa: E731
    target = stack(lambda s: _columns(own[0], s))
    nominal = np.column_stack([stack(lambda s: np.sin(s['angle'])), stack(lambda s: s['angular_rate']),
                               stack(lambda s: s['thrust'])])

    def left(columns: np.ndarray) -> float:
        coefficients, *_ = np.linalg.lstsq(columns, target, rcond=None)
        return float(np.sum((target - columns @ coefficients) ** 2))

    beyond = left(nominal)
    if not beyond > 1e-12 * float(np.sum(target ** 2)):
        return []
    ranked = []
    for term in VOCABULARY:
        if not term.simulated or term.catalog_kind:
            continue
        column = stack(lambda s, t=term: _columns(t, s))
        if not (np.all(np.isfinite(column)) and np.std(column) > 0):
            continue
        if abs(np.corrcoef(column, target)[0, 1]) > SPAN_CORRELATION:
            continue                    # the effect's own term here, not a look-alike
        share = 1.0 - left(np.column_stack([nominal, column])) / beyond
        if math.isfinite(share):
            ranked.append((share, term))
    ranked.sort(key=lambda row: -row[0])
    return ranked


def _beside(prep, final, without, model, fixed, effect, say, at_cap: list[dict]) -> DiscoveredTerm | None:
    """The best imitator of `effect` fitted in its place (:func:`imitators`; the weak-form screening's strongest term
    for an effect the vocabulary has no column for), as a confounded term, or None. Fits stopped at their evaluation
    cap are appended to `at_cap`."""
    ranked = imitators(model_states(prep, without), effect)
    if not ranked:
        entry = _set_lookalike(prep, final, model, fixed, (effect,), without, say, may_replace=False, tries=1,
                               at_cap=at_cap)
        return entry if entry is not None and entry.status == 'confounded' else None
    share, term = ranked[0]
    say(f'discovery: {term.expression} in place of {effect} (it writes {share * 100:.0f} % of its column beyond the '
        'nominal ones)')
    entry = _swapped_in(prep, final, model, fixed, (effect,), without, term, 0.0, math.nan, False, at_cap)
    return entry if entry is not None and entry.status == 'confounded' else None


def named_lookalikes(prep: PreparedRecord, final: Comparison, without_set: Comparison, model: tuple[str, ...],
                     fixed: Mapping[str, float], catalog_set: tuple[str, ...],
                     say: Callable[[str], None] = lambda message: None) -> Discovery | None:
    """The terms outside the catalog that explain the record as well as an effect of `catalog_set` in its place.

    Parameters
    ----------
    prep : PreparedRecord [-]
        The record (training and held-out parts).
    final : Comparison [-]
        The model with the selected set (nominal + `model`), fitted by output error.
    without_set : Comparison [-]
        The model without the selected set (the model as given).
    model : tuple of str [-]
        `final`'s effects.
    fixed : mapping of str -> float [SI]
        Parameters held at given values.
    catalog_set : tuple of str [-]
        The effects the catalog search selected (part of `model`).
    say : callable [-]
        Progress messages.

    Returns
    -------
    Discovery or None
        Its terms are the look-alikes found, status ``'confounded'`` with ``confounded_with`` the effect; its
        ``at_cap`` the judgements that rest on a fit stopped at its evaluation cap (said, never silently: a fit let
        run on could bring an imitator's error closer). None when no effect has a look-alike and every fit finished,
        or nothing was selected.
    """
    found: list[DiscoveredTerm] = []
    at_cap: list[dict] = []
    for effect in catalog_set:
        without = without_set if len(catalog_set) == 1 else model_without(prep, final, model, fixed, effect)
        if without is None:
            continue
        entry = _beside(prep, final, without, model, fixed, effect, say, at_cap)
        if entry is not None:
            found.append(entry)
    return Discovery(found, note=NOTE, at_cap=at_cap) if found or at_cap else None


__all__ = ['NOTE', 'imitators', 'named_lookalikes']
