"""The words of the discovery stage: the verdict's sentence, the summary's lines and the effects module it writes.

The numbers come from :mod:`aeropend_core.diagnosis.discovery`; only their wording lives here.
"""
from __future__ import annotations

import math


def term_text(term) -> str:
    """'c * EXPRESSION with c = value +- sigma UNIT' for a :class:`~aeropend_core.diagnosis.discovery.DiscoveredTerm`.

    Parameters
    ----------
    term : DiscoveredTerm [-]
        The term with its output-error (or weak-form) coefficient.

    Returns
    -------
    str
        The term as the pendulum equation reads it, SI units.
    """
    value, sigma = (term.value, term.sigma) if math.isfinite(term.value) else (term.weak_coefficient,
                                                                               term.weak_sigma)
    return f'dW/dt += c * {term.term.expression} with c = {value:.4g} +- {sigma:.2g} {term.term.unit}'


def discovery_sentence(discovery, noise_rms: float, explained_below: float = math.inf) -> str:
    """The verdict's sentence about the discovery stage ('' when it found nothing worth saying).

    Parameters
    ----------
    discovery : Discovery [-]
        The stage's result.
    noise_rms : float [rad]
        The angle's measurement noise.
    explained_below : float [rad]
        A proven term that leaves more error beyond the noise than this explains only part of it (said so).

    Returns
    -------
    str
        One or two sentences, numbers in mrad and SI units.
    """
    if discovery is None:
        return ''
    proven = [t for t in discovery.terms if t.status == 'proven']
    if proven and proven[0].excess_after > explained_below:
        best = proven[0]
        return (f'Outside the catalog, the term {term_text(best)} ({best.term.reading}) is significant but explains '
                f'only part of the error: {best.excess_before * 1e3:.2f} -> {best.excess_after * 1e3:.2f} mrad beyond '
                f'the noise ({best.share_removed * 100:.0f} %); the rest is unexplained, so it is a hint, not the '
                f'missing physics (try it with {" ".join(_quoted(best.add))}).')
    if proven:
        best = proven[0]
        return (f'Outside the catalog, the data support the term {term_text(best)} ({best.term.reading}): it removes '
                f'{best.share_removed * 100:.0f} % of the held-out error beyond the noise, '
                f'{best.excess_before * 1e3:.2f} -> {best.excess_after * 1e3:.2f} mrad (noise '
                f'{noise_rms * 1e3:.2f} mrad); HAC t = {best.t_statistic:.1f}, training BIC {best.delta_bic:+.1f}, '
                f'held-out Diebold-Mariano {best.dm_statistic:+.1f}.'
                + (f' With it, {" + ".join(best.replaces)} add{"s" if len(best.replaces) == 1 else ""} nothing '
                   f'significant: {"it was" if len(best.replaces) == 1 else "they were"} the term\'s shadow, not the '
                   'physics.' if best.replaces else '')
                + (f' This data explains about as well with {", ".join(best.alternatives)}: the physics is one of '
                   'these; excite larger angles and free decays to separate them.' if best.alternatives else '')
                + ' Add it with '
                f'{" ".join(_quoted(best.add))}, or keep it as an effect module (aeropend effects '
                f'--write-discovered FILE.py --term \'{best.term.expression}\').')
    confounded = [t for t in discovery.terms if t.status == 'confounded']
    if confounded:
        best = confounded[0]
        return (f'The term {term_text(best)} ({best.term.reading}) explains the data as well as '
                f'{" + ".join(best.confounded_with)} ({best.excess_after * 1e3:.2f} mrad beyond the noise): this '
                f'data cannot tell them apart; vary the step amplitudes and add free decays and rests at duty 0.')
    catalog = [t for t in discovery.terms if t.status == 'catalog']
    tried = [t for t in discovery.terms if t.status == 'not_proven']
    parts = []
    if catalog:
        parts.append(f'The discrepancy points at the catalog effect {catalog[0].catalog_effect} '
                     f'({catalog[0].term.expression}).')
    if tried:
        best = tried[0]
        parts.append(f'Best candidate outside the catalog: {term_text(best)} ({best.term.reading}), not proven: '
                     f'{best.why_not}.')
    if not parts:
        parts.append('The sparse regression of the discrepancy found no term of the vocabulary that stands out '
                     'from the noise.')
    return ' '.join(parts)


def _quoted(arguments: list[str]) -> list[str]:
    return [f"'{a}'" if any(c in a for c in '*()^ ,') else a for a in arguments]


def discovery_lines(discovery) -> list[str]:
    """The summary's lines about the discovery stage (empty when it did not run).

    Parameters
    ----------
    discovery : Discovery or None [-]
        The stage's result.

    Returns
    -------
    list of str
        One line per term, best first.
    """
    if discovery is None:
        return []
    lines = ['Discovery (sparse regression of the discrepancy, terms refitted by output error):']
    if discovery.note:
        lines.append(f'  {discovery.note}')
    if not discovery.terms:
        lines.append('  no term of the vocabulary stands out from the noise')
    for term in discovery.terms:
        after = (f', beyond noise {term.excess_before * 1e3:.2f} -> {term.excess_after * 1e3:.2f} mrad, t = '
                 f'{term.t_statistic:.1f}, dBIC {term.delta_bic:+.1f}, DM {term.dm_statistic:+.1f}'
                 if math.isfinite(term.excess_after) else '')
        why = f' ({term.why_not})' if term.why_not and term.status != 'proven' else ''
        lines.append(f'  {term.status.upper():10s} {term_text(term)}{after}{why}')
    return lines


def effect_module_text(terms) -> str:
    """A Python effects module registering each term as an effect (``--effects-module`` loads it).

    Parameters
    ----------
    terms : sequence of Term [-]
        Vocabulary terms (:data:`aeropend_core.diagnosis.discovery.VOCABULARY`).

    Returns
    -------
    str
        The module's source: one :func:`~aeropend_core.model.effects.register_effect` per term, with the physics in
        its docstring for the user to rename and edit.
    """
    out = ['"""Effects discovered by `aeropend diagnose` (sparse regression of the pendulum equation\'s discrepancy).',
           '',
           'Each term enters the pendulum equation as dW/dt += c * TERM (per unit inertia, SI units). Rename them and',
           'give them a physical parameterisation once you know the mechanism; load with',
           '`aeropend diagnose FILE --effects-module THIS.py --add NAME`.',
           '"""', 'import numpy as np', '', 'from aeropend_core.model.effects import EffectParameter, register_effect',
           '']
    for term in terms:
        name = f'discovered_{term.slug}'
        thrust = 'thrust' in term.expression
        code = _numpy_expression(term.expression)
        out += ['', f'@register_effect({name!r}, {term.reading!r},',
                f"                 signature='residual ~ {term.expression}',",
                f"                 equation='eq (6): dW/dt = ... + c * {term.expression}',",
                f'                 parameters=[EffectParameter({name + "_coefficient"!r}, {term.unit!r}, '
                f"'coefficient c of {term.expression}', 0.0, -1e6, 1e6)])",
                f'def {name}(angle, angular_rate, {name}_coefficient{", thrust" if thrust else ""}):',
                f'    """{term.reading[0].upper() + term.reading[1:]}: dW/dt += c * {term.expression} [rad/s^2]."""',
                f'    return {name}_coefficient * ({code})', '']
    return '\n'.join(out).rstrip() + '\n'


def _numpy_expression(expression: str) -> str:
    code = expression.replace('^', '**')
    for name in ('sin', 'cos', 'exp', 'sqrt', 'abs'):
        code = code.replace(f'{name}(', f'np.{name}(')
    code = code.replace('sign(angular_rate)', 'np.tanh(angular_rate / 0.01)')
    return code if code != '1' else 'np.ones_like(angle)'


__all__ = ['term_text', 'discovery_sentence', 'discovery_lines', 'effect_module_text']
