"""Interactive, self-contained figures of the diagnosis report (plotly; its JavaScript library inlined once).

The time traces — measured vs simulated angle, the held-out part, the error against time, the motor observer — are
interactive when ``plotly`` is installed: zoom (drag; double-click to reset), pan, hover values, legend entries that
hide or show a trace, PNG export from the toolbar. The page stays one file that works offline: plotly.js is put in
the page once (``plotly.offline.get_plotlyjs()``, ~4.8 MB), the data are embedded as typed arrays, nothing is fetched.
Without plotly the same figures fall back to the matplotlib PNGs (:mod:`aeropend_core.present.plots`).

Plots use SVG traces (not WebGL), so they draw in any browser, also without a GPU. Each trace is decimated by
striding to at most :data:`MAX_POINTS` points (60 s at 490 Hz is 29,400 samples: every second one is drawn); the
CSV export carries every sample.
"""
from __future__ import annotations

import numpy as np

from aeropend_core.diagnosis.diagnose import Candidate, Diagnosis
from aeropend_core.present.formatting import (
    BEFORE,
    CANDIDATE,
    CURRENT,
    HELDOUT_SHADE,
    MEASURED,
    NOISE_SHADE,
    SMOOTHING_SECONDS,
    WORST_SHADE,
    _model_name,
    _running_mean,
)

#: Most points per interactive trace (decimated by striding beyond).
MAX_POINTS = 15000

#: Options of every figure: no plotly logo or cloud links, responsive width, PNG export at 2x.
CONFIG = {'displaylogo': False, 'responsive': True, 'showSendToCloud': False,
          'toImageButtonOptions': {'format': 'png', 'scale': 2}}

DASH = {'-': 'solid', '--': 'dash', ':': 'dot'}
OBSERVER = '#e66101'


def available() -> bool:
    """True when plotly is installed (interactive figures); else the report uses the PNG fallback."""
    try:
        import plotly.graph_objects  # noqa: F401
        import plotly.offline  # noqa: F401
    except ImportError:
        return False
    return True


def library_html() -> str:
    """plotly.js as one inline ``<script>`` (put once in the page, before the figures)."""
    from plotly.offline import get_plotlyjs
    return '<script>' + get_plotlyjs() + '</script>'


def figure_html(figure, element_id: str, height: int) -> str:
    """One figure as a ``<div>`` with its inline ``Plotly.newPlot`` call (no library, no external resource)."""
    import plotly.io
    # its own id: the report's section headings already use the plain names ('overlay', 'error', ...)
    return ('<div class="plot" id="figure-' + element_id + '">'
            + plotly.io.to_html(figure, full_html=False, include_plotlyjs=False, div_id='plotly-' + element_id,
                                config=CONFIG,
                                default_height=f'{height}px', default_width='100%')
            + '</div>')


def _decimated(time: np.ndarray, values: np.ndarray, breaks=()) -> tuple[np.ndarray, np.ndarray]:
    """Finite samples of `values`, strided to at most MAX_POINTS, NaN-separated at `breaks`; float32 (compact)."""
    index = np.flatnonzero(np.isfinite(values))
    if index.size == 0:
        return np.zeros(0, np.float32), np.zeros(0, np.float32)
    index = index[::max(1, int(np.ceil(index.size / MAX_POINTS)))]
    t, v = time[index].astype(float), values[index].astype(float)
    cuts = np.searchsorted(index, sorted(set(breaks)))
    cuts = cuts[(cuts > 0) & (cuts < index.size)]
    if cuts.size:
        t, v = np.insert(t, cuts, np.nan), np.insert(v, cuts, np.nan)
    return t.astype(np.float32), v.astype(np.float32)


def _layout(figure, height: int, y_title: str, rows: int = 1) -> None:
    figure.update_layout(template='none', height=height, margin=dict(l=70, r=20, t=40, b=45),
                         legend=dict(orientation='h', yanchor='bottom', y=1.01, x=0, font=dict(size=11)),
                         hovermode='x unified', font=dict(family='DejaVu Sans, Arial, sans-serif', size=12),
                         plot_bgcolor='white')
    figure.update_xaxes(showgrid=True, gridcolor='#e6e6e6', zeroline=False, showline=True, linecolor='#999')
    figure.update_yaxes(showgrid=True, gridcolor='#e6e6e6', zeroline=False, showline=True, linecolor='#999')
    figure.update_xaxes(title_text='time [s]', row=rows, col=1)
    figure.update_yaxes(title_text=y_title, row=1, col=1)


def _heldout_shape(figure, start: float, stop: float) -> None:
    figure.add_vrect(x0=start, x1=stop, fillcolor=HELDOUT_SHADE, opacity=0.6, layer='below', line_width=0,
                     row='all', col=1)


def _segment_starts(diagnosis: Diagnosis) -> list[int]:
    prep = diagnosis.prepared
    return [a for a, _ in getattr(prep.train, 'segments', [])] + [prep.split]


def _model_traces(diagnosis: Diagnosis, best: Candidate | None):
    """(label, simulated angle [rad], colour, dash) of every model drawn."""
    traces = []
    if diagnosis.before is not None:
        traces.append((f'before: {_model_name(diagnosis.before.effects)}', diagnosis.before.evaluation.simulated,
                       BEFORE, 'dot'))
    traces.append((f'model as given: {_model_name(diagnosis.effects)}', diagnosis.current.evaluation.simulated,
                   CURRENT, 'solid'))
    if best is not None:
        status = 'significant' if best.significant else 'not significant'
        traces.append((f'best candidate: + {best.effect} ({status})', best.comparison.evaluation.simulated,
                       CANDIDATE, 'dash'))
    return traces


def overlay_figure(diagnosis: Diagnosis, best: Candidate | None, heldout_only: bool = False) -> str:
    """Measured vs simulated angle [deg] with Va [V] and Ia [A] below (whole record, or the held-out part)."""
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    prep = diagnosis.prepared
    part = slice(prep.split, len(prep.time)) if heldout_only else slice(0, len(prep.time))
    time = prep.time[part]
    breaks = [] if heldout_only else _segment_starts(diagnosis)
    rows = 1 if heldout_only else 3
    figure = make_subplots(rows=rows, cols=1, shared_xaxes=True, vertical_spacing=0.04,
                           row_heights=[0.62, 0.19, 0.19] if rows == 3 else None)
    t, y = _decimated(time, np.degrees(prep.angle[part]))
    figure.add_trace(go.Scatter(x=t, y=y, name='measured', line=dict(color=MEASURED, width=1), opacity=0.75),
                     row=1, col=1)
    for label, simulated, colour, dash in _model_traces(diagnosis, best):
        t, y = _decimated(time, np.degrees(simulated[part]), breaks)
        figure.add_trace(go.Scatter(x=t, y=y, name=label, line=dict(color=colour, width=1.6, dash=dash)), row=1, col=1)
    if rows == 3:
        t, v = _decimated(time, prep.armature_voltage)
        figure.add_trace(go.Scatter(x=t, y=v, name='Va [V]', line=dict(color='#7b3294', width=1)), row=2, col=1)
        t, i = _decimated(time, prep.armature_current)
        figure.add_trace(go.Scatter(x=t, y=i, name='Ia [A]', line=dict(color=OBSERVER, width=0.8), opacity=0.8),
                         row=3, col=1)
        _heldout_shape(figure, float(prep.time[prep.split]), float(prep.time[-1]))
        for start in breaks[1:-1]:
            figure.add_vline(x=float(prep.time[start]), line=dict(color='#999', width=0.6, dash='dot'), row=1, col=1)
    height = 420 if heldout_only else 640
    _layout(figure, height, 'angle [deg]', rows)
    if rows == 3:
        figure.update_yaxes(title_text='Va [V]', row=2, col=1)
        figure.update_yaxes(title_text='Ia [A]', row=3, col=1)
    else:
        figure.update_layout(plot_bgcolor='#fffbea')
    return figure_html(figure, 'heldout' if heldout_only else 'overlay', height)


def error_figure(diagnosis: Diagnosis, best: Candidate | None) -> str:
    """Measured minus simulated angle [mrad]: raw, running mean, the noise band and the worst windows."""
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    prep = diagnosis.prepared
    time = prep.time
    breaks = _segment_starts(diagnosis)
    noise = diagnosis.noise_rms * 1e3
    width = max(1, round(SMOOTHING_SECONDS / prep.sample_time / 2))   # simulated every 2nd sample
    figure = make_subplots(rows=1, cols=1)
    _heldout_shape(figure, float(time[prep.split]), float(time[-1]))
    for rank, window in enumerate(diagnosis.current.evaluation.worst_windows, 1):
        figure.add_vrect(x0=window['start'], x1=window['stop'], fillcolor=WORST_SHADE, opacity=0.5, layer='below',
                         line_width=0, annotation_text=f'#{rank}', annotation_position='top',
                         annotation_font=dict(color='#b2182b', size=11))
    figure.add_hrect(y0=-noise, y1=noise, fillcolor=NOISE_SHADE, opacity=0.6, layer='below', line_width=0)
    error = prep.angle - diagnosis.current.evaluation.simulated
    t, e = _decimated(time, error * 1e3, breaks)
    figure.add_trace(go.Scatter(x=t, y=e, name='error, model as given (raw)', line=dict(color=CURRENT, width=0.6),
                                opacity=0.35))
    t, e = _decimated(time, _running_mean(error, width) * 1e3, breaks)
    figure.add_trace(go.Scatter(x=t, y=e, name=f'error, model as given ({SMOOTHING_SECONDS:g} s running mean)',
                                line=dict(color=CURRENT, width=1.8)))
    others = []
    if diagnosis.before is not None:
        others.append(('error, before (running mean)', diagnosis.before.evaluation.simulated, BEFORE, 'dot'))
    if best is not None:
        others.append((f'error, + {best.effect} (running mean)', best.comparison.evaluation.simulated, CANDIDATE,
                       'dash'))
    for label, simulated, colour, dash in others:
        t, e = _decimated(time, _running_mean(prep.angle - simulated, width) * 1e3, breaks)
        figure.add_trace(go.Scatter(x=t, y=e, name=label, line=dict(color=colour, width=1.4, dash=dash)))
    figure.add_trace(go.Scatter(x=[None], y=[None], mode='markers', name=f'± noise RMS ({noise:.1f} mrad)',
                                marker=dict(color=NOISE_SHADE, size=12, symbol='square')))
    _layout(figure, 430, 'measured − simulated angle [mrad]')
    return figure_html(figure, 'error', 430)


def observer_figure(time: np.ndarray, measured_current: np.ndarray, model_current: np.ndarray | None,
                    thrust_voltage: np.ndarray, measured_emf: np.ndarray, heldout_from: float) -> str:
    """Measured Ia vs the motor observer's model current [A], and the back-EMF used for the thrust [V]."""
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    figure = make_subplots(rows=2, cols=1, shared_xaxes=True, vertical_spacing=0.06)
    t, i = _decimated(time, measured_current)
    figure.add_trace(go.Scatter(x=t, y=i, name='measured Ia [A]', line=dict(color=MEASURED, width=0.8),
                                opacity=0.7), row=1, col=1)
    if model_current is not None:
        t, i = _decimated(time, model_current)
        figure.add_trace(go.Scatter(x=t, y=i, name='observer model current [A]', line=dict(color=OBSERVER,
                                                                                          width=1.6)), row=1, col=1)
    t, e = _decimated(time, measured_emf)
    figure.add_trace(go.Scatter(x=t, y=e, name='Va − R·Ia from the measurements [V]',
                                line=dict(color=MEASURED, width=0.8), opacity=0.6), row=2, col=1)
    t, e = _decimated(time, thrust_voltage)
    label = 'back-EMF e used for the thrust [V]' if model_current is not None else \
        'thrust input Va − R·Ia (measured; observer not used) [V]'
    figure.add_trace(go.Scatter(x=t, y=e, name=label, line=dict(color=CURRENT, width=1.6)), row=2, col=1)
    _heldout_shape(figure, heldout_from, float(time[-1]))
    _layout(figure, 520, 'armature current [A]', rows=2)
    figure.update_yaxes(title_text='back-EMF [V]', row=2, col=1)
    return figure_html(figure, 'observer', 520)


def time_figure(kind: str, diagnosis: Diagnosis, best: Candidate | None) -> str | None:
    """The interactive `kind` ('overlay', 'heldout', 'error') as HTML, or None without plotly (use the PNG)."""
    if not available():
        return None
    if kind == 'error':
        return error_figure(diagnosis, best)
    return overlay_figure(diagnosis, best, heldout_only=kind == 'heldout')


__all__ = ['available', 'error_figure', 'figure_html', 'library_html', 'observer_figure', 'overlay_figure',
           'time_figure']
