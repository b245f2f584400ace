"""Benchmark: the sim node's rate and jitter at 490 Hz across processes, against a plain 490 Hz publisher.

Both publishers run as separate processes (local discovery, a private ROS_DOMAIN_ID), one after the other, and the
same receiver (this process, best effort with a deep queue) measures for --seconds each:

- rate by receive count, by the publisher's sequence numbers over the window, and as the Theil-Sen slope of
  sequence number against receive time [Hz] (target 490 Hz +- 1 %),
- samples lost (sequence gaps),
- inter-arrival jitter: standard deviation, 99th percentile and maximum of the receive intervals [ms],
- stamp spacing error: max |stamp_k - stamp_0 - (seq_k - seq_0) Ts| [ns] (0 for the sim: stamps are counter x Ts),
- CPU of the publisher process [% of one core] from /proc.

The baseline is a plain rclpy timer at Ts publishing one JointState of the same layout per tick (stamp = now).
Ratios sim / baseline are printed for rate, jitter and CPU. Usage::

    .venv/bin/python bench/bench_sim_node.py [--seconds 20] [--json PATH]      (~50 s with the defaults)
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import add_json_argument, figure, write_json

from aeropend_ros._ros_env import ensure_ros_environment, local_ros_environment
from aeropend_ros.testing import interrupt


def baseline_publisher() -> int:
    """A plain 490 Hz publisher: one JointState per timer tick (the reference for the sim node)."""
    ensure_ros_environment()
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from sensor_msgs.msg import JointState

    from aeropend_core.model.parameters import SAMPLE_TIME
    from aeropend_ros import topics

    rclpy.init()
    node = rclpy.create_node('baseline_publisher')
    publisher = node.create_publisher(JointState, topics.SAMPLES_TOPIC, topics.samples_qos())
    counter = [0]
    msg = JointState()

    def tick():
        sample = topics.Sample(node.get_clock().now().nanoseconds, 0.1, 1.0, 0.5, 0.3, counter[0])
        publisher.publish(topics.sample_to_msg(sample, msg))
        counter[0] += 1

    node.create_timer(SAMPLE_TIME, tick)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process [s] from /proc/<pid>/stat."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def measure(command: list[str], env: dict, seconds: float, context) -> dict:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState

    from aeropend_core.model.parameters import SAMPLE_TIME
    from aeropend_ros import topics

    received = []
    node = rclpy.create_node('bench_receiver', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    node.create_subscription(JointState, topics.SAMPLES_TOPIC,
                             lambda m: received.append((time.monotonic(), topics.msg_to_sample(m))),
                             QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT))
    process = subprocess.Popen(command, env=env, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 30.0
        while len(received) < 50:           # discovery and start-up, then a clean window
            if time.monotonic() > deadline:
                raise RuntimeError(f'no samples from {command}')
            executor.spin_once(timeout_sec=0.05)
        warm_up = time.monotonic() + 2.0   # a just-started publisher may still catch up its start-up backlog
        while time.monotonic() < warm_up:
            executor.spin_once(timeout_sec=0.01)
        received.clear()
        cpu_start, wall_start = cpu_seconds(process.pid), time.monotonic()
        while time.monotonic() - wall_start < seconds:
            executor.spin_once(timeout_sec=0.01)
        window = time.monotonic() - wall_start
        cpu = (cpu_seconds(process.pid) - cpu_start) / window
    finally:
        interrupt(process, 10)
        executor.shutdown()
        node.destroy_node()
    arrival = np.array([t for t, _ in received])
    sequence = np.array([s.sequence for _, s in received], dtype=np.int64)
    stamps = np.array([s.stamp_ns for _, s in received], dtype=np.int64)
    intervals = np.diff(arrival) * 1e3
    from scipy.stats import theilslopes
    pick = np.linspace(0, len(received) - 1, 400).astype(int)
    return {
        'rate_by_slope': float(theilslopes(sequence[pick], arrival[pick])[0]),
        'rate_by_count': len(received) / window,
        'rate_by_sequence': (sequence[-1] - sequence[0]) / (arrival[-1] - arrival[0]),
        'lost': int(np.sum(np.diff(sequence) - 1)),
        'jitter_std_ms': float(np.std(intervals)),
        'jitter_p99_ms': float(np.percentile(intervals, 99)),
        'jitter_max_ms': float(np.max(intervals)),
        'stamp_error_ns': float(np.max(np.abs((stamps - stamps[0]) - (sequence - sequence[0]) * SAMPLE_TIME * 1e9))),
        'cpu_percent': 100.0 * cpu,
        'samples': len(received),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--seconds', type=float, default=20.0, help='measurement window per publisher [s]')
    parser.add_argument('--publish-period', type=float, default=0.004, help="sim node's timer period [s]")
    add_json_argument(parser)
    parser.add_argument('--role', choices=['bench', 'baseline'], default='bench', help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role == 'baseline':
        return baseline_publisher()

    domain = 100 - (os.getpid() % 40)
    os.environ['ROS_DOMAIN_ID'] = str(domain)
    ensure_ros_environment(local_only=True)
    import rclpy
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    env = local_ros_environment(domain_id=domain)
    python = sys.executable
    runs = {
        'baseline': measure([python, __file__, '--role', 'baseline'], env, args.seconds, context),
        'sim_node': measure([python, '-m', 'aeropend_ros.sim_node', '--ros-args', '-p',
                             f'publish_period:={args.publish_period}'], env, args.seconds, context),
    }
    rclpy.try_shutdown(context=context)
    keys = ['rate_by_count', 'rate_by_sequence', 'rate_by_slope', 'lost', 'jitter_std_ms', 'jitter_p99_ms',
            'jitter_max_ms', 'stamp_error_ns', 'cpu_percent', 'samples']
    print(f'# sim node vs plain 490 Hz publisher, {args.seconds:g} s each, cross-process, '
          f'load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs')
    print(f'{"metric":18s} {"baseline":>12s} {"sim_node":>12s} {"ratio":>8s}')
    for key in keys:
        base, sim = runs['baseline'][key], runs['sim_node'][key]
        ratio = sim / base if base else float('nan')
        print(f'{key:18s} {base:12.3f} {sim:12.3f} {ratio:8.3f}')
    sim = runs['sim_node']
    within = abs(sim['rate_by_sequence'] - 490.0) <= 4.9 and abs(sim['rate_by_count'] - 490.0) <= 4.9
    print(f'sim node rate within 490 Hz +- 1 %: {"yes" if within else "NO"}')
    base = runs['baseline']
    write_json(args.json, 'bench_sim_node', [
        figure('sim node rate (by sequence numbers)', sim['rate_by_sequence'], 'Hz', baseline=base['rate_by_sequence'],
               baseline_name='plain rclpy 490 Hz timer publisher', ratio_meaning='sim / baseline',
               target='490 Hz +- 1 %', met=within),
        figure('sim node samples lost', sim['lost'], 'samples', baseline=base['lost'], baseline_name='plain timer',
               target='0', met=sim['lost'] == 0),
        figure('sim node inter-arrival jitter, 99th percentile', sim['jitter_p99_ms'], 'ms',
               baseline=base['jitter_p99_ms'], baseline_name='plain timer', ratio_meaning='sim / baseline'),
        figure('sim node inter-arrival jitter, standard deviation', sim['jitter_std_ms'], 'ms',
               baseline=base['jitter_std_ms'], baseline_name='plain timer', ratio_meaning='sim / baseline'),
        figure('sim node publisher CPU', sim['cpu_percent'], '% of one core', baseline=base['cpu_percent'],
               baseline_name='plain timer', ratio_meaning='sim / baseline'),
    ], seconds=args.seconds, publish_period_s=args.publish_period, runs=runs)
    return 0 if within else 1


if __name__ == '__main__':
    sys.exit(main())
