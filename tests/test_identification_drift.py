"""The identification node's per-parameter topics and its drift test, with known truth (real node over DDS).

The test feeds identification_node (its sample topic remapped, so only this test's samples reach it) with records
of the full rig simulator at 5x real time, published sample by sample as the rig's bridge would:

1. a thrust gain that sags by 20 % over 240 s (:func:`aeropend_core.testing.rigs.simulate_drifting`, as a sagging
   supply would): the node reports the drift on /diagnostics (WARN "parameter drift: thrust gain ...") and sets
   ``drifting`` on /aeropend/parameters/thrust_gain, with the change over the tested span within 5 points of the
   truth over that span; damping and gravity are not flagged;
2. then (the source restarts: the counter goes back) a clean record of 160 s: no drift on any parameter in any
   window (the false-alarm test), although the trend is tested (at least 4 windows that do not overlap).

Every window's per-parameter messages agree with the old keyed JointState (value and 1σ) and carry the bands
(value ∓ σ), the estimator, the SI unit and the data flag.
"""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

from tests.ros_helpers import NodeProcess, own_context, private_domain_id, use_domain, wait_for

DOMAIN_ID = private_domain_id()
use_domain(DOMAIN_ID)

import rclpy  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from aeropend_core.model.parameters import DEFAULT_PARAMETERS, SAMPLE_TIME  # noqa: E402
from aeropend_core.sim.excitation import lhc_schedule  # noqa: E402
from aeropend_core.sim.noise import MeasurementNoise  # noqa: E402
from aeropend_core.sim.simulate import simulate  # noqa: E402
from aeropend_core.testing.rigs import simulate_drifting  # noqa: E402
from aeropend_ros import topics  # noqa: E402

pytestmark = pytest.mark.timeout(900)

DISCOVERY_TIMEOUT = 30.0
#: The analysis worker (a spawned process importing the numerical stack) can take minutes to start on a loaded machine.
WORKER_START_TIMEOUT = 300.0
SAMPLES = '/drift_test/samples'
WINDOW_S = 20.0
#: A window every 10 s: the drift test uses windows that do not overlap, so a denser hop adds run time, not power.
HOP_S = 10.0
#: Publishing speed against real time (lost samples would be filled and flagged, which the test also checks).
SPEED = 5.0
DRIFT_SECONDS, DRIFT = 240.0, 0.20
CLEAN_SECONDS = 160.0
WATCHED = ('thrust_gain', 'damping', 'gravity_stiffness', 'armature_resistance')


class Feeder:
    """In-test node: publishes samples, keeps /diagnostics statuses, the old parameters and per-parameter topics."""

    def __init__(self, context) -> None:
        from aeropend_ros.identification_node import DIAGNOSTIC_NAME, PARAMETERS_TOPIC, msg_to_named_values, \
            results_qos
        self.node = rclpy.create_node('drift_feeder', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.publisher = self.node.create_publisher(JointState, SAMPLES, topics.samples_qos())
        self.statuses: list[tuple[str, bytes, dict]] = []
        self.keyed: dict[int, dict] = {}
        self.estimates: dict[str, dict[int, topics.ParameterEstimate]] = {name: {} for name in WATCHED}
        self.weak: dict[int, topics.ParameterEstimate] = {}

        def on_status(msg):
            for status in msg.status:
                if status.name == DIAGNOSTIC_NAME:
                    self.statuses.append((status.message, status.level, {kv.key: kv.value for kv in status.values}))

        def on_keyed(msg):
            self.keyed[msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec] = msg_to_named_values(msg)

        def on_estimate(table, name):
            def store(msg):
                estimate = topics.msg_to_parameter(msg, name)
                table[estimate.stamp_ns] = estimate
            return store

        from aeropend_ros import topics as t
        self.node.create_subscription(DiagnosticArray, t.DIAGNOSTICS_TOPIC, on_status, t.diagnostics_qos())
        self.node.create_subscription(JointState, PARAMETERS_TOPIC, on_keyed, results_qos())
        for name in WATCHED:
            self.node.create_subscription(JointState, t.parameter_topic(name), on_estimate(self.estimates[name], name),
                                          results_qos())
        self.node.create_subscription(JointState, t.parameter_topic('thrust_gain', 'weak_sindy'),
                                      on_estimate(self.weak, 'thrust_gain'), results_qos())

    def feed(self, trajectory, first_stamp_ns: int, speed: float = SPEED) -> int:
        """Publish every sample of `trajectory` (sequence from 0) at up to `speed` x real time, in lock-step with the
        node: after each window comes due, wait until the node has reported on it (a status naming the window's end),
        so that no window is skipped because the previous one is still being computed on a busy machine (the node
        counts acquisition time, so a pause changes nothing). Returns the last stamp [ns]."""
        stamps = first_stamp_ns + np.round(np.arange(len(trajectory.time)) * SAMPLE_TIME * 1e9).astype(np.int64)
        # 25 samples past each window's end: a lost sample there only moves the window by a sample or two
        due = [int(np.searchsorted(stamps - first_stamp_ns, int((WINDOW_S + HOP_S * m) * 1e9))) + 25
               for m in range(int((len(stamps) * SAMPLE_TIME - WINDOW_S) / HOP_S) + 1)]
        block = 49
        published = 0
        for stop in [d for d in due if d <= len(stamps)] + [len(stamps)]:
            started, first = time.monotonic(), published
            while published < stop:
                for k in range(published, min(published + block, stop)):
                    self.publisher.publish(topics.sample_to_msg(topics.Sample(
                        int(stamps[k]), trajectory.angle[k], trajectory.armature_voltage[k],
                        trajectory.armature_current[k], trajectory.duty[k], k)))
                published = min(published + block, stop)
                pause_until = started + (published - first) * SAMPLE_TIME / speed
                while True:                        # keep receiving the results meanwhile
                    self.executor.spin_once(timeout_sec=0.0)
                    if time.monotonic() >= pause_until:
                        break
                    time.sleep(min(0.002, max(pause_until - time.monotonic(), 0.0)))
            if stop in due:
                reached = int(stamps[stop - 1]) - int(HOP_S / 2 * 1e9)
                assert self.wait_for_window(reached), f'no report on the window ending at sample {stop}'
        return int(stamps[-1])

    def wait_for_window(self, stamp_ns: int, timeout: float = 240.0) -> bool:
        """Wait until a status reports on a window ending at or after `stamp_ns` (analysed or refused)."""
        return wait_for(lambda: any(int(v.get('window_stop_ns', 0)) >= stamp_ns for _, _, v in self.statuses[-20:]),
                        timeout, executor=self.executor)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()


def _records():
    duty = lhc_schedule(DRIFT_SECONDS, seed=31).duty(duration=DRIFT_SECONDS)
    sagging = lambda t: DEFAULT_PARAMETERS.scaled(thrust_coefficient=1 - DRIFT * t / DRIFT_SECONDS)  # noqa: E731
    drifting = simulate_drifting(duty, sagging, noise=MeasurementNoise(50.0, True), seed=32)
    duty = lhc_schedule(CLEAN_SECONDS, seed=51).duty(duration=CLEAN_SECONDS)
    clean = simulate(duty, noise=MeasurementNoise(50.0, True), seed=52)
    return drifting, clean


def test_node_reports_a_sagging_thrust_gain_as_drift_and_a_clean_record_as_none():
    drifting, clean = _records()
    domain_id = private_domain_id()
    arguments = ['-r', f'/aeropend/samples:={SAMPLES}', '-p', f'window_s:={WINDOW_S}', '-p', f'hop_s:={HOP_S}']
    with own_context(domain_id) as context, \
            NodeProcess('aeropend_ros.identification_node', arguments, domain_id) as identification:
        feeder = Feeder(context)
        try:
            assert wait_for(lambda: feeder.publisher.get_subscription_count() >= 1, DISCOVERY_TIMEOUT,
                            executor=feeder.executor), identification.output()
            # the node's status arrives once a second while it waits: its /diagnostics reached us too, and it says
            # when its analysis worker has started (tens of seconds on a loaded machine): feed only then, so that
            # no window is skipped because the worker is still starting
            assert wait_for(lambda: feeder.statuses and 'still starting' not in feeder.statuses[-1][0],
                            WORKER_START_TIMEOUT, executor=feeder.executor), identification.output()
            origin = time.time_ns()
            last_ns = feeder.feed(drifting, origin)
            # the last window's parameters came before its status
            assert wait_for(lambda: max(feeder.estimates['thrust_gain'], default=0) >= last_ns - int(HOP_S * 1e9),
                            30.0, executor=feeder.executor), (identification.output(), feeder.statuses[-3:])
            drift_statuses = list(feeder.statuses)
            drift_estimates = {name: dict(table) for name, table in feeder.estimates.items()}
            # The source restarts (counter back to 0, later stamps): the drift test starts again.
            clean_origin = last_ns + int(10e9)
            last_ns = feeder.feed(clean, clean_origin)
            assert wait_for(lambda: max(feeder.estimates['thrust_gain'], default=0) >= last_ns - int(HOP_S * 1e9),
                            30.0, executor=feeder.executor), (identification.output(), feeder.statuses[-3:])
        finally:
            feeder.close()
        output = identification.output()

    # ---- the sagging gain: named as drift, sized within 5 points of the truth over the tested span
    gain = [drift_estimates['thrust_gain'][s] for s in sorted(drift_estimates['thrust_gain'])]
    assert len(gain) >= 21, output                      # 23 windows due; a refused one (lost samples) is said
    flagged = [e for e in gain if e.drifting]
    assert flagged, [(e.trend_change, e.drifting) for e in gain]
    warned = [(m, v) for m, level, v in drift_statuses if v.get('drift', 'none') != 'none']
    assert warned and all(level == b'\x01' for _, level, v in drift_statuses if v.get('drift', 'none') != 'none')
    message, values = warned[-1]
    assert 'parameter drift: thrust gain' in message and 'supply voltage sag' in message, message
    assert values['trend_thrust_gain'].endswith('DRIFT'), values
    print(f'drifting record, last window: {message}')
    span = float(values['trend_thrust_gain'].split(' over ')[1].split(' s')[0])
    # the sag over the span of the tested windows, as a fraction of the mean gain (about the record's middle)
    truth_change = -DRIFT * span / DRIFT_SECONDS / (1 - 0.5 * DRIFT)
    assert gain[-1].drifting and gain[-1].trend_change == pytest.approx(truth_change, abs=0.05), \
        (gain[-1], truth_change)
    for name in ('damping', 'gravity_stiffness'):
        assert not any(e.drifting for e in drift_estimates[name].values()), name
    # ---- the clean record: the trend is tested, no drift on any parameter in any window
    clean_estimates = {name: [e for s, e in table.items() if s >= clean_origin]
                       for name, table in feeder.estimates.items()}
    assert len(clean_estimates['thrust_gain']) >= 13, output        # 15 windows due
    for name, estimates in clean_estimates.items():
        assert not any(e.drifting for e in estimates), (name, [e.trend_change for e in estimates])
    tested = [e for e in clean_estimates['thrust_gain'] if math.isfinite(e.trend_change)]
    assert tested and abs(tested[-1].trend_change) < 0.05, tested[-1]
    clean_statuses = [v for _, _, v in feeder.statuses[len(drift_statuses):] if 'drift' in v]
    assert clean_statuses and all(v['drift'] == 'none' for v in clean_statuses)
    assert 'windows' in clean_statuses[-1]['trend_thrust_gain']
    print('clean record, last window: ' + ', '.join(f'{k} {v}' for k, v in clean_statuses[-1].items()
                                                    if k.startswith('trend_')))

    # ---- every per-parameter message agrees with the keyed JointState and carries its band, estimator and unit
    units = {'thrust_gain': 'rad/s^2/V^2', 'damping': '1/s', 'gravity_stiffness': '1/s^2', 'armature_resistance': 'ohm'}
    checked = 0
    for name, table in feeder.estimates.items():
        for stamp, estimate in table.items():
            if stamp not in feeder.keyed:
                continue
            value, sigma = feeder.keyed[stamp][name]
            assert estimate.value == value and (estimate.sigma == sigma or math.isnan(sigma) and math.isnan(
                estimate.sigma))
            if math.isfinite(sigma):
                assert (estimate.lower, estimate.upper) == pytest.approx((value - sigma, value + sigma))
            assert estimate.unit == units[name]
            expected = {'armature_resistance': ('motor_observer', 'output_error')}.get(name, ('output_error',))
            assert estimate.estimator in expected, estimate
            assert estimate.data == 'clean' or estimate.data.startswith('flagged:')
            checked += 1
    assert checked >= 40
    weak = list(feeder.weak.values())
    assert weak and all(e.estimator == 'weak_sindy' and e.unit == 'rad/s^2/V^2' and e.sigma > 0 for e in weak)
    assert np.median([e.value for e in weak if e.stamp_ns < clean_origin][:3]) == pytest.approx(
        DEFAULT_PARAMETERS.thrust_gain, rel=0.15)
