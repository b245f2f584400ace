"""Report sections that judge the fitted model the way MATLAB's ``compare``/``resid`` users expect.

- the held-out simulated angle with its +-2 sigma band from the parameter covariance (sigma points through the
  simulator, :func:`aeropend_core.diagnosis.validation.simulation_band`) and the k-step-ahead predictions as points;
- the residual against the rod's rate, its angle and the thrust input (a dry friction shows as a step at zero rate);
- residual autocorrelation and residual-input cross-correlation to 5 s lags with their 99 % bands, and the residual
  spectrum against the white-noise floor;
- the validation record (``diagnose --validate FILE``): the same model simulated on data it never saw.

Each function returns an HTML fragment; figures are inline SVG (:mod:`aeropend_core.present.svgplot`).
"""
from __future__ import annotations


import numpy as np

from aeropend_core.diagnosis.output_error import STRIDE
from aeropend_core.diagnosis.validation import (Validation, prediction_points, residual_correlations,
                                                simulation_band)
from aeropend_core.present.formatting import (BEFORE, CANDIDATE, CURRENT, HELDOUT_SHADE, MEASURED, NOISE_SHADE, _esc,
                                              _finite_trace, _model_name, _mrad, _num, envelope)
from aeropend_core.present.svgplot import Figure
from aeropend_core.present.result_types import DiagnosisLike


#: Points of a residual scatter drawn at most (strided); the binned mean uses every sample.
SCATTER_POINTS = 1500

#: Bins of the binned mean residual in a scatter.
SCATTER_BINS = 40

#: Highest frequency of the residual spectrum plot [Hz] (the rod's dynamics are below ~5 Hz; above is noise).
SPECTRUM_MAX_HZ = 25.0


def _band_figure(diagnosis: DiagnosisLike) -> tuple[str, str]:
    prep = diagnosis.prepared
    band = simulation_band(prep, diagnosis.current)
    predicted_index, predicted = prediction_points(prep, diagnosis.current)
    part = slice(prep.split, len(prep.time))
    time = prep.time[part]
    figure = Figure(430)
    top, bottom = figure.grid(2, 1, height_ratios=[2.3, 1])
    t, y = _finite_trace(time, np.degrees(prep.angle[part]))
    top.line(t, y, MEASURED, width=0.7, opacity=0.7, label='measured')
    finite = np.isfinite(band.low[part])
    step = max(1, int(finite.sum() // 500))              # the band is smooth: 500 points draw it
    keep = np.flatnonzero(finite)[::step]
    top.fill(time[keep], np.degrees(band.low[part][keep]), np.degrees(band.high[part][keep]), CURRENT,
             opacity=0.25, label='\u00b12\u03c3 band (parameter uncertainty)')
    t, y = _finite_trace(time, np.degrees(band.simulated[part]))
    top.line(t, y, CURRENT, width=1.3, label=f'free-run simulation: {_model_name(diagnosis.effects)}')
    horizon = diagnosis.current.evaluation.prediction_horizon
    if predicted.size:
        top.points(prep.time[predicted_index], np.degrees(predicted), CANDIDATE, size=4,
                   label=f'{horizon:g} s-ahead prediction (restarted from the measured state)')
        error = (prep.angle[predicted_index] - predicted) * 1e3
        bottom.points(prep.time[predicted_index], error, CANDIDATE, size=4,
                      label=f'{horizon:g} s-ahead prediction error')
    residual = (prep.angle[part] - band.simulated[part]) * 1e3
    t, r = _finite_trace(time, residual)
    bottom.line(t, r, CURRENT, width=0.6, opacity=0.5, label='free-run simulation error')
    noise = diagnosis.noise_rms * 1e3
    bottom.span(y0=-noise, y1=noise, colour=NOISE_SHADE, opacity=0.6, label=f'\u00b1 noise RMS ({noise:.1f} mrad)')
    width = (band.high[part] - band.low[part]) / 2 * 1e3
    t, w = _finite_trace(time, width)
    bottom.line(t, w, CURRENT, width=0.9, style='--', label='2\u03c3 half-width of the band [mrad]')
    top.ylabel = 'angle [deg]'
    bottom.xlim = (time[0], time[-1])
    bottom.ylabel = 'error [mrad]'
    bottom.xlabel = 'time [s] (held-out part)'
    for axes in (top, bottom):
        axes.background = HELDOUT_SHADE + '40'
    return figure.html('held-out simulation with a 2 sigma band and k-step predictions'), band.method


def band_section(diagnosis: DiagnosisLike) -> str:
    """The held-out simulation with its +-2 sigma band and the k-step predictions as points."""
    plot, method = _band_figure(diagnosis)
    evaluation = diagnosis.current.evaluation
    return ('<h3 id="band">Held-out part, enlarged: the simulation with its &plusmn;2&sigma; band, and the k-step '
            'prediction</h3>'
            '<p class="caption">Top: the held-out part, measured (grey) and simulated free-running from the measured '
            f'Va and Ia (blue) with the &plusmn;2&sigma; band the parameters\' uncertainty allows: {method}. The band '
            'is about the model only; the measurement noise comes on top. Green points: the model restarted from '
            f'the measured state and run {evaluation.prediction_horizon:g} s ahead (MATLAB <code>compare</code> '
            f'with a finite horizon); their RMS error is {_mrad(evaluation.prediction_rms)}. Bottom: both errors in '
            'mrad. A free-run error far outside the band means the model structure, not its parameters, is '
            'wrong.</p>' + plot)


# -- residual against the state and the input ---------------------------------------------------------------------

def _binned_mean(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    low, high = np.percentile(x, [1, 99])
    if not high > low:
        return np.zeros(0), np.zeros(0)
    edges = np.linspace(low, high, SCATTER_BINS + 1)
    which = np.digitize(x, edges) - 1
    inside = (which >= 0) & (which < SCATTER_BINS)
    counts = np.bincount(which[inside], minlength=SCATTER_BINS)
    sums = np.bincount(which[inside], weights=y[inside], minlength=SCATTER_BINS)
    centres = 0.5 * (edges[1:] + edges[:-1])
    enough = counts >= 10
    return centres[enough], sums[enough] / counts[enough]


def scatter_section(diagnosis: DiagnosisLike) -> str:
    """Residual vs rate, angle and thrust input, with the binned mean (whole record where simulated)."""
    prep = diagnosis.prepared
    simulated = diagnosis.current.evaluation.simulated
    e = prep.voltage - diagnosis.current.parameters.get('armature_resistance', 0.0) * prep.current
    index = np.flatnonzero(np.isfinite(simulated))
    residual = (prep.angle[index] - simulated[index]) * 1e3
    before = None
    if diagnosis.before is not None:
        before = (prep.angle[index] - diagnosis.before.evaluation.simulated[index]) * 1e3
    axes_data = [('rate of the rod &Omega; [rad/s]', 'rate \u03a9 [rad/s]', prep.smoothed_rate[index]),
                 ('angle y [deg]', 'angle y [deg]', np.degrees(prep.smoothed_angle[index])),
                 ('thrust input e|e| [V&sup2;]', 'thrust input e|e| [V\u00b2]', (e * np.abs(e))[index])]
    figure = Figure(300)
    panels = figure.grid(1, 3, column_gap=22)
    shown = index[::max(1, index.size // SCATTER_POINTS)]
    pick = np.searchsorted(index, shown)
    noise = diagnosis.noise_rms * 1e3
    spread = max(np.percentile(np.abs(residual), 99.5), noise) * 1.15
    for axes, (_, label, x) in zip(panels, axes_data):
        axes.span(y0=-noise, y1=noise, colour=NOISE_SHADE, opacity=0.6)
        axes.points(x[pick], residual[pick], MEASURED, size=2, opacity=0.35)
        if before is not None:          # after --add: the signature the added effect took away, beside the flat one
            centres, means = _binned_mean(x, before)
            axes.line(centres, means, BEFORE, width=1.6, style=':', label='binned mean, before')
        centres, means = _binned_mean(x, residual)
        axes.line(centres, means, CURRENT, width=1.8, label='binned mean' + (', after' if before is not None else ''))
        axes.points(centres, means, CURRENT, size=5)
        axes.rule(y=0, colour='black', width=0.7)
        axes.xlabel = label
        axes.ylim = (-spread, spread)
    for axes in panels[1:]:
        axes.yticks = ([], [])
    panels[0].rule(x=0, colour='#b2182b', width=0.9, style=':')
    panels[0].ylabel = 'measured \u2212 simulated [mrad]'
    return ('<h3 id="scatter">Residual against rate, angle and thrust</h3><p class="caption">Measured minus '
            'simulated angle (model as given, training segments and held-out part; grey points: every '
            f'{max(1, index.size // SCATTER_POINTS)}th sample; blue: mean in {SCATTER_BINS} bins; grey band: '
            '&plusmn; the noise RMS) against the rod\'s rate, its angle and the thrust input. A model that lacks '
            'nothing leaves a flat mean. Signatures: a step at zero rate (dotted red line) is dry friction '
            '(sign &Omega;); a slope against the rate, damping; an S against the angle, a cable or an offset; a bend '
            'at low thrust, a dead zone.'
            + (f' Red dotted: the binned mean of the model before ({_esc(_model_name(diagnosis.before.effects))}), '
               'the signature the added effect took away.' if before is not None else '')
            + '</p>' + figure.html('residual against rate, angle and thrust input'))


# -- residual correlations and spectrum -------------------------------------------------------------------------------

def _decimated(lags: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A correlation against lag [s] reduced to a third-width panel's pixel columns (min/max envelope)."""
    return envelope(lags, values, columns=350)


def correlation_section(diagnosis: DiagnosisLike, best) -> str:
    """Residual autocorrelation and cross-correlation with the thrust input to 5 s, and the residual spectrum."""
    from scipy.signal import welch

    prep = diagnosis.prepared
    models = [('model as given', diagnosis.current, CURRENT)]
    if best is not None and best.comparison is not None:
        models.append((f'+ {best.effect}', best.comparison, CANDIDATE))
    figure = Figure(330)
    auto_axes, cross_axes, spectrum_axes = figure.grid(1, 3, top=24, left=62, column_gap=66)
    texts = []
    rate = 1.0 / (STRIDE * prep.sample_time)
    for label, comparison, colour in models:
        c = residual_correlations(prep, comparison)
        auto_axes.line(*_decimated(c.lag_seconds, c.autocorrelation), colour, width=1.2, label=label)
        cross_axes.line(*_decimated(c.cross_lag_seconds, c.cross_correlation), colour, width=1.2)
        if comparison is diagnosis.current:
            auto_axes.span(y0=-c.auto_band, y1=c.auto_band, colour='#c6dbef', opacity=0.8,
                           label=f'autocorrelation 99 % band \u00b12.58/\u221aN, N = {c.samples}')
            cross_axes.span(y0=-c.cross_band, y1=c.cross_band, colour='#c6dbef', opacity=0.8,
                            label=f'cross-correlation 99 % band \u00b12.58/\u221aN_eff, N_eff = '
                                  f'{c.effective_samples:.0f}')
        outside_auto = int(np.sum(np.abs(c.autocorrelation[1:]) > c.auto_band))
        outside_cross = int(np.sum(np.abs(c.cross_correlation) > c.cross_band))
        first_zero = np.flatnonzero(c.autocorrelation <= 0)
        decorrelated = (f'{c.lag_seconds[first_zero[0]]:.2f} s' if first_zero.size
                        else f'beyond {c.lag_seconds[-1]:g} s')
        texts.append(f'<b>{_esc(label)}</b>: autocorrelation first crosses zero at {decorrelated}; {outside_auto} of '
                     f'{c.autocorrelation.size - 1} lags outside its band; {outside_cross} of '
                     f'{c.cross_correlation.size} cross-correlation lags outside its band')
        index = prep.heldout.residual_index
        residual = prep.angle[index] - comparison.evaluation.simulated[index]
        frequency, density = welch(residual, fs=rate, nperseg=min(residual.size, 2048))
        shown = (frequency > 0) & (frequency <= SPECTRUM_MAX_HZ)
        spectrum_axes.line(frequency[shown], 10 * np.log10(np.maximum(density[shown], 1e-30)), colour, width=1.2)
    noise_floor = 2 * diagnosis.noise_rms ** 2 / rate
    spectrum_axes.rule(y=10 * np.log10(noise_floor), colour='black', style='--', width=1,
                       label=f'white noise of {diagnosis.noise_rms * 1e3:.1f} mrad RMS (spectrum)')
    auto_axes.title = 'residual autocorrelation (whiteness)'
    cross_axes.title = 'residual vs thrust e|e| (independence)'
    spectrum_axes.title = 'residual spectrum (Welch)'
    auto_axes.xlabel = 'lag [s]'
    cross_axes.xlabel = 'lag [s]  (> 0: the input leads)'
    spectrum_axes.xlabel = 'frequency [Hz]'
    spectrum_axes.ylabel = 'PSD [dB re 1 rad\u00b2/Hz]'
    spectrum_axes.xlim = (0, min(SPECTRUM_MAX_HZ, rate / 2))
    for axes in (auto_axes, cross_axes):
        axes.rule(y=0, colour='black', width=0.7)
    return ('<h3 id="long-residuals">Residual correlations to 5 s and spectrum</h3><p class="caption">The '
            'held-out simulation residual (every second sample, where the simulation lands) as MATLAB '
            '<code>resid</code> shows it, but to 5 s of lag (the rod swings at about 1 Hz, so 0.1 s is too short). '
            'The autocorrelation band assumes a white residual (N = residual samples); the cross-correlation band '
            'uses Bartlett\'s effective count N_eff = N / &Sigma;<sub>k</sub> r<sub>rr</sub>(k) r<sub>uu</sub>(k), '
            'because a correlated residual and a correlated input give larger chance correlations. How to read: a '
            'white residual stays inside the band after lag 0, a slow decay is unmodelled dynamics (a free-run '
            'residual is rarely white); a cross-correlation peak at lag k means the input k seconds earlier still '
            'explains part of the error (a lag, a missing input path); residual power above the dashed white-noise '
            'floor, at the rod\'s swing frequency, is model error. '
            + '</p><ul class="notes">' + ''.join(f'<li>{t}</li>' for t in texts) + '</ul>'
            + figure.html('residual autocorrelation, cross-correlation and spectrum to long lags'))


# -- validation record --------------------------------------------------------------------------------------------

def validation_section(diagnosis: DiagnosisLike, validation: Validation) -> str:
    """The fitted model on the validation record: numbers and the measured vs simulated angle."""
    figure = Figure(370)
    top, bottom = figure.grid(2, 1, height_ratios=[2.2, 1])
    t, y = _finite_trace(validation.time, np.degrees(validation.angle))
    top.line(t, y, MEASURED, width=0.7, opacity=0.75, label='measured (validation record)')
    t, y = _finite_trace(validation.time, np.degrees(validation.simulated))
    top.line(t, y, CURRENT, width=1.3, label=f'simulated: {_model_name(validation.effects)}')
    t, r = _finite_trace(validation.time, (validation.angle - validation.simulated) * 1e3)
    bottom.line(t, r, CURRENT, width=0.6, label='measured \u2212 simulated')
    noise = validation.noise_rms * 1e3
    bottom.span(y0=-noise, y1=noise, colour=NOISE_SHADE, opacity=0.6, label=f'\u00b1 noise RMS ({noise:.1f} mrad)')
    top.ylabel = 'angle [deg]'
    bottom.ylabel = 'error [mrad]'
    bottom.xlabel = 'time [s] (validation record)'
    bottom.xlim = (validation.time[0], validation.time[-1])
    current = diagnosis.current
    rows = [('fit % (NRMSE, free run, MATLAB compare)', _num(current.fit_percent, 2, suffix='&nbsp;%'),
             _num(validation.fit_percent, 2, suffix='&nbsp;%')),
            ('RMS error', _mrad(current.rms_error), _mrad(validation.rms_error)),
            ('measurement noise RMS', _mrad(diagnosis.noise_rms), _mrad(validation.noise_rms)),
            ('model error beyond the noise', _mrad(current.evaluation.excess_error), _mrad(validation.excess_error)),
            ('residual mean (an offset the model lacks)', '&mdash;', _mrad(validation.residual_mean)),
            ('residual standard deviation', '&mdash;', _mrad(validation.residual_std)),
            (f'{validation.prediction_horizon:g} s-ahead prediction RMS error',
             _mrad(current.evaluation.prediction_rms), _mrad(validation.prediction_rms))]
    table = ('<table style="width:auto"><tr><th>measure</th><th>held-out part of the fitting record</th>'
             '<th>validation record</th></tr>'
             + ''.join(f'<tr><td>{a}</td><td class="num">{b}</td><td class="num">{c}</td></tr>' for a, b, c in rows)
             + '</table>')
    notes = ''.join(f'<li>{_esc(n)}</li>' for n in validation.notes)
    return ('<section id="validation"><h2>Validation record: ' + _esc(validation.source) + '</h2>'
            '<p class="caption">The model fitted above (parameters unchanged) simulated free-running over a second '
            f'record it never saw ({validation.duration:.1f} s, {validation.samples} residual samples), from an '
            'initial state estimated on that record\'s first second, as MATLAB <code>compare</code> with validation '
            'data. A fit much lower here than on the held-out part means the model fits the first record only.</p>'
            + table + (f'<ul class="notes">{notes}</ul>' if notes else '')
            + figure.html('measured and simulated angle on the validation record') + '</section>')


__all__ = ['band_section', 'correlation_section', 'scatter_section', 'validation_section',
           'SCATTER_POINTS']
