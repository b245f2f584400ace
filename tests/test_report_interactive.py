"""The report's plots (inline SVG, decimated to a min/max envelope per pixel column), the candidate chart, the model
checks (residual scatter, long-lag correlations, spectrum, +-2 sigma band, k-step points), the model sections (motor
observer, identified equation, parameter correlation) and the compressed CSV export; the page rendered in headless
Chromium (no JavaScript error, nothing fetched), screenshots kept as test artefacts in ``out/test-artifacts/report``
(or ``$AEROPEND_TEST_ARTIFACTS``).

Two diagnoses (~5-10 s each) of a 30 s simulated record with dry friction hidden, PSNR 40 dB, 10-bit angle
quantisation: as recorded, and with ``--add coulomb_friction`` (the before -> after chart).
"""
from __future__ import annotations

import base64
import csv
import gzip
import html
import io
import json
import os
import re
import shutil
import subprocess
from collections import Counter
from pathlib import Path

import dataclasses

import numpy as np
import pytest

from aeropend_core.diagnosis.diagnose import diagnose
from aeropend_core.io.recording import from_columns
from aeropend_core.model.parameters import SAMPLE_TIME
from aeropend_core.present import model_sections, plots, svgplot
from aeropend_core.present.formatting import PIXEL_COLUMNS, _excess, envelope
from aeropend_core.present.report import write_report
from aeropend_core.present.svgplot import Figure
from aeropend_core.signals.preprocess import STEP_SETTLING_SAMPLES
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate

CHROMIUM = shutil.which('chromium') or shutil.which('chromium-browser') or shutil.which('google-chrome')
needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason='headless Chromium is not installed (Debian package '
                                    '`chromium`, listed in scripts/apt-packages.txt)')
ARTIFACTS = Path(os.environ.get('AEROPEND_TEST_ARTIFACTS', Path(__file__).resolve().parents[1] / 'out' /
                                 'test-artifacts')) / 'report'


@pytest.fixture(scope='module')
def record():
    duty = lhc_schedule(30.0, seed=3).duty(SAMPLE_TIME, 30.0)
    run = simulate(duty, effects={'coulomb_friction': 4.0}, noise=MeasurementNoise(40, True), seed=3)
    return from_columns(run.columns(with_truth=False), source='friction.csv')


@pytest.fixture(scope='module')
def diagnosis(record):
    return diagnose(record)


@pytest.fixture(scope='module')
def added(record):
    """The same record diagnosed with the missing effect given (--add): the report compares before and after."""
    return diagnose(record, effects=['coulomb_friction'], candidates=['thrust_lag', 'cable_torque'])


@pytest.fixture(scope='module')
def page(diagnosis, tmp_path_factory):
    path = write_report(diagnosis, tmp_path_factory.mktemp('interactive') / 'report.html', source='friction.csv')
    return path, path.read_text(encoding='utf-8')


def embedded_csv(text: str) -> str:
    match = re.search(r'<script type="application/gzip" id="traces-csv">(.*?)</script>', text, re.DOTALL)
    assert match, 'no embedded CSV'
    return gzip.decompress(base64.b64decode(match.group(1), validate=True)).decode('utf-8')


def test_page_is_self_contained_and_small(page):
    path, text = page
    assert path.stat().st_size < 1_000_000            # 30 s; the bench measures 60 s and 600 s
    assert 'Plotly' not in text and 'plotly' not in text.lower()
    # no script or stylesheet from elsewhere; element ids unique (a plot drawn into a heading would be a bug)
    assert not re.search(r'<script[^>]*\bsrc=|<link\b|<iframe', text, re.IGNORECASE)
    markup = re.sub(r'<script.*?</script>', '', text, flags=re.DOTALL)
    ids = Counter(re.findall(r'\bid="([^"]+)"', markup))
    assert not [i for i, n in ids.items() if n > 1], ids
    assert not re.search(r'https?://', markup)
    # the CSV's column list wraps (a list in columns), it does not run off the page as one long code element
    assert '<ul class="columns">' in text and 'ul.columns { columns:' in text


def test_envelope_keeps_every_extreme_in_few_points():
    """A min/max envelope per pixel column: ~2 points per column, every spike kept, breaks kept as gaps."""
    rng = np.random.default_rng(1)
    n = 294_000                                   # 600 s at 490 Hz
    time = np.arange(n) * SAMPLE_TIME
    values = rng.normal(size=n)
    values[[1234, 150_000, n - 7]] = [50.0, -60.0, 40.0]     # single-sample spikes
    values[200_000:200_100] = np.nan
    t, v = envelope(time, values, breaks=[100_000])
    assert v.size <= 2 * PIXEL_COLUMNS + 10
    assert {50.0, -60.0, 40.0} <= set(v[np.isfinite(v)].tolist())
    assert np.nanmax(v) == np.nanmax(values) and np.nanmin(v) == np.nanmin(values)
    assert np.all(np.diff(t[np.isfinite(t)]) > 0)                   # time order within and across columns
    gap = np.flatnonzero(np.isnan(v))
    assert gap.size == 1 and t[gap[0] - 1] < time[100_000] <= t[gap[0] + 1]
    short = np.arange(50.0)
    assert np.array_equal(envelope(short, short)[1], short)         # nothing to decimate


def test_svg_axes_put_data_on_the_right_pixels_and_ticks_on_round_numbers():
    figure = Figure(200)
    axes, = figure.grid(left=50, right=10, top=10, bottom=40)
    axes.line([0.0, 5.0, np.nan, 6.0, 10.0], [-1.0, 0.0, np.nan, 0.5, 1.0], '#123456')
    axes.xlim, axes.ylim = (0.0, 10.0), (-1.0, 1.0)
    drawn = re.search(r'<path d="([^"]+)" fill="none" stroke="#123456"', axes.svg()).group(1)
    # plotting area 1070 x 150 px; y grows downwards; the NaN starts a new piece
    assert drawn == 'M0 150l535-75M642 37.5l428-37.5'
    # far outside the limits (hidden by the clipping): exact steps, so the points after it are not moved
    far = Figure(200)
    axes, = far.grid(left=50, right=10, top=10, bottom=40)
    axes.line([0.0, 1.0, 2.0, 10.0], [0.0, 1e9, 0.0, 1.0], '#123456')
    axes.xlim, axes.ylim = (0.0, 10.0), (-1.0, 1.0)
    steps = re.search(r'<path d="M0 75l([^"]+)" fill="none" stroke="#123456"', axes.svg()).group(1)
    numbers = [float(v) for v in re.findall(r'-?(?:\d+\.?\d*|\.\d+)', steps)]
    assert sum(numbers[0::2]) == 1070.0 and 75 + sum(numbers[1::2]) == 0.0      # ends at (1070, 0) px
    ticks, step = svgplot.nice_ticks(-1.1, 1.1, 5)
    assert step == 0.5 and ticks.tolist() == [-1.0, -0.5, 0.0, 0.5, 1.0]
    assert svgplot.tick_labels(ticks, step) == ['\u22121.0', '\u22120.5', '0.0', '0.5', '1.0']
    assert svgplot.tick_labels(*svgplot.nice_ticks(0.0, 60.0, 6))[-1] == '60'
    html_text = figure.html('a <test>')
    assert 'aria-label="a &lt;test&gt;"' in html_text and html_text.count('<svg class="plot"') == 1


def test_candidate_chart_highlights_the_selected_set(diagnosis):
    rows = plots.candidate_chart_rows(diagnosis)
    selected = [r for r in rows if r['tag'] == 'SELECTED']
    assert [r['effect'] for r in selected] == diagnosis.missing_effects == ['coulomb_friction']
    assert selected[0]['colour'] == plots.SELECTED
    assert all(r['colour'] != plots.SELECTED for r in rows if r['effect'] not in (None, 'coulomb_friction'))
    # the selected candidate is the longest arrow: it removes the most error beyond the noise
    removed = {r['effect']: r['start'] - r['end'] for r in rows if r['effect']}
    assert max(removed, key=removed.get) == 'coulomb_friction'
    assert any(r['label'].startswith('selected set: + coulomb_friction') for r in rows)


def test_candidate_chart_after_add_shows_before_and_after(added, tmp_path):
    rows = plots.candidate_chart_rows(added)
    assert rows[0]['label'] == 'before: nominal' and rows[1]['label'] == 'after: nominal + coulomb_friction'
    assert rows[0]['end'] == pytest.approx(_excess(added.before) * 1e3)
    assert rows[1]['end'] == pytest.approx(_excess(added.current) * 1e3)
    assert rows[1]['end'] < 0.5 * rows[0]['end']                  # the friction removed most of the error
    text = write_report(added, tmp_path / 'after.html', source='friction.csv').read_text(encoding='utf-8')
    chart = re.search(r'<h2 id="candidates">.*?<svg class="plot"', text, re.DOTALL)
    assert chart, 'no candidate chart after --add'
    visible = re.sub(r'<[^>]+>', ' ', re.sub(r'<script.*?</script>', '', text, flags=re.DOTALL))
    assert not re.search(r'\binf\b', visible)                 # a profiled threshold's t statistic said in words


def test_candidate_labels_end_inside_the_chart(diagnosis):
    """Issue #42 item 7: a candidate's label ran past the chart's right edge (clipped at 1000 px). With a candidate
    significant alone but not selected (the longest tag) beside a long arrow, every label still ends inside."""
    first = next(c for c in diagnosis.candidates if c.effect not in diagnosis.missing_effects and c.comparison)
    redundant = dataclasses.replace(first, significant=True, excess_after=0.6 * first.excess_before)
    # the arrows that end right of the model as given (worse) widen the axis and would hide the problem: left out
    kept = [redundant if c is first else c for c in diagnosis.candidates
            if c.comparison is not None and c.excess_after <= c.excess_before * 1.01]
    crowded = dataclasses.replace(diagnosis, candidates=kept)
    chart = plots._plot_candidates(crowded)
    frame = re.search(r'<g transform="translate\(([\d.]+) [\d.]+\)">.*?<rect width="([\d.]+)" height="[\d.]+" '
                      r'fill="none"', chart, re.DOTALL)
    width = float(frame.group(2))
    labels = re.findall(r'<text x="([\d.]+)"[^>]*>([^<]*\u2014[^<]*)</text>', chart)
    assert any('significant alone, not selected' in label for _, label in labels), labels
    for x, label in labels:
        assert float(x) + 0.65 * 10.5 * len(label) <= width + 1, (x, label, width)     # x holds the 10 px gap


def test_after_add_the_report_shows_the_old_signature_and_no_insignificant_candidate(added, tmp_path):
    """Issue #42 item 7: after --add the report still drew a "best candidate (not significant)" line, and the
    residual-vs-state plot showed only the (flat) residual of the model with the effect, not the signature it took
    away. The equation the effects cite as eq (5)/(6) is shown, numbered."""
    best = next(c for c in added.candidates if c.comparison is not None)
    assert not best.significant
    text = write_report(added, tmp_path / 'after.html', source='friction.csv').read_text(encoding='utf-8')
    assert 'best candidate' not in text and '(not significant)' not in text
    scatter = text.split('id="scatter"', 1)[1].split('<h3', 1)[0]
    assert 'binned mean, before' in scatter and 'the signature the added effect took away' in scatter
    equation = text.split('id="equation"', 1)[1].split('</section>', 1)[0]
    assert '&emsp;(5)' in equation and '&emsp;(6)' in equation and 'f_eq5' in equation


def test_the_confounded_column_names_what_the_notes_call_indistinguishable(diagnosis):
    """Issue #42 item 7: "confounded with —" stood beside a note saying the thrust lag found includes any angle
    filter. The column now names the pairs of the chain notes."""
    from aeropend_core.diagnosis.doubts import chain_confusions, chain_notes
    from aeropend_core.present.report import _candidates_table
    lag = dataclasses.replace(diagnosis.found[0], effect='thrust_lag', parameters={'time_constant': 0.14},
                              confounded_with=())
    pairs = chain_confusions([lag], ['thrust_lag'])
    assert pairs == {'thrust_lag': ['angle_filter'], 'angle_filter': ['thrust_lag']}
    assert len(chain_notes([lag], ['thrust_lag'])) == 1
    candidates = [dataclasses.replace(diagnosis.candidates[0], effect=name, confounded_with=())
                  for name in ('thrust_lag', 'angle_filter')]
    table = _candidates_table(dataclasses.replace(diagnosis, found=[lag], candidates=candidates, effects=[]))
    cells = re.findall(r'<td>([^<]*(?:<small>.*?</small>)?)</td></tr>', table)
    assert [cell.split(' <small>')[0] for cell in cells[:1]] == ['angle_filter'], cells
    assert 'this record cannot tell them apart' in table and '&mdash;' not in table


def test_rows_without_error_to_remove_do_not_claim_a_share():
    """A candidate added to a model already within the noise removes nothing: no 'removes 100 %' on a 'no' row, and a
    profiled threshold's infinite t statistic said in words -- by the diagnosis's own wording, not patched later."""
    from aeropend_core.diagnosis.evidence import share_words, t_statistic_words
    from aeropend_core.present.report import _plain
    text = f'{t_statistic_words(float("inf"))}; {share_words(1.0, 0.0)}'
    assert 'removes 100 %' not in text and 'no error beyond the noise' in text
    assert 'inf' not in text.split() and 'threshold' in text
    assert share_words(0.42, 1e-3) == 'it removes 42 % of the held-out mean-square error beyond the noise'
    assert t_statistic_words(4.25) == 'parameter 4.2 HAC standard errors from zero'
    assert _plain('interval [0.1, inf] rad') == 'interval [0.1, unbounded] rad'


def test_csv_export_holds_every_sample_and_the_models(page, diagnosis):
    _, text = page
    prep = diagnosis.prepared
    rows = list(csv.DictReader(io.StringIO(embedded_csv(text))))
    assert len(rows) == prep.time.size
    assert f'{prep.time.size} rows' in text and 'Download friction_traces.csv' in text
    assert 'aeropendDownloadCsv' in text and "new DecompressionStream('gzip')" in text

    def column(name):
        return np.array([float(r[name]) if r[name] else np.nan for r in rows])

    np.testing.assert_allclose(column('time_s'), prep.time, atol=1e-6)
    np.testing.assert_allclose(column('angle_rad'), prep.angle, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(column('armature_current_A'), prep.armature_current, rtol=1e-5, atol=1e-9)
    assert column('held_out').sum() == prep.time.size - prep.split
    simulated = diagnosis.current.evaluation.simulated
    np.testing.assert_array_equal(np.isnan(column('simulated_angle_rad')), np.isnan(simulated))
    np.testing.assert_allclose(column('simulated_angle_rad'), simulated, rtol=1e-6, equal_nan=True)
    best = next(c for c in diagnosis.candidates if c.comparison is not None)
    np.testing.assert_allclose(column(f'simulated_angle_with_{best.effect}_rad'), best.comparison.evaluation.simulated,
                               rtol=1e-6, equal_nan=True)


def test_observer_current_reproduces_the_observers_own_error(diagnosis):
    """The plotted model current is the observer's: its RMS error against Ia is the one the observer reports."""
    prep = diagnosis.prepared
    motor = prep.motor
    assert motor is not None, 'the observer explains Ia on this record'
    traces = model_sections.observer_traces(diagnosis)
    keep = np.ones(prep.time.size, dtype=bool)
    for k in prep.step_indices:
        keep[k:k + STEP_SETTLING_SAMPLES] = False
    keep[:STEP_SETTLING_SAMPLES] = False
    error = float(np.sqrt(np.mean((traces['model_current'] - prep.armature_current)[keep] ** 2)))
    assert error == pytest.approx(motor.current_rms_error, rel=0.05)
    assert error < 1.5 * motor.current_noise_rms
    # the thrust input is the observer's back-EMF, and Va - Rm Ia scatters around it
    np.testing.assert_array_equal(traces['thrust_voltage'], motor.back_emf)
    assert abs(np.nanmedian(traces['measured_emf'] - motor.back_emf)) < 0.02


def test_correlation_matrix_is_the_fits(page, diagnosis):
    _, text = page
    section = re.search(r'<section id="correlation">.*?</section>', text, re.DOTALL).group(0)
    first = re.search(r'<table class="correlation".*?</table>', section, re.DOTALL).group(0)
    fit = diagnosis.current.fit
    cells = [float(v) for v in re.findall(r'<td class="num" style="[^"]*">([+-]\d\.\d\d)</td>', first)]
    assert np.allclose(np.reshape(cells, (len(fit.free_names),) * 2), np.round(fit.correlation, 2), atol=0.006)
    for name in fit.free_names:
        assert f'<th><code>{name}</code></th>' in first
    strong = sum(abs(fit.correlation[i, j]) > model_sections.STRONG_CORRELATION
                 for i in range(len(fit.free_names)) for j in range(len(fit.free_names)) if i != j)
    assert first.count('outline:2px') == strong


def test_identified_equation_carries_the_numbers_and_units(page, diagnosis):
    _, text = page
    section = re.search(r'<section id="equation">.*?</section>', text, re.DOTALL).group(0)
    assert 'd&Omega;/dt = &minus;a&middot;sin y &minus; b&middot;&Omega; + k&middot;e|e|' in section
    assert 'back-EMF of the motor observer' in section
    parameters, errors = diagnosis.current.parameters, diagnosis.current.fit.standard_errors
    for name, symbol, unit in (('gravity_stiffness', 'a', '1/s^2'), ('damping', 'b', '1/s'),
                               ('thrust_gain', 'k', 'rad/s^2/V^2')):
        assert f'{symbol} = <b>{parameters[name]:.4g} &plusmn; {errors[name]:.2g}</b> {unit}' in section, name
    best = next(c for c in diagnosis.candidates if c.comparison is not None)
    assert best.effect == 'coulomb_friction' and best.significant
    # the significant candidate's equation follows: its record's line and its fitted value
    from aeropend_core.model.effects import CATALOG
    value = best.comparison.parameters['friction_acceleration']
    assert html.escape(CATALOG['coulomb_friction'].equation) in section
    assert f'<code>friction_acceleration</code> = <b>{value:.4g}' in section


def test_long_lag_correlations_and_their_bands(diagnosis):
    """To 5 s of lag (or a third of the held-out part), with the 99 % bands of the stated N and N_eff."""
    from aeropend_core.diagnosis.validation import residual_correlations
    prep = diagnosis.prepared
    nominal = residual_correlations(prep, diagnosis.current)
    heldout_seconds = prep.time[-1] - prep.time[prep.split]
    assert nominal.lag_seconds[-1] >= min(5.0, heldout_seconds / 3) - 0.01
    assert nominal.auto_band == pytest.approx(2.58 / np.sqrt(nominal.samples))
    assert nominal.cross_band == pytest.approx(2.58 / np.sqrt(nominal.effective_samples))
    assert 1 <= nominal.effective_samples < nominal.samples      # the residual and the input are correlated
    assert nominal.autocorrelation[0] == pytest.approx(1.0)
    # the nominal model's residual is still correlated at 0.1 s (issue #24: 0.7 there); the right model's is not
    at = int(np.argmin(np.abs(nominal.lag_seconds - 0.1)))
    right = residual_correlations(prep, next(c for c in diagnosis.candidates
                                             if c.effect == 'coulomb_friction').comparison)
    assert nominal.autocorrelation[at] > 0.5 > 5 * abs(right.autocorrelation[at])


def test_band_comes_from_the_covariance_and_k_step_points_match_the_card(diagnosis):
    from aeropend_core.diagnosis.validation import prediction_points, simulation_band
    prep = diagnosis.prepared
    band = simulation_band(prep, diagnosis.current)
    index = prep.heldout.residual_index
    half = (band.high - band.low)[index] / 2
    assert band.points == 2 * len(diagnosis.current.fit.free_names)
    assert np.all(np.isfinite(half)) and np.all(half >= 0) and np.median(half) > 0
    assert np.all(band.low[index] <= band.simulated[index]) and np.all(band.simulated[index] <= band.high[index])
    # half the standard errors: about half the band (the parameters' uncertainty propagated; near-linear there)
    fit = diagnosis.current.fit
    halved = dataclasses.replace(diagnosis.current, fit=dataclasses.replace(
        fit, standard_errors={k: 0.5 * v for k, v in fit.standard_errors.items()}))
    narrower = simulation_band(prep, halved)
    ratio = np.median((narrower.high - narrower.low)[index]) / np.median((band.high - band.low)[index])
    assert 0.4 < ratio < 0.6
    predicted_index, predicted = prediction_points(prep, diagnosis.current)
    rms = np.sqrt(np.mean((prep.angle[predicted_index] - predicted) ** 2))
    assert rms == pytest.approx(diagnosis.current.evaluation.prediction_rms)


def test_residual_against_rate_shows_the_friction_step(diagnosis):
    """Dry friction's sign(rate) is a jump of the residual's binned mean across zero rate (the residual just before
    the rod stops differs from just after it starts the other way); with friction in the model the jump is gone."""
    from aeropend_core.present.model_checks import _binned_mean
    prep = diagnosis.prepared

    def jump(comparison):
        simulated = comparison.evaluation.simulated
        index = np.flatnonzero(np.isfinite(simulated))
        rate, residual = prep.smoothed_rate[index], prep.angle[index] - simulated[index]
        centres, means = _binned_mean(rate, residual)
        return abs(np.mean(means[(centres > -0.35) & (centres < 0)]) - np.mean(means[(centres > 0) & (centres < 0.35)]))

    with_friction = next(c for c in diagnosis.candidates if c.effect == 'coulomb_friction').comparison
    assert jump(diagnosis.current) > 0.5 * diagnosis.noise_rms
    assert jump(with_friction) < jump(diagnosis.current) / 3


# -- headless Chromium --------------------------------------------------------------------------------------------

def chromium(url: str, tmp_path, *extra: str, size: tuple[int, int] = (1400, 3000)) -> tuple[str, str, list[str]]:
    """(stdout, browser log, http(s) URLs the page itself requested) of one headless Chromium run."""
    profile = tmp_path / f'profile_{len(list(tmp_path.iterdir()))}'
    net_log = profile.with_suffix('.net.json')
    command = [CHROMIUM, '--headless', '--no-sandbox', '--disable-gpu', '--disable-background-networking',
               '--disable-component-update', '--no-first-run', f'--user-data-dir={profile}', '--enable-logging=stderr',
               '--v=0', f'--log-net-log={net_log}', f'--window-size={size[0]},{size[1]}', '--virtual-time-budget=15000',
               *extra, url]
    result = subprocess.run(command, capture_output=True, text=True, timeout=180)
    log = json.loads(net_log.read_text())
    names = {value: key for key, value in log['constants']['logEventTypes'].items()}
    # Requests of the page (a file:// document) carry its network isolation key; the browser's own background
    # traffic (time, update and account checks) does not.
    requested = [event['params']['url'] for event in log['events']
                 if names.get(event['type']) == 'URL_REQUEST_START_JOB'
                 and 'file://' in event['params'].get('network_isolation_key', '')
                 and event['params'].get('url', '').startswith(('http://', 'https://'))]
    return result.stdout, result.stderr, requested


@needs_chromium
@pytest.mark.timeout(300)
def test_the_checks_catch_a_script_error_and_a_fetch(tmp_path):
    """The browser checks below can fail: a page with an uncaught error and two remote loads is caught."""
    bad = tmp_path / 'bad.html'
    bad.write_text('<html><body><img src="https://example.invalid/x.png"><script>fetch("http://example.invalid/y");'
                   'throw new Error("boom");</script></body></html>')
    _, log, requested = chromium(bad.as_uri(), tmp_path, '--dump-dom')
    assert 'Uncaught Error: boom' in log
    assert sorted(requested) == ['http://example.invalid/y', 'https://example.invalid/x.png']


CSV_PROBE = """<script>
// What the page's download function starts from, checked synchronously (the decompression itself runs off the main
// thread, after --dump-dom has already written the page): the embedded text decodes with the browser's atob, starts
// with gzip's magic bytes, and the browser has DecompressionStream.
var packed = document.getElementById('traces-csv').textContent.replace(/\\s+/g, '');
var bytes = Uint8Array.from(atob(packed), function (c) { return c.charCodeAt(0); });
document.body.setAttribute('data-gzip-bytes', String(bytes.length));
document.body.setAttribute('data-gzip-magic', bytes[0].toString(16) + bytes[1].toString(16));
document.body.setAttribute('data-decompression', typeof DecompressionStream);
document.body.setAttribute('data-download', typeof aeropendDownloadCsv);
</script>"""


@pytest.mark.slow
@needs_chromium
@pytest.mark.timeout(600)
def test_chromium_renders_without_errors_or_fetches(page, added, diagnosis, tmp_path):
    """No JavaScript error, nothing fetched, the page drawn (screenshots kept as artefacts); the embedded CSV is
    readable by the browser's own decoders (its decompression to every sample is checked in Python above)."""
    path, text = page
    after = write_report(added, tmp_path / 'after.html', source='friction.csv')
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    from PIL import Image
    for name, report in (('report', path), ('report_after_add', after)):
        shot = ARTIFACTS / f'{name}.png'
        _, log, requested = chromium(report.as_uri(), tmp_path, f'--screenshot={shot}', size=(1280, 12000))
        assert 'Uncaught' not in log, [line for line in log.splitlines() if 'Uncaught' in line or 'CONSOLE' in line]
        assert requested == []
        image = Image.open(shot).convert('RGB')
        assert image.size == (1280, 12000)
        colours = image.getcolors(maxcolors=1 << 20)
        assert colours is not None and len(colours) > 200          # plots, not a blank page
    probe = tmp_path / 'probe.html'
    probe.write_text(text.replace('</body>', CSV_PROBE + '</body>'), encoding='utf-8')
    dom, log, requested = chromium(probe.as_uri(), tmp_path, '--dump-dom')
    assert 'Uncaught' not in log and requested == []
    packed = re.search(r'<script type="application/gzip" id="traces-csv">(.*?)</script>', text, re.DOTALL).group(1)
    assert f'data-gzip-bytes="{len(base64.b64decode(packed))}"' in dom
    assert 'data-gzip-magic="1f8b"' in dom
    assert 'data-decompression="function"' in dom and 'data-download="function"' in dom


ZOOM_PROBE = """<script>
// Shift + wheel over the time trace, then a drag: the data group is scaled along x and the ticks rewritten.
var svg = document.querySelector('svg.zoom'), box = svg.querySelector('g.zx').parentNode.getBoundingClientRect();
var x = box.left + box.width / 2, y = box.top + box.height / 2;
svg.dispatchEvent(new WheelEvent('wheel', {deltaY: -100, shiftKey: true, clientX: x, clientY: y, bubbles: true,
                                           cancelable: true}));
svg.dispatchEvent(new WheelEvent('wheel', {deltaY: -100, shiftKey: true, clientX: x, clientY: y, bubbles: true,
                                           cancelable: true}));
document.body.setAttribute('data-zoom-transform', svg.querySelector('g.zx').getAttribute('transform'));
document.body.setAttribute('data-zoom-view', svg.aeropendView.map(function (v) { return v.toFixed(3); }).join(' '));
document.body.setAttribute('data-zoom-ticks', Array.from(svg.querySelectorAll('g.xt text')).map(
    function (t) { return t.textContent; }).join(' '));
svg.dispatchEvent(new MouseEvent('mousedown', {clientX: x, clientY: y, bubbles: true}));
svg.dispatchEvent(new MouseEvent('mousemove', {clientX: x + box.width / 4, clientY: y, bubbles: true}));
window.dispatchEvent(new MouseEvent('mouseup', {bubbles: true}));
document.body.setAttribute('data-pan-view', svg.aeropendView.map(function (v) { return v.toFixed(3); }).join(' '));
svg.dispatchEvent(new MouseEvent('dblclick', {bubbles: true}));
document.body.setAttribute('data-reset-zoomed', String(svg.classList.contains('zoomed')));
</script>"""


@needs_chromium
@pytest.mark.timeout(300)
def test_time_traces_zoom_and_pan_offline(page, diagnosis, tmp_path):
    """Issue #42 item 7: static time traces. Shift + wheel zooms the time axis of the overlay (0.8 x per step,
    about the pointer), a drag pans it, a double-click resets; the ticks are rewritten; nothing is fetched."""
    path, text = page
    assert text.count('<svg class="plot zoom"') == 2                # the whole-record overlay and the error trace
    probe = tmp_path / 'zoom.html'
    probe.write_text(text.replace('</body>', ZOOM_PROBE + '</body>'), encoding='utf-8')
    dom, log, requested = chromium(probe.as_uri(), tmp_path, '--dump-dom')
    assert 'Uncaught' not in log and requested == []
    time = diagnosis.prepared.time
    full = time[-1] - time[0]
    view = [float(v) for v in re.search(r'data-zoom-view="([^"]+)"', dom).group(1).split()]
    assert view[1] - view[0] == pytest.approx(0.64 * full, rel=1e-3)          # two steps of 0.8
    assert 'scale(1.5625 1)' in re.search(r'data-zoom-transform="([^"]+)"', dom).group(1)
    ticks = [float(t) for t in re.search(r'data-zoom-ticks="([^"]+)"', dom).group(1).split()]
    assert len(ticks) >= 5 and view[0] <= ticks[0] and ticks[-1] <= view[1] + 1e-9
    panned = [float(v) for v in re.search(r'data-pan-view="([^"]+)"', dom).group(1).split()]
    assert panned[0] < view[0] and panned[1] - panned[0] == pytest.approx(view[1] - view[0], rel=1e-6)
    assert 'data-reset-zoomed="false"' in dom


# -- pictures for the docs (issue #42 item 8) -----------------------------------------------------------------------

DOC_IMAGES = Path(__file__).resolve().parents[1] / 'docs' / 'images'


def _monitor_page(tmp_path) -> Path:
    """`aeropend monitor`'s table and live plot, as the monitor draws them, for three windows identified by the
    online analysis itself (25 s windows every 5 s over a simulated 35 s run with the default hidden 0.05 rad angle
    offset, 40 dB): the terminal's text in a <pre>, the plot as the PNG the monitor saves with --plot-file."""
    from aeropend_core.diagnosis.online import analyze_window
    from aeropend_core.model.effects import parameter_unit
    from aeropend_core.present.live_plot import LivePlot, WindowPoint
    from aeropend_ros.cli.monitor import DriftTracker, render
    duty = lhc_schedule(35.0, seed=7).duty(SAMPLE_TIME, 35.0)
    columns = simulate(duty, effects={'angle_offset': 0.05}, noise=MeasurementNoise(40, True),
                       seed=7).columns(with_truth=False)
    time = columns['t']
    tracker, plot, text = DriftTracker(), LivePlot(interactive=False), ''
    for stop in (25.0, 30.0, 35.0):
        inside = (time >= stop - 25.0) & (time < stop)
        result = analyze_window(time[inside], columns['armature_voltage'][inside],
                                columns['armature_current'][inside], columns['angle'][inside])
        drift = tracker.update(result.parameters)
        fit = {'fit_percent': (result.fit_percent, 0.0), 'rms_error': (result.rms_error, 0.0),
               'noise_rms': (result.noise_rms, 0.0), 'compute_time': (result.compute_time, 0.0)}
        text = render(result.parameters, result.coefficients, fit, f'fit {result.fit_percent:.1f} % on '
                      f'{result.held_out_seconds:.1f} s held out', drift, len(plot.points) + 1, width=None,
                      estimators=result.estimators, data='', span=(stop - 25.0, stop))
        plot.add(WindowPoint(stop, dict(result.parameters), result.fit_percent))
        plot.units.update({name: parameter_unit(name) for name in result.parameters})
        plot.estimators.update(result.estimators)
    plot.draw()
    png = tmp_path / 'live.png'
    plot.save(str(png))
    page = tmp_path / 'monitor.html'
    page.write_text('<!DOCTYPE html><html><body style="margin:0;background:#fff;font-family:sans-serif">'
                    '<pre style="background:#1e1e1e;color:#e6e6e6;padding:12px;margin:0;font-size:12px;'
                    f'white-space:pre-wrap">$ aeropend monitor\n{html.escape(text)}</pre><img style="display:block" '
                    f'src="data:image/png;base64,{base64.b64encode(png.read_bytes()).decode()}"></body></html>',
                    encoding='utf-8')
    return page


def _small_png(shot: Path, target: Path, height: int) -> None:
    """The screenshot's top `height` px, in 256 colours (a small file for the repository)."""
    from PIL import Image
    image = Image.open(shot).convert('RGB')
    image.crop((0, 0, image.width, min(height, image.height))).quantize(colors=256).save(target, optimize=True)


@pytest.mark.slow
@needs_chromium
@pytest.mark.timeout(600)
def test_screenshots_of_the_report_and_the_monitor_for_the_docs(page, tmp_path):
    """The pictures in README.md and docs/ are made here, by headless Chromium, from a real report and from the
    monitor's own table and plot: kept as artefacts, and written to docs/images/ with AEROPEND_UPDATE_SCREENSHOTS=1.
    Either way the page loads nothing from outside and the pictures the docs show exist and are shown."""
    from PIL import Image
    path, _ = page
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    update = os.environ.get('AEROPEND_UPDATE_SCREENSHOTS') == '1'
    for name, source, size, keep in (('report', path, (1100, 1500), 1250),
                                     ('monitor', _monitor_page(tmp_path), (1000, 1100), 1100)):
        shot = ARTIFACTS / f'{name}_full.png'
        _, log, requested = chromium(source.as_uri(), tmp_path, f'--screenshot={shot}', size=size)
        assert 'Uncaught' not in log and requested == []
        _small_png(shot, ARTIFACTS / f'{name}.png', keep)
        if update:
            DOC_IMAGES.mkdir(exist_ok=True)
            shutil.copyfile(ARTIFACTS / f'{name}.png', DOC_IMAGES / f'{name}.png')
        shown = DOC_IMAGES / f'{name}.png'
        assert shown.is_file(), f'{shown} missing: run this test with AEROPEND_UPDATE_SCREENSHOTS=1'
        with Image.open(shown) as image:
            assert image.width == size[0] and 600 <= image.height <= keep
            assert len(image.convert('RGB').getcolors(maxcolors=1 << 16) or []) > 50     # a picture, not a blank
        assert shown.stat().st_size < 400_000
    readme = (DOC_IMAGES.parents[1] / 'README.md').read_text(encoding='utf-8')
    assert 'docs/images/report.png' in readme and 'docs/images/monitor.png' in readme
    assert 'images/report.png' in (DOC_IMAGES.parent / 'report.md').read_text(encoding='utf-8')
    assert 'images/monitor.png' in (DOC_IMAGES.parent / 'live.md').read_text(encoding='utf-8')
