"""The ± of an effect named beside a remainder the catalog cannot write: the noise's spread and the model's doubt.

A catalog effect's ± from the output-error fit is the spread the noise gives (HAC-inflated for correlated residuals).
When the model with the selected set still misses the data beyond the noise, the discovery stage refits terms outside
the catalog beside it; each such term stands for a shape the remainder may have, and the selected effects' parameters
move when it is added (a ripple of the torque with the angle pulled a dry friction of 4.0 rad/s^2 to 3.88 +- 0.04,
z = -3). Their largest move over the terms refitted is the parameter's *model doubt*; the ± reported is the noise's
and the model doubt's in quadrature, and the doubt is said beside it (text and JSON), so that the ± keeps meaning what
it says beside an unknown remainder.
"""
from __future__ import annotations

import math
from dataclasses import replace


def widen_for_remainder(found: list, discovery) -> tuple[list, list[str]]:
    """(the selected effects with their ± widened by the model doubt, a note per parameter widened).

    Parameters
    ----------
    found : list of Found [-]
        The selected set (parameters and 1σ, SI).
    discovery : Discovery or None [-]
        The discovery stage's result (its refitted terms carry ``parameter_shifts``).

    Returns
    -------
    (list of Found, list of str)
        ``Found.model_doubt`` holds the doubt [SI] of each widened parameter.
    """
    terms = [t for t in (discovery.terms if discovery is not None else []) if t.parameter_shifts]
    if not terms or not found:
        return list(found), []
    widened, notes = [], []
    for entry in found:
        errors, doubt = dict(entry.standard_errors), {}
        for name, sigma in entry.standard_errors.items():
            moves = [(abs(t.parameter_shifts[name]), t.term.expression) for t in terms if name in t.parameter_shifts]
            if not moves:
                continue
            move, expression = max(moves)
            if math.isfinite(move) and math.isfinite(sigma) and move > sigma:
                doubt[name] = move
                errors[name] = math.hypot(sigma, move)
                notes.append(f'{entry.effect}: the +- of {name} includes {move:.3g} of model doubt (beside the '
                             f'noise\'s {sigma:.2g}): with the remainder the catalog cannot write modelled by '
                             f'{expression} it moves by that much ({len(terms)} term(s) outside the catalog refitted '
                             'beside the selected set); its value depends on what that remainder is')
        widened.append(replace(entry, standard_errors=errors, model_doubt=doubt) if doubt else entry)
    return widened, notes


def joint_evidence(entry, name: str, discovery) -> tuple[float, str] | None:
    """The smallest t-statistic [-] of `entry`'s parameter `name` over the refits with one term outside the catalog
    beside the selected set (the effect and a model of the remainder fitted together), and that term; None when no
    term was refitted or one refit gave no finite 1-sigma. A refit that puts the parameter on the other side of zero
    counts as t = 0 (the effect's sign depends on what the remainder is)."""
    terms = [t for t in (discovery.terms if discovery is not None else []) if name in t.parameter_shifts]
    if not terms or name not in entry.parameters:
        return None
    value, worst = entry.parameters[name], None
    for term in terms:
        joint = value + term.parameter_shifts[name]
        sigma = getattr(term, 'parameter_sigmas', {}).get(name, math.nan)
        if not (math.isfinite(joint) and math.isfinite(sigma) and sigma > 0):
            return None
        t = abs(joint) / sigma if joint * value > 0 else 0.0
        if worst is None or t < worst[0]:
            worst = (t, term.term.expression)
    return worst


#: Statuses of a refitted term that the data support as part of the remainder (the catalog's evidence).
SUPPORTED = ('proven',)


def supported_doubt(entry, name: str, discovery) -> tuple[float, str] | None:
    """(the largest move [SI] of `entry`'s parameter `name` over the refitted terms the data support as part of the
    remainder (status in :data:`SUPPORTED`), that term), or None when no such term moved it."""
    moves = [(abs(t.parameter_shifts[name]), t.term.expression)
             for t in (discovery.terms if discovery is not None else [])
             if t.status in SUPPORTED and name in t.parameter_shifts and math.isfinite(t.parameter_shifts[name])]
    return max(moves) if moves else None


def _joint_words(entry, name: str, doubt: float, discovery) -> str:
    """What the remainder as the data model it does to `entry`'s parameter `name` (`doubt` [SI] its model doubt):
    the proven terms' doubt and the weakest joint refit, in words ('' without `discovery`)."""
    if discovery is None:
        return ''
    value = abs(entry.parameters[name])
    noise_sigma = math.sqrt(max(entry.standard_errors[name] ** 2 - doubt ** 2, 0.0))
    proven = supported_doubt(entry, name, discovery)
    joint = joint_evidence(entry, name, discovery)
    words = ([f'the term {proven[1]}, proven as part of the remainder, moves it by {proven[0]:.3g} '
              f'({value / math.hypot(noise_sigma, proven[0]):.1f} standard errors from zero with that doubt alone)']
             if proven is not None else ['no term proven as part of the remainder moves it'])
    words.append(f'fitted together with {joint[1]} it is {joint[0]:.1f} of that fit\'s standard errors from zero (the '
                 'weakest joint refit)' if joint is not None else 'a joint refit gave no finite standard error')
    return '; ' + ', and '.join(words)


def beyond_doubt(found: list, t_min: float, discovery=None) -> tuple[list, list[str]]:
    """(the effects still named, a note per effect no longer named) once the ± carries the model doubt.

    An effect is named when its parameter is at least `t_min` standard errors from zero (the catalog search's rule).
    With the model doubt in its ± (:func:`widen_for_remainder`) an effect that only stands in for part of the
    remainder falls below that: its value depends on what the remainder is (an angle offset of 0.024 +- 0.019 rad,
    all but 0.005 of it doubt, read for a thrust loss above a knee, where the term thrust^2, proven, takes most of it).

    With `discovery`, the note also says what the remainder as the data model it does to the effect: the doubt from
    the terms the discovery stage *proved* alone, and the weakest joint refit (:func:`joint_evidence`: the effect
    fitted together with each term refitted beside it). These are said, not decided on: naming an effect whenever
    no proven term takes it within `t_min` standard errors of zero and every joint refit keeps it `t_min` of that
    fit's standard errors from zero on its side named a cable torque for a thrust loss above a knee alone
    (bench/remainder.py seed 41042) and rescued no catalog effect beside a remainder on the reported records
    (bench/results/2026-12-07-s22-remainder/), so it is not the rule.

    Parameters
    ----------
    found : list of Found [-]
        The selected set, its ± widened (``Found.model_doubt`` [SI] set where it was).
    t_min : float [-]
        Standard errors from zero a parameter must be.
    discovery : Discovery or None [-]
        The discovery stage's result (its refitted terms' status, ``parameter_shifts`` and ``parameter_sigmas``);
        None: the notes give the doubt only. The doubt decides either way.

    Returns
    -------
    (list of Found, list of str)
        With `discovery`, each note also gives the proven terms' doubt and the weakest joint refit.
    """
    kept, notes = [], []
    for entry in found:
        doubt = getattr(entry, 'model_doubt', {}) or {}
        doubted = {name: (abs(entry.parameters[name]) / entry.standard_errors[name])
                   for name in doubt if name in entry.parameters and entry.standard_errors.get(name, 0.0) > 0}
        weak = {name: t for name, t in doubted.items() if t < t_min}
        if not weak:
            kept.append(entry)
            continue
        name = min(weak, key=weak.get)
        notes.append(f'{entry.effect} is not named: significant against the noise and against the remainder '
                     f'modelled as a disturbance, but with the model doubt in its +- its {name} = '
                     f'{entry.parameters[name]:.3g} +- {entry.standard_errors[name]:.2g} is {weak[name]:.1f} standard '
                     f'errors from zero (fewer than {t_min:g})' + _joint_words(entry, name, doubt[name], discovery)
                     + ': it may only stand in for part of the remainder the catalog cannot write')
    return kept, notes


def beside_lookalikes(found: list, discovery) -> tuple[list, list[str]]:
    """(the effects still named, a note per effect no longer named) beside a remainder, once the discovery stage
    has fitted terms outside the catalog in the selected effects' place.

    A term of the discovery vocabulary is a smooth function of the state and the input; where one fitted in place of
    a selected effect explains the record as well as the effect, and neither adds anything significant on top of the
    other (its status ``'confounded'``), the effect only holds while no such term is present: beside a remainder the
    catalog cannot write, the data cannot tell the effect from that shape of the remainder, so it is not named as
    present (an angle offset of 0.04 +- 0.002 rad read for a thrust lost above a knee, where a constant torque explains
    the record as well). The discovery stage's sentence says the two are confounded, and with which parameters.

    Parameters
    ----------
    found : list of Found [-]
        The selected set.
    discovery : Discovery or None [-]
        The discovery stage's result.

    Returns
    -------
    (list of Found, list of str)
    """
    terms = [t for t in (discovery.terms if discovery is not None else []) if t.status == 'confounded']
    kept, notes = [], []
    for entry in found:
        twin = next((t for t in terms if entry.effect in t.confounded_with), None)
        if twin is None:
            kept.append(entry)
            continue
        notes.append(f'{entry.effect} is not named: beside a remainder the catalog cannot write, the term '
                     f'{twin.term.expression} ({twin.term.reading}) fitted in its place explains the record as well '
                     f'({twin.excess_after * 1e3:.2f} mrad beyond the noise) and neither adds anything significant on '
                     'top of the other: the two are confounded, and the effect may only stand in for that shape of '
                     'the remainder')
    return kept, notes


__all__ = ['beside_lookalikes', 'beyond_doubt', 'widen_for_remainder']
