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
