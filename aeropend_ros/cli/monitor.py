"""Show the live identification: parameters with uncertainty and their estimator, the held-out fit, drift.

Listens to the identification node's topics (/aeropend/identification/parameters, .../coefficients, .../fit)
and its /diagnostics status, and redraws a table whenever a window completes. Each parameter names its estimator
(output_error: the free-run simulation fitted to the angle; motor_observer: the observer fitted to the armature
current; weak_sindy: the weak-form regression, whose coefficients are listed below the table). The drift test is the
node's own (a straight-line trend over the windows that do not overlap: "parameter drift: thrust gain -15 % over
120 s"); a parameter is also marked when it jumps more than --drift-sigma (default 3) of its standard errors away
from the running mean of the previous windows. Windows whose data were repaired or flagged say so.

With a display (X11/Wayland and an interactive matplotlib backend) it also draws a live plot: every parameter over
the windows with its ±1σ band, drift and flagged windows marked (--no-plot: the table only); --plot-file FILE.png
saves that figure after every window, display or not. --json [FILE] writes one JSON object per update (JSON lines:
every status of the identification node, with the window's parameters, fit and drift when it carries a result; to
standard output with - or no FILE, which then carries the JSON lines only). Everything shown is also on the
recorded topics, plottable in Foxglove or PlotJuggler (config/).

Examples:
  aeropend monitor                 # until Ctrl-C
  aeropend monitor --once          # print the latest result and exit (exit 1 if none within --timeout)
  aeropend monitor --json - | jq -c 'select(.window) | .window.parameters.thrust_gain'
"""
from __future__ import annotations

import math
import shutil
import sys
import time
from dataclasses import dataclass, field

from aeropend_core.errors import AeropendError


def add_arguments(parser) -> None:
    parser.add_argument('--once', action='store_true', help='print the latest result once and exit')
    parser.add_argument('--timeout', type=float, default=30.0, metavar='S',
                        help='with --once: how long to wait for a result [s] (default 30)')
    parser.add_argument('--duration', type=float, default=0.0, metavar='S',
                        help='exit after this many seconds (default: run until Ctrl-C)')
    parser.add_argument('--window', type=float, default=25.0, metavar='S',
                        help='the identification windows\' length [s] (the node\'s window_s): only for the trend of a '
                             'node that does not run the drift test itself (windows that do not overlap)')
    parser.add_argument('--drift-sigma', type=float, default=3.0, metavar='K',
                        help='flag a parameter more than K standard errors from its running mean (default 3)')
    parser.add_argument('--no-clear', action='store_true',
                        help='append each refresh instead of redrawing the screen (automatic when not a terminal)')
    parser.add_argument('--local', action='store_true',
                        help='set ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST (unless already set)')
    parser.add_argument('--rig', metavar='NAME', default=None,
                        help='watch rig NAME (the graph of `aeropend run --rig NAME`, namespace /NAME); '
                             'default: the root namespace\'s graph')
    parser.add_argument('--no-plot', action='store_true', help='no live plot even with a display (the table only)')
    parser.add_argument('--plot-file', metavar='FILE.png',
                        help='save the live plot to this file after every window (PNG, SVG or PDF; no display needed)')
    from aeropend_core.cli._checks import add_json_argument
    add_json_argument(parser, 'one object per update (JSON lines)')


@dataclass
class RunningStats:
    """Running mean and count of one quantity (Welford)."""

    count: int = 0
    mean: float = 0.0

    def add(self, value: float) -> None:
        self.count += 1
        self.mean += (value - self.mean) / self.count


@dataclass
class DriftTracker:
    """Running means of each parameter over windows and the drift test of each new window.

    A parameter drifts when ``|value - mean of previous windows| > sigma * standard_error`` of the new window,
    once ``min_windows`` previous windows exist. The statistics restart when the set of parameter names changes
    (the model's effects changed, which legitimately moves the other parameters).
    """

    sigma: float = 3.0
    min_windows: int = 3
    stats: dict[str, RunningStats] = field(default_factory=dict)

    def update(self, values: dict[str, tuple[float, float]]) -> dict[str, tuple[float, float | None, bool]]:
        """Add one window; returns ``{name: (running mean with this window, deviation from the mean of the previous
        windows in this window's sigmas, drifting)}`` (the mean is the value itself on the first window)."""
        if set(values) != set(self.stats):
            self.stats = {name: RunningStats() for name in values}
        report = {}
        for name, (value, error) in values.items():
            stats = self.stats[name]
            deviation = None
            drifting = False
            if stats.count >= self.min_windows and math.isfinite(value) and error > 0 and math.isfinite(error):
                deviation = (value - stats.mean) / error
                drifting = abs(deviation) > self.sigma
            if math.isfinite(value):
                stats.add(value)
            report[name] = (stats.mean if stats.count else value, deviation, drifting)
        return report


#: Weak-form coefficients of d²angle/dt² that are one parameter of the refined model: ``{term: (parameter, sign)}``
#: (the parameter is sign x the coefficient).
WEAK_TWINS = {'sin(angle)': ('gravity_stiffness', -1.0), 'dangle/dt': ('damping', -1.0)}

#: The weak form disagrees with the output-error fit beyond this many combined standard errors [-].
WEAK_AGREEMENT_SIGMAS = 3.0


def weak_form_remark(term: str, value: float, sigma: float, parameters: dict) -> str:
    """What a weak-form coefficient says beside the output-error fit of the same quantity ('' when none).

    Parameters
    ----------
    term : str [-]
        The library term (``sin(angle)``, ...).
    value, sigma : float [rad/s² per unit term]
        The coefficient and its standard error.
    parameters : dict [-]
        The refined model's ``{name: (value, sigma)}`` (SI).

    Returns
    -------
    str
        '= gravity_stiffness 3.56 +- 3.5 1/s^2: DISAGREES with the output-error fit 145 +- 2 (40 sigma); read ...'.
    """
    from aeropend_core.model.effects import parameter_unit
    if term not in WEAK_TWINS or WEAK_TWINS[term][0] not in parameters:
        return ''
    name, sign = WEAK_TWINS[term]
    implied = sign * value
    fitted, fitted_sigma = parameters[name]
    combined = math.hypot(sigma if math.isfinite(sigma) else 0.0, fitted_sigma if math.isfinite(fitted_sigma) else 0.0)
    head = f'= {name} {implied:.4g} +- {sigma:.2g} {parameter_unit(name)}'
    if not (combined > 0 and math.isfinite(implied)):
        return head
    apart = abs(implied - fitted) / combined
    if apart <= WEAK_AGREEMENT_SIGMAS:
        return f'{head}: agrees with the output-error fit {fitted:.4g} ({apart:.1f} sigma)'
    return f'{head}: DISAGREES with the output-error fit {fitted:.4g} +- {fitted_sigma:.2g} ({apart:.0f} sigma)*'


def render(parameters, coefficients, fit, status, drift, windows: int, width: int | None = 100, trends=None,
           estimators=None, node_drift: str = '', data: str | None = None,
           span: tuple[float, float] | None = None, ended: str = '') -> str:
    """The text table of one refresh (all arguments may be empty before the first window).

    `drift` maps a parameter to (running mean with this window, deviation in sigmas or None, jump) as
    :meth:`DriftTracker.update` returns it; `width` cuts the status lines to a terminal's columns (None: never cut,
    e.g. when piped); `trends` maps a parameter to the node's trend text (``trend_<name>`` on /diagnostics) or to a
    local trend row; `estimators` maps a parameter to its estimator (the node's default, output_error, when it does
    not say); `node_drift` is the node's drift sentence ('' or 'none': none); `data` is the window's data-quality
    flags ('' when clean, None when the node did not say); `span` the window's start and end in acquisition time
    since the run began [s] (as ``aeropend run`` prints them); `ended` says that the run has ended ('' while it runs).
    """
    from aeropend_core.model.effects import parameter_unit
    from aeropend_core.model.names import DERIVED_PARAMETERS
    lines = []
    if not parameters and not fit:
        lines.append('aeropend monitor: waiting for the identification node\'s first window ...')
        if status:
            lines.append(f'identification: {status}')
        if ended:
            lines.append(f'RUN ENDED: {ended}')
        return '\n'.join(lines)
    where = f', the latest {span[0]:.1f}-{span[1]:.1f} s (acquisition time)' if span else ''
    lines.append(f'aeropend monitor: {windows} window(s) received{where}' + ' ' * 4 + time.strftime('%H:%M:%S'))
    if fit:
        get = {name: value for name, (value, _) in fit.items() if math.isfinite(value)}
        shown = [(key, text) for key, text in (('fit_percent', 'held-out fit {:7.2f} %'),
                                               ('rms_error', 'rms error {:7.2f} mrad'),
                                               ('noise_rms', 'noise {:6.2f} mrad'),
                                               ('compute_time', 'compute {:.2f} s'))
                 if key in get]      # what the node did not say is left out, never shown as nan
        lines.append('   '.join(text.format(get[key] * (1e3 if key in ('rms_error', 'noise_rms') else 1.0))
                                for key, text in shown))
    if status:
        lines.append(f'identification: {status}'[:width])
    if data:
        lines.append(f'DATA REPAIRED OR FLAGGED in this window: {data} (the numbers below carry that doubt)'[:width])
    elif data is not None:
        lines.append('data clean in this window (no sample lost, nothing repaired)')
    if node_drift and node_drift != 'none':
        lines.append(f'DRIFT: {node_drift}')
    lines.append('')
    estimators = estimators or {}
    lines.append('parameters of the refined model (estimator: output_error = free-run simulation fitted to the angle; '
                 'motor_observer = observer fitted to Ia):'[:max(width, 60) if width else None])
    lines.append(f'{"parameter":26s} {"value":>13s} {"±1σ":>11s} {"unit":12s} {"mean so far":>13s}  '
                 f'{"estimator":15s} jump / trend')
    trends = trends or {}
    derived = []
    for name, (value, error) in parameters.items():
        if name in DERIVED_PARAMETERS:
            derived.append(f'  {name} = {value:.4g} +- {error:.2g} {parameter_unit(name)} '
                           f'({DERIVED_PARAMETERS[name][1]})')
            continue
        mean, deviation, drifting = drift.get(name, (value, None, False))
        flag = f'JUMP ({deviation:+.1f}σ)' if drifting else (f'{deviation:+.1f}σ' if deviation is not None else '')
        trend = trends.get(name)
        if isinstance(trend, str) and trend:
            flag += f'  trend {trend}'
        elif isinstance(trend, dict) and trend['stretches'] >= 4 and math.isfinite(trend['change']):
            flag += (f'  trend {trend["change"] * 100:+.0f} % over {trend["span"]:.0f} s'
                     + (' PARAMETER DRIFT' if trend['drifting'] else ''))
        estimator = estimators.get(name, 'output_error')
        lines.append(f'{name:26s} {value:13.6g} {error:11.3g} {parameter_unit(name) or "-":12s} {mean:13.6g}  '
                     f'{estimator:15s} {flag}')
    if derived:
        lines.append('not fitted, derived with the paper\'s constants (aeropend diagnose does not print it):')
        lines += derived
    disagree = False
    if coefficients:
        lines.append('')
        lines.append('estimator weak_sindy: coefficients of d²angle/dt² [rad/s² per unit term], the start of the '
                     'refinement above (where they name the same quantity, read the refined value):')
        for name, (value, error) in coefficients.items():
            remark = weak_form_remark(name, value, error, parameters)
            lines.append(f'  {name:38s} {value:13.6g} ± {error:.3g}' + (f'  {remark}' if remark else ''))
            disagree = disagree or 'DISAGREES' in remark
        if disagree:
            lines.append('  * read the output-error value above: the weak form only starts that fit, and noise and '
                         'what the model lacks bias it')
    if ended:
        lines.append('')
        lines.append(f'RUN ENDED: {ended}')
    return '\n'.join(lines)


#: Silence of the identification node after which the run is said to have ended: this many times the usual interval
#: between its windows [-], and at least SILENCE_MIN_S [s].
SILENCE_WINDOWS = 3.0
SILENCE_MIN_S = 15.0


def silent_for(state: dict, now: float) -> float:
    """Seconds the identification node has been silent when that says the run ended (0.0 while it is not), from
    ``state['last_status_at']`` and ``state['result_times']`` (monotonic seconds) of the windows received."""
    times = state['result_times']
    if not times or state['last_status_at'] is None:
        return 0.0
    usual = float(sorted(b - a for a, b in zip(times, times[1:]))[(len(times) - 2) // 2]) if len(times) > 1 else 0.0
    quiet = now - state['last_status_at']
    return quiet if quiet > max(SILENCE_MIN_S, SILENCE_WINDOWS * usual) else 0.0


def output_width(stream) -> int | None:
    """Columns to cut status lines at: the terminal's width, or None (never cut) when `stream` is not a terminal
    (piped to a file, less or grep, a line is kept whole)."""
    return shutil.get_terminal_size().columns if stream.isatty() else None


def window_data(values: dict[str, str]) -> str:
    """A window's data doubts from its /diagnostics key/values: the data-quality findings and the samples it lost
    ('' when clean)."""
    parts = [values['data_quality']] if values.get('data_quality') else []
    if values.get('lost_samples', '0') not in ('', '0'):
        parts.append(f'{values["lost_samples"]} samples lost in {values.get("gaps", "?")} gap(s), the fits split '
                     'there')
    if values.get('rejected'):
        parts.append(f'rejected: {values["rejected"]}')
    return '; '.join(parts)


def window_span(values: dict[str, str]) -> tuple[float, float] | None:
    """A window's start and end in acquisition time since the run's first sample [s] (what ``aeropend run``
    prints), from its /diagnostics key/values; None when the node does not say (``stream_start_ns``)."""
    try:
        stop = (int(values['window_stop_ns']) - int(values['stream_start_ns'])) * 1e-9
        return stop - float(values.get('window_s', 'nan')), stop
    except (KeyError, ValueError):
        return None


def waiting_kind(status: str) -> str:
    """The waiting status without its numbers ('waiting for data: # of # s buffered'): a pipe gets a line only
    when this changes."""
    import re
    return re.sub(r'\d+(\.\d+)?', '#', status or '')


def check_arguments(args) -> None:
    """Refuse negative, zero or non-finite times and thresholds (AeropendError)."""
    if not 0 < args.window < math.inf:
        raise AeropendError(f'--window must be a positive number of seconds, got {args.window}')
    if not 0 < args.timeout < math.inf:
        raise AeropendError(f'--timeout must be a positive number of seconds, got {args.timeout}')
    if not 0 <= args.duration < math.inf:
        raise AeropendError(f'--duration must be >= 0 s (0 = until Ctrl-C), got {args.duration}')
    if not 0 < args.drift_sigma < math.inf:
        raise AeropendError(f'--drift-sigma must be a positive number of standard errors (e.g. 3), got '
                            f'{args.drift_sigma}')


def main(args) -> int:
    check_arguments(args)
    from aeropend_ros.topics import rig_namespace, status_prefix
    namespace = rig_namespace(args.rig)            # AeropendError (exit 2) for a bad name
    from aeropend_core.cli._checks import check_json_target, check_report_path
    check_json_target(args.json)
    check_report_path(args.plot_file, '--plot-file')
    from aeropend_ros._ros_env import ensure_ros_environment
    ensure_ros_environment(local_only=args.local)
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import ExternalShutdownException
    from sensor_msgs.msg import JointState

    from aeropend_core.model.effects import parameter_unit
    from aeropend_core.present.json_output import JsonLines
    from aeropend_ros import topics
    from aeropend_ros.identification_node import (COEFFICIENTS_TOPIC, DIAGNOSTIC_NAME, FIT_TOPIC, PARAMETERS_TOPIC,
                                                  msg_to_named_values, results_qos)

    state = {'parameters': {}, 'coefficients': {}, 'fit': {}, 'status': '', 'drift': {}, 'windows': 0,
             'dirty': False, 'values': {}, 'stamp_ns': 0, 'first_ns': None, 'counted_ns': None, 'window_ready': False,
             'ended': '', 'last_status_at': None, 'result_times': []}
    tracker = DriftTracker(sigma=args.drift_sigma)
    from aeropend_core.diagnosis.online import ParameterTrends
    local_trends = ParameterTrends(args.window)      # only for a node that does not run the trend test itself
    plot = _open_plot(args)
    json_out = JsonLines(args.json) if args.json else None
    text_out = sys.stderr if args.json == '-' else sys.stdout

    def on_parameters(msg):
        state['parameters'] = msg_to_named_values(msg)
        state['stamp_ns'] = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec

    def on_coefficients(msg):
        state['coefficients'] = msg_to_named_values(msg)

    def on_fit(msg):
        state['fit'] = msg_to_named_values(msg)

    def on_done(msg):
        if msg.data and not state['ended']:
            state['ended'] = ('the excitation has finished (aeropend/excitation/done); a window still being computed '
                              'may follow, then nothing more')
            state['dirty'] = state['window_ready'] = True

    def count_window(values):
        """A window's result is complete (its status came after its numbers): counted, tracked, drawn, once."""
        if state['counted_ns'] == state['stamp_ns']:
            return
        state['counted_ns'] = state['stamp_ns']
        state['windows'] += 1
        state['drift'] = tracker.update(state['parameters'])
        state['local_trends'] = local_trends.add(state['stamp_ns'] * 1e-9, state['parameters'])
        state['result_times'].append(time.monotonic())
        state['window_ready'] = True

    def on_diagnostics(msg):
        for status in msg.status:
            if status.name != status_prefix(namespace) + DIAGNOSTIC_NAME:     # this rig's identification only
                continue
            values = {kv.key: kv.value for kv in status.values}
            state['last_status_at'] = time.monotonic()
            extra = ' | '.join(f'{k} {values[k]}' for k in ('excitation', 'lost_samples', 'effects') if k in values)
            state['status'] = status.message + (f' | {extra}' if extra else '')
            state['dirty'] = True
            result = 'fit_percent' in values and values.get('window_stop_ns') == str(state['stamp_ns'])
            if result:
                state['values'] = values
                if state['counted_ns'] != state['stamp_ns']:
                    count_window(values)
                    _on_window(state, values, plot, args, parameter_unit)
            if json_out is not None:
                json_out.write(_json_line(status, values, state if result else None, parameter_unit))

    rclpy.init()
    node = rclpy.create_node('aeropend_monitor', namespace=namespace)  # relative topics resolve in the rig's
    node.create_subscription(JointState, PARAMETERS_TOPIC, on_parameters, results_qos())
    node.create_subscription(JointState, COEFFICIENTS_TOPIC, on_coefficients, results_qos())
    node.create_subscription(JointState, FIT_TOPIC, on_fit, results_qos())
    node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS_TOPIC, on_diagnostics, topics.diagnostics_qos())
    from std_msgs.msg import Bool

    from aeropend_ros.excitation_node import DONE_TOPIC, done_qos
    node.create_subscription(Bool, DONE_TOPIC, on_done, done_qos())
    clear = text_out.isatty() and not args.no_clear and not args.once
    started = time.monotonic()
    last_draw = 0.0
    shown_kind = None
    status = 0

    def table(width: int | None = None) -> str:
        values = state['values']
        trends = ({name[len('trend_'):]: text for name, text in values.items() if name.startswith('trend_')}
                  or state.get('local_trends'))
        estimators = dict(part.split(':', 1) for part in values.get('estimators', '').split(',') if ':' in part)
        shown = bool(state['windows'])        # a window's numbers only once its status has completed them
        return render(state['parameters'] if shown else {}, state['coefficients'] if shown else {},
                      state['fit'] if shown else {}, state['status'], state['drift'],
                      state['windows'], width, trends=trends, estimators=estimators,
                      node_drift=values.get('drift', ''), span=window_span(values), ended=state['ended'],
                      data=window_data(values) if 'lost_samples' in values or values.get('data_quality') else None)
    try:
        while rclpy.ok():
            rclpy.spin_once(node, timeout_sec=0.1)
            now = time.monotonic()
            if plot is not None and not plot.alive():
                break                                   # the user closed the plot window
            if args.once:
                if state['parameters'] and state['fit'] and state['values']:
                    print(table(output_width(text_out)), file=text_out)
                    break
                if now - started > args.timeout:
                    print(f'aeropend monitor: no identification result within {args.timeout:g} s (is '
                          f'identification_node running, on the same ROS_DOMAIN_ID? last status: '
                          f'{state["status"] or "none"})', file=sys.stderr)
                    status = 1
                    break
                continue
            if args.duration and now - started > args.duration:
                break
            # One redraw per window: its parameters, coefficients, fit and status arrive within milliseconds. While
            # waiting: a terminal's screen is redrawn at most once a second; a pipe gets a line only when the
            # waiting status changes its kind (not each second's "12.0 of 25 s buffered").
            silence = silent_for(state, now)
            if silence and not state['ended']:
                state['ended'] = (f'no status from the identification node for {silence:.0f} s: the run has ended '
                                  '(or the node stopped); the latest window above is the last')
                state['window_ready'] = True
            if state['windows']:
                due = state['window_ready']          # one table per window (and one when the run ends)
            elif clear:
                due = (state['dirty'] and now - last_draw > 1.0) or last_draw == 0.0 or state['window_ready']
            else:
                due = waiting_kind(state['status']) != shown_kind or last_draw == 0.0 or state['window_ready']
            if due:
                text = table(output_width(text_out))
                print(('\x1b[H\x1b[2J' if clear else '\n') + text, flush=True, file=text_out)
                state['dirty'] = state['window_ready'] = False
                shown_kind = waiting_kind(state['status'])
                last_draw = now
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        if json_out is not None:
            json_out.close()
    return status


def _open_plot(args):
    """The live plot: a window when there is a display (unless --no-plot), off-screen for --plot-file; else None."""
    from aeropend_core.present.live_plot import LivePlot, has_display
    interactive = not args.no_plot and not args.once and has_display()
    if not interactive and not args.plot_file:
        return None
    return LivePlot(interactive=interactive)


def _on_window(state: dict, values: dict, plot, args, parameter_unit) -> None:
    """A window's result is complete (parameters, fit, its status): add it to the plot, redraw, save."""
    if plot is None:
        return
    from aeropend_core.present.live_plot import WindowPoint
    if state['first_ns'] is None:      # acquisition time 0: the node's first sample (an older node: the first window)
        state['first_ns'] = int(values.get('stream_start_ns') or state['stamp_ns'])
    flagged = bool(window_data(values))
    fit = state['fit'].get('fit_percent', (float('nan'), 0.0))[0]
    plot.add(WindowPoint((state['stamp_ns'] - state['first_ns']) * 1e-9, dict(state['parameters']), fit, flagged))
    plot.units.update({name: parameter_unit(name) for name in state['parameters']})
    plot.estimators.update(dict(part.split(':', 1) for part in values.get('estimators', '').split(',') if ':' in part))
    plot.drift = {name[len('trend_'):]: text for name, text in values.items() if name.startswith('trend_')}
    plot.draw()
    if args.plot_file:
        plot.save(args.plot_file)


def _number(text: str) -> float | str:
    """A diagnostic value as a number where it is one (ROS carries every value as text), else the text."""
    try:
        value = float(text)
    except (TypeError, ValueError):
        return text
    return value if math.isfinite(value) else text


def _json_line(status, values: dict, state: dict | None, parameter_unit) -> dict:
    """One JSON line: the status and, when it reports a window's result, that window's numbers."""
    line = {'time': time.time(), 'level': {0: 'OK', 1: 'WARN', 2: 'ERROR', 3: 'STALE'}.get(
        int.from_bytes(status.level, 'little') if isinstance(status.level, bytes) else int(status.level), 'UNKNOWN'),
        'message': status.message, 'values': {name: _number(text) for name, text in values.items()}}
    if state is None:
        return line
    estimators = dict(part.split(':', 1) for part in values.get('estimators', '').split(',') if ':' in part)
    trends = {name[len('trend_'):]: text for name, text in values.items() if name.startswith('trend_')}
    line['window'] = {
        'stop_ns': state['stamp_ns'],
        'parameters': {name: {'value': value, 'sigma': sigma, 'lower': value - sigma, 'upper': value + sigma,
                              'unit': parameter_unit(name), 'estimator': estimators.get(name, ''),
                              'trend': trends.get(name, '')}
                       for name, (value, sigma) in state['parameters'].items()},
        'coefficients': {name: {'value': value, 'sigma': sigma} for name, (value, sigma) in
                         state['coefficients'].items()},
        'fit': {name: value for name, (value, _) in state['fit'].items()},
        'drift': values.get('drift', ''),
        'data_quality': values.get('data_quality', ''), 'lost_samples': int(values.get('lost_samples', 0) or 0),
        'gaps': int(values.get('gaps', 0) or 0), 'data': window_data(values) or 'clean',
        'span_s': list(window_span(values) or ())}
    return line
