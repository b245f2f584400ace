"""Report sections about the identified model itself: the motor observer the thrust relies on, the identified
equation written out with numbers and units, the parameter correlation matrix of the output-error fit, and the CSV
export of every trace.

Each function returns an HTML fragment (a ``<section>`` with its own ``id``); :func:`model_sections` returns all of
them for :func:`aeropend_core.present.report.render_report`. Figures are inline SVG.
"""
from __future__ import annotations


import base64
import gzip
import math

import numpy as np

from aeropend_core.diagnosis.compare import Comparison
from aeropend_core.diagnosis.candidates import Candidate
from aeropend_core.model.effects import CATALOG
from aeropend_core.present.formatting import _esc, _model_name, _sig, _unit_and_meaning
from aeropend_core.present.result_types import DiagnosisLike


#: |correlation| above which two parameters are hard to tell apart from this record (highlighted).
STRONG_CORRELATION = 0.9

#: Name of the downloaded CSV file (the page's title is added in front).
CSV_SUFFIX = '_traces.csv'


# -- motor observer -------------------------------------------------------------------------------------------------

def observer_traces(diagnosis: DiagnosisLike) -> dict[str, np.ndarray | None]:
    """The motor-observer quantities over the whole record.

    Returns
    -------
    dict
        ``model_current`` [A]: the observer's current (Va - e)/Rm, passed through the electrical lag
        tau_e = La/Rm when the observer was fitted with it (None without an observer); ``thrust_voltage`` [V]: the
        back-EMF e that drives the thrust k e|e| (Va - R Ia from the measurements when no observer is used);
        ``measured_emf`` [V]: Va - R Ia from the measured samples (noisy), for comparison.
    """
    prep = diagnosis.prepared
    motor = prep.motor
    resistance = diagnosis.current.parameters.get('armature_resistance', 0.0)
    thrust_voltage = prep.voltage - resistance * prep.current
    if motor is None:
        measured = prep.armature_voltage - resistance * prep.armature_current
        return {'model_current': None, 'thrust_voltage': thrust_voltage, 'measured_emf': measured}
    rm = motor.parameters['motor_resistance']
    drive = prep.gate_voltage if prep.gate_voltage is not None else prep.armature_voltage
    quasi_static = (drive - motor.back_emf) / rm
    tau = motor.parameters.get('electrical_time_constant')
    if tau:
        # exact first-order lag of the piecewise-constant quasi-static current over each sample
        decay = math.exp(-prep.sample_time / tau)
        current = np.empty_like(quasi_static)
        current[0] = prep.armature_current[0] if np.isfinite(prep.armature_current[0]) else quasi_static[0]
        for k in range(1, current.size):
            current[k] = decay * current[k - 1] + (1.0 - decay) * quasi_static[k - 1]
    else:
        current = quasi_static
    measured = prep.armature_voltage - rm * prep.armature_current
    return {'model_current': current, 'thrust_voltage': thrust_voltage, 'measured_emf': measured}


def observer_section(diagnosis: DiagnosisLike) -> str:
    """Measured Ia vs the observer's model current, and the back-EMF used for the thrust."""
    prep = diagnosis.prepared
    motor = prep.motor
    traces = observer_traces(diagnosis)
    if motor is None:
        text = ('<p class="caption"><b>The motor observer was not used</b> for this record: it could not explain the '
                'armature current to within 1.5&times; its noise (or Va is not a step input), so the thrust input is '
                'the measured <code>Va &minus; R&middot;Ia</code> with R fitted '
                f'({_sig(diagnosis.current.parameters.get("armature_resistance"))} &Omega;). Its current noise reaches '
                'the thrust: expect a higher error floor.</p>')
    else:
        units = {'motor_drive_rate': '1/s', 'motor_friction_rate': '1/s', 'motor_drag_rate': '1/(V&middot;s)',
                 'motor_resistance': '&Omega;', 'electrical_time_constant': 's'}
        values = ', '.join(f'<code>{_esc(name)}</code> = {_sig(value)} {units.get(name, "")}'
                           for name, value in motor.parameters.items())
        ratio = motor.current_rms_error / motor.current_noise_rms if motor.current_noise_rms > 0 else float('nan')
        text = ('<p class="caption">The thrust is computed from the back-EMF <i>e</i> = K&omega;&middot;&omega;<sub>1'
                '</sub> of a small motor model fitted to the measured Ia (<code>Ia = (Va &minus; e)/Rm</code>, '
                '<code>de/dt = p1(Va &minus; e) &minus; p2&middot;e &minus; p3&middot;e|e|</code>), not from the '
                'noisy <code>Va &minus; R&middot;Ia</code>. Top: measured Ia (grey) and the observer\'s current '
                '(orange); they must agree to within the current\'s noise, or the thrust input is wrong. Bottom: the '
                'back-EMF used for the thrust (blue) against <code>Va &minus; Rm&middot;Ia</code> from the samples '
                f'(grey). Fitted: {values}. Current RMS error {motor.current_rms_error * 1e3:.2f} mA against a noise '
                f'of {motor.current_noise_rms * 1e3:.2f} mA ({ratio:.2f}&times;; the observer is used below '
                '1.5&times;' + (f', and above it while its thrust voltage is off by at most half of what '
                                f'<code>Va &minus; R&middot;Ia</code> carries: here '
                                f'{motor.voltage_error_bound * 1e3:.2f} mV against '
                                f'{motor.fallback_voltage_error * 1e3:.2f} mV'
                                if motor.kept_against_fallback else '') + ').</p>')
    figure = _observer_plot(diagnosis, traces)
    return ('<section id="observer"><h2>Motor observer: armature current and back-EMF</h2>' + text + figure
            + '</section>')


def _observer_plot(diagnosis: DiagnosisLike, traces: dict) -> str:
    from aeropend_core.present.formatting import HELDOUT_SHADE, MEASURED, _finite_trace
    from aeropend_core.present.svgplot import Figure
    prep = diagnosis.prepared
    figure = Figure(400)
    top, bottom = figure.grid(2, 1)
    for axes in (top, bottom):
        axes.span(x0=prep.time[prep.split], x1=prep.time[-1], colour=HELDOUT_SHADE)
    top.line(*_finite_trace(prep.time, prep.armature_current), MEASURED, width=0.7, label='measured Ia')
    if traces['model_current'] is not None:
        top.line(*_finite_trace(prep.time, traces['model_current']), '#e66101', width=1.3,
                 label='observer model current')
    bottom.line(*_finite_trace(prep.time, traces['measured_emf']), MEASURED, width=0.7,
                label='Va - R Ia measured')
    bottom.line(*_finite_trace(prep.time, traces['thrust_voltage']), '#1f63b4', width=1.3,
                label='back-EMF used for the thrust')
    top.ylabel = 'Ia [A]'
    bottom.ylabel = 'back-EMF [V]'
    bottom.xlabel = 'time [s]'
    bottom.xlim = (prep.time[0], prep.time[-1])
    return figure.html('measured armature current against the motor observer, and the back-EMF')


# -- the identified equation ----------------------------------------------------------------------------------------

def _value(comparison: Comparison, name: str, symbol: str) -> str:
    value = comparison.parameters.get(name, float('nan'))
    sigma = comparison.fit.standard_errors.get(name, float('nan'))
    unit, _ = _unit_and_meaning(name)
    spread = f' &plusmn; {_sig(sigma, 2)}' if np.isfinite(sigma) and sigma > 0 else ''
    return (f'<span class="term" title="{_esc(name)}">{symbol} = <b>{_sig(value)}{spread}</b> '
            f'{_esc(unit)}</span>')


def equation_html(comparison: Comparison, observer: bool) -> str:
    """The identified model as equations with the fitted numbers (&plusmn; 1 sigma) and SI units.

    The nominal equation is written here; every effect in the model adds the line of its catalog record
    (:mod:`aeropend_core.model.effects`), so no effect is named in this module.
    """
    effects = comparison.effects
    lines = ['dy/dt = &Omega; &emsp;(7)', 'd&Omega;/dt = &minus;a&middot;sin y &minus; b&middot;&Omega; + '
             'k&middot;e|e|' + (' (+ the effects below)' if effects else '') + ' &emsp;(6)']
    lines += [f'{_esc(name)}: {_esc(CATALOG[name].equation or CATALOG[name].description)}'
              for name in effects if name in CATALOG]
    lines.append('e = back-EMF of the motor observer [V] (fitted to Ia)' if observer else
                 'e = Va &minus; R&middot;Ia [V] (measured)')
    lines.append('k&middot;e|e| is the quasi-static thrust per unit inertia, f_eq5 &prop; (Va &minus; R&middot;Ia)'
                 '&sup2; &emsp;(5)')
    symbols = {'gravity_stiffness': 'a', 'damping': 'b', 'thrust_gain': 'k'}
    if not observer:
        symbols['armature_resistance'] = 'R'
    shown = [name for name in comparison.parameters if not (observer and name == 'armature_resistance')]   # R = 0
    values = [_value(comparison, name, symbols.get(name, f'<code>{_esc(name)}</code>')) for name in shown]
    return ('<div class="equation">' + '<br>'.join(lines) + '</div><div class="terms">' + ' &nbsp; '.join(values)
            + '</div>')


def equation_section(diagnosis: DiagnosisLike, best: Candidate | None) -> str:
    observer = diagnosis.prepared.motor is not None
    parts = ['<section id="equation"><h2>The identified equation</h2><p class="caption">The model as given '
             f'(<b>{_esc(_model_name(diagnosis.effects))}</b>), fitted by output error on the training part; y is the '
             'rod angle [rad], &Omega; its rate [rad/s]; &plusmn; 1&sigma; as in the parameter table. The numbers '
             'in brackets are the source paper\'s equations that the effects, the candidates and the notes cite: '
             '(5) the quasi-static thrust f_eq5, (6) the rod\'s angular acceleration, (7) its angle.</p>',
             equation_html(diagnosis.current, observer)]
    if best is not None and best.significant and best.comparison is not None:
        parts.append(f'<h3>With the missing effect added (+ {_esc(best.effect)})</h3>'
                     + equation_html(best.comparison, observer))
    return ''.join(parts) + '</section>'


# -- parameter correlation ------------------------------------------------------------------------------------------

def _cell_colour(r: float) -> str:
    """White at 0, red for +1, blue for -1."""
    if not np.isfinite(r):
        return '#eeeeee'
    strength = min(abs(r), 1.0)
    low = round(255 - 150 * strength)
    return f'rgb(255,{low},{low})' if r > 0 else f'rgb({low},{low},255)'


def correlation_table(comparison: Comparison) -> str:
    """The parameter correlation matrix of the output-error fit (from its covariance) as a coloured table."""
    names = list(comparison.fit.free_names)
    matrix = np.asarray(comparison.fit.correlation, dtype=float)
    if not names or matrix.shape != (len(names), len(names)):
        return '<p class="caption">No correlation matrix: the fit has no free parameters.</p>'
    head = '<tr><th></th>' + ''.join(f'<th><code>{_esc(n)}</code></th>' for n in names) + '</tr>'
    rows = []
    for i, name in enumerate(names):
        cells = []
        for j in range(len(names)):
            r = matrix[i, j]
            strong = i != j and np.isfinite(r) and abs(r) > STRONG_CORRELATION
            style = f'background:{_cell_colour(r)}' + (';font-weight:bold;outline:2px solid #b2182b' if strong else '')
            cells.append(f'<td class="num" style="{style}">{r:+.2f}</td>' if np.isfinite(r) else
                         '<td class="num">&mdash;</td>')
        rows.append(f'<tr><th><code>{_esc(name)}</code></th>' + ''.join(cells) + '</tr>')
    return '<table class="correlation" style="width:auto">' + head + ''.join(rows) + '</table>'


def correlation_section(diagnosis: DiagnosisLike, best: Candidate | None) -> str:
    names = list(diagnosis.current.fit.free_names)
    matrix = np.asarray(diagnosis.current.fit.correlation, dtype=float)
    strong = [(names[i], names[j], matrix[i, j]) for i in range(len(names)) for j in range(i + 1, len(names))
              if matrix.shape == (len(names), len(names)) and np.isfinite(matrix[i, j])
              and abs(matrix[i, j]) > STRONG_CORRELATION]
    verdict = ('Strongly correlated (|r| &gt; ' + f'{STRONG_CORRELATION:g}, outlined): '
               + '; '.join(f'<code>{_esc(a)}</code> / <code>{_esc(b)}</code> ({r:+.2f})' for a, b, r in strong)
               + '. This record cannot tell them apart well: their individual values are uncertain together (the '
               '&plusmn;1&sigma; of each already includes it); an experiment that moves them differently separates '
               'them.') if strong else (f'No pair above |r| = {STRONG_CORRELATION:g}: every parameter is determined '
                                        'by this record on its own.')
    parts = ['<section id="correlation"><h2>Parameter correlation</h2><p class="caption">Correlation matrix of the '
             'fitted parameters from the output-error fit\'s Gauss-Newton covariance (free parameters only; '
             f'red positive, blue negative). {verdict}</p>', correlation_table(diagnosis.current)]
    if best is not None and best.significant and best.comparison is not None:
        parts.append(f'<h3>With + {_esc(best.effect)}</h3>' + correlation_table(best.comparison))
    return ''.join(parts) + '</section>'


# -- CSV export -----------------------------------------------------------------------------------------------------

def traces_csv(diagnosis: DiagnosisLike, best: Candidate | None) -> str:
    """Every sample of the record and of the models as CSV text (SI units; empty field = not simulated there)."""
    prep = diagnosis.prepared
    traces = observer_traces(diagnosis)
    columns = {'time_s': (prep.time, '%.6f'), 'armature_voltage_V': (prep.armature_voltage, '%.6g'),
               'armature_current_A': (prep.armature_current, '%.6g'), 'angle_rad': (prep.angle, '%.7g'),
               'held_out': ((np.arange(prep.time.size) >= prep.split).astype(float), '%.0f'),
               'simulated_angle_rad': (diagnosis.current.evaluation.simulated, '%.7g')}
    if diagnosis.before is not None:
        columns['simulated_angle_before_rad'] = (diagnosis.before.evaluation.simulated, '%.7g')
    if best is not None and best.comparison is not None:
        effect = ''.join(c if c.isalnum() else '_' for c in best.effect)      # a plain column name
        columns[f'simulated_angle_with_{effect}_rad'] = (best.comparison.evaluation.simulated, '%.7g')
    if traces['model_current'] is not None:
        columns['observer_current_A'] = (traces['model_current'], '%.6g')
    columns['thrust_back_emf_V'] = (traces['thrust_voltage'], '%.6g')
    data = np.column_stack([np.asarray(values, dtype=float) for values, _ in columns.values()])
    # one %-format over all the values (a C loop; np.savetxt formats row by row in Python, 2x slower)
    row = ','.join(fmt for _, fmt in columns.values()) + '\n'
    body = (row * data.shape[0]) % tuple(data.ravel()) if data.size else ''
    # a sample that was not simulated is an empty field ('%g' writes nan, with no sign)
    body = ('\n' + body).replace(',nan', ',').replace('\nnan,', '\n,')[1:]
    return ','.join(columns) + '\n' + body


def compressed_csv(text: str) -> str:
    """`text` gzip-compressed and base64-encoded (the page holds this; the browser decompresses it on download)."""
    return base64.b64encode(gzip.compress(text.encode('utf-8'), compresslevel=3, mtime=0)).decode('ascii')


DOWNLOAD_SCRIPT = """<script>
function aeropendDownloadCsv(name) {
  var packed = document.getElementById('traces-csv').textContent.replace(/\\s+/g, '');
  if (typeof DecompressionStream === 'undefined') {
    alert('This browser cannot decompress the embedded CSV (DecompressionStream is missing); open the report in a ' +
          'current Chromium, Firefox or Safari.');
    return;
  }
  var bytes = Uint8Array.from(atob(packed), function (c) { return c.charCodeAt(0); });
  var stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('gzip'));
  new Response(stream).blob().then(function (blob) {
    var link = document.createElement('a');
    link.href = URL.createObjectURL(new Blob([blob], {type: 'text/csv'}));
    link.download = name;
    document.body.appendChild(link);
    link.click();
    setTimeout(function () { URL.revokeObjectURL(link.href); link.remove(); }, 1000);
  });
}
</script>"""


def csv_section(diagnosis: DiagnosisLike, best: Candidate | None, file_stem: str = 'aeropend') -> str:
    """A download button for the traces as CSV (embedded gzip-compressed in the page; no server, no network)."""
    text = traces_csv(diagnosis, best)
    columns = text.split('\n', 1)[0].split(',')
    rows = text.count('\n') - 1
    name = ''.join(c if c.isalnum() or c in '-_.' else '_' for c in file_stem) + CSV_SUFFIX
    packed = compressed_csv(text)
    listed = ''.join(f'<li><code>{_esc(c)}</code></li>' for c in columns)
    return ('<section id="export"><h2>Export the traces</h2><p class="caption">Every sample (not decimated) of the '
            f'measured and simulated traces, SI units, {rows} rows ({len(text) / 1e6:.1f} MB as CSV; '
            f'{len(packed) / 1e6:.1f} MB compressed in this page). <code>held_out</code> is 1 on the held-out part; an '
            'empty field has no simulated value at that sample (the simulation is kept at every second sample, from '
            f'the first fitted state of each segment on). Columns:</p><ul class="columns">{listed}</ul>'
            f'<p><button type="button" onclick="aeropendDownloadCsv({_esc(repr(name))})">Download {_esc(name)}'
            f'</button></p><script type="application/gzip" id="traces-csv">{packed}</script>' + DOWNLOAD_SCRIPT
            + '</section>')


def model_sections(diagnosis: DiagnosisLike, best: Candidate | None, file_stem: str) -> list[str]:
    """The sections of this module in page order."""
    return [observer_section(diagnosis), equation_section(diagnosis, best),
            correlation_section(diagnosis, best), csv_section(diagnosis, best, file_stem)]


__all__ = ['compressed_csv', 'correlation_table', 'csv_section', 'equation_html', 'model_sections', 'observer_traces',
           'traces_csv']
