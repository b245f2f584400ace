"""Report sections that judge the fitted model the way MATLAB's ``compare``/``resid`` users expect.

- the held-out simulated angle with its +-2 sigma band from the parameter covariance (sigma points through the
  simulator, :func:`aeropend_core.diagnosis.validation.simulation_band`) and the k-step-ahead predictions as points;
- the residual against the rod's rate, its angle and the thrust input (a dry friction shows as a step at zero rate);
- residual autocorrelation and residual-input cross-correlation to 5 s lags with their 99 % bands, and the residual
  spectrum against the white-noise floor;
- the validation record (``diagnose --validate FILE``): the same model simulated on data it never saw.

Each function returns an HTML fragment; figures are PNGs drawn with matplotlib's object API (no pyplot).
"""
from __future__ import annotations

import numpy as np

from aeropend_core.diagnosis.diagnose import Diagnosis
from aeropend_core.diagnosis.output_error import STRIDE
from aeropend_core.diagnosis.validation import (Validation, prediction_points, residual_correlations,
                                                simulation_band)
from aeropend_core.present.formatting import (CANDIDATE, CURRENT, HELDOUT_SHADE, MEASURED, NOISE_SHADE, _esc,
                                              _fixed_figure, _finite_trace, _img, _model_name, _mrad, _num, _png)

#: Points of a residual scatter drawn at most (strided); the binned mean uses every sample.
SCATTER_POINTS = 2500

#: Bins of the binned mean residual in a scatter.
SCATTER_BINS = 40

#: Highest frequency of the residual spectrum plot [Hz] (the rod's dynamics are below ~5 Hz; above is noise).
SPECTRUM_MAX_HZ = 25.0


def _band_figure(diagnosis: Diagnosis) -> tuple[str, str]:
    prep = diagnosis.prepared
    band = simulation_band(prep, diagnosis.current)
    predicted_index, predicted = prediction_points(prep, diagnosis.current)
    part = slice(prep.split, len(prep.time))
    time = prep.time[part]
    figure = _fixed_figure(12.5, 5.4, top=0.15, hspace=0.1)
    top, bottom = figure.subplots(2, 1, sharex=True, height_ratios=[2.3, 1])
    t, y = _finite_trace(time, np.degrees(prep.angle[part]))
    top.plot(t, y, color=MEASURED, lw=0.6, alpha=0.7, label='measured')
    finite = np.isfinite(band.low[part])
    step = max(1, int(finite.sum() // 1500))
    keep = np.flatnonzero(finite)[::step]
    top.fill_between(time[keep], np.degrees(band.low[part][keep]), np.degrees(band.high[part][keep]), color=CURRENT,
                     alpha=0.25, lw=0, label='\u00b12\u03c3 band (parameter uncertainty)')
    t, y = _finite_trace(time, np.degrees(band.simulated[part]))
    top.plot(t, y, color=CURRENT, lw=1.2, label=f'free-run simulation: {_model_name(diagnosis.effects)}')
    horizon = diagnosis.current.evaluation.prediction_horizon
    if predicted.size:
        top.plot(prep.time[predicted_index], np.degrees(predicted), 'o', ms=2.8, color=CANDIDATE,
                 label=f'{horizon:g} s-ahead prediction (restarted from the measured state)')
        error = (prep.angle[predicted_index] - predicted) * 1e3
        bottom.plot(prep.time[predicted_index], error, 'o', ms=2.8, color=CANDIDATE,
                    label=f'{horizon:g} s-ahead prediction error')
    residual = (prep.angle[part] - band.simulated[part]) * 1e3
    t, r = _finite_trace(time, residual)
    bottom.plot(t, r, color=CURRENT, lw=0.5, alpha=0.5, label='free-run simulation error')
    noise = diagnosis.noise_rms * 1e3
    bottom.axhspan(-noise, noise, color=NOISE_SHADE, alpha=0.6, zorder=0, label=f'\u00b1 noise RMS ({noise:.1f} mrad)')
    width = (band.high[part] - band.low[part]) / 2 * 1e3
    t, w = _finite_trace(time, width)
    bottom.plot(t, w, color=CURRENT, lw=0.8, ls='--', label='2\u03c3 half-width of the band [mrad]')
    top.set_ylabel('angle [deg]')
    top.set_xlim(time[0], time[-1])
    bottom.set_ylabel('error [mrad]')
    bottom.set_xlabel('time [s] (held-out part)')
    for axes in (top, bottom):
        axes.grid(alpha=0.3)
        axes.set_facecolor(HELDOUT_SHADE + '40')
    top.legend(fontsize=8, loc='upper left', ncol=2, framealpha=0.85)
    bottom.legend(fontsize=8, loc='upper left', ncol=4, framealpha=0.85)
    return _png(figure), band.method


def band_section(diagnosis: Diagnosis) -> str:
    """The held-out simulation with its +-2 sigma band and the k-step predictions as points."""
    uri, method = _band_figure(diagnosis)
    evaluation = diagnosis.current.evaluation
    return ('<h3 id="band">Held-out part, enlarged: the simulation with its &plusmn;2&sigma; band, and the k-step '
            'prediction</h3>'
            '<p class="caption">Top: the held-out part, measured (grey) and simulated free-running from the measured '
            f'Va and Ia (blue) with the &plusmn;2&sigma; band the parameters\' uncertainty allows: {method}. The band '
            'is about the model only; the measurement noise comes on top. Green points: the model restarted from '
            f'the measured state and run {evaluation.prediction_horizon:g} s ahead (MATLAB <code>compare</code> '
            f'with a finite horizon); their RMS error is {_mrad(evaluation.prediction_rms)}. Bottom: both errors in '
            'mrad. A free-run error far outside the band means the model structure, not its parameters, is '
            'wrong.</p>' + _img(uri, 'held-out simulation with a 2 sigma band and k-step predictions'))


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


def scatter_section(diagnosis: Diagnosis) -> str:
    """Residual vs rate, angle and thrust input, with the binned mean (whole record where simulated)."""
    prep = diagnosis.prepared
    simulated = diagnosis.current.evaluation.simulated
    e = prep.voltage - diagnosis.current.parameters.get('armature_resistance', 0.0) * prep.current
    index = np.flatnonzero(np.isfinite(simulated))
    residual = (prep.angle[index] - simulated[index]) * 1e3
    axes_data = [('rate of the rod &Omega; [rad/s]', 'rate \u03a9 [rad/s]', prep.smoothed_rate[index]),
                 ('angle y [deg]', 'angle y [deg]', np.degrees(prep.smoothed_angle[index])),
                 ('thrust input e|e| [V&sup2;]', 'thrust input e|e| [V\u00b2]', (e * np.abs(e))[index])]
    figure = _fixed_figure(12.5, 3.7, top=0.15, wspace=0.06)
    panels = figure.subplots(1, 3, sharey=True)
    shown = index[::max(1, index.size // SCATTER_POINTS)]
    pick = np.searchsorted(index, shown)
    noise = diagnosis.noise_rms * 1e3
    for axes, (_, label, x) in zip(panels, axes_data):
        axes.axhspan(-noise, noise, color=NOISE_SHADE, alpha=0.6, zorder=0)
        axes.plot(x[pick], residual[pick], '.', ms=1.6, color=MEASURED, alpha=0.35, rasterized=True)
        centres, means = _binned_mean(x, residual)
        axes.plot(centres, means, '-o', ms=3, lw=1.6, color=CURRENT, label='binned mean')
        axes.axhline(0, color='black', lw=0.6)
        axes.set_xlabel(label)
        axes.grid(alpha=0.3)
        spread = np.percentile(np.abs(residual), 99.5)
        axes.set_ylim(-1.15 * max(spread, noise), 1.15 * max(spread, noise))
    panels[0].axvline(0, color='#b2182b', lw=0.8, ls=':')
    panels[0].set_ylabel('measured \u2212 simulated [mrad]')
    panels[0].legend(fontsize=8, loc='upper left')
    return ('<h3 id="scatter">Residual against rate, angle and thrust</h3><p class="caption">Measured minus '
            'simulated angle (model as given, training segments and held-out part; grey points: every '
            f'{max(1, index.size // SCATTER_POINTS)}th sample; blue: mean in {SCATTER_BINS} bins; grey band: '
            '&plusmn; the noise RMS) against the rod\'s rate, its angle and the thrust input. A model that lacks '
            'nothing leaves a flat mean. Signatures: a step at zero rate (dotted red line) is dry friction '
            '(sign &Omega;); a slope against the rate, damping; an S against the angle, a cable or an offset; a bend '
            'at low thrust, a dead zone.</p>'
            + _img(_png(figure), 'residual against rate, angle and thrust input'))


# -- residual correlations and spectrum -------------------------------------------------------------------------------

def correlation_section(diagnosis: Diagnosis, best) -> str:
    """Residual autocorrelation and cross-correlation with the thrust input to 5 s, and the residual spectrum."""
    from scipy.signal import welch

    prep = diagnosis.prepared
    models = [('model as given', diagnosis.current, CURRENT)]
    if best is not None and best.comparison is not None:
        models.append((f'+ {best.effect}', best.comparison, CANDIDATE))
    figure = _fixed_figure(12.5, 3.9, top=0.35, left=0.75, bottom=0.6, wspace=0.3)
    auto_axes, cross_axes, spectrum_axes = figure.subplots(1, 3)
    texts = []
    rate = 1.0 / (STRIDE * prep.sample_time)
    for label, comparison, colour in models:
        c = residual_correlations(prep, comparison)
        auto_axes.plot(c.lag_seconds, c.autocorrelation, color=colour, lw=1.1, label=label)
        cross_axes.plot(c.cross_lag_seconds, c.cross_correlation, color=colour, lw=1.1, label=label)
        if comparison is diagnosis.current:
            auto_axes.axhspan(-c.auto_band, c.auto_band, color='#c6dbef', alpha=0.8, zorder=0,
                              label=f'99 % band \u00b12.58/\u221aN, N = {c.samples}')
            cross_axes.axhspan(-c.cross_band, c.cross_band, color='#c6dbef', alpha=0.8, zorder=0,
                               label=f'99 % band \u00b12.58/\u221aN_eff, N_eff = {c.effective_samples:.0f}')
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
        spectrum_axes.plot(frequency[shown], 10 * np.log10(np.maximum(density[shown], 1e-30)), color=colour,
                           lw=1.1, label=label)
    noise_floor = 2 * diagnosis.noise_rms ** 2 / rate
    spectrum_axes.axhline(10 * np.log10(noise_floor), color='black', ls='--', lw=1,
                          label=f'white noise of {diagnosis.noise_rms * 1e3:.1f} mrad RMS')
    auto_axes.set_title('residual autocorrelation (whiteness)', fontsize=10)
    cross_axes.set_title('residual vs thrust e|e| (independence)', fontsize=10)
    spectrum_axes.set_title('residual spectrum (Welch)', fontsize=10)
    auto_axes.set_xlabel('lag [s]')
    cross_axes.set_xlabel('lag [s]  (> 0: the input leads)')
    spectrum_axes.set_xlabel('frequency [Hz]')
    spectrum_axes.set_ylabel('power spectral density [dB re 1 rad\u00b2/Hz]')
    spectrum_axes.set_xlim(0, min(SPECTRUM_MAX_HZ, rate / 2))
    for axes in (auto_axes, cross_axes, spectrum_axes):
        axes.grid(alpha=0.3)
        axes.legend(fontsize=8, loc='upper right', framealpha=0.9)
    for axes in (auto_axes, cross_axes):
        axes.axhline(0, color='black', lw=0.6)
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
            + _img(_png(figure), 'residual autocorrelation, cross-correlation and spectrum to long lags'))


# -- validation record --------------------------------------------------------------------------------------------

def validation_section(diagnosis: Diagnosis, validation: Validation) -> str:
    """The fitted model on the validation record: numbers and the measured vs simulated angle."""
    figure = _fixed_figure(12.5, 4.6, top=0.15, hspace=0.1)
    top, bottom = figure.subplots(2, 1, sharex=True, height_ratios=[2.2, 1])
    t, y = _finite_trace(validation.time, np.degrees(validation.angle))
    top.plot(t, y, color=MEASURED, lw=0.6, alpha=0.75, label='measured (validation record)')
    t, y = _finite_trace(validation.time, np.degrees(validation.simulated))
    top.plot(t, y, color=CURRENT, lw=1.2, label=f'simulated: {_model_name(validation.effects)}')
    t, r = _finite_trace(validation.time, (validation.angle - validation.simulated) * 1e3)
    bottom.plot(t, r, color=CURRENT, lw=0.5)
    noise = validation.noise_rms * 1e3
    bottom.axhspan(-noise, noise, color=NOISE_SHADE, alpha=0.6, zorder=0)
    top.set_ylabel('angle [deg]')
    bottom.set_ylabel('error [mrad]')
    bottom.set_xlabel('time [s] (validation record)')
    top.set_xlim(validation.time[0], validation.time[-1])
    for axes in (top, bottom):
        axes.grid(alpha=0.3)
    top.legend(fontsize=8, loc='upper left', ncol=2)
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
            + _img(_png(figure), 'measured and simulated angle on the validation record') + '</section>')


__all__ = ['band_section', 'correlation_section', 'scatter_section', 'validation_section',
           'SCATTER_POINTS']
