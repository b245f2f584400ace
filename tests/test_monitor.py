"""`aeropend monitor` against a real node graph (sim, excitation, identification as processes over DDS): the table
with each parameter's estimator, JSON lines, the live plot saved off-screen (no display: MPLBACKEND=Agg); and the
table and the plot from known numbers (no ROS)."""
from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest

from aeropend_ros._ros_env import local_ros_environment
from tests.ros_helpers import ROOT, NodeProcess, private_domain_id

AEROPEND = [sys.executable, '-c', 'import sys; from aeropend_core.cli import main; sys.exit(main())']


@pytest.mark.timeout(300)
def test_monitor_table_json_lines_and_plot_file_on_a_live_graph(tmp_path):
    domain_id = private_domain_id()
    env = local_ros_environment(domain_id=domain_id)
    env.pop('DISPLAY', None)
    env.pop('WAYLAND_DISPLAY', None)
    env['MPLBACKEND'] = 'Agg'
    plot = tmp_path / 'live.png'
    lines = tmp_path / 'monitor.jsonl'
    with NodeProcess('aeropend_ros.sim_node', ['-p', 'realtime_factor:=2.0', '-p', "effects:=['angle_offset=0.05']"],
                     domain_id) as sim, \
            NodeProcess('aeropend_ros.excitation_node', ['-p', 'duration:=600.0', '-p', 'start_delay:=0.5'],
                        domain_id), \
            NodeProcess('aeropend_ros.identification_node', ['-p', 'window_s:=12.0', '-p', 'hop_s:=3.0'],
                        domain_id) as identification:
        as_json = subprocess.Popen(AEROPEND + ['monitor', '--once', '--timeout', '120', '--json', '-',
                                               '--plot-file', str(plot)],
                                   env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        table = subprocess.run(AEROPEND + ['monitor', '--once', '--timeout', '120', '--json', str(lines)],
                               env=env, cwd=ROOT, capture_output=True, text=True, timeout=180)
        out, err = as_json.communicate(timeout=180)
        logs = identification.output() + sim.output()
    # The table: every parameter with its estimator; the weak-SINDy coefficients below.
    assert table.returncode == 0, table.stderr + table.stdout + logs
    assert 'estimator' in table.stdout and 'output_error' in table.stdout, table.stdout
    row = next(line for line in table.stdout.splitlines() if line.startswith('thrust_gain '))
    assert 'output_error' in row
    assert 'estimator weak_sindy' in table.stdout and 'sin(angle)' in table.stdout
    # issue #42: the first table a monitor prints has a unit per row, a running mean and an estimator (no nan, ?)
    rows = [line for line in table.stdout.splitlines()
            if line.split() and line.split()[0] in ('gravity_stiffness', 'damping', 'thrust_gain')]
    assert len(rows) == 3 and not [r for r in rows if 'nan' in r or ' ? ' in r], table.stdout
    assert 'rad/s^2/V^2' in row and 'window(s) received' in table.stdout
    # JSON lines to a file: each line one object; the window's line carries value, sigma, band, unit, estimator.
    objects = [json.loads(line) for line in lines.read_text().splitlines()]
    window = [o for o in objects if 'window' in o][-1]['window']
    gain = window['parameters']['thrust_gain']
    assert gain['unit'] == 'rad/s^2/V^2' and gain['estimator'] == 'output_error'
    assert gain['lower'] == pytest.approx(gain['value'] - gain['sigma'])
    assert gain['upper'] == pytest.approx(gain['value'] + gain['sigma'])
    assert math.isfinite(window['fit']['fit_percent']) and 'drift' in window
    # --json -: standard output carries the JSON lines only, the table went to standard error.
    assert as_json.returncode == 0, err + out
    streamed = [json.loads(line) for line in out.splitlines()]
    assert streamed and any('window' in o for o in streamed)
    assert 'held-out fit' in err
    # The plot, drawn without a display: a PNG.
    assert plot.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n' and plot.stat().st_size > 10_000


def test_monitor_refuses_a_json_folder_before_listening(tmp_path):
    env = local_ros_environment(domain_id=private_domain_id())
    result = subprocess.run(AEROPEND + ['monitor', '--once', '--json', str(tmp_path)], env=env, cwd=ROOT,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and 'is a folder' in result.stderr and result.stdout == ''
    assert result.stderr.count('\n') == 1, result.stderr


def test_render_names_estimators_drift_and_flagged_data():
    from aeropend_ros.cli.monitor import render
    text = render({'thrust_gain': (120.0, 1.0), 'armature_resistance': (1.08, float('nan'))}, {}, {
        'fit_percent': (95.0, float('nan'))}, 'fit 95 %', {}, 7,
        trends={'thrust_gain': '-15.0 % over 120 s, t = -9.1, p = 1e-05, 6 windows, DRIFT'},
        estimators={'thrust_gain': 'output_error', 'armature_resistance': 'motor_observer'},
        node_drift='parameter drift: thrust gain -15 % over 120 s', data='angle_jump:repaired')
    assert 'DRIFT: parameter drift: thrust gain -15 % over 120 s' in text
    assert 'DATA REPAIRED OR FLAGGED in this window: angle_jump:repaired' in text
    gain = next(line for line in text.splitlines() if line.startswith('thrust_gain'))
    assert 'output_error' in gain and 'trend -15.0 %' in gain
    assert 'motor_observer' in next(line for line in text.splitlines() if line.startswith('armature_resistance'))


def test_live_plot_draws_bands_drift_and_flags_off_screen(tmp_path):
    import matplotlib
    matplotlib.use('Agg')
    from aeropend_core.present.live_plot import LivePlot, WindowPoint
    plot = LivePlot(interactive=False)
    for k in range(10):
        plot.add(WindowPoint(5.0 * k, {'thrust_gain': (140.0 - k, 1.0), 'damping': (13.8, 0.1),
                                       'angle_offset': (0.05, 0.001)}, 95.0, flagged=k == 4))
    plot.units = {'thrust_gain': 'rad/s^2/V^2'}
    plot.estimators = {'thrust_gain': 'output_error'}
    plot.drift = {'thrust_gain': '-6.4 % over 45 s, DRIFT'}
    plot.draw()
    axes = plot.figure.axes
    assert [a.get_title(loc='left').split(' [')[0] for a in axes[:3]] == ['damping', 'thrust_gain', 'angle_offset']
    gain = axes[1]
    assert 'output_error' in gain.get_title(loc='left') and 'DRIFT' in gain.get_title(loc='left')
    band = gain.collections[0].get_paths()[0].vertices[:, 1]
    assert band.max() == pytest.approx(141.0) and band.min() == pytest.approx(130.0)      # value ± σ
    flagged = [line for line in gain.get_lines() if line.get_marker() == 'x']
    assert len(flagged) == 1 and list(flagged[0].get_xdata()) == [20.0]
    path = tmp_path / 'frame.png'
    plot.save(str(path))
    assert path.read_bytes()[:4] == b'\x89PNG'


def test_the_first_table_has_units_means_and_no_unknowns():
    """Issue #42 item 2: the first table showed `nan` (the running mean of no previous window) and `?` (the
    estimator, before the window's status said it); no unit column. Now the mean counts the window itself, the
    estimator defaults to the node's own (output_error), and every row carries its SI unit."""
    from aeropend_ros.cli.monitor import DriftTracker, render
    parameters = {'gravity_stiffness': (145.0, 2.0), 'thrust_gain': (136.7, 2.0), 'damping': (14.0, 0.3)}
    drift = DriftTracker().update(parameters)
    text = render(parameters, {}, {'fit_percent': (95.0, math.nan)}, 'fit 95 %', drift, 1, width=None)
    rows = {line.split()[0]: line for line in text.splitlines() if line.split() and line.split()[0] in parameters}
    assert set(rows) == set(parameters)
    assert 'nan' not in text and '?' not in text
    assert 'unit' in text and 'rad/s^2/V^2' in rows['thrust_gain'] and '1/s^2' in rows['gravity_stiffness']
    assert rows['damping'].split()[4] == '14' and 'output_error' in rows['damping']          # the mean: the value
    second = DriftTracker()
    second.update({'damping': (14.0, 0.3)})
    assert second.update({'damping': (16.0, 0.3)})['damping'][0] == pytest.approx(15.0)      # with this window


def test_the_weak_form_says_when_it_disagrees_and_a_derived_value_is_labelled():
    """The issue's window: the weak form's sin(angle) coefficient -3.56 +- 3.53 beside gravity 145 with no word why,
    and thrust_coefficient 5.04e-06 printed like a fit though no diagnosis prints it."""
    from aeropend_ros.cli.monitor import render, weak_form_remark
    parameters = {'gravity_stiffness': (145.0, 2.0), 'damping': (14.0, 0.3), 'thrust_coefficient': (5.04e-6, 1e-7)}
    coefficients = {'sin(angle)': (-3.56, 3.53), 'dangle/dt': (-14.2, 0.5), 'armature_voltage^2': (12.0, 1.0)}
    text = render(parameters, coefficients, {'fit_percent': (95.0, math.nan)}, '', {}, 4, width=None,
                  ended='the excitation has finished')
    sin_row = next(line for line in text.splitlines() if line.strip().startswith('sin(angle)'))
    assert 'gravity_stiffness 3.56' in sin_row and 'DISAGREES' in sin_row and '145' in sin_row
    assert sin_row.endswith('sigma)*') and '* read the output-error value above' in text
    rate_row = next(line for line in text.splitlines() if line.strip().startswith('dangle/dt'))
    assert 'agrees with the output-error fit' in rate_row and 'DISAGREES' not in rate_row
    assert weak_form_remark('armature_voltage^2', 12.0, 1.0, parameters) == ''
    assert not [line for line in text.splitlines() if line.startswith('thrust_coefficient')]      # not a table row
    assert '  thrust_coefficient = 5.04e-06 +- 1e-07 N s^2 (Kq, from thrust_gain' in text
    assert 'not fitted, derived' in text and 'does not print it' in text
    assert text.rstrip().endswith('RUN ENDED: the excitation has finished')


def test_the_end_of_the_run_is_said_after_a_silence_of_three_windows():
    from aeropend_ros.cli.monitor import SILENCE_MIN_S, silent_for
    state = {'result_times': [100.0, 105.0, 110.0, 115.0], 'last_status_at': 115.0}
    assert silent_for(state, 115.0 + SILENCE_MIN_S - 1) == 0.0
    assert silent_for(state, 115.0 + SILENCE_MIN_S + 1) == pytest.approx(SILENCE_MIN_S + 1)
    slow = {'result_times': [0.0, 30.0, 60.0], 'last_status_at': 60.0}                   # windows every 30 s
    assert silent_for(slow, 60.0 + 80.0) == 0.0 and silent_for(slow, 60.0 + 91.0) > 90.0
    assert silent_for({'result_times': [], 'last_status_at': None}, 1e6) == 0.0


def test_live_plot_keeps_bands_inside_and_labels_what_leaves_the_axis(tmp_path):
    """The issue's PNG: +-1 sigma bands left the axes and a fit point fell below them unlabelled. The limits now
    hold the recent windows' bands; a value beyond them is drawn at the edge with its value written beside it, and
    the panel's legend says what the triangle is; a band wider than the axis is said in the title."""
    import matplotlib
    matplotlib.use('Agg')
    from aeropend_core.present.live_plot import LivePlot, WindowPoint
    plot = LivePlot(interactive=False)
    for k in range(12):
        gravity = (710.0, 90.0) if k == 6 else (140.0 + 0.5 * math.sin(k), 4.0 if k != 9 else 400.0)
        plot.add(WindowPoint(5.0 * k, {'gravity_stiffness': gravity}, -35.0 if k == 8 else 95.0 + 0.2 * k))
    plot.units = {'gravity_stiffness': '1/s^2'}
    plot.draw()
    gravity_axes, fit_axes = plot.figure.axes
    low, high = gravity_axes.get_ylim()
    ordinary = [140.0 + 0.5 * math.sin(k) for k in range(12) if k not in (6, 9)]
    assert low <= min(ordinary) - 4.0 and high >= max(ordinary) + 4.0          # every ordinary band inside
    assert high < 700.0                                                        # the wild window does not squash
    notes = [text.get_text() for text in gravity_axes.texts]
    assert '710 1/s^2' in notes
    assert 'band wider than the axis in 1 window(s)' in gravity_axes.get_title(loc='left')
    assert [text.get_text() for text in fit_axes.texts] == ['-35 %']
    assert fit_axes.get_legend() is not None and 'off scale' in fit_axes.get_legend().get_texts()[-1].get_text()
    plot.save(str(tmp_path / 'frame.png'))
