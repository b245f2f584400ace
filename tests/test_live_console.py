"""The live output says what each window lost (issue #22 item 4, #24 item 5): the identification node's window
events counted by sequence number, `aeropend run`'s one line per window with its data state and its buffering line,
and `aeropend monitor`'s output (quiet while waiting, never cut when piped, robust axis limits).

The node tests drive a real rclpy node with the exact CDR bytes a subscription hands it; the analysis worker is
replaced by one that returns a known result at once (what is tested is the bookkeeping around it, not the fit)."""
from __future__ import annotations

import io
import math
import subprocess
import sys
from concurrent.futures import Future

import numpy as np
import pytest

from tests.ros_helpers import ROOT, NodeProcess, private_domain_id


def _sample_bytes(sequence: int, stamp_ns: int, t: float) -> bytes:
    from rclpy.serialization import serialize_message

    from aeropend_ros import topics
    duty = 0.3 + 0.2 * (int(t) % 2)                 # a duty step every second
    angle = 0.4 + 0.3 * math.sin(2.1 * t) + 0.002 * math.sin(377.0 * t)
    return serialize_message(topics.sample_to_msg(topics.Sample(stamp_ns, angle, 1.0 + 2.0 * duty,
                                                                0.2 + 0.3 * duty, duty, sequence)))


class _InstantWorker:
    """Stands in for the analysis process: every window 'computes' at once to `result` (a WindowResult)."""

    def __init__(self, result) -> None:
        self.result = result
        self.submitted = 0

    def submit(self, function, *args, **keywords) -> Future:
        self.submitted += 1
        future = Future()
        future.set_result(self.result)
        return future

    def shutdown(self, wait: bool = True, cancel_futures: bool = False) -> None:
        pass


@pytest.fixture
def node_factory():
    import rclpy
    from rclpy.parameter import Parameter

    from aeropend_ros.identification_node import IdentificationNode
    made = []
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=private_domain_id())

    def make(result, window_s: float = 4.0, hop_s: float = 2.0):
        node = IdentificationNode(context=context, parameter_overrides=[Parameter('window_s', value=window_s),
                                                                        Parameter('hop_s', value=hop_s)])
        node.worker.shutdown(wait=False, cancel_futures=True)
        node.worker, node.pending = _InstantWorker(result), None
        made.append(node)
        return node
    yield make
    for node in made:
        node.destroy_node()
    rclpy.try_shutdown(context=context)


def _result(fit_percent: float = 93.0):
    from aeropend_core.diagnosis.online import WindowResult
    return WindowResult(start=0.0, stop=4.0, effects=(), parameters={'gravity_stiffness': (140.0, 2.0)},
                        fit_percent=fit_percent, rms_error=0.002, noise_rms=0.001, held_out_seconds=1.0,
                        compute_time=0.1, method='window')


def _feed(node, seconds: float, missing=frozenset(), start: int = 0) -> int:
    from aeropend_core.model.parameters import SAMPLE_TIME
    start_ns = 1_000_000_000_000
    end = start + int(round(seconds / SAMPLE_TIME))
    for sequence in range(start, end):
        if sequence not in missing:
            t = sequence * SAMPLE_TIME
            node._on_sample(_sample_bytes(sequence, start_ns + round(t * 1e9), t))
    return end


def test_each_window_says_what_it_lost_by_sequence_number(node_factory):
    """Three windows: clean, 40 samples lost in one gap (published, flagged), 45 % lost (withheld): one event each,
    counted by sequence numbers, and `run`'s console line for each carries that state."""
    from aeropend_ros.cli.run import window_line
    node = node_factory(_result(-126.49))
    fed = _feed(node, 4.2)                                            # the first window: 0-4 s, nothing lost
    assert node.windows_due == 1 and len(node.window_events) == 1
    clean = node.window_events[0]
    assert clean.state == 'clean' and clean.lost_samples == 0 and clean.result is not None
    assert clean.stop_s == pytest.approx(4.0, abs=0.01) and clean.start_s == pytest.approx(0.0, abs=0.01)
    line = window_line(clean)
    assert line.endswith('data clean') and '0.0-  4.0 s' in line, line
    fed = _feed(node, 2.0, missing=frozenset(range(fed + 100, fed + 140)), start=fed)   # a 40-sample gap
    assert len(node.window_events) == 2
    flagged = node.window_events[1]
    assert flagged.state == 'flagged' and flagged.lost_samples == 40 and flagged.gaps == 1, flagged
    line = window_line(flagged)
    assert 'held-out fit -126.49 %' in line and 'data FLAGGED: 40 samples lost in 1 gap(s)' in line, line
    missing = frozenset(range(fed + 10, fed + 900))     # with the earlier gap, over 30 % of the next window
    fed = _feed(node, 2.0, missing=missing, start=fed)
    assert len(node.window_events) == 3
    withheld = node.window_events[2]
    assert withheld.state == 'withheld' and withheld.result is None and withheld.lost_samples >= 890
    line = window_line(withheld)
    assert 'WITHHELD (not published)' in line and 'held-out fit' not in line and 'samples lost' in line, line
    assert node.worker.submitted == 2                                # the withheld window was not analysed


def test_run_console_buffers_then_prints_each_window_once(node_factory, capsys):
    """Before the first window: a buffering line on standard error ("buffering 2/4 s"); then one line per window
    on standard output, a skipped window included, each exactly once however often the console refreshes."""
    from aeropend_ros.cli.run import _WindowPrinter
    node = node_factory(_result())
    printer = _WindowPrinter(node, 4.0)
    printer.update()
    fed = _feed(node, 2.0)
    printer.update()
    printer.update()
    captured = capsys.readouterr()
    assert 'buffering 2/4 s of samples for the first window' in captured.err and captured.out == ''
    fed = _feed(node, 2.2, start=fed)                                 # the first window comes due and 'computes'
    node.pending = Future()                                           # the next one finds the worker busy
    _feed(node, 2.0, start=fed)
    for _ in range(3):
        printer.update()
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 2, out
    assert 'data clean' in out[0] and 'SKIPPED (not computed): the previous window is still being computed' in out[1]
    assert printer.all_shown()


def test_robust_axis_limits_keep_one_bad_window_off_the_scale(tmp_path):
    """A 710 among windows near 140 (the issue's monitor) neither stretches the axis nor disappears: it is drawn at
    the edge as a red triangle."""
    import matplotlib
    matplotlib.use('Agg')
    from aeropend_core.present.live_plot import LivePlot, WindowPoint, robust_limits
    values = [140.0 + 0.5 * np.sin(k) for k in range(12)] + [710.0]
    low, high = robust_limits(values)
    assert 137.0 < low < 139.5 and 140.5 < high < 150.0          # not 710
    assert robust_limits([2.0]) == pytest.approx((1.9, 2.1))
    assert robust_limits([math.nan]) is None
    plot = LivePlot(interactive=False)
    for k, value in enumerate(values):
        plot.add(WindowPoint(30.0 + 5 * k, {'gravity_stiffness': (value, 2.0)}, 90.0 if k < 12 else -126.0,
                             flagged=k == 12))
    plot.draw()
    axes = plot.figure.axes[0]
    assert axes.get_ylim()[1] < 150.0
    edge = [line for line in axes.get_lines() if line.get_marker() == '^']
    assert len(edge) == 1 and list(edge[0].get_xdata()) == [90.0]
    assert 'acquisition time' in plot.figure.axes[-1].get_xlabel()


def test_monitor_output_is_never_cut_when_piped_and_names_what_a_window_lost():
    from aeropend_ros.cli.monitor import output_width, render, window_data, window_span
    assert output_width(io.StringIO()) is None
    values = {'lost_samples': '312', 'gaps': '20', 'window_stop_ns': str(61_000_000_000),
              'stream_start_ns': str(1_000_000_000), 'window_s': '25'}
    assert window_data(values) == '312 samples lost in 20 gap(s), the fits split there'
    assert window_span(values) == pytest.approx((35.0, 60.0))
    status = 'fit 93.0 % on 6.2 s held out; ' + 'x' * 200
    text = render({'gravity_stiffness': (140.0, 2.0)}, {}, {'fit_percent': (93.0, math.nan)}, status, {}, 3,
                  width=None, data=window_data(values), span=window_span(values))
    assert status in text and '312 samples lost in 20 gap(s)' in text and '35.0-60.0 s' in text


@pytest.mark.timeout(180)
def test_monitor_is_quiet_while_waiting(tmp_path):
    """With an identification node that has no samples (it says "waiting for data" once a second), a piped
    monitor prints its waiting line only when the status changes its kind (at start, while the node's worker
    starts, once it has started: at most 3 times here), not every second."""
    from aeropend_ros._ros_env import local_ros_environment
    domain_id = private_domain_id()
    env = local_ros_environment(domain_id=domain_id)
    with NodeProcess('aeropend_ros.identification_node', [], domain_id) as node:
        monitor = subprocess.run([sys.executable, '-c', 'import sys; from aeropend_core.cli import main; '
                                  'sys.exit(main())', 'monitor', '--no-plot', '--duration', '12'],
                                 env=env, cwd=ROOT, capture_output=True, text=True, timeout=120)
        logs = node.output()
    assert monitor.returncode == 0, monitor.stderr + logs
    assert monitor.stdout.count('waiting for the identification node') <= 3, monitor.stdout
