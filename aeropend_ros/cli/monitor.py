"""Show the live identification in the terminal: parameters with uncertainty, the held-out fit, drift flagged.

Listens to the identification node's topics (/aeropend/identification/parameters, .../coefficients, .../fit)
and its /diagnostics status, and redraws a table whenever a window completes. A parameter is flagged DRIFT when
it moves more than --drift-sigma (default 3) of its standard errors away from the running mean of the previous
windows (the running statistics restart when the model's effects change). Everything shown is also on the
recorded topics, plottable in Foxglove or PlotJuggler.

Examples:
  aeropend monitor                 # until Ctrl-C
  aeropend monitor --once          # print the latest result and exit (exit 1 if none within --timeout)
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
                        help='the identification windows\' length [s] (the node\'s window_s; trends use windows that '
                             'do not overlap)')
    parser.add_argument('--drift-sigma', type=float, default=3.0, metavar='K',
                        help='flag a parameter more than K standard errors from its running mean (default 3)')
    parser.add_argument('--no-clear', action='store_true',
                        help='append each refresh instead of redrawing the screen (automatic when not a terminal)')
    parser.add_argument('--local', action='store_true',
                        help='set ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST (unless already set)')


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
        """Add one window; returns ``{name: (running mean before this window, deviation in sigmas, drifting)}``."""
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
            report[name] = (stats.mean if stats.count else float('nan'), deviation, drifting)
            if math.isfinite(value):
                stats.add(value)
        return report


def render(parameters, coefficients, fit, status, drift, windows: int, width: int = 100, trends=None) -> str:
    """The text table of one refresh (all arguments may be empty before the first window)."""
    lines = []
    if not parameters and not fit:
        lines.append('aeropend monitor: waiting for the identification node\'s first window ...')
        if status:
            lines.append(f'identification: {status}')
        return '\n'.join(lines)
    lines.append(f'aeropend monitor: {windows} window(s) received' + ' ' * 4 + time.strftime('%H:%M:%S'))
    if fit:
        get = {name: value for name, (value, _) in fit.items()}
        lines.append(f'held-out fit {get.get("fit_percent", float("nan")):7.2f} %   rms error '
                     f'{get.get("rms_error", float("nan")) * 1e3:7.2f} mrad   noise '
                     f'{get.get("noise_rms", float("nan")) * 1e3:6.2f} mrad   compute '
                     f'{get.get("compute_time", float("nan")):.2f} s')
    if status:
        lines.append(f'identification: {status}'[:width])
    lines.append('')
    lines.append('parameters of the refined model (estimator: output error; armature_resistance from the motor '
                 'observer when its ±1σ is nan):')
    lines.append(f'{"parameter (SI)":26s} {"value":>13s} {"±1σ":>11s} {"running mean":>13s}  drift')
    trends = trends or {}
    for name, (value, error) in parameters.items():
        mean, deviation, drifting = drift.get(name, (float('nan'), None, False))
        flag = f'DRIFT ({deviation:+.1f}σ)' if drifting else (f'{deviation:+.1f}σ' if deviation is not None else '')
        trend = trends.get(name)
        if trend is not None and trend['stretches'] >= 4 and math.isfinite(trend['change']):
            flag += (f'  trend {trend["change"] * 100:+.0f} % over {trend["span"]:.0f} s'
                     + (' PARAMETER DRIFT' if trend['drifting'] else ''))
        lines.append(f'{name:26s} {value:13.6g} {error:11.3g} {mean:13.6g}  {flag}')
    if coefficients:
        lines.append('')
        lines.append('estimator weak SINDy: coefficients of d²angle/dt² [rad/s² per unit term] (-sin(angle) '
                     'coefficient = its gravity_stiffness, the start of the refinement above):')
        for name, (value, error) in coefficients.items():
            lines.append(f'  {name:38s} {value:13.6g} ± {error:.3g}')
    return '\n'.join(lines)


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
    from aeropend_ros._ros_env import ensure_ros_environment
    ensure_ros_environment(local_only=args.local)
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import ExternalShutdownException
    from sensor_msgs.msg import JointState

    from aeropend_ros import topics
    from aeropend_ros.identification_node import (COEFFICIENTS_TOPIC, DIAGNOSTIC_NAME, FIT_TOPIC, PARAMETERS_TOPIC,
                                                  msg_to_named_values, results_qos)

    state = {'parameters': {}, 'coefficients': {}, 'fit': {}, 'status': '', 'drift': {}, 'windows': 0,
             'dirty': False}
    tracker = DriftTracker(sigma=args.drift_sigma)
    from aeropend_core.diagnosis.online import ParameterTrends
    trends = ParameterTrends(args.window)

    def on_parameters(msg):
        values = msg_to_named_values(msg)
        state['parameters'] = values
        state['drift'] = tracker.update(values)
        state['trends'] = trends.add(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec, values)
        state['windows'] += 1
        state['dirty'] = True

    def on_coefficients(msg):
        state['coefficients'] = msg_to_named_values(msg)

    def on_fit(msg):
        state['fit'] = msg_to_named_values(msg)
        state['dirty'] = True

    def on_diagnostics(msg):
        for status in msg.status:
            if status.name == DIAGNOSTIC_NAME:
                values = {kv.key: kv.value for kv in status.values}
                extra = ' | '.join(f'{k} {values[k]}' for k in ('excitation', 'lost_samples', 'effects')
                                   if k in values)
                state['status'] = status.message + (f' | {extra}' if extra else '')
                state['dirty'] = True

    rclpy.init()
    node = rclpy.create_node('aeropend_monitor')
    node.create_subscription(JointState, PARAMETERS_TOPIC, on_parameters, results_qos())
    node.create_subscription(JointState, COEFFICIENTS_TOPIC, on_coefficients, results_qos())
    node.create_subscription(JointState, FIT_TOPIC, on_fit, results_qos())
    node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS_TOPIC, on_diagnostics, topics.diagnostics_qos())
    clear = sys.stdout.isatty() and not args.no_clear and not args.once
    started = time.monotonic()
    last_draw = 0.0
    status = 0
    try:
        while rclpy.ok():
            rclpy.spin_once(node, timeout_sec=0.1)
            now = time.monotonic()
            if args.once:
                if state['parameters'] and state['fit']:
                    # let the coefficients and the status of the same window arrive too
                    end = time.monotonic() + 0.5
                    while time.monotonic() < end:
                        rclpy.spin_once(node, timeout_sec=0.05)
                    print(render(state['parameters'], state['coefficients'], state['fit'], state['status'],
                                 state['drift'], state['windows'], trends=state.get('trends')))
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
            # One redraw per window: its parameters, coefficients, fit and status arrive within milliseconds.
            if (state['dirty'] and now - last_draw > 0.5) or (not state['parameters'] and now - last_draw > 2.0):
                text = render(state['parameters'], state['coefficients'], state['fit'], state['status'],
                              state['drift'], state['windows'], shutil.get_terminal_size().columns,
                              trends=state.get('trends'))
                print(('\x1b[H\x1b[2J' if clear else '\n') + text, flush=True)
                state['dirty'] = False
                last_draw = now
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return status
