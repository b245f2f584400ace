"""The report's interactive plots, the model sections (motor observer, identified equation, parameter correlation) and
the CSV export; the page rendered in headless Chromium (no JavaScript error, every plot drawn, nothing fetched).

One diagnosis (~5 s) of a 30 s simulated record with dry friction hidden, PSNR 40 dB, 10-bit angle quantisation.
"""
from __future__ import annotations

import csv
import html
import io
import json
import re
import shutil
import subprocess
from collections import Counter

import numpy as np
import pytest

from aeropend_core.diagnosis.diagnose import diagnose
from aeropend_core.io.recording import from_columns
from aeropend_core.model.parameters import SAMPLE_TIME
from aeropend_core.present import interactive, model_sections
from aeropend_core.present.report import render_report, write_report
from aeropend_core.signals.preprocess import STEP_SETTLING_SAMPLES
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate

CHROMIUM = shutil.which('chromium') or shutil.which('chromium-browser') or shutil.which('google-chrome')
needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason='headless Chromium is not installed (Debian package '
                                    '`chromium`, listed in scripts/apt-packages.txt)')
needs_plotly = pytest.mark.skipif(not interactive.available(), reason='plotly is not installed')
FIGURES = ('overlay', 'heldout', 'error', 'observer')


@pytest.fixture(scope='module')
def diagnosis():
    duty = lhc_schedule(30.0, seed=3).duty(SAMPLE_TIME, 30.0)
    run = simulate(duty, effects={'coulomb_friction': 4.0}, noise=MeasurementNoise(40, True), seed=3)
    return diagnose(from_columns(run.columns(with_truth=False), source='friction.csv'))


@pytest.fixture(scope='module')
def page(diagnosis, tmp_path_factory):
    path = write_report(diagnosis, tmp_path_factory.mktemp('interactive') / 'report.html', source='friction.csv')
    return path, path.read_text(encoding='utf-8')


def embedded_csv(text: str) -> str:
    match = re.search(r'<script type="text/csv" id="traces-csv">\n(.*?)</script>', text, re.DOTALL)
    assert match, 'no embedded CSV'
    return match.group(1)


@needs_plotly
def test_page_is_self_contained_with_plotly_inlined_once(page):
    _, text = page
    library = interactive.library_html()
    assert text.count(library) == 1 and text.index(library) < text.index('<body>')
    for name in FIGURES:
        assert text.count(f'<div id="plotly-{name}" class="plotly-graph-div"') == 1, name
        assert f'Plotly.newPlot(                        "plotly-{name}"' in text, name
    # no script or stylesheet from elsewhere; element ids unique (a plot drawn into a heading would be a bug)
    assert not re.search(r'<script[^>]*\bsrc=|<link\b|<iframe', text, re.IGNORECASE)
    markup = re.sub(r'<script.*?</script>', '', text, flags=re.DOTALL)
    ids = Counter(re.findall(r'\bid="([^"]+)"', markup))
    assert not [i for i, n in ids.items() if n > 1], ids
    assert not re.search(r'https?://', markup)
    assert '"showLink"' not in text and '"displaylogo": false' in text


def test_csv_export_holds_every_sample_and_the_models(page, diagnosis):
    _, text = page
    prep = diagnosis.prepared
    rows = list(csv.DictReader(io.StringIO(embedded_csv(text))))
    assert len(rows) == prep.time.size
    assert f'{prep.time.size} rows' in text and 'Download friction_traces.csv' in text
    assert 'aeropendDownloadCsv' in text and "new Blob([text], {type: 'text/csv'})" in text

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


def test_without_plotly_the_pngs_come_back(diagnosis, monkeypatch):
    monkeypatch.setattr(interactive, 'available', lambda: False)
    text = render_report(diagnosis, 'friction.csv')
    assert 'Plotly.newPlot' not in text and '<div class="plot"' not in text
    # overlay, held-out zoom, error, regimes, residual tests, candidates, motor observer
    assert len(re.findall(r'<img src="data:image/png;base64,', text)) == 7
    assert len(list(csv.reader(io.StringIO(embedded_csv(text))))) == diagnosis.prepared.time.size + 1


# -- headless Chromium --------------------------------------------------------------------------------------------

def chromium(url: str, tmp_path, *extra: str) -> tuple[str, str, list[str]]:
    """(stdout, browser log, http(s) URLs the page itself requested) of one headless Chromium run."""
    profile = tmp_path / f'profile_{len(list(tmp_path.iterdir()))}'
    net_log = profile.with_suffix('.net.json')
    command = [CHROMIUM, '--headless', '--no-sandbox', '--disable-gpu', '--disable-background-networking',
               '--disable-component-update', '--no-first-run', f'--user-data-dir={profile}', '--enable-logging=stderr',
               '--v=0', f'--log-net-log={net_log}', '--window-size=1400,3000', '--virtual-time-budget=15000',
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


@needs_chromium
@needs_plotly
@pytest.mark.timeout(300)
def test_chromium_draws_every_plot_without_errors_or_fetches(page, tmp_path):
    path, _ = page
    dom, log, requested = chromium(path.as_uri(), tmp_path, '--dump-dom')
    assert 'Uncaught' not in log, [line for line in log.splitlines() if 'Uncaught' in line or 'CONSOLE' in line]
    assert requested == []
    for name in FIGURES:               # plotly drew an SVG plot with its traces in every figure
        figure = re.search(rf'<div id="plotly-{name}" class="[^"]*js-plotly-plot[^"]*".*?class="main-svg"', dom,
                           re.DOTALL)
        assert figure, f'{name} not drawn'
    assert dom.count('class="scatterlayer') >= len(FIGURES)
    shot = tmp_path / 'report.png'
    _, log, requested = chromium(path.as_uri(), tmp_path, f'--screenshot={shot}')
    assert 'Uncaught' not in log and requested == []
    from PIL import Image
    image = Image.open(shot).convert('RGB')
    assert image.size == (1400, 3000)
    colours = image.getcolors(maxcolors=1 << 20)
    assert colours is not None and len(colours) > 200          # plots, not a blank page
