"""A self-contained HTML report of a diagnosis: one file, no script library and no external resource; every plot
is inline SVG (:mod:`aeropend_core.present.svgplot`) whose lines are decimated to what its pixels can show (a min/max
envelope per pixel column, :func:`aeropend_core.present.formatting.envelope`); the browser lays out its text and
ticks. A 60 s record gives a page of about 1.2 MB written in about half a second of CPU. Every sample is in the
page's CSV export (gzip-compressed).

The page answers, top to bottom: what is missing (the verdict and the key numbers with units), where the model
fails (measured vs simulated angle, error vs time with the worst windows, error by regime, residual correlation
tests like MATLAB ``resid``), which effect explains it (the candidate ranking with parameters +- 1 sigma), and
what adding it changed (before -> after); then the model itself (:mod:`aeropend_core.present.model_sections`):
the motor observer, the identified equation, the parameter correlation matrix and a CSV export of every trace.
Angles on the plots are in degrees; numbers in the text are in mrad.

Plots are plain strings built from NumPy arrays (no plotting library, no global state), so :func:`write_report` is
safe to call from a library, a CLI or a thread.
"""
from __future__ import annotations


import datetime
import math
import re
from pathlib import Path

import numpy as np

from aeropend_core.diagnosis.compare import Comparison
from aeropend_core.diagnosis.candidates import BIC_MARGIN, DM_MIN, MATERIAL, T_MIN, Candidate
from aeropend_core.diagnosis.thresholds import UNEXPLAINED_NOISE
from aeropend_core.diagnosis.validation import Validation
from aeropend_core.errors import AeropendError
from aeropend_core.signals.reduced import MAP_PARAMETERS
from aeropend_core.present.formatting import (
    BEFORE,
    CANDIDATE,
    CURRENT,
    MRAD_PER_DEGREE,
    SMOOTHING_SECONDS,
    VERDICT_CLASSES,
    VERDICT_TITLES,
    _best_candidate,
    _esc,
    _excess,
    _model_name,
    _mrad,
    _num,
    _sig,
    _unit_and_meaning,
)
from aeropend_core.present.model_checks import (band_section, correlation_section, scatter_section,
                                                validation_section)
from aeropend_core.present.discovery_text import discovery_html, motor_html
from aeropend_core.present.plain_verdict import plain_verdict
from aeropend_core.present.svgplot import ZOOM_CSS, ZOOM_SCRIPT
from aeropend_core.present.verdict_text import verdict_of
from aeropend_core.present.model_sections import model_sections
from aeropend_core.present.plots import (
    _plot_candidates,
    _plot_error,
    _plot_overlay,
    _plot_regimes,
)
from aeropend_core.present.result_types import DiagnosisLike



CSS = """
body { font-family: 'DejaVu Sans', Arial, Helvetica, sans-serif; color: #222; margin: 0; background: #f4f5f7; }
main { max-width: 1180px; margin: 0 auto; padding: 18px 24px 40px; background: #fff; }
h1 { font-size: 22px; margin: 6px 0 2px; }
h2 { font-size: 18px; margin: 30px 0 6px; padding-top: 8px; border-top: 2px solid #e3e6ea; }
h3 { font-size: 15px; margin: 16px 0 4px; }
p, li { line-height: 1.45; font-size: 14.5px; }
.sub { color: #555; margin: 0 0 10px; }
.verdict { border-radius: 6px; padding: 12px 16px; margin: 12px 0; border-left: 8px solid; }
.verdict .title { font-size: 20px; font-weight: bold; margin-bottom: 4px; }
.verdict.found { background: #fff1e6; border-color: #e66101; }
.verdict.ok { background: #e9f6ec; border-color: #1a9641; }
.verdict.warn { background: #fffbe0; border-color: #d9a400; }
.verdict.bad { background: #fdecec; border-color: #d7301f; }
.verdict .plain { font-size: 16px; }
details.evidence { margin-top: 6px; font-size: 13.5px; } details.evidence summary { cursor: pointer; color: #1f63b4; }
.next { font-family: 'DejaVu Sans Mono', monospace; background: #f1f1f1; padding: 2px 6px; border-radius: 3px; }
.cards { display: flex; flex-wrap: wrap; gap: 10px; margin: 10px 0; }
.card { flex: 1 1 200px; border: 1px solid #dde1e6; border-radius: 6px; padding: 8px 12px; background: #fafbfc; }
.card .label { font-size: 12px; color: #555; text-transform: uppercase; letter-spacing: .03em; }
.card .value { font-size: 24px; font-weight: bold; margin: 2px 0; }
.card .value.bad { color: #b2182b; }
.card .value.ok { color: #1a9641; }
.card .hint { font-size: 12px; color: #555; line-height: 1.35; }
.card .was { font-size: 13px; color: #444; }
img { max-width: 100%; display: block; margin: 6px 0; }
figure.plot { margin: 6px 0 10px; }
svg.plot { width: 100%; height: auto; display: block; overflow: visible; }
.legend { font-size: 12.5px; color: #333; margin: 2px 0 0 60px; line-height: 1.6; }
.legend .key { display: inline-block; margin-right: 16px; white-space: nowrap; }
.legend .key svg { vertical-align: middle; margin-right: 5px; }
.caption { font-size: 13px; color: #444; margin: 2px 0 10px; }
table { border-collapse: collapse; margin: 8px 0; font-size: 13.5px; width: 100%; }
th, td { border-bottom: 1px solid #e3e6ea; padding: 5px 8px; text-align: left; vertical-align: top; }
th { background: #f0f2f5; font-weight: 600; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
tr.significant td { background: #eaf7ee; }
tr.expl td { font-size: 12.5px; color: #444; border-bottom: 2px solid #d5d9de; padding-top: 0; }
tr.main td { border-bottom: none; }
.badge { display: inline-block; padding: 1px 7px; border-radius: 10px; font-size: 11.5px; font-weight: bold; }
.badge.yes { background: #1a9641; color: #fff; }
.badge.no { background: #e0e0e0; color: #444; }
.badge.na { background: #fdd; color: #900; }
.badge.best { background: #e66101; color: #fff; }
.up { color: #b2182b; } .down { color: #1a9641; }
.notes li { margin: 4px 0; }
.bar { display: inline-block; height: 10px; background: #7b3294; vertical-align: middle; }
nav { font-size: 13px; margin: 6px 0 0; color: #555; }
nav a { color: #1f63b4; text-decoration: none; margin-right: 12px; }
footer { margin-top: 30px; font-size: 12px; color: #666; border-top: 1px solid #e3e6ea; padding-top: 8px; }
code { font-family: 'DejaVu Sans Mono', monospace; font-size: 92%; }
.plot { margin: 6px 0 10px; }
.equation { font-family: 'DejaVu Serif', Georgia, serif; font-size: 17px; line-height: 1.8; background: #f7f8fa;
  border-left: 4px solid #1f63b4; padding: 8px 14px; margin: 8px 0; }
.terms { font-size: 13.5px; margin: 4px 0 10px; } .terms .term { display: inline-block; margin-right: 14px; }
table.correlation td, table.correlation th { text-align: center; padding: 4px 7px; }
ul.columns { columns: 3 220px; font-size: 12.5px; margin: 4px 0 8px; padding-left: 18px; }
ul.columns code { overflow-wrap: anywhere; }
button { font-size: 14px; padding: 6px 14px; border-radius: 4px; border: 1px solid #1f63b4; background: #eaf1fb;
  cursor: pointer; }
"""


def _noise_limited_fit(diagnosis: DiagnosisLike) -> float:
    """Fit % a perfect model would reach at this noise: 100 (1 - noise / std of the held-out angle)."""
    prep = diagnosis.prepared
    index = prep.heldout.residual_index
    spread = float(np.std(prep.angle[index]))
    return 100.0 * (1.0 - diagnosis.noise_rms / spread) if spread > 0 else float('nan')


def _verdict_html(diagnosis: DiagnosisLike, source: str | None = None) -> str:
    title = VERDICT_TITLES.get(diagnosis.verdict, diagnosis.verdict).format(
        missing=', '.join(diagnosis.missing_effects) or diagnosis.missing_effect)
    css = VERDICT_CLASSES.get(diagnosis.verdict, 'warn')
    parts = [f'<section class="verdict {css}" id="verdict"><div class="title">{_esc(title)}</div>',
             f'<div class="plain">{_esc(_plain(plain_verdict(diagnosis, source, report=True)))}</div>',
             f'<details class="evidence"><summary>The evidence (the statistics behind the verdict)</summary>'
             f'<div>{_esc(_plain(_without_title(verdict_of(diagnosis))))}</div></details>']
    proven = diagnosis.discovery.proven if getattr(diagnosis, 'discovery', None) is not None else []
    if diagnosis.verdict == 'term_discovered' and proven:
        parts.append('<div style="margin-top:6px">The term, its &plusmn; and its lookalikes: <a href="#discovery">'
                     'see below</a>.</div>')
    if diagnosis.notes:
        parts.append(f'<div style="margin-top:6px">{len(diagnosis.notes)} note(s) on confounding and experiments: '
                     f'<a href="#notes">see below</a>.</div>')
    if diagnosis.residual_structure:
        parts.append('<div style="margin-top:6px">What the residual correlates with, as a lead for a new effect: '
                     '<a href="#structure">see below</a>.</div>')
    parts.append('</section>')
    return ''.join(parts)


#: Openings of a verdict message that only repeat the banner's title (the title says it already).
_TITLE_REPEATS = re.compile(r'^(missing effects?|nothing significant is missing)\s*:\s*', re.IGNORECASE)


def _without_title(message: str) -> str:
    """The verdict message without an opening that repeats the banner's title."""
    rest = _TITLE_REPEATS.sub('', message, count=1)
    first_word = rest.split(' ', 1)[0]
    # a sentence starts with a capital; an effect's snake_case name keeps its spelling
    return rest[:1].upper() + rest[1:] if rest != message and '_' not in first_word else rest


def _plain(text: str) -> str:
    """Text for the page without an 'inf' (an unbounded interval or ratio said in a word)."""
    return re.sub(r'(?<![\w.])[+-]?inf(?![\w])', 'unbounded', text)


def _quality_html(diagnosis: DiagnosisLike) -> str:
    """The data-quality gate's findings, above the verdict: every repair and warning the numbers depend on."""
    findings = diagnosis.findings
    if not findings:
        return '<p class="sub" id="data-quality">Data quality: clean (no repairs, no warnings).</p>'
    items = ''.join(f'<li><b>{_esc(f.severity)}</b> ({_esc(f.code)}): {_esc(f.message)}</li>' for f in findings)
    return (f'<section class="verdict warn" id="data-quality"><div class="title">Data quality: {len(findings)} '
            f'finding(s)</div><div>Every number on this page comes from the data as repaired:</div><ul>{items}</ul>'
            '</section>')


def _within_noise_text(excess: float, noise: float) -> str:
    ratio = excess / noise if noise > 0 else float('inf')
    if excess <= UNEXPLAINED_NOISE * noise:
        return f'within the noise ({ratio:.2f}&times; the noise RMS; limit {UNEXPLAINED_NOISE:g}&times;)'
    return (f'{ratio:.2f}&times; the noise RMS: the model misses the data (within the noise below '
            f'{UNEXPLAINED_NOISE:g}&times;)')


def _card(label: str, value: str, hint: str, key: str = '', was: str = '') -> str:
    was_html = f'<div class="was">{was}</div>' if was else ''
    return (f'<div class="card"><div class="label">{label}</div><div class="value {key}">{value}'
            f'</div>{was_html}<div class="hint">{hint}</div></div>')


def _cards_html(diagnosis: DiagnosisLike) -> str:
    current, before = diagnosis.current, diagnosis.before
    evaluation = current.evaluation
    prep = diagnosis.prepared
    noise = diagnosis.noise_rms
    heldout_seconds = prep.time[-1] - prep.time[prep.split] + prep.sample_time
    def was(old: float, new: float, text: str, higher_is_better: bool = False) -> str:
        if before is None:
            return ''
        better = (new > old) if higher_is_better else (new < old)
        arrow = '&#9650;' if new > old else '&#9660;'
        css = 'down' if better else 'up'
        return (f'<span class="{css}">{arrow}</span> from {text} without '
                f'{_esc(", ".join(e for e in current.effects if e not in before.effects))}')
    cards = [
        _card('Held-out fit', _num(current.fit_percent, 2, suffix='&nbsp;%'),
              f'NRMSE fit of the free-run simulated angle on the held-out last {heldout_seconds:.1f} s, as MATLAB '
              f'<code>compare</code>: 100&nbsp;(1&nbsp;&minus;&nbsp;&#8214;y&minus;&#375;&#8214;&nbsp;/&nbsp;'
              f'&#8214;y&minus;mean&nbsp;y&#8214;). A perfect model reaches only about '
              f'{_num(_noise_limited_fit(diagnosis), 1)}&nbsp;% at this noise.',
              was=was(before.fit_percent, current.fit_percent, _num(before.fit_percent, 2, suffix='&nbsp;%'), True)
              if before is not None else ''),
        _card('Model error beyond noise', _mrad(_excess(current)),
              f'<b>{_within_noise_text(_excess(current), noise)}</b>. '
              '&radic;(RMS error&sup2; &minus; noise&sup2;) on the held-out part: the number to watch.',
              key='ok' if _excess(current) <= UNEXPLAINED_NOISE * noise else 'bad',
              was=was(_excess(before), _excess(current), _mrad(_excess(before))) if before is not None else ''),
        _card('Held-out RMS error', _mrad(current.rms_error),
              f'measured &minus; simulated angle ({_num(current.rms_error, 2, 180 / math.pi)}&deg;)',
              was=was(before.rms_error, current.rms_error, _mrad(before.rms_error)) if before is not None else ''),
        _card('Measurement noise', _mrad(noise),
              f'RMS of the angle\'s noise, estimated from the data itself ({_num(noise, 3, 180 / math.pi)}&deg;)'),
        _card(f'{evaluation.prediction_horizon:g}&nbsp;s-ahead prediction', _mrad(evaluation.prediction_rms),
              f'RMS error of the model restarted from the measured state every '
              f'{evaluation.prediction_horizon:g}&nbsp;s (held-out part)'),
    ]
    return '<div class="cards">' + ''.join(cards) + '</div>'


def _observer_meaning(name: str, motor, meaning: str) -> str:
    """With the motor observer the thrust input is its back-EMF e, not Va - R Ia."""
    if name == 'thrust_gain' and motor is not None:
        return 'thrust term per e|e|, e = the motor observer\'s back-EMF [V] (eq (5) with R Ia removed)'
    return meaning


def _parameter_rows(comparison: Comparison, diagnosis: DiagnosisLike) -> str:
    rows = []
    motor = diagnosis.prepared.motor if diagnosis.prepared is not None else None
    errors = diagnosis.reported_errors(comparison)
    warnings = diagnosis.parameter_warnings
    from aeropend_core.diagnosis.doubts import rate_doubts
    prep = diagnosis.prepared
    doubts = rate_doubts(getattr(prep, 'sample_time', None), getattr(prep, 'reduced', False))
    doubts.update(getattr(diagnosis, 'parameter_doubts', {}))         # e.g. Ra against a current's scale
    reported = diagnosis.reported_parameters(comparison)
    if motor is not None:            # the observer's R is shown from the comparison's row below
        reported = {**reported, 'armature_resistance': comparison.parameters.get('armature_resistance', 0.0)}
    for name, value in reported.items():
        unit, meaning = _unit_and_meaning(name)
        unit = MAP_PARAMETERS.get(name, unit)
        sigma = errors.get(name, float('nan'))
        relative = abs(sigma / value) * 100 if value and np.isfinite(sigma) else float('nan')
        shown = f'{_sig(value)} &plusmn; {_sig(sigma, 2)}'
        if name in warnings:
            shown += f' <b style="color:#b00">&#9888; {_esc(warnings[name])}</b>'
        if name in doubts:
            shown += f' <i>({_esc(doubts[name])})</i>'
        if name == 'armature_resistance' and motor is not None:
            shown = (f'{_sig(motor.parameters["motor_resistance"])} &plusmn; '
                     f'{_sig(motor.standard_errors.get("motor_resistance", float("nan")), 2)} (motor observer)')
            meaning = ('the motor observer\'s back-EMF is the thrust input, so R is 0 in the pendulum model; '
                       'shown: the armature resistance the observer estimated')
            relative = float('nan')
            if name in doubts:                          # a current's scale: said beside the observer's value
                shown += f' <b style="color:#b00">{_esc(doubts[name])}</b>'
        meaning = _observer_meaning(name, motor, meaning)
        rows.append(f'<tr><td><code>{_esc(name)}</code></td><td class="num">{shown}</td><td>{_esc(unit)}</td>'
                    f'<td class="num">{_num(relative, 1, suffix="&nbsp;%")}</td><td>{_esc(meaning)}</td></tr>')
    return ('<table><tr><th>parameter</th><th>value &plusmn; 1&sigma;</th><th>unit (SI)</th><th>1&sigma; / value'
            '</th><th>meaning</th></tr>' + ''.join(rows) + '</table>')


def _worst_windows_html(diagnosis: DiagnosisLike) -> str:
    rows = []
    for rank, window in enumerate(diagnosis.current.evaluation.worst_windows, 1):
        rows.append(f'<tr><td>#{rank}</td><td class="num">{window["start"]:.1f} &ndash; {window["stop"]:.1f}</td>'
                    f'<td>{_esc(window["part"])}</td><td class="num">{_mrad(window["rms_error"])}</td>'
                    f'<td>{_esc(window["input"])}</td></tr>')
    if not rows:
        return ''
    return ('<table><tr><th>window</th><th>time [s]</th><th>part</th><th>RMS error</th><th>what the input was '
            'doing</th></tr>' + ''.join(rows) + '</table>')


def _regime_table(diagnosis: DiagnosisLike, best: Candidate | None) -> str:
    current = diagnosis.current.evaluation.regimes
    before = diagnosis.before.evaluation.regimes if diagnosis.before is not None else None
    after = best.comparison.evaluation.regimes if best is not None else None
    head = '<tr><th>regime</th><th>share of samples</th>'
    if before is not None:
        head += '<th>RMS error, before</th>'
    head += '<th>RMS error, model as given</th><th>&times; its overall RMS</th>'
    if after is not None:
        head += f'<th>RMS error, + {_esc(best.effect)}</th>'
    rows = []
    for name, stats in sorted(current.items(), key=lambda kv: -kv[1]['ratio_to_overall']):
        row = f'<tr><td>{_esc(name)}</td><td class="num">{stats["fraction_of_samples"] * 100:.0f}&nbsp;%</td>'
        if before is not None:
            row += f'<td class="num">{_mrad(before.get(name, {}).get("rms_error"), 1)}</td>'
        row += (f'<td class="num">{_mrad(stats["rms_error"], 1)}</td>'
                f'<td class="num">{_num(stats["ratio_to_overall"], 2)}</td>')
        if after is not None:
            row += f'<td class="num">{_mrad(after.get(name, {}).get("rms_error"), 1)}</td>'
        rows.append(row + '</tr>')
    return '<table>' + head + '</tr>' + ''.join(rows) + '</table>'


def _percent_change(value: float) -> str:
    if not np.isfinite(value):
        return '&mdash;'
    return '0&nbsp;%' if abs(value) < 0.5 else f'{value:+.0f}&nbsp;%'


def _parameters_with_sigma(candidate: Candidate) -> str:
    parts = []
    for name, value in candidate.parameters.items():
        unit, _ = _unit_and_meaning(name)
        sigma = candidate.standard_errors.get(name, float('nan'))
        sigma_text = f' &plusmn; {_sig(sigma, 2)}' if np.isfinite(sigma) and sigma > 0 else ''
        parts.append(f'<code>{_esc(name)}</code> = {_sig(value)}{sigma_text} {_esc(unit)}')
    return '<br>'.join(parts) or '&mdash;'


def _candidates_table(diagnosis: DiagnosisLike) -> str:
    rows = []
    from aeropend_core.diagnosis.doubts import chain_confusions
    # the pairs the notes call indistinguishable are named in the column too (never a dash beside such a note)
    chain = chain_confusions(diagnosis.found, [*diagnosis.effects, *(f.effect for f in diagnosis.found)])
    for rank, candidate in enumerate(diagnosis.candidates, 1):
        if candidate.comparison is None:
            badge = '<span class="badge na">not testable</span>'
        elif candidate.effect in diagnosis.missing_effects:
            badge = '<span class="badge best">SELECTED: missing</span>'
        elif candidate.significant:
            badge = '<span class="badge yes">significant alone</span><br><small>not selected: redundant with the ' \
                    'selected set</small>'
        else:
            badge = '<span class="badge no">no</span>'
        css = 'main significant' if candidate.effect in diagnosis.missing_effects else 'main'
        change = (_percent_change(-candidate.improvement * 100) if candidate.comparison is not None
                  and candidate.excess_before > 0 else 'nothing to remove')
        found = next((f for f in diagnosis.found if f.effect == candidate.effect), None)
        together = [*candidate.confounded_with, *(found.confounded_with if found is not None else ()),
                    *chain.get(candidate.effect, ())]
        confounded = ', '.join(_esc(c) for c in dict.fromkeys(together)) or '&mdash;'
        if chain.get(candidate.effect):
            confounded += ' <small>(this record cannot tell them apart; <a href="#notes">notes</a>)</small>'
        rows.append(
            f'<tr class="{css}"><td>{rank}</td><td><b>{_esc(candidate.effect)}</b></td><td>{badge}</td>'
            f'<td class="num">{_num(candidate.fit_percent, 2, suffix="&nbsp;%")}</td>'
            f'<td class="num">{_mrad(candidate.excess_after)} <small>({change})</small><br>'
            f'<small>RMS {_mrad(candidate.rms_error)}</small></td>'
            f'<td class="num">{_num(candidate.delta_bic, 1)}</td><td>{_parameters_with_sigma(candidate)}</td>'
            f'<td>{confounded}</td></tr>')
        detail = _esc(_plain(candidate.explanation or candidate.error))
        if candidate.evidence and 'Improved most' not in (candidate.explanation or ''):
            detail += '<br><b>Evidence</b> (regimes that improved most): ' + '; '.join(
                _esc(e) for e in candidate.evidence)
        rows.append(f'<tr class="expl"><td></td><td colspan="7">{detail}</td></tr>')
    head = ('<tr><th>#</th><th>effect added</th><th>verdict</th><th>held-out fit</th>'
            '<th>error beyond noise (change)<br><small>held-out RMS error</small></th>'
            '<th>&Delta;BIC (training)</th><th>estimated parameters &plusmn; 1&sigma; (SI)</th>'
            '<th>confounded with</th></tr>')
    return '<table id="candidate-table">' + head + ''.join(rows) + '</table>'


def _before_after_html(diagnosis: DiagnosisLike) -> str:
    before, current = diagnosis.before, diagnosis.current
    noise = diagnosis.noise_rms

    def arrow(old: float, new: float, lower_is_better: bool = True, digits: int = 2, scale: float = 1.0,
              unit: str = '') -> str:
        if not (np.isfinite(old) and np.isfinite(new)):
            return '&mdash;'
        better = new < old if lower_is_better else new > old
        css = 'down' if better else 'up'
        relative = f' ({(new - old) / old * 100:+.0f}&nbsp;%)' if old else ''
        return (f'<span class="{css}">{old * scale:.{digits}f} &rarr; <b>{new * scale:.{digits}f}</b>{unit}'
                f'{relative}</span>')

    rows = [
        ('held-out fit (NRMSE %, MATLAB compare)', arrow(before.fit_percent, current.fit_percent, False, 2, 1,
                                                        '&nbsp;%')),
        ('model error beyond the noise', arrow(_excess(before), _excess(current), True, 2, 1e3, '&nbsp;mrad')),
        ('held-out RMS error', arrow(before.rms_error, current.rms_error, True, 2, 1e3, '&nbsp;mrad')),
        (f'{current.evaluation.prediction_horizon:g} s-ahead prediction RMS error',
         arrow(before.evaluation.prediction_rms, current.evaluation.prediction_rms, True, 2, 1e3, '&nbsp;mrad')),
    ]
    summary = ''.join(f'<tr><td>{label}</td><td class="num">{value}</td></tr>' for label, value in rows)
    text = (f'<p class="caption">Model before: <b>{_esc(_model_name(before.effects))}</b>; after: '
            f'<b>{_esc(_model_name(current.effects))}</b>. Both fitted on the same training part and judged on the '
            f'same held-out part; the measurement noise is {_mrad(noise)}, so raw fit % cannot rise far: watch the '
            f'error beyond the noise.</p>')
    moves = []
    motor = diagnosis.prepared.motor if diagnosis.prepared is not None else None
    for name, new in current.parameters.items():
        unit, meaning = _unit_and_meaning(name)
        if name == 'armature_resistance' and motor is not None:
            continue
        meaning = _observer_meaning(name, motor, meaning)
        old = before.parameters.get(name)
        sigma = current.fit.standard_errors.get(name, float('nan'))
        if old is None:
            moves.append(f'<tr><td><code>{_esc(name)}</code></td><td class="num">(not in the model)</td>'
                         f'<td class="num">{_sig(new)} &plusmn; {_sig(sigma, 2)}</td><td>{_esc(unit)}</td>'
                         f'<td class="num">new</td><td>{_esc(meaning)}</td></tr>')
            continue
        change = (new - old) / old * 100 if old else float('nan')
        emphasis = ' style="font-weight:bold"' if np.isfinite(change) and abs(change) >= 10 else ''
        moves.append(f'<tr><td><code>{_esc(name)}</code></td><td class="num">{_sig(old)}</td>'
                     f'<td class="num">{_sig(new)} &plusmn; {_sig(sigma, 2)}</td><td>{_esc(unit)}</td>'
                     f'<td class="num"{emphasis}>{_num(change, 1, suffix="&nbsp;%")}</td><td>{_esc(meaning)}</td>'
                     f'</tr>')
    return (text + '<table style="width:auto"><tr><th>held-out measure</th><th>before &rarr; after</th></tr>'
            + summary + '</table><h3>How the parameters moved</h3><p class="caption">A nominal parameter that moves a '
            'lot was absorbing the missing effect (e.g. damping standing in for dry friction). Bold: moved by '
            '10 % or more.</p><table><tr><th>parameter</th><th>before</th><th>after &plusmn; 1&sigma;</th>'
            '<th>unit</th><th>change</th><th>meaning</th></tr>' + ''.join(moves) + '</table>')


def _structure_html(diagnosis: DiagnosisLike) -> str:
    rows = []
    for row in diagnosis.residual_structure:
        r = float(row['correlation'])
        rows.append(f'<tr><td>{_esc(row["signature"])}</td><td class="num">{r:+.2f}</td>'
                    f'<td><span class="bar" style="width:{abs(r) * 300:.0f}px"></span></td></tr>')
    return ('<p class="caption">Correlation of the simulation residual (measured &minus; simulated angle) with '
            'signatures of possible missing terms. A strong one is a lead for a new effect: write a small function '
            'and register it with <code>aeropend_core.model.effects.register_effect</code>, then rerun with '
            '<code>--effects-module my_effects.py</code>.</p><table style="width:auto"><tr><th>signature</th>'
            '<th>r</th><th>|r|</th></tr>' + ''.join(rows) + '</table>')


def render_report(diagnosis: DiagnosisLike, source: str | None = None, validation: Validation | None = None) -> str:
    """The report as one HTML string (see :func:`write_report`)."""
    if diagnosis.prepared is None:
        raise AeropendError('this diagnosis carries no prepared recording; run diagnose() on a recording to '
                            'make a report')
    best = _best_candidate(diagnosis)
    if best is not None and diagnosis.before is not None and not best.significant:
        best = None         # after --add: a candidate that adds nothing is not drawn beside the model (no line)
    prep = diagnosis.prepared
    model = _model_name(diagnosis.effects)
    heldout_from = prep.time[prep.split]
    title = 'aeropend diagnosis' + (f': {source}' if source else '')
    sections = []
    nav = ['<a href="#overlay">1 angle</a>', '<a href="#error">2 error vs time</a>',
           '<a href="#regimes">3 by regime</a>', '<a href="#residuals">4 residual tests</a>',
           '<a href="#candidates">5 candidates</a>']
    if diagnosis.before is not None:
        nav.append('<a href="#before-after">6 before &rarr; after</a>')
    if getattr(diagnosis, 'discovery', None) is not None:
        nav.append('<a href="#discovery">discovery</a>')
    if getattr(diagnosis, 'motor_discovery', None) is not None and diagnosis.motor_discovery.terms:
        nav.append('<a href="#motor-discovery">motor discovery</a>')
    if validation is not None:
        nav.append('<a href="#validation">validation record</a>')
    nav.append('<a href="#parameters">parameters</a>')
    nav += ['<a href="#observer">motor observer</a>', '<a href="#equation">equation</a>',
            '<a href="#correlation">correlation</a>', '<a href="#export">CSV</a>']
    if diagnosis.notes:
        nav.append('<a href="#notes">notes</a>')
    if diagnosis.residual_structure:
        nav.append('<a href="#structure">residual structure</a>')
    if getattr(diagnosis, 'state_map', None) is not None:
        nav.append('<a href="#state-map">where it fails</a>')

    header = (f'<h1>{_esc(title)}</h1><p class="sub">Model: <b>{_esc(model)}</b>'
              + (f' (compared with <b>{_esc(_model_name(diagnosis.before.effects))}</b>)'
                 if diagnosis.before is not None else '')
              + f' &middot; {prep.duration:.1f} s recorded at {1 / prep.sample_time:.0f} Hz; fitted on '
              f't &lt; {heldout_from:.1f} s, judged on the held-out t &ge; {heldout_from:.1f} s &middot; only Va, '
              f'Ia and the angle are used</p><nav>' + ''.join(nav) + '</nav>')
    sections.append(header + _quality_html(diagnosis) + _verdict_html(diagnosis, source) + _cards_html(diagnosis))

    best_text = (f', the best candidate (<span style="color:{CANDIDATE}">+ {_esc(best.effect)}</span>, dashed)'
                 if best is not None else '')
    before_text = (f', the model before (<span style="color:{BEFORE}">{_esc(_model_name(diagnosis.before.effects))}'
                   f'</span>, dotted)' if diagnosis.before is not None else '')
    sections.append(
        '<h2 id="overlay">1. Measured vs simulated angle</h2>'
        f'<p class="caption">Measured angle (grey), the model as given (<span style="color:{CURRENT}">blue</span>)'
        f'{best_text}{before_text}. Angles in <b>degrees</b> on the plots (1&deg; = {MRAD_PER_DEGREE:.2f} mrad; '
        'the numbers in the text are mrad). Shaded yellow: the held-out part, simulated free-running from the '
        'measured Va and Ia after estimating its initial state on its first second; the fit % is computed there. '
        'On the training part each ~10 s segment (dotted lines) restarts from a fitted initial state. Bottom: the '
        'armature voltage driving the rig. Each line keeps the smallest and largest sample of every pixel column '
        '(all samples are in the CSV export below).</p>'
        + _plot_overlay(diagnosis, best)
        + band_section(diagnosis))

    sections.append(
        '<h2 id="error">2. Error vs time: where the model fails</h2>'
        '<p class="caption">Measured minus simulated angle in mrad: raw (faint) and a '
        f'{SMOOTHING_SECONDS:g} s running mean (bold) that shows the model error under the noise. Grey band: '
        '&plusmn; the measurement noise RMS; an error that stays inside it is noise. Salmon spans #1&ndash;#5: the '
        'one-second windows with the largest RMS error (table below). Yellow: held-out part.</p>'
        + _plot_error(diagnosis, best)
        + _worst_windows_html(diagnosis))

    sections.append(
        '<h2 id="regimes">3. Error by regime</h2>'
        '<p class="caption">Model error beyond the measurement noise in each operating regime, over the training '
        'segments and the held-out part (the noise is the same everywhere, so it is taken out to show the '
        'differences; the table gives the raw RMS errors). A regime much above the others points at the missing '
        'physics: e.g. direction reversals for dry friction, large angles for a cable spring, just after steps for '
        'a thrust lag, low thrust for a dead zone.</p>'
        + _plot_regimes(diagnosis, best) + _regime_table(diagnosis, best))

    sections.append(
        '<h2 id="residuals">4. Residual tests (as MATLAB <code>resid</code>, to long lags)</h2>'
        + scatter_section(diagnosis) + correlation_section(diagnosis, best))

    chart = _plot_candidates(diagnosis)
    sections.append(
        '<h2 id="candidates">5. Which effect is missing: candidate ranking</h2>'
        f'<p class="caption">Each catalog effect not yet in the model was added, the model refitted on the training '
        f'part and judged on the held-out part. Best first. A candidate is <b>significant</b> when its parameter '
        f'is more than {T_MIN:g} HAC standard errors from zero, it lowers the training BIC (effective sample '
        f'count) by more than {BIC_MARGIN:g}, and it predicts the held-out part better (Diebold-Mariano above '
        f'{DM_MIN:g}, mean-square error lower by more than ({MATERIAL:g}&times; the noise)&sup2;). The search '
        f'adds the strongest, tries the others on top of it and drops effects made redundant: the result is the '
        f'<b>selected set</b> (orange, as in the verdict). A light-green arrow is significant when tried alone but '
        f'not selected (the selected set already explains what it would); grey is not significant. The chart '
        f'starts with the reference models (before &rarr; after when the model was given <code>--add</code>); each '
        f'candidate is an arrow from the model as given to the error with that candidate added. The effects\' '
        f'equations cite the source paper\'s eq (5) (the quasi-static thrust f_eq5) and eq (6) (the rod\'s angular '
        f'acceleration), written out with their numbers in <a href="#equation">the identified equation</a>.</p>'
        + (chart or '')
        + _candidates_table(diagnosis))

    if diagnosis.before is not None:
        sections.append('<h2 id="before-after">6. Before &rarr; after adding '
                        f'{_esc(", ".join(e for e in diagnosis.effects if e not in diagnosis.before.effects))}</h2>'
                        + _before_after_html(diagnosis))

    if getattr(diagnosis, 'discovery', None) is not None:
        sections.append(discovery_html(diagnosis.discovery, diagnosis.noise_rms, source))
    sections.append(motor_html(getattr(diagnosis, 'motor_discovery', None)))
    if validation is not None:
        sections.append(validation_section(diagnosis, validation))
    sections.append(f'<h2 id="parameters">Parameters of the model as given ({_esc(model)})</h2>'
                    '<p class="caption">Fitted on the training part by output error (free-run simulation); '
                    '&plusmn; 1&sigma; from the Gauss-Newton covariance, inflated for residual correlation. '
                    'Per unit inertia, as they enter the angular acceleration.</p>'
                    + _parameter_rows(diagnosis.current, diagnosis))
    sections += model_sections(diagnosis, best, Path(source).stem if source else 'aeropend')

    if diagnosis.notes:
        sections.append('<h2 id="notes">Notes: confounding and suggested experiments</h2><ul class="notes">'
                        + ''.join(f'<li>{_esc(n)}</li>' for n in diagnosis.notes) + '</ul>')
    if diagnosis.residual_structure:
        sections.append('<h2 id="structure">Structure of the unexplained residual</h2>' + _structure_html(diagnosis))
    from aeropend_core.present.state_map_text import state_map_html
    sections.append(state_map_html(diagnosis))

    stamp = datetime.datetime.now(datetime.UTC).strftime('%Y-%m-%d %H:%M UTC')
    sections.append(f'<footer>Generated by <code>aeropend diagnose</code> on {stamp}; the diagnosis took '
                    f'{diagnosis.seconds:.1f} s. Angles in rad/mrad in the text, degrees on the plots; parameters in '
                    'SI. Self-contained: no external resources'
                    + ' (plots are inline SVG; the CSV export is decompressed by the browser itself).</footer>')
    return ('<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            '<meta name="viewport" content="width=device-width, initial-scale=1">'
            f'<title>{_esc(title)}</title><style>{CSS}{ZOOM_CSS}</style>'
            + '</head><body><main>'
            + '\n'.join(sections) + f'</main>{ZOOM_SCRIPT}</body></html>\n')


def write_report(diagnosis: DiagnosisLike, path: str | Path, source: str | None = None,
                 validation: Validation | None = None) -> Path:
    """Write the diagnosis as one self-contained HTML file (plots and data embedded) and return its path.

    Parameters
    ----------
    diagnosis : Diagnosis [-]
        The result of :func:`aeropend_core.diagnosis.diagnose.diagnose` (it carries the prepared recording).
    path : str or Path [-]
        Output file, e.g. ``report.html``; its folder must exist.
    source : str, optional [-]
        Name of the recording, shown in the title.
    validation : Validation, optional [-]
        The model on a second record (:func:`aeropend_core.diagnosis.validation.validate`): a section of its own.

    Returns
    -------
    Path
        The file written.
    """
    from aeropend_core.io.paths import output_target, write_atomically
    output_target(path, '--report')                 # refused before the rendering: folder, device, FIFO, loop
    text = render_report(diagnosis, source, validation)
    write_atomically(path, lambda handle: handle.write(text), '--report', 'the report')
    return Path(path)


__all__ = ['render_report', 'write_report']
