"""Doubts the verdict must carry: a candidate supported but not named, a lag that may hold an unstated filter.

**Near misses.** A candidate is named only when it is also *material* by the rule of
:mod:`aeropend_core.diagnosis.diagnose`: its held-out mean-square error gain must exceed (``MATERIAL`` x noise
RMS)^2, and the training BIC must fall by more than ``BIC_MARGIN``. A small effect can pass the parameter t and the
held-out Diebold--Mariano test and still fail those, for two reasons measured on a 9.4 ms thrust lag at 40 dB
(bench/results/2026-11-24-diagnosis-3/lag/README.md):

* the nominal parameters absorb most of it: in the linear regime a thrust lag ``d`` acts like a rod ``1 + (c/J) d``
  times heavier (mgd/J, c/J and the thrust gain all fit ~11 % low without it), so only a small remainder is left
  for the lag to explain;
* that remainder is of the size of the sampling spread of the noise powers the error beyond the noise is the
  difference of (:func:`aeropend_core.diagnosis.diagnose.beyond_spread`).

The verdict then stays "nothing significant is missing" -- but the parameters it reports are off by as much as
the candidate moves them. :func:`near_miss_notes` writes that doubt next to the numbers: which candidate, its
estimate and evidence, the share it removes, how far the nominal parameters move with it, and the experiment that
separates it.

**An unstated measurement chain.** A named effect that the catalog declares confusable with a measurement-chain
effect (the thrust lag with the angle read through a low-pass: lags commute) absorbs that effect's delay when the
chain was not given: a 75 ms lag read through the rig's 14.1 ms filter is named as a lag of 95-96 ms (robustness bench).
:func:`chain_notes` says so when the model does not hold the chain effect (``--fix``/``--calibration``).
"""
from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from aeropend_core.diagnosis.evidence import t_statistic_words
from aeropend_core.model.effects import CATALOG, MEASUREMENT_FILTER, get_effect, separating_experiment
from aeropend_core.signals.rate_accuracy import RATE_ACCURACY
from aeropend_core.model.names import NOMINAL_PARAMETERS

#: Nominal parameters that move by more than this fraction when the candidate is added are listed.
MOVE_REPORTED = 0.01


def parameter_moves(before: dict[str, float], after: dict[str, float]) -> list[tuple[str, float, float, float]]:
    """Nominal parameters that move by more than MOVE_REPORTED, largest relative move first.

    Parameters
    ----------
    before, after : dict of str -> float [SI unit of each parameter]
        Fitted parameters without and with the candidate.

    Returns
    -------
    list of (name, before, after, relative change)
        Relative change [-] = after / before - 1.
    """
    moves = []
    for name in NOMINAL_PARAMETERS:
        old, new = before.get(name), after.get(name)
        if old is None or new is None or not (math.isfinite(old) and math.isfinite(new)) or old == 0.0:
            continue
        change = new / old - 1.0
        if abs(change) > MOVE_REPORTED:
            moves.append((name, old, new, change))
    moves.sort(key=lambda move: -abs(move[3]))
    return moves


#: The advice when the catalog knows no experiment that shows an effect.
DEFAULT_EXPERIMENT = 'vary the step amplitudes and add rests at duty 0; longer records narrow the uncertainty'


def excitation_advice(effect: str) -> str:
    """The experiment that shows `effect` best: the one separating it from a nominal parameter, if known."""
    for nominal in NOMINAL_PARAMETERS:
        advice = separating_experiment(effect, nominal)
        if advice:
            return advice
    return DEFAULT_EXPERIMENT


#: A near miss that moves no nominal parameter beyond its +- 2 sigma is worth a note only when it removes at least
#: this share of the held-out error beyond the noise [-].
MATERIAL_SHARE = 0.05


def material_moves(current, after: dict[str, float]) -> list[tuple[str, float, float, float]]:
    """:func:`parameter_moves` that take a nominal parameter beyond +- 2 of its standard errors in `current` (all of
    them when `current` carries no standard errors).

    Parameters
    ----------
    current : Comparison [-]
        The model the candidate was added to (``parameters``, ``fit.standard_errors``; SI).
    after : dict of str -> float [SI unit of each parameter]
        The parameters with the candidate.

    Returns
    -------
    list of (name, before, after, relative change)
        As :func:`parameter_moves`.
    """
    errors = getattr(getattr(current, 'fit', None), 'standard_errors', None) or {}
    moves = parameter_moves(current.parameters, after)
    return [move for move in moves if not (math.isfinite(errors.get(move[0], math.nan))
                                           and abs(move[2] - move[1]) <= 2.0 * errors[move[0]])]


def near_miss_notes(candidates: Iterable, current, prep) -> list[str]:
    """One note per candidate that passes the parameter t and the held-out test but is not named, when it matters:
    it moves a nominal parameter beyond its +- 2 sigma, or removes at least ``MATERIAL_SHARE`` of the error beyond
    the noise (a note on a model already within the noise that moves nothing would contradict "nothing missing").

    The tests and thresholds are those of :mod:`aeropend_core.diagnosis.candidates` (``T_MIN``, ``DM_MIN``,
    ``BIC_MARGIN``, ``MATERIAL``); the noise-power spread is its
    :func:`~aeropend_core.diagnosis.candidates.beyond_spread`.

    Parameters
    ----------
    candidates : iterable of Candidate [-]
        Candidates tried against `current` (:class:`aeropend_core.diagnosis.diagnose.Candidate`).
    current : Comparison [-]
        The model they were added to.
    prep : PreparedRecord [-]
        The record (its angle noise RMS [rad] and held-out part).

    Returns
    -------
    list of str
        The notes (empty when no candidate is a near miss).
    """
    from aeropend_core.diagnosis.candidates import BIC_MARGIN, DM_MIN, MATERIAL, T_MIN, beyond_spread
    noise, spread = prep.noise_rms, beyond_spread(prep)
    notes = []
    for candidate in candidates:
        if candidate.significant or candidate.comparison is None or not candidate.parameters:
            continue
        if getattr(candidate, 'lost_to_remainder', False) and candidate.modelled is not None:
            notes.append(f'{candidate.effect} is not named: against white noise it would be significant (training '
                         f'BIC {candidate.delta_bic:+.0f}, held-out Diebold-Mariano {candidate.dm_statistic:+.1f}), '
                         f'but not {candidate.modelled.sentence()}: what it removes, the remainder\'s own past '
                         'predicts (it imitates part of a remainder the catalog cannot write).')
            continue
        if not (candidate.t_statistic >= T_MIN and candidate.dm_statistic >= DM_MIN
                and math.isfinite(candidate.delta_bic)):
            continue
        floor = (MATERIAL * noise) ** 2
        failed = ([f'training BIC {candidate.delta_bic:+.0f} is not below -{BIC_MARGIN:g}']
                  if candidate.delta_bic >= -BIC_MARGIN else []) + (
            [f'it lowers the held-out mean-square error by {candidate.mse_gain * 1e6:.3f} mrad^2, less than '
             f'({MATERIAL:g} x the noise RMS)^2 = {floor * 1e6:.3f} mrad^2'] if candidate.mse_gain < floor
            else [])
        units = {p.name: p.unit for p in get_effect(candidate.effect).parameters}
        values = ', '.join(f'{name} = {value:.4g} +- {candidate.standard_errors.get(name, float("nan")):.2g} '
                           f'{units.get(name, "")}' for name, value in candidate.parameters.items())
        beyond = max(current.rms_error ** 2 - noise ** 2, 0.0)
        moves = material_moves(current, candidate.comparison.parameters)
        if not moves and not (candidate.excess_before > 0 and candidate.share_removed >= MATERIAL_SHARE):
            continue    # moves nothing beyond its +- and removes next to nothing: not worth a doubt beside "nothing"
        moved = '; '.join(f'{name} {old:.4g} -> {new:.4g} {NOMINAL_PARAMETERS[name][0]} ({change * 100:+.1f} %)'
                          for name, old, new, change in moves[:3])
        notes.append(
            f'a small {candidate.effect} cannot be ruled out ({values}; {t_statistic_words(candidate.t_statistic)}'
            f', training BIC {candidate.delta_bic:+.0f}, held-out Diebold-Mariano {candidate.dm_statistic:+.1f}), '
            f'but it is too small to name: {"; ".join(failed) or "it is not significant"}. '
            + (f'It removes {candidate.share_removed * 100:.0f} % of the held-out error beyond the noise '
               f'({candidate.mse_gain * 1e6:.2f} of {beyond * 1e6:.2f} mrad^2, which is known only to '
               f'+-{spread * 1e6:.2f} mrad^2).' if candidate.excess_before > 0 else
               'The model is already within the noise without it.')
            + (f' With it the nominal parameters move: {moved}; the reported values are uncertain by that much'
               f' (the nominal parameters can absorb most of a small {candidate.effect}).' if moves else '')
            + f' To decide, {excitation_advice(candidate.effect)}.')
    return notes


def chain_confusions(found: Iterable, model: Iterable[str]) -> dict[str, list[str]]:
    """The measurement-chain effects each named effect may hold (the pairs :func:`chain_notes` writes about).

    Parameters
    ----------
    found : iterable of Found [-]
        The selected effects.
    model : iterable of str [-]
        Effects in the model.

    Returns
    -------
    dict of str -> list of str
        ``{named effect: [chain effects this data cannot tell apart from it]}``, both directions (the chain effect
        maps to the named one too); empty when the chain is in the model.
    """
    held = set(model)
    chain = [name for name, effect in CATALOG.items() if effect.kind == MEASUREMENT_FILTER and name not in held]
    pairs: dict[str, list[str]] = {}
    for item in found:
        if item.confounded_with:
            continue            # already reported as "one of ..." with the experiment that separates them
        for other in chain:
            if separating_experiment(item.effect, other):
                pairs.setdefault(item.effect, []).append(other)
                pairs.setdefault(other, []).append(item.effect)
    return pairs


def chain_notes(found: Iterable, model: Iterable[str]) -> list[str]:
    """A note for each named effect that may hold the delay of a measurement-chain effect nobody stated.

    Parameters
    ----------
    found : iterable of Found [-]
        The selected effects (:class:`aeropend_core.diagnosis.diagnose.Found`).
    model : iterable of str [-]
        Effects in the model (``--add``, ``--fix``, the calibration file's chain, and the found ones).

    Returns
    -------
    list of str
        The notes (empty when the chain is in the model or nothing confusable with it was named).
    """
    found = list(found)
    pairs = chain_confusions(found, model)
    notes = []
    for item in found:
        for other in pairs.get(item.effect, []) if not item.confounded_with else []:
            experiment = separating_experiment(item.effect, other)
            entry = get_effect(other)
            typical = ', '.join(f'{p.name} = {p.typical:g} {p.unit}' for p in entry.parameters)
            values = ', '.join(f'{name} = {value:.4g}' for name, value in item.parameters.items())
            notes.append(f'the measurement chain was not given: the {item.effect} found ({values}) includes any '
                         f'{other} in the record, which this data cannot tell apart from it (the rig: {typical}); '
                         f'to separate them, {experiment}.')
    return notes


def doubt_notes(candidates: Iterable, found: list, current, prep, model: Iterable[str]) -> list[str]:
    """Every doubt note of a diagnosis: near misses (only when nothing was found: the candidates were then tried on
    the current model) and an unstated measurement chain.

    Parameters
    ----------
    candidates : iterable of Candidate [-]
        The first round's candidates, tried against `current`.
    found : list of Found [-]
        The selected effects.
    current : Comparison [-]
        The current model.
    prep : PreparedRecord [-]
        The record.
    model : iterable of str [-]
        Effects in the final model.

    Returns
    -------
    list of str
        The notes.
    """
    return ([] if found else near_miss_notes(candidates, current, prep)) + chain_notes(found, model) + \
        ambiguity_notes(candidates, found, current)


def ambiguity_notes(candidates: Iterable, found: list, current) -> list[str]:
    """A second basin of a nonlinear parameter that fits nearly as well (:mod:`aeropend_core.diagnosis.basins`),
    in the current model or in a found effect's fit: both basins, never one hidden behind a tight sigma.

    Parameters
    ----------
    candidates : iterable of Candidate [-]
        The first round's candidates (their fits).
    found : list of Found [-]
        The selected effects.
    current : Comparison [-]
        The current model.

    Returns
    -------
    list of str
        One note per ambiguous fit.
    """
    named = {f.effect for f in found}
    fits = [('the current model', current.fit)] + [(f'with {c.effect}', c.comparison.fit) for c in candidates
                                                  if c.effect in named and c.comparison is not None]
    notes = []
    for label, fit in fits:
        ambiguity = fit.extra.get('ambiguity')
        if not ambiguity:
            continue
        sides = '; '.join(', '.join(f'{name} {value:.4g}' for name, value in basin['parameters'].items()
                                    if name != 'armature_resistance')
                          + f' (rms error {basin["residual_rms"] * 1e3:.2f} mrad)' for basin in ambiguity['basins'])
        notes.append(f'AMBIGUOUS ({label}): {ambiguity["note"]} Basins: {sides}.')
    return notes


def residual_structure(prep, comparison, count: int = 5) -> list[dict]:
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


#: Sample time [s] above which the rate's limit on time constants is said (below it the rig's 490 Hz resolves
#: every catalog time constant).
RATE_NOTE_TIME = 1.5 / 490.0


def unresolvable(effect: str, parameters: dict, sample_time: float) -> list[str]:
    """Names of `effect`'s time parameters (unit s) whose value is below one sample period `sample_time` [s]:
    a time constant or delay shorter than a sample is not resolvable at that rate (its fitted value is no size).

    Parameters
    ----------
    effect : str [-]
    parameters : dict of str -> float [SI]
    sample_time : float [s]

    Returns
    -------
    list of str
    """
    from aeropend_core.model.effects import get_effect
    try:
        units = {p.name: p.unit for p in get_effect(effect).parameters}
    except Exception:  # noqa: BLE001 - an unknown (user) effect has nothing to say here
        return []
    return [name for name, value in parameters.items()
            if units.get(name) == 's' and math.isfinite(value) and value < sample_time]


def rate_notes(found: list, sample_time: float) -> list[str]:
    """What the sample rate cannot resolve: said at a rate below ~327 Hz, and for every selected effect whose time
    parameter is below one sample period.

    Parameters
    ----------
    found : list of Found [-]
    sample_time : float [s]

    Returns
    -------
    list of str
    """
    if sample_time <= RATE_NOTE_TIME:
        return []
    rate, period_ms = 1.0 / sample_time, sample_time * 1e3
    notes = [f'at {rate:.4g} Hz one sample is {period_ms:.3g} ms: a time constant or delay shorter than that (a thrust '
             f'lag, the angle filter, a sensor lag) is not resolvable at this rate; such a candidate\'s value is '
             f'marked, not taken as a size']
    for f in found:
        for name in unresolvable(f.effect, f.parameters, sample_time):
            notes.append(f'{f.effect}: {name} = {f.parameters[name] * 1e3:.3g} ms is below one sample period '
                         f'({period_ms:.3g} ms at {rate:.4g} Hz): not resolvable at this rate; record faster to '
                         'size it')
    return notes


def rate_doubts(sample_time: float | None, reduced: bool = False) -> dict[str, str]:
    """What the sample rate does to the accuracy of each nominal parameter, to be said next to its number.

    Below ~327 Hz (:data:`RATE_NOTE_TIME`) each of gravity_stiffness, damping and thrust_gain gets the largest error
    measured at this rate (within 2 %), else the larger of the two measured rates around it
    (:data:`aeropend_core.signals.rate_accuracy.RATE_ACCURACY`); a rate below the lowest measured one says that the
    error there may be larger than measured.

    Parameters
    ----------
    sample_time : float or None [s]
    reduced : bool [-]
        The reduced model (no period-average current): its accuracy per rate was not measured, and that is said.

    Returns
    -------
    dict of str -> str
        Parameter name -> the doubt (empty at the rig's rate or without a sample time).
    """
    if sample_time is None or not sample_time > RATE_NOTE_TIME:
        return {}
    if reduced:
        return dict.fromkeys(('gravity_stiffness', 'damping', 'thrust_gain'),
                             f'rate: the reduced model\'s accuracy at {1.0 / sample_time:.4g} Hz has not been measured')
    rate = 1.0 / sample_time
    exact = [entry for entry in RATE_ACCURACY if abs(entry[0] / rate - 1.0) <= 0.02]
    lower = [entry for entry in RATE_ACCURACY if entry[0] <= rate] or [RATE_ACCURACY[-1]]
    upper = [entry for entry in RATE_ACCURACY if entry[0] > rate][-1:]
    # between two measured rates: the larger error of the two (the measured errors do not fall monotonically)
    below = rate < RATE_ACCURACY[-1][0] * 0.98
    chosen = exact[:1] or (RATE_ACCURACY[-1:] if below else lower[:1] + upper)
    at = ' and '.join(f'{entry[0]:g}' for entry in chosen)
    errors = {name: max(entry[1][name] for entry in chosen) for name in chosen[0][1]}
    tolerance = chosen[0][2]
    out = {}
    for name, error in errors.items():
        if error is None:
            continue
        limit = tolerance * (2 if name == 'thrust_gain' else 1)
        text = (f'rate: at {at} Hz this parameter was off by up to {error * 100:.0f} % on seeded simulations '
                f'(bench/lowrate_accuracy.py)')
        if below:
            text += f'; {rate:.4g} Hz is slower than any rate measured: the error may be larger'
        if error > limit:
            text += f', beyond the {limit * 100:.0f} % this rate is held to: not trustworthy as a number'
        out[name] = text
    return out


__all__ = ['DEFAULT_EXPERIMENT', 'ambiguity_notes', 'chain_notes', 'doubt_notes', 'excitation_advice',
           'near_miss_notes', 'parameter_moves', 'rate_doubts', 'rate_notes', 'residual_structure', 'unresolvable']
