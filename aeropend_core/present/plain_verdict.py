"""The verdict in one plain sentence a student reads first: what is missing, how big (with its unit), what to do next.

The diagnosis's full message (:func:`aeropend_core.present.verdict_text.verdict_of`) is the evidence layer: the
statistics behind the decision (HAC standard errors, the Diebold-Mariano test, the training BIC). The plain sentence
says the same decision without them: no test names, no equation numbers, no symbols from the source paper, and
nothing that contradicts the evidence. Words only; the inputs are duck-typed (a
:class:`~aeropend_core.diagnosis.diagnose.Diagnosis` and its ``facts``).
"""
from __future__ import annotations

import math
import shlex

from aeropend_core.model.effects import get_effect, parameter_unit
from aeropend_core.present.discovery_text import lookalike_clause, lookalike_terms


def _decide_lookalike(discovery) -> str:
    """What decides between a catalog effect and a term outside the catalog that explains a record as well: an
    independent measurement of a parameter their fits disagree on, when there is one, before any new record (a
    cable spring and a hardening cubic stay alike at every rest the rig reaches, yet disagree in gravity by the
    cable's size)."""
    twins = lookalike_terms(discovery)         # the terms lookalike_clause names, in its order
    differing = dict(getattr(next(iter(twins.values()))[0], 'differing', None) or {}) if twins else {}
    experiment = 'record an experiment that may separate them (aeropend run --until-decided)'
    if not differing:
        return experiment
    name, (with_set, _, with_term, _) = next(iter(differing.items()))
    return (f'measure {name} independently ({with_set:.4g} with the catalog effect, {with_term:.4g} '
            f'{parameter_unit(name)} with the term), or {experiment}')


def _sizes(found) -> str:
    """'time_constant 0.14 +- 0.0036 s': an effect's parameters +- 1 sigma in their SI units."""
    units = {p.name: p.unit for p in get_effect(found.effect).parameters}
    return ', '.join(f'{name} {value:.4g} +- {found.standard_errors.get(name, float("nan")):.2g} {units[name]}'
                     for name, value in found.parameters.items())


def _what(found) -> str:
    """'thrust_lag, time_constant 0.14 +- 0.0036 s (thrust builds up ...)': an effect, its size +- 1 sigma and what it
    is in words."""
    sizes = _sizes(found)
    return f'{found.effect}{", " + sizes if sizes else ""} ({get_effect(found.effect).description})'


def _spans_zero(found) -> bool:
    """True when one of the effect's parameters is within 2 sigma of zero (its size is not pinned by the record)."""
    return any(abs(value) < 2.0 * found.standard_errors.get(name, math.inf)
               for name, value in found.parameters.items())


def _catalog_stand_in(found: list, command: str) -> str:
    """The look-alike verdict's advice for the meantime: the catalog's effect with its size, said unpinned when a
    parameter's ± reaches zero (then the model with it is only the better-fitting stand-in, not a measured size)."""
    sizes = '; '.join(f'{f.effect} {_sizes(f)}' for f in found)
    if any(_spans_zero(f) for f in found):
        return (f'until then the catalog\'s effect ({sizes}) fits best, but its size is within 2 sigma of zero, so '
                f'this record does not measure it: {command} only as a stand-in')
    return f'until then the catalog\'s effect ({sizes}) is the model to use: {command}'


def _next_command(source: str | None, effects, report: bool = False) -> str:
    """The command that diagnoses again with `effects` added (in words when the record's name is not known)."""
    adds = ''.join(f' --add {e}' for e in effects)
    if not source:
        return f'diagnose again with{adds}'
    return f'aeropend diagnose {shlex.quote(source)}{adds}' + (' --report after.html' if report else '')



def plain_verdict(diagnosis, source: str | None = None, report: bool = False) -> str:
    """One or two plain sentences: what is missing, how big (mrad or the effect's SI unit), what to do next.

    Parameters
    ----------
    diagnosis : Diagnosis [-]
        A finished diagnosis (its ``facts``, ``effects``, ``verdict``).
    source : str, optional [-]
        The record's name, put into the suggested command (said in words when not given).
    report : bool [-]
        The suggested command writes the next report (``--report after.html``).

    Returns
    -------
    str
        The sentence(s); angles in mrad, effect parameters in their SI unit, ± one standard error.
    """
    facts = diagnosis.facts
    verdict = diagnosis.verdict
    noise = f'{facts.noise_rms * 1e3:.2f} mrad'
    given = list(getattr(diagnosis, 'effects', ()) or ())
    pinned = [f for f in facts.found if not f.confounded_with]
    unsure = [f for f in facts.found if f.confounded_with]
    rate = (f' The record is at {facts.low_rate_hz:.3g} Hz: confirm it on a record at the rig\'s 490 Hz.'
            if facts.low_rate_hz is not None and facts.found else '')
    if verdict == 'model_does_not_fit':
        return ('The model does not fit this record: a fitted parameter is physically impossible (see the parameters '
                'marked !!), so no effect can be judged. Next: check the data and the units of the log first.')
    if verdict == 'drift':
        return ('A parameter of the rig changed during the record (drift), so no single model fits it: '
                f'{facts.drift_text.rstrip(".")}. Next: record again with the rig warmed up, or diagnose shorter '
                'records separately.')
    if verdict == 'confounded' and unsure:
        names = ' or '.join([unsure[0].effect, *unsure[0].confounded_with])
        return (f'One of {names} is missing (together they take the model\'s error beyond the {noise} noise from '
                f'{facts.excess_current * 1e3:.2f} to {facts.excess_final * 1e3:.2f} mrad), but this record cannot '
                'tell which. Next: record the experiment that separates them (aeropend run --until-decided, or '
                'the notes below).')
    alike = lookalike_clause(facts.discovery) if verdict == 'confounded' else ''
    if alike and facts.found:
        command = _next_command(source, given + [f.effect for f in facts.found], report)
        return (f'One of {alike} is missing (with {", ".join(f.effect for f in facts.found)} the error beyond the '
                f'{noise} noise falls from {facts.excess_current * 1e3:.2f} to {facts.excess_final * 1e3:.2f} mrad, '
                'and the term in its place explains the record as well), but this record cannot tell which. Next: '
                f'{_decide_lookalike(facts.discovery)}; {_catalog_stand_in(facts.found, command)}.' + rate)
    if verdict in ('effect_found', 'confounded') and facts.found:
        what = '; '.join(_what(f) for f in facts.found)
        command = _next_command(source, given + [f.effect for f in facts.found], report)
        return (f'Missing: {what}. Adding {"it" if len(facts.found) == 1 else "them"} takes the error '
                f'beyond the {noise} measurement noise from {facts.excess_current * 1e3:.2f} to '
                f'{facts.excess_final * 1e3:.2f} mrad. Next: {command}.' + rate)
    if verdict == 'term_discovered':
        proven = facts.discovery.proven if facts.discovery is not None else []
        motor = facts.motor.proven if facts.motor is not None else []
        if proven:
            best = proven[0]
            kept = given + [f.effect for f in pinned if f.effect not in best.replaces]
            return (f'Something outside the catalog of effects is missing; the term {best.term.expression} '
                    f'({best.term.reading}) takes the error beyond the {noise} noise from '
                    f'{best.excess_before * 1e3:.2f} to {best.excess_after * 1e3:.2f} mrad. Next: '
                    f'{_next_command(source, kept)} {" ".join(shlex.quote(a) for a in best.add)}'
                    + (' --report after.html.' if report and source else '.'))
        if motor:
            best = motor[0]
            return (f'The motor equation misses something: the term {best.term.expression} ({best.term.reading}) '
                    f'takes the armature current\'s error beyond its noise from {best.excess_before * 1e3:.2f} to '
                    f'{best.excess_after * 1e3:.2f} mA. Next: see the evidence and the motor discovery below.')
    if verdict == 'nothing_missing':
        return (f'Nothing is missing that this record can show: the model follows the angle to within the {noise} '
                f'measurement noise (error beyond the noise {facts.excess_final * 1e3:.2f} mrad). Next: score the '
                'model on a second record (--validate OTHER.csv), or excite the rig differently to test more.')
    if facts.heldout_only:
        lead = facts.heldout_only[0]
        return (f'The model misses the held-out end of the record by {facts.excess_final * 1e3:.2f} mrad beyond the '
                f'{noise} noise; {lead.effect} would explain it there but the rest of the record shows no sign of '
                f'it, so nothing is named. Next: {facts.heldout_advice}.')
    rate_limit = facts.reduced_rate_hz or (facts.low_rate_hz if facts.low_rate_hz is not None else None)
    lead = facts.structure[0]['signature'] if facts.structure else ''
    return (f'Something the catalog of effects does not hold is missing: the model misses the angle by '
            f'{facts.excess_final * 1e3:.2f} mrad beyond the {noise} noise'
            + (f' (at {rate_limit:.3g} Hz part of that can be the model\'s own limit at this rate)' if rate_limit
               else '')
            + '. Next: '
            + (f'look at what the error follows (strongest: {lead}) and write an effect for it' if lead else
               'write an effect for what the error follows')
            + (', or record at the rig\'s 490 Hz.' if rate_limit else '.'))


__all__ = ['plain_verdict']
