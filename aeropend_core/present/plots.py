"""The diagnosis report's figures: measured vs simulated angle, error vs time with the worst windows, error by
regime and the candidate ranking, each as inline SVG (:mod:`aeropend_core.present.svgplot`) returned as HTML.
"""
from __future__ import annotations


import math

import numpy as np

from aeropend_core.diagnosis.compare import excess_error
from aeropend_core.diagnosis.candidates import BIC_MARGIN, MATERIAL, Candidate
from aeropend_core.present.formatting import (
    BEFORE,
    CANDIDATE,
    CURRENT,
    HELDOUT_SHADE,
    MEASURED,
    NOISE_SHADE,
    WORST_SHADE,
    SMOOTHING_SECONDS,
    _excess,
    _finite_trace,
    _model_name,
    _running_mean,
)
from aeropend_core.present.svgplot import TICK_FONT, Figure
from aeropend_core.present.result_types import DiagnosisLike



def _segment_starts(diagnosis: DiagnosisLike) -> list[int]:
    prep = diagnosis.prepared
    starts = [a for a, _ in getattr(prep.train, 'segments', [])]
    return starts + [prep.split]


def _overlay_traces(diagnosis: DiagnosisLike, best: Candidate | None) -> list[tuple[str, np.ndarray, str, str, float]]:
    """(label, simulated angle [rad], colour, line style, width) of every model drawn on the overlays."""
    traces = []
    if diagnosis.before is not None:
        traces.append((f'before: {_model_name(diagnosis.before.effects)}', diagnosis.before.evaluation.simulated,
                       BEFORE, ':', 1.4))
    traces.append((f'model as given: {_model_name(diagnosis.effects)}', diagnosis.current.evaluation.simulated,
                   CURRENT, '-', 1.4))
    if best is not None:
        status = 'significant' if best.significant else 'not significant'
        traces.append((f'best candidate: + {best.effect} ({status})', best.comparison.evaluation.simulated,
                       CANDIDATE, '--', 1.4))
    return traces


def _plot_overlay(diagnosis: DiagnosisLike, best: Candidate | None) -> str:
    prep = diagnosis.prepared
    time = prep.time
    breaks = _segment_starts(diagnosis)
    figure = Figure(440)
    angle_axes, input_axes = figure.grid(2, 1, top=22, height_ratios=[3.2, 1])
    angle_axes.zoom_x = input_axes.zoom_x = True
    t_split = time[prep.split]
    for axes in (angle_axes, input_axes):
        axes.span(x0=t_split, x1=time[-1], colour=HELDOUT_SHADE)
        for start in breaks[1:-1]:
            axes.rule(x=time[start], colour='#999999', width=0.8, style=':')
    t, y = _finite_trace(time, prep.angle)
    angle_axes.line(t, np.degrees(y), MEASURED, width=0.7, opacity=0.8, label='measured')
    for label, simulated, colour, style, width in _overlay_traces(diagnosis, best):
        t, y = _finite_trace(time, simulated, breaks)
        angle_axes.line(t, np.degrees(y), colour, width=width, style=style, label=label)
    angle_axes.ylabel = 'angle [deg]'
    angle_axes.text(t_split, 1.0, ' held-out part: fit % computed here', colour='#8a6d00', dy=-5, y_fraction=True)
    angle_axes.text(time[0], 1.0, 'training part (fitted in ~10 s segments, each restarted from a fitted state)',
                    colour='#666666', dy=-5, y_fraction=True)
    t, v = _finite_trace(time, prep.armature_voltage)
    input_axes.line(t, v, '#7b3294', width=0.9)
    input_axes.ylabel = 'Va [V]'
    input_axes.xlabel = 'time [s]'
    input_axes.xlim = (time[0], time[-1])
    return figure.html('measured and simulated angle over the whole record')


def _plot_error(diagnosis: DiagnosisLike, best: Candidate | None) -> str:
    prep = diagnosis.prepared
    time = prep.time
    breaks = _segment_starts(diagnosis)
    noise = diagnosis.noise_rms
    width = max(1, round(SMOOTHING_SECONDS / prep.sample_time / 2))   # simulated every 2nd sample
    figure = Figure(330)
    axes, = figure.grid()
    axes.zoom_x = True
    axes.span(x0=time[prep.split], x1=time[-1], colour=HELDOUT_SHADE)
    windows = diagnosis.current.evaluation.worst_windows
    for rank, window in enumerate(windows, 1):
        axes.span(x0=window['start'], x1=window['stop'], colour=WORST_SHADE, opacity=0.55)
        axes.text(0.5 * (window['start'] + window['stop']), 1.0, f'#{rank}', colour='#b2182b', anchor='middle',
                  dy=13, bold=True, y_fraction=True)
    axes.span(y0=-noise * 1e3, y1=noise * 1e3, colour=NOISE_SHADE, opacity=0.6,
              label=f'\u00b1 measurement noise RMS ({noise * 1e3:.1f} mrad)')
    error = prep.angle - diagnosis.current.evaluation.simulated
    t, e = _finite_trace(time, error, breaks)
    axes.line(t, e * 1e3, CURRENT, width=0.5, opacity=0.35, label='error, model as given (raw)')
    t, e = _finite_trace(time, _running_mean(error, width), breaks)
    axes.line(t, e * 1e3, CURRENT, width=1.6, label=f'error, model as given ({SMOOTHING_SECONDS:g} s running mean)')
    if diagnosis.before is not None:
        before = _running_mean(prep.angle - diagnosis.before.evaluation.simulated, width)
        t, e = _finite_trace(time, before, breaks)
        axes.line(t, e * 1e3, BEFORE, width=1.3, style=':', label='error, before (running mean)')
    if best is not None:
        candidate = _running_mean(prep.angle - best.comparison.evaluation.simulated, width)
        t, e = _finite_trace(time, candidate, breaks)
        axes.line(t, e * 1e3, CANDIDATE, width=1.3, style='--', label=f'error, + {best.effect} (running mean)')
    axes.rule(y=0, colour='black', width=0.7)
    axes.xlim = (time[0], time[-1])
    axes.xlabel = 'time [s]'
    axes.ylabel = 'measured \u2212 simulated angle [mrad]'
    return figure.html('simulation error against time with the worst windows marked')


def _label_pixels(labels: list[str], fontsize: float = TICK_FONT) -> float:
    """Left margin [px] for y tick labels of this length (DejaVu Sans: about 0.6 em per character)."""
    longest = max((len(label) for label in labels), default=10)
    return 14 + longest * 0.6 * fontsize


def _regime_excess(regimes: dict, name: str, noise: float) -> float:
    """Error beyond the noise in one regime [rad] (the noise is white, the same in every regime)."""
    rms = regimes.get(name, {}).get('rms_error', float('nan'))
    return excess_error(rms, noise) if np.isfinite(rms) else float('nan')


def _plot_regimes(diagnosis: DiagnosisLike, best: Candidate | None) -> str:
    current = diagnosis.current.evaluation.regimes
    noise = diagnosis.noise_rms
    names = sorted(current, key=lambda name: _regime_excess(current, name, noise))
    series = []
    if diagnosis.before is not None:
        series.append(('before: ' + _model_name(diagnosis.before.effects), diagnosis.before.evaluation.regimes,
                       BEFORE))
    series.append(('model as given: ' + _model_name(diagnosis.effects), current, CURRENT))
    if best is not None:
        series.append((f'+ {best.effect} (best candidate)', best.comparison.evaluation.regimes, CANDIDATE))
    height = 0.8 / len(series)
    labels = [f'{name}  [{current[name]["fraction_of_samples"] * 100:.0f} % of samples]' for name in names]
    figure = Figure(60 + 30 * len(names) * (0.6 + 0.4 * len(series)))
    axes, = figure.grid(left=_label_pixels(labels))
    positions = np.arange(len(names), dtype=float)
    largest = 0.0
    for k, (label, regimes, colour) in enumerate(series):
        # the first series on top within each group
        offset = (len(series) - 1 - 2 * k) * height / 2
        values = np.array([_regime_excess(regimes, name, noise) for name in names]) * 1e3
        largest = max(largest, np.nanmax(values) if np.isfinite(values).any() else 0.0)
        axes.bars(positions + offset, np.zeros_like(values), values, height * 0.92, colour, label=label)
        for position, value in zip(positions + offset, values):
            if np.isfinite(value):
                axes.text(value, position, f' {value:.1f}', colour=colour, size=10, dy=3.5)
    axes.yticks = (positions, labels)
    axes.grid = 'x'
    axes.xlim = (0, max(largest, 0.1 * noise * 1e3) * 1.12)
    axes.ylim = (-0.6, len(names) - 0.4)
    axes.xlabel = (f'model error beyond the noise in the regime, \u221a(RMS\u00b2 \u2212 noise\u00b2) [mrad]'
                   f'   (noise RMS {noise * 1e3:.1f} mrad)')
    return figure.html('RMS error by regime')


#: Colour of the selected set (the verdict's missing effects), as the MISSING badge of the table.
SELECTED = '#e66101'

#: Colour of a candidate significant on its own but not selected (made redundant by the selected set).
REDUNDANT = '#a6d96a'


def _candidate_status(diagnosis: DiagnosisLike, candidate: Candidate) -> tuple[str, str]:
    """(colour, tag) of a candidate on the chart: selected, significant alone but not selected, or not."""
    if candidate.effect in diagnosis.missing_effects:
        return SELECTED, 'SELECTED'
    if candidate.significant:
        return REDUNDANT, 'significant alone, not selected'
    return '#9e9e9e', 'not significant'


def candidate_chart_rows(diagnosis: DiagnosisLike) -> list[dict]:
    """The rows of the candidate chart, top to bottom.

    Returns
    -------
    list of dict
        ``label``; ``start`` and ``end`` [mrad]: held-out error beyond the noise (a reference model is a bar from 0
        to its value; a candidate an arrow from the model it was added to, to the model with it); ``colour``;
        ``tag`` (``'reference'``, ``'SELECTED'``, ``'significant alone, not selected'``, ``'not significant'``);
        ``effect`` (None for a reference model).
    """
    now = _excess(diagnosis.current) * 1e3
    rows = []
    if diagnosis.before is not None:
        before = _excess(diagnosis.before) * 1e3
        rows.append(dict(label=f'before: {_model_name(diagnosis.before.effects)}', start=0.0, end=before,
                         colour=BEFORE, tag='reference', effect=None))
        rows.append(dict(label=f'after: {_model_name(diagnosis.effects)}', start=0.0, end=now, colour=CURRENT,
                         tag='reference', effect=None))
    else:
        rows.append(dict(label=f'model as given: {_model_name(diagnosis.effects)}', start=0.0, end=now,
                         colour=CURRENT, tag='reference', effect=None))
    if diagnosis.selected is not None and diagnosis.missing_effects:
        rows.append(dict(label='selected set: + ' + ' + '.join(diagnosis.missing_effects), start=0.0,
                         end=_excess(diagnosis.selected) * 1e3, colour=SELECTED, tag='reference', effect=None))
    for candidate in diagnosis.candidates:
        if candidate.comparison is None or not np.isfinite(candidate.excess_after):
            continue
        colour, tag = _candidate_status(diagnosis, candidate)
        rows.append(dict(label=f'+ {candidate.effect}', start=candidate.excess_before * 1e3,
                         end=candidate.excess_after * 1e3, colour=colour, tag=tag, effect=candidate.effect))
    return rows


def _plot_candidates(diagnosis: DiagnosisLike) -> str | None:
    """Held-out error beyond the noise: the reference models as bars, each candidate as an arrow from the model it
    was added to (the model as given) to where adding it takes the error; the selected set highlighted."""
    rows = candidate_chart_rows(diagnosis)
    if len(rows) < 2:
        return None
    noise = diagnosis.noise_rms * 1e3
    now = _excess(diagnosis.current) * 1e3
    figure = Figure(64 + 27 * len(rows))
    axes, = figure.grid(left=_label_pixels([row['label'] for row in rows], 12))
    positions = list(range(len(rows)))[::-1]
    references = 0
    labels = []                      # (x where the text starts [mrad], its estimated width [px])
    for position, row in zip(positions, rows):
        start, end, colour = row['start'], row['end'], row['colour']
        if row['effect'] is None:
            references += 1
            axes.bars([position], [0.0], [end], 0.62, colour, opacity=0.85)
            axes.text(end, position, f'{end:.2f} mrad', colour=colour, size=10.5, dx=6, dy=4, bold=True)
            labels.append((end, 6 + 0.65 * 10.5 * len(f'{end:.2f} mrad')))
            continue
        axes.line([start, end], [position, position], colour, width=3, scale=False)
        axes.marker(end, position, '<' if end < start else '>', colour)
        removed = start - end
        change = ('no error beyond the noise to remove' if start <= 0 else
                  f'{end:.2f} mrad, unchanged' if abs(removed) < 0.005 * start else
                  f'{end:.2f} mrad, {removed:.2f} removed' if removed > 0 else f'{end:.2f} mrad, worse')
        selected = row['tag'] == 'SELECTED'
        text = f'{change}  \u2014 {row["tag"]}'
        axes.text(max(start, end), position, text, colour=SELECTED if selected else '#333333', size=10.5, dx=10,
                  dy=4, bold=selected)
        labels.append((max(start, end), 10 + 0.65 * 10.5 * len(text)))
    if references < len(rows):
        axes.rule(y=positions[references - 1] - 0.5, colour='#999999', width=0.8)
    axes.rule(x=noise, colour='black', style='--', width=1,
              label=f'measurement noise RMS ({noise:.2f} mrad), for scale')
    needed = math.sqrt(max(now ** 2 - (MATERIAL * noise) ** 2, 0.0))
    if now - needed > 0.01 * max(now, 1e-9):
        axes.rule(x=needed, colour=CURRENT, width=1, style=':',
                  label=f'a candidate must reach left of this ({needed:.2f} mrad; also \u0394BIC < '
                        f'\u2212{BIC_MARGIN:g}, parameter > 3\u03c3)')
    axes.yticks = (positions, [row['label'] for row in rows])
    axes.grid = 'x'
    largest = max([max(row['start'], row['end']) for row in rows] + [noise])
    # wide enough that every label ends inside the plot (x / limit * width + text <= width): none is clipped
    width = axes.box[2]
    fits = [x * width / (width - pixels) for x, pixels in labels if pixels < 0.9 * width]
    axes.xlim = (0, max([largest * 1.15, *fits]))
    axes.ylim = (-0.6, len(rows) - 0.4)
    axes.xlabel = ('held-out model error beyond the noise, \u221a(RMS\u00b2 \u2212 noise\u00b2) [mrad]  '
                   '(shorter is better; arrow: model as given \u2192 with the candidate)')
    return figure.html('held-out error beyond the noise per candidate')
