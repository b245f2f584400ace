"""The words of the discovery stage: the verdict's sentence, the summary's lines, the report's section and the effects
module it writes.

The numbers come from :mod:`aeropend_core.diagnosis.discovery`; only their wording lives here.
"""
from __future__ import annotations

import html
import math
import shlex


def differing_text(term) -> str:
    """The parameters a confounded term's fit and the catalog set's disagree on, as one sentence ('' when none):
    which values hang on the choice between the two explanations."""
    differing = getattr(term, 'differing', None) or {}
    if not differing:
        return ''
    parts = [f'{name} {a:.4g} +- {sa:.2g} with {" + ".join(term.confounded_with)}, {b:.4g} +- {sb:.2g} with the term'
             for name, (a, sa, b, sb) in differing.items()]
    return (f' The two explanations differ in {"; ".join(parts)} (more than their combined +-): '
            f'{"this value depends" if len(parts) == 1 else "these values depend"} on which one is true, and '
            f'{"it" if len(parts) == 1 else "they"}, measured independently of this record (a nominal parameter '
            'from the rig\'s masses and lengths, or a calibration), would decide between them.')


def at_cap_sentences(discovery) -> list[str]:
    """One sentence per look-alike judgement that rests on an output-error fit stopped at its evaluation cap (the
    discovery's ``at_cap``; empty when every fit finished): a fit run on could lower the term's error and change the
    judgement, so the check's "no look-alike" is not settled there."""
    sentences = []
    for row in (getattr(discovery, 'at_cap', None) or []) if discovery is not None else []:
        named = ' + '.join(row['in_place_of'])
        sentences.append(
            f'The look-alike judgement of {row["term"]} against {named} rests on a fit ({row["fit"]}) stopped at its '
            f'evaluation cap, not converged ({row["term_excess_error"] * 1e3:.2f} mrad beyond the noise with the '
            f'term, {row["set_excess_error"] * 1e3:.2f} with {named}): a finished fit could bring the two closer, so '
            'whether the term imitates it is not settled by this check.')
    return sentences


def lookalike_terms(discovery) -> dict[str, list]:
    """{catalog effect: the discovered terms confounded with it} ({} when none): a term outside the catalog that
    explains the record as well in the effect's place, neither adding anything significant to the other."""
    twins: dict[str, list] = {}
    for term in (discovery.terms if discovery is not None else ()):
        if term.status == 'confounded':
            for effect in term.confounded_with:
                twins.setdefault(effect, []).append(term)
    return twins


def lookalike_clause(discovery) -> str:
    """'EFFECT or, in its place, the term outside the catalog EXPRESSION' for each named effect a discovered term is
    confounded with, joined ('' when none)."""
    return '; '.join(f'{effect} or, in its place, the term outside the catalog '
                     f'{" or ".join(t.term.expression for t in terms)}'
                     for effect, terms in lookalike_terms(discovery).items())


def _coefficient(term) -> tuple[float, float]:
    """The term's output-error coefficient and σ [its unit], or the weak form's when it was not refitted."""
    return term.coefficient()


def _value_text(term) -> str:
    """'value +- sigma UNIT', or 'value UNIT (weak-form screening value, no +-)' when it has no sigma."""
    value, sigma = _coefficient(term)
    if not math.isfinite(value):
        return f'no estimate [{term.term.unit}] (not screened by the weak form, and its refit gave none)'
    if not math.isfinite(sigma):
        return f'{value:.4g} {term.term.unit} ({"weak-form screening value, " if term.doubt else ""}no +-)'
    return f'{value:.4g} +- {sigma:.2g} {term.term.unit}'


def _doubt_lines(terms) -> list[str]:
    """The summary's line saying why screening values have no +- (said once; empty when none lacks one)."""
    doubt = next((t.doubt for t in terms if t.doubt), '')
    return [f'  {doubt[:1].upper()}{doubt[1:]}.'] if doubt else []


def _doubt_html(terms) -> str:
    """The report's paragraph saying why screening values have no +- ('' when none lacks one)."""
    doubt = next((t.doubt for t in terms if t.doubt), '')
    return f'<p>{html.escape(doubt[:1].upper() + doubt[1:])}.</p>' if doubt else ''

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
    return f'dW/dt += c * {term.term.expression} with c = {_value_text(term)}'


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
    capped = ' '.join(at_cap_sentences(discovery))
    if capped and not discovery.terms and discovery.note:
        return capped               # the look-alike check alone (the discovery stage did not run): its fits' doubt
    return ' '.join(part for part in (_found_sentence(discovery, noise_rms, explained_below), capped) if part)


def _found_sentence(discovery, noise_rms: float, explained_below: float) -> str:
    """:func:`discovery_sentence` without the evaluation-cap sentences."""
    confounded = [t for t in discovery.terms if t.status == 'confounded']
    lookalike = ''
    if confounded:
        best = confounded[0]
        lookalike = (f'The term {term_text(best)} ({best.term.reading}) explains the data as well as '
                     f'{" + ".join(best.confounded_with)} ({best.excess_after * 1e3:.2f} mrad beyond the noise): this '
                     f'data cannot tell them apart; {separating_experiment(best.term.expression)}.'
                     + differing_text(best))
    proven = [t for t in discovery.terms if t.status == 'proven']
    if proven and proven[0].excess_after > explained_below:
        best = proven[0]
        return (f'Outside the catalog, the term {term_text(best)} ({best.term.reading}) is significant but explains '
                f'only part of the error: {best.excess_before * 1e3:.2f} -> {best.excess_after * 1e3:.2f} mrad beyond '
                f'the noise ({best.share_removed * 100:.0f} %); the rest is unexplained, so it is a hint, not the '
                f'missing physics (try it with {" ".join(_quoted(best.add))}).' + (' ' + lookalike if lookalike
                                                                                   else ''))
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
                f'--write-discovered FILE.py --term \'{best.term.expression}\').' + (' ' + lookalike if lookalike
                                                                                     else ''))
    if lookalike:
        return lookalike
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


def motor_term_text(term) -> str:
    """'La dIa/dt = Va - R Ia - e + c * EXPRESSION with c = value +- sigma UNIT' for a motor-equation term.

    Parameters
    ----------
    term : MotorDiscoveredTerm [-]
        The term (:class:`aeropend_core.diagnosis.motor_discovery.MotorDiscoveredTerm`), coefficient SI.

    Returns
    -------
    str
        The term as the armature circuit reads it, SI units.
    """
    return f'La dIa/dt = Va - R Ia - e + c * {term.term.expression} with c = {_value_text(term)}'


def motor_sentence(motor, input_corrected: bool = False) -> str:
    """The verdict's sentence about a term proven in the motor equation ('' when none was).

    Parameters
    ----------
    motor : MotorDiscovery [-]
        The motor equation's discovery (:class:`aeropend_core.diagnosis.motor_discovery.MotorDiscovery`).
    input_corrected : bool [-]
        The pendulum's model was fitted and searched again on the thrust input rebuilt with the term.

    Returns
    -------
    str
        One sentence, currents in mA and SI units.
    """
    proven = motor.proven if motor is not None else []
    if not proven:
        return ''
    best = proven[0]
    return (f'In the motor equation (the armature current is measured), the data support the term '
            f'{motor_term_text(best)} ({best.term.reading}): it removes {best.share_removed * 100:.0f} % of the '
            f'held-out current error beyond the noise, {best.excess_before * 1e3:.2f} -> '
            f'{best.excess_after * 1e3:.2f} mA (noise '
            f'{motor.noise_rms * 1e3:.2f} mA); HAC t = {best.t_statistic:.1f}, training BIC {best.delta_bic:+.1f}, '
            f'held-out Diebold-Mariano {best.dm_statistic:+.1f}.'
            + (f' With the thrust input rebuilt from the corrected motor observer the pendulum\'s held-out error '
               f'beyond the noise goes {best.pendulum_excess_before * 1e3:.2f} -> '
               f'{best.pendulum_excess_after * 1e3:.2f} mrad'
               + ('.' if best.pendulum_excess_after <= best.pendulum_excess_before else
                  ': worse, so the term explains the current but not the motor\'s speed (the torque side of the '
                  'same effect may be missing too); the pendulum keeps the uncorrected observer\'s thrust input.')
               if math.isfinite(best.pendulum_excess_after) else '')
            + f' Put it in the motor observer with {" ".join(_quoted(best.add))}'
            + (' (the pendulum\'s parameters and the catalog search above are already those on the input rebuilt '
               'with it).' if input_corrected else
               ' (the pendulum\'s parameters above were fitted with the uncorrected observer).'))


def motor_lines(motor) -> list[str]:
    """The summary's lines about the motor equation's discovery (empty when it did not run).

    Parameters
    ----------
    motor : MotorDiscovery or None [-]
        The motor equation's discovery.

    Returns
    -------
    list of str
        A heading, the note when it did not search, then one line per term tried, best first.
    """
    if motor is None:
        return []
    lines = ['Discovery in the motor equation (armature current; weak-form screening, terms refitted in the observer):']
    if motor.note:
        lines.append(f'  {motor.note}')
    added = getattr(motor, 'added', None)
    if added is not None:
        lines.append(f'  ADDED      La dIa/dt = Va - R Ia - e + c * {added.term.expression} with c = {added.value:.4g} '
                     f'+- {added.sigma:.2g} {added.term.unit}: the current\'s held-out error beyond the noise '
                     f'{added.current_excess_before * 1e3:.2f} -> {added.current_excess_after * 1e3:.2f} mA (noise '
                     f'{motor.noise_rms * 1e3:.2f} mA)')
    for term in motor.terms:
        after = (f', current beyond noise {term.excess_before * 1e3:.2f} -> {term.excess_after * 1e3:.2f} mA, t = '
                 f'{term.t_statistic:.1f}, dBIC {term.delta_bic:+.1f}, DM {term.dm_statistic:+.1f}'
                 if math.isfinite(term.excess_after) else '')
        why = f' ({term.why_not})' if term.why_not and term.status != 'proven' else ''
        lines.append(f'  {term.status.upper():10s} {motor_term_text(term)}{after}{why}')
        if math.isfinite(term.pendulum_excess_after):
            lines.append(f'             with it as the thrust input, the pendulum\'s angle beyond noise '
                         f'{term.pendulum_excess_before * 1e3:.2f} -> {term.pendulum_excess_after * 1e3:.2f} mrad')
    return lines + _doubt_lines(motor.terms)


def separating_experiment(expression: str) -> str:
    """The experiment that separates a discovered term from the catalog set it is confounded with, by what the term
    is a function of.

    Parameters
    ----------
    expression : str [-]
        The term's expression (vocabulary names).

    Returns
    -------
    str
        One clause, e.g. 'add free decays from several angles ...'.
    """
    if 'thrust' in expression:
        clause = ('vary the step amplitudes (several thrust levels, each held until the rod rests) and add free decays '
                  'from rest at duty 0, so that the thrust and the angle stop moving together')
    elif 'angular_rate' in expression:
        clause = ('add free decays from several starting angles (a wide range of rod speeds, from the largest to '
                  'rest), where the speed\'s law (its power, a breakaway) shows in how the swing dies out')
    else:
        clause = ('add rests at several angles, at the bottom and in large excursions (70-85 deg), where the angle\'s '
                  'law (a harmonic, a spring, an offset) shows in the static thrust-to-angle curve')
    # A hint by the term's variables, not a prediction: with the thrust gain refitted, two angle laws can stay alike
    # at every rest the rig reaches (a cable spring and a hardening cubic do, to 85 deg); the experiment loop
    # designs the schedule on both fits and says when none separates them.
    return (f'an experiment that may separate them: {clause} (aeropend run --until-decided designs one within the '
            'rig\'s limits on both fits, and says when none exists)')


def _html_number(value: float, digits: int = 2, scale: float = 1.0, suffix: str = '') -> str:
    return f'{value * scale:.{digits}f}{suffix}' if value is not None and math.isfinite(value) else '&mdash;'


def _coefficient_html(term) -> str:
    value, sigma = _coefficient(term)
    if not math.isfinite(value):
        return '&mdash; <small>(not screened by the weak form, and its refit gave none)</small>'
    estimator = '' if math.isfinite(term.value) else ' <small>(weak form only)</small>'
    sigma_text = (f' &plusmn; {sigma:.2g}' if math.isfinite(sigma) else
                  ' <small>(screening value, no &plusmn;)</small>' if term.doubt else ' &plusmn; unknown')
    return f'{value:.4g}{sigma_text} {html.escape(term.term.unit)}{estimator}'


def discovery_html(discovery, noise_rms: float, source: str | None = None) -> str:
    """The HTML report's section on the discovery stage ('' when it did not run).

    Parameters
    ----------
    discovery : Discovery or None [-]
        The stage's result (:class:`aeropend_core.diagnosis.discovery.Discovery`).
    noise_rms : float [rad]
        The angle's measurement noise.
    source : str, optional [-]
        The recording's file name, for the command that adds the term.

    Returns
    -------
    str
        A ``<h2 id="discovery">`` section: each proven term as an equation with its coefficient +- 1 sigma and unit,
        the error beyond the noise before -> after (mrad) and the share it removes, the evidence, the physical
        reading and the command-line arguments that add it; then the terms tried and why they were not proven.
    """
    if discovery is None:
        return ''
    esc = html.escape
    data = shlex.quote(source) if source else 'DATA'
    parts = ['<h2 id="discovery">Discovery: a term outside the catalog</h2>',
             '<p class="caption">The catalog left error beyond the noise (or its choice was suspect), so the '
             'pendulum equation&rsquo;s discrepancy was regressed sparsely (weak form) over a vocabulary of '
             'physically typed terms; the strongest were each added as <code>dW/dt += c &middot; term</code>, '
             'refitted by output error and judged by the same evidence as a catalog effect (HAC t, training BIC, '
             f'held-out Diebold-Mariano, materiality). Measurement noise {_html_number(noise_rms, 2, 1e3)}'
             '&nbsp;mrad. A proven term is a hypothesis that removes the error, not a measured mechanism: '
             'lookalikes are named.</p>']
    if discovery.note:
        parts.append(f'<p>{esc(discovery.note)}</p>')
    parts.extend(f'<p>{esc(sentence)}</p>' for sentence in at_cap_sentences(discovery))
    for term in [t for t in discovery.terms if t.status == 'proven']:
        fall = (f'{_html_number(term.excess_before, 2, 1e3)} &rarr; <b>{_html_number(term.excess_after, 2, 1e3)}'
                f'</b>&nbsp;mrad')
        command = ' '.join(shlex.quote(a) for a in term.add)
        rows = [('equation', f'<span class="equation" style="display:inline-block;padding:2px 10px">dW/dt = '
                             f'&hellip; + c &middot; <code>{esc(term.term.expression)}</code></span>'),
                ('coefficient c &plusmn; 1&sigma;', _coefficient_html(term)),
                ('held-out error beyond the noise', f'<span class="down">{fall}</span> (removes '
                 f'{_html_number(term.share_removed, 0, 100)}&nbsp;% of it)'),
                ('evidence', f'HAC t = {_html_number(term.t_statistic, 1)}, training &Delta;BIC '
                             f'{_html_number(term.delta_bic, 1)}, held-out Diebold-Mariano '
                             f'{_html_number(term.dm_statistic, 1)}'),
                ('physical reading', esc(term.term.reading)),
                ('add it', f'<span class="next">aeropend diagnose {esc(data)} {esc(command)}</span>'),
                ('keep it', f'<span class="next">aeropend effects --write-discovered kept.py --term '
                            f'{esc(shlex.quote(term.term.expression))}</span>')]
        if term.replaces:
            rows.append(('replaces', f'{esc(" + ".join(term.replaces))}: with the term in the model the catalog '
                                     'set adds nothing significant (it was the term&rsquo;s shadow)'))
        if term.alternatives:
            rows.append(('lookalikes', f'{esc(", ".join(term.alternatives))} explain about as much on this data: '
                                       'excite larger angles and free decays to separate them'))
        parts.append(f'<h3>PROVEN: <code>{esc(term.term.expression)}</code></h3><table style="width:auto">'
                     + ''.join(f'<tr><th style="text-align:left">{label}</th><td>{value}</td></tr>'
                               for label, value in rows) + '</table>')
    others = [t for t in discovery.terms if t.status != 'proven']
    if others:
        rows = ''.join(
            f'<tr><td><code>{esc(t.term.expression)}</code></td><td>{esc(t.status.replace("_", " "))}</td>'
            f'<td class="num">{_coefficient_html(t)}</td><td class="num">{_html_number(t.excess_after, 2, 1e3)}</td>'
            f'<td>{esc(t.why_not or t.term.reading)}</td></tr>' for t in others)
        parts.append('<h3>Other terms tried</h3><table><tr><th>term</th><th>status</th><th>c &plusmn; 1&sigma;</th>'
                     '<th>beyond noise after [mrad]</th><th>why not proven / reading</th></tr>' + rows + '</table>')
        parts.append(_doubt_html(others))
    if not discovery.terms:
        parts.append('<p>No term of the vocabulary stands out from the noise in the discrepancy.</p>')
    return ''.join(parts)


def motor_html(motor) -> str:
    """The HTML report's section on the motor equation's discovery ('' when no term was tried).

    Parameters
    ----------
    motor : MotorDiscovery or None [-]
        The motor equation's discovery (:class:`aeropend_core.diagnosis.motor_discovery.MotorDiscovery`).

    Returns
    -------
    str
        A ``<h2 id="motor-discovery">`` section: one row per term tried, with its equation, c +- 1 sigma and unit,
        the current's held-out error beyond its noise before -> after [mA], the evidence and the status.
    """
    if motor is None or not motor.terms:
        return ''
    esc = html.escape
    rows = []
    for term in motor.terms:
        pendulum = (f'; pendulum {_html_number(term.pendulum_excess_before, 2, 1e3)} &rarr; '
                    f'{_html_number(term.pendulum_excess_after, 2, 1e3)}&nbsp;mrad'
                    if math.isfinite(term.pendulum_excess_after) else '')
        rows.append(f'<tr><td><code>{esc(term.term.expression)}</code></td><td>{esc(term.status.replace("_", " "))}'
                    f'</td><td class="num">{_coefficient_html(term)}</td>'
                    f'<td class="num">{_html_number(term.excess_before, 2, 1e3)} &rarr; '
                    f'{_html_number(term.excess_after, 2, 1e3)}{pendulum}</td>'
                    f'<td>t = {_html_number(term.t_statistic, 1)}, &Delta;BIC {_html_number(term.delta_bic, 1)}, '
                    f'DM {_html_number(term.dm_statistic, 1)}</td><td>{esc(term.why_not or term.term.reading)}</td>'
                    '</tr>')
    return ('<h2 id="motor-discovery">Discovery in the motor equation</h2>'
            '<p class="caption">The armature current is measured: its equation <code>La dIa/dt = Va - R Ia - e + c '
            '&middot; term</code> was screened in weak form and the strongest terms refitted in the motor observer by '
            f'output error, judged on the held-out current (noise {_html_number(motor.noise_rms, 2, 1e3)}&nbsp;mA). '
            'The pendulum&rsquo;s error is given with its thrust input rebuilt from the corrected observer.</p>'
            '<table><tr><th>term</th><th>status</th><th>c &plusmn; 1&sigma;</th><th>current beyond noise [mA]</th>'
            '<th>evidence</th><th>why not proven / reading</th></tr>' + ''.join(rows) + '</table>'
            + _doubt_html(motor.terms))


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
    lines.extend(f'  {sentence}' for sentence in at_cap_sentences(discovery))
    if not discovery.terms:
        alone = getattr(discovery, 'at_cap', None) and discovery.note      # the look-alike check alone
        lines.append('  no look-alike found by finished fits' if alone else
                     '  no term of the vocabulary stands out from the noise')
    for term in discovery.terms:
        after = (f', beyond noise {term.excess_before * 1e3:.2f} -> {term.excess_after * 1e3:.2f} mrad, t = '
                 f'{term.t_statistic:.1f}, dBIC {term.delta_bic:+.1f}, DM {term.dm_statistic:+.1f}'
                 if math.isfinite(term.excess_after) else '')
        why = f' ({term.why_not})' if term.why_not and term.status != 'proven' else ''
        lines.append(f'  {term.status.upper():10s} {term_text(term)}{after}{why}')
    return lines + _doubt_lines(discovery.terms)


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
    # the vocabulary's (and the kernel's) sign: a true sign in the power laws |W|^P sign W, smoothed as the catalog's
    # friction, tanh(W / 0.01 rad/s), alone and in Stribeck's terms (a written module is the term it was proven as)
    code = code.replace('*sign(angular_rate)', '*SIGN') if code.startswith('np.abs(angular_rate)**') else code
    code = code.replace('sign(angular_rate)', 'np.tanh(angular_rate / 0.01)').replace('SIGN', 'np.sign(angular_rate)')
    return code if code != '1' else '1.0 + 0.0 * angle'      # a float for a float (numba compiles it)


__all__ = ['differing_text', 'lookalike_terms', 'lookalike_clause',
           'separating_experiment', 'term_text', 'discovery_sentence', 'motor_term_text',
           'motor_sentence', 'motor_lines', 'motor_html', 'discovery_lines', 'discovery_html', 'effect_module_text']
