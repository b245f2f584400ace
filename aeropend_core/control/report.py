"""Self-contained HTML pages of the closed loop: the check (measured vs predicted transients overlaid, step by
step) and the linearised model (step response and Bode plot). Inline SVG (:mod:`aeropend_core.present.svgplot`),
no outside request; one file that works offline.
"""
from __future__ import annotations

import html
import math

import numpy as np

from aeropend_core.present.svgplot import Figure

_STYLE = ('body{font-family:system-ui,sans-serif;max-width:1160px;margin:1em auto;color:#222}'
          'table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:2px 8px;text-align:right}'
          'th{background:#f3f3f3}.miss{color:#b00020;font-weight:bold}.ok{color:#1b6e20}figure{margin:0 0 1.5em}'
          'pre{background:#f7f7f7;padding:0.6em;overflow-x:auto}')


def _page(title: str, body: str) -> str:
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>'
            f'<style>{_STYLE}</style></head><body><h1>{html.escape(title)}</h1>{body}</body></html>\n')


def check_report(result, measured_time: np.ndarray, measured_angle: np.ndarray, measured_duty: np.ndarray,
                 reference: np.ndarray | None, source: str) -> str:
    """The check's page: the verdict, the table of every item, and per step the measured and predicted angle [deg]
    and duty over the hold, with the settling band."""
    parts = [f'<p>Record: <code>{html.escape(source)}</code>. Template: {html.escape(result.template.text())}. '
             f'<b>Verdict: {html.escape(result.verdict)}.</b></p>']
    rows = ['<tr><th>step</th><th>item</th><th>measured</th><th>predicted</th><th>limit</th><th>judged</th></tr>']
    from aeropend_core.control.check import ITEM_NAMES, _limit, _show
    for step in result.steps:
        for item in ('overshoot', 'settling', 'error', 'duty'):
            limit = getattr(result.template, item)
            missed = item in step.measured_misses
            judged = 'not judged' if limit is None else ('MISSED' if missed else 'met')
            if missed and item not in step.predicted_misses:
                judged += ' (predicted met)'
            css = 'miss' if missed else 'ok'
            rows.append(f'<tr><td>{step.index}</td><td style="text-align:left">{ITEM_NAMES[item]}</td>'
                        f'<td>{_show(item, step.measured)}</td>'
                        f'<td>{_show(item, step.predicted) if step.predicted else "n/a"}</td>'
                        f'<td>{_limit(item, limit)}</td><td class="{css}">{judged}</td></tr>')
    parts.append('<table>' + ''.join(rows) + '</table>')
    for step in result.steps:
        m = step.measured
        start, end = m.start, m.start + m.hold
        inside = (measured_time >= start - 0.2) & (measured_time < end)
        predicted_inside = (result.predicted_time >= start - 0.2) & (result.predicted_time < end)
        figure = Figure(height=360)
        angle_axes, duty_axes = figure.grid(2, 1, height_ratios=[2.2, 1.0])
        t = measured_time[inside] - start
        angle_axes.span(y0=math.degrees(m.final - m.band), y1=math.degrees(m.final + m.band), colour='#e8f1e8',
                        label='settling band')
        if reference is not None:
            angle_axes.line(t, np.degrees(reference[inside]), '#888888', style='--', label='reference')
        angle_axes.line(t, np.degrees(measured_angle[inside]), '#1f77b4', width=1.0, label='measured angle')
        angle_axes.line(result.predicted_time[predicted_inside] - start,
                        np.degrees(result.predicted_angle[predicted_inside]), '#d62728', width=1.4,
                        label='predicted angle (the design model, same law)')
        angle_axes.ylabel = 'angle [deg]'
        duty_axes.line(t, measured_duty[inside], '#1f77b4', width=1.0, label='measured duty')
        duty_axes.line(result.predicted_time[predicted_inside] - start, result.predicted_duty[predicted_inside],
                       '#d62728', width=1.2, label='predicted duty')
        if result.template.duty is not None:
            duty_axes.rule(y=result.template.duty, colour='#b00020', style=':')
        duty_axes.ylabel = 'duty [1]'
        duty_axes.xlabel = 'time from the step [s]'
        parts.append(f'<h3>Step {step.index}: {math.degrees(m.initial):.1f} -> {math.degrees(m.target):.1f} deg</h3>'
                     + figure.html(f'step {step.index}: measured and predicted angle and duty'))
    parts.extend(f'<p>Note: {html.escape(note)}</p>' for note in result.notes)
    return _page('aeropend control check', ''.join(parts))


def linearisation_report(lin, source: str) -> str:
    """The linearised model's page: its state space, the step response of duty -> angle and the Bode plot."""
    import control
    system = lin.state_space()
    dc = lin.dc_gain
    slowest = min(abs(p.real) for p in np.linalg.eigvals(lin.A) if abs(p.real) > 1e-9)
    horizon = min(20.0, 8.0 / slowest)
    response = control.step_response(system, T=np.linspace(0.0, horizon, 2000))
    time, output = response.time, np.squeeze(response.outputs)
    frequencies = np.logspace(-1.5, 2.5, 400)                     # [rad/s]
    magnitude, phase, _ = control.frequency_response(system, frequencies)
    magnitude, phase = np.squeeze(magnitude), np.unwrap(np.squeeze(phase))
    parts = [f'<p>Model: <code>{html.escape(source)}</code>; linearised at {math.degrees(lin.angle):.1f} deg '
             f'(duty {lin.duty:.4f}); input duty [1], output measured angle [rad]; DC gain {dc:.4f} rad per unit '
             f'duty.</p>']
    figure = Figure(height=300)
    (axes,) = figure.grid(1, 1)
    axes.line(time, np.degrees(0.01 * output), '#1f77b4', label='angle after a 0.01 duty step')
    axes.rule(y=math.degrees(0.01 * dc), colour='#888888', style='--')
    axes.xlabel, axes.ylabel = 'time [s]', 'angle change [deg]'
    parts.append('<h2>Step response (linear model)</h2>' + figure.html('step response of the linearised model'))
    figure = Figure(height=420)
    gain_axes, phase_axes = figure.grid(2, 1)
    hertz = np.log10(frequencies / (2 * math.pi))
    gain_axes.line(hertz, 20 * np.log10(np.maximum(magnitude, 1e-300)), '#1f77b4', label='gain')
    gain_axes.ylabel = 'gain [dB rad per unit duty]'
    phase_axes.line(hertz, np.degrees(phase), '#d62728', label='phase')
    phase_axes.ylabel = 'phase [deg]'
    phase_axes.xlabel = 'log10 of the frequency [Hz] (-1: 0.1 Hz, 0: 1 Hz, 1: 10 Hz)'
    parts.append('<h2>Bode plot (linear model)</h2>' + figure.html('Bode plot of the linearised model'))
    with np.printoptions(precision=5, linewidth=110):
        parts.append('<h2>State space</h2><pre>' + html.escape(
            f'states: {", ".join(lin.states)}\nA =\n{lin.A}\nB = {lin.B.ravel()}\nC = {lin.C.ravel()}') + '</pre>')
    for name, why in lin.left_out.items():
        parts.append(f'<p>Note: {html.escape(name)} left out: {html.escape(why)}</p>')
    return _page('aeropend control linearise', ''.join(parts))
