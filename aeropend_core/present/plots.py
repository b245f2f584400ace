"""The diagnosis report's figures: measured vs simulated angle, the held-out zoom, error vs time with the worst
windows, error by regime, residual tests (MATLAB ``resid`` style) and the candidate ranking.
"""
from __future__ import annotations

import math

import numpy as np

from aeropend_core.diagnosis.compare import excess_error
from aeropend_core.diagnosis.diagnose import BIC_MARGIN, MATERIAL, Candidate, Diagnosis
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
    _fixed_figure,
    _top_legend,
    _finite_trace,
    _model_name,
    _png,
    _running_mean,
)


def _segment_starts(diagnosis: Diagnosis) -> list[int]:
    prep = diagnosis.prepared
    starts = [a for a, _ in getattr(prep.train, 'segments', [])]
    return starts + [prep.split]


def _overlay_traces(diagnosis: Diagnosis, best: Candidate | None) -> list[tuple[str, np.ndarray, str, str, float]]:
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


def _plot_overlay(diagnosis: Diagnosis, best: Candidate | None) -> str:
    prep = diagnosis.prepared
    time = prep.time
    breaks = _segment_starts(diagnosis)
    figure = _fixed_figure(12.5, 5.8, top=0.75, hspace=0.08)
    grid = figure.add_gridspec(2, 1, height_ratios=[3.2, 1])
    angle_axes = figure.add_subplot(grid[0])
    input_axes = figure.add_subplot(grid[1], sharex=angle_axes)
    t_split = time[prep.split]
    for axes in (angle_axes, input_axes):
        axes.axvspan(t_split, time[-1], color=HELDOUT_SHADE, zorder=0)
        for start in breaks[1:-1]:
            axes.axvline(time[start], color='#999999', lw=0.6, ls=(0, (2, 3)), zorder=1)
    t, y = _finite_trace(time, prep.angle)
    angle_axes.plot(t, np.degrees(y), color=MEASURED, lw=0.6, alpha=0.8, label='measured')
    for label, simulated, colour, style, width in _overlay_traces(diagnosis, best):
        t, y = _finite_trace(time, simulated, breaks)
        angle_axes.plot(t, np.degrees(y), color=colour, ls=style, lw=width, label=label)
    angle_axes.set_ylabel('angle [deg]')
    angle_axes.text(t_split, 1.0, ' held-out part: fit % computed here', transform=angle_axes.get_xaxis_transform(),
                    va='bottom', ha='left', fontsize=9, color='#8a6d00')
    angle_axes.text(time[0], 1.0, 'training part (fitted in ~10 s segments, each restarted from a fitted state)',
                    transform=angle_axes.get_xaxis_transform(), va='bottom', ha='left', fontsize=9,
                    color='#666666')
    _top_legend(figure, angle_axes, 4)
    angle_axes.grid(alpha=0.3)
    angle_axes.tick_params(labelbottom=False)
    t, v = _finite_trace(time, prep.armature_voltage)
    input_axes.plot(t, v, color='#7b3294', lw=0.8)
    input_axes.set_ylabel('Va [V]')
    input_axes.set_xlabel('time [s]')
    input_axes.grid(alpha=0.3)
    input_axes.set_xlim(time[0], time[-1])
    return _png(figure)


def _plot_error(diagnosis: Diagnosis, best: Candidate | None) -> str:
    prep = diagnosis.prepared
    time = prep.time
    breaks = _segment_starts(diagnosis)
    noise = diagnosis.noise_rms
    width = max(1, round(SMOOTHING_SECONDS / prep.sample_time / 2))   # simulated every 2nd sample
    figure = _fixed_figure(12.5, 4.6, top=0.75)
    axes = figure.add_subplot()
    axes.axvspan(time[prep.split], time[-1], color=HELDOUT_SHADE, zorder=0)
    windows = diagnosis.current.evaluation.worst_windows
    for rank, window in enumerate(windows, 1):
        axes.axvspan(window['start'], window['stop'], color=WORST_SHADE, alpha=0.55, zorder=0.5)
        axes.text(0.5 * (window['start'] + window['stop']), 0.98, f'#{rank}', transform=axes.get_xaxis_transform(),
                  ha='center', va='top', fontsize=9, color='#b2182b', fontweight='bold')
    axes.axhspan(-noise * 1e3, noise * 1e3, color=NOISE_SHADE, alpha=0.6, zorder=0.6,
                 label=f'\u00b1 measurement noise RMS ({noise * 1e3:.1f} mrad)')
    error = prep.angle - diagnosis.current.evaluation.simulated
    t, e = _finite_trace(time, error, breaks)
    axes.plot(t, e * 1e3, color=CURRENT, lw=0.4, alpha=0.35, label='error, model as given (raw)')
    t, e = _finite_trace(time, _running_mean(error, width), breaks)
    axes.plot(t, e * 1e3, color=CURRENT, lw=1.5,
              label=f'error, model as given ({SMOOTHING_SECONDS:g} s running mean)')
    if diagnosis.before is not None:
        before = _running_mean(prep.angle - diagnosis.before.evaluation.simulated, width)
        t, e = _finite_trace(time, before, breaks)
        axes.plot(t, e * 1e3, color=BEFORE, lw=1.2, ls=':', label='error, before (running mean)')
    if best is not None:
        candidate = _running_mean(prep.angle - best.comparison.evaluation.simulated, width)
        t, e = _finite_trace(time, candidate, breaks)
        axes.plot(t, e * 1e3, color=CANDIDATE, lw=1.2, ls='--', label=f'error, + {best.effect} (running mean)')
    axes.axhline(0, color='black', lw=0.6)
    axes.set_xlim(time[0], time[-1])
    axes.set_xlabel('time [s]')
    axes.set_ylabel('measured \u2212 simulated angle [mrad]')
    _top_legend(figure, axes, 3)
    axes.grid(alpha=0.3)
    return _png(figure)


def _label_inches(labels: list[str], fontsize: float) -> float:
    """Left margin [in] for y tick labels of this length (DejaVu Sans: about 0.6 em per character)."""
    longest = max((len(label) for label in labels), default=10)
    return 0.35 + longest * 0.6 * fontsize / 72


def _regime_excess(regimes: dict, name: str, noise: float) -> float:
    """Error beyond the noise in one regime [rad] (the noise is white, the same in every regime)."""
    rms = regimes.get(name, {}).get('rms_error', float('nan'))
    return excess_error(rms, noise) if np.isfinite(rms) else float('nan')


def _plot_regimes(diagnosis: Diagnosis, best: Candidate | None) -> str:
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
    figure_height = 1.3 + 0.42 * len(names) * (0.6 + 0.4 * len(series))
    figure = _fixed_figure(12.5, figure_height, left=_label_inches(labels, 8.5), top=0.45, bottom=0.6)
    axes = figure.add_subplot()
    positions = np.arange(len(names), dtype=float)
    largest = 0.0
    for k, (label, regimes, colour) in enumerate(series):
        # the first series on top within each group
        offset = (len(series) - 1 - 2 * k) * height / 2
        values = np.array([_regime_excess(regimes, name, noise) for name in names]) * 1e3
        largest = max(largest, np.nanmax(values) if np.isfinite(values).any() else 0.0)
        bars = axes.barh(positions + offset, values, height=height * 0.92, color=colour, label=label)
        for bar, value in zip(bars, values):
            if np.isfinite(value):
                axes.text(bar.get_width(), bar.get_y() + bar.get_height() / 2, f' {value:.1f}', va='center',
                          fontsize=7.5, color=colour)
    axes.set_yticks(positions, labels, fontsize=8.5)
    axes.set_xlim(0, max(largest, 0.1 * noise * 1e3) * 1.12)
    axes.set_xlabel(f'model error beyond the noise in the regime, \u221a(RMS\u00b2 \u2212 noise\u00b2) [mrad]'
                    f'   (noise RMS {noise * 1e3:.1f} mrad)')
    _top_legend(figure, axes, 4)
    axes.grid(axis='x', alpha=0.3)
    return _png(figure)


#: Colour of the selected set (the verdict's missing effects), as the MISSING badge of the table.
SELECTED = '#e66101'

#: Colour of a candidate significant on its own but not selected (made redundant by the selected set).
REDUNDANT = '#a6d96a'


def _candidate_status(diagnosis: Diagnosis, candidate: Candidate) -> tuple[str, str]:
    """(colour, tag) of a candidate on the chart: selected, significant alone but not selected, or not."""
    if candidate.effect in diagnosis.missing_effects:
        return SELECTED, 'SELECTED'
    if candidate.significant:
        return REDUNDANT, 'significant alone, not selected (redundant with the selected set)'
    return '#9e9e9e', 'not significant'


def candidate_chart_rows(diagnosis: Diagnosis) -> list[dict]:
    """The rows of the candidate chart, top to bottom.

    Returns
    -------
    list of dict
        ``label``; ``start`` and ``end`` [mrad]: held-out error beyond the noise (a reference model is a bar from 0
        to its value; a candidate an arrow from the model it was added to, to the model with it); ``colour``;
        ``tag`` (``'reference'``, ``'SELECTED'``, ``'significant alone, not selected ...'``, ``'not significant'``);
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


def _plot_candidates(diagnosis: Diagnosis) -> str | None:
    """Held-out error beyond the noise: the reference models as bars, each candidate as an arrow from the model it
    was added to (the model as given) to where adding it takes the error; the selected set highlighted."""
    rows = candidate_chart_rows(diagnosis)
    if len(rows) < 2:
        return None
    noise = diagnosis.noise_rms * 1e3
    now = _excess(diagnosis.current) * 1e3
    figure = _fixed_figure(12.5, 1.5 + 0.36 * len(rows), left=_label_inches([row['label'] for row in rows], 9),
                           top=0.45, bottom=0.6)
    axes = figure.add_subplot()
    positions = list(range(len(rows)))[::-1]
    references = 0
    for position, row in zip(positions, rows):
        start, end, colour = row['start'], row['end'], row['colour']
        if row['effect'] is None:
            references += 1
            axes.barh(position, end, color=colour, height=0.62, alpha=0.85)
            axes.annotate(f'{end:.2f} mrad', (end, position), xytext=(6, 0), textcoords='offset points',
                          va='center', fontsize=8, color=colour, fontweight='bold')
            continue
        axes.plot([start, end], [position, position], color=colour, lw=2.2, solid_capstyle='butt')
        axes.plot([end], [position], marker='<' if end < start else '>', color=colour, ms=8, zorder=3,
                  clip_on=False)
        removed = start - end
        change = ('no error beyond the noise to remove' if start <= 0 else
                  f'{end:.2f} mrad, unchanged' if abs(removed) < 0.005 * start else
                  f'{end:.2f} mrad, {removed:.2f} removed' if removed > 0 else f'{end:.2f} mrad, worse')
        selected = row['tag'] == 'SELECTED'
        axes.annotate(f'{change}  \u2014 {row["tag"]}', (max(start, end), position), xytext=(8, 0),
                      textcoords='offset points', va='center', fontsize=8, color=SELECTED if selected else '#333333',
                      fontweight='bold' if selected else 'normal')
    if references < len(rows):
        axes.axhline(positions[references - 1] - 0.5, color='#999999', lw=0.8)
    axes.axvline(noise, color='black', ls='--', lw=1, label=f'measurement noise RMS ({noise:.2f} mrad), for scale')
    needed = math.sqrt(max(now ** 2 - (MATERIAL * noise) ** 2, 0.0))
    if now - needed > 0.01 * max(now, 1e-9):
        axes.axvline(needed, color=CURRENT, lw=1, ls=':',
                     label=f'a candidate must reach left of this ({needed:.2f} mrad; also \u0394BIC < '
                           f'\u2212{BIC_MARGIN:g}, parameter > 3\u03c3)')
    axes.set_yticks(positions, [row['label'] for row in rows], fontsize=9)
    largest = max([max(row['start'], row['end']) for row in rows] + [noise])
    axes.set_xlim(0, largest * 1.75)
    axes.set_xlabel('held-out model error beyond the noise, \u221a(RMS\u00b2 \u2212 noise\u00b2) [mrad]  '
                    '(shorter is better; arrow: model as given \u2192 with the candidate)')
    _top_legend(figure, axes, 2)
    axes.grid(axis='x', alpha=0.3)
    return _png(figure)
