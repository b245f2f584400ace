"""Recorder memory growth in minutes instead of hours: replay a recorded full-graph bag to a recorder_node, faster.

The recorder's resident memory grew with the *messages* it recorded, not with the wall clock: replaying the bag of a
full-graph load test (samples, duty commands, identification outputs, /diagnostics, each on its own topic with
its original QoS kind) at ``--speed`` times its rate reproduces in two minutes what the graph shows in ten. Each
case starts its own recorder (a private ROS domain) and samples the recorder's anonymous RSS from /proc every
``--sample-period`` seconds; the slope of a least-squares line after ``--warm-up`` seconds of *recorded* time is
reported in MB per minute of recorded time (what one real minute of the graph costs).

Cases (each a separate recorder, one after the other):

- ``samples``: only ``/aeropend/samples`` (the baseline in the same run: chunks and their index alone);
- ``all``: every topic of the bag, as in the graph;
- ``all, chunk_size:=N`` for each ``--chunk-size`` given (chunk size experiments).

Usage::

    .venv/bin/python bench/load_test.py --duration 420 --keep-bag --out /tmp/lt     # a bag to replay, once
    .venv/bin/python bench/recorder_memory.py /tmp/lt/bag --speed 5 --seconds 100 --chunk-size 65536

The replaying publisher is a Python loop: above ~5x (2,500 samples/s) it may fall behind, which only stretches
the recorded time (the slope is per recorded minute, from the stamps actually replayed).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from aeropend_ros._ros_env import ensure_ros_environment, local_ros_environment  # noqa: E402

SAMPLES = '/aeropend/samples'


def anonymous_rss_mb(pid: int) -> float:
    with open(f'/proc/{pid}/status', encoding='ascii') as status:
        for line in status:
            if line.startswith('RssAnon'):
                return int(line.split()[1]) / 1024
    return float('nan')


def qos_for(topic: str):
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    if topic == SAMPLES:
        return QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
    if topic.startswith('/aeropend/identification/') or topic == '/aeropend/excitation/done':
        return QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    return QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


def replay_case(messages, recorder_args: list[str], args, label: str) -> dict:
    """One recorder fed `messages` at args.speed for args.seconds: its anonymous RSS against recorded time."""
    import rclpy
    from aeropend_ros.recorder_node import message_class
    domain_id = _domain()
    work = Path(tempfile.mkdtemp(prefix='aeropend_recorder_memory_'))
    env = local_ros_environment(domain_id=domain_id)
    log = open(work / 'recorder.log', 'w')          # noqa: SIM115 - closed below
    recorder = subprocess.Popen([sys.executable, '-m', 'aeropend_ros.recorder_node', '--ros-args',
                                 '-p', f'output:={work / "bag"}', *recorder_args], env=env, cwd=ROOT, stdout=log,
                                stderr=subprocess.STDOUT)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = rclpy.create_node('recorder_memory_replay', context=context)
    publishers = {}
    for message in messages:
        if message.topic not in publishers:
            publishers[message.topic] = node.create_publisher(message_class(message.type), message.topic,
                                                              qos_for(message.topic))
    deadline = time.monotonic() + 60.0
    while any(p.get_subscription_count() == 0 for p in publishers.values()):
        if time.monotonic() > deadline or recorder.poll() is not None:
            raise RuntimeError(f'{label}: the recorder did not subscribe; see {work / "recorder.log"}')
        time.sleep(0.1)
    span_s = (messages[-1].log_time_ns - messages[0].log_time_ns) * 1e-9
    rows = []                                          # (recorded seconds, anonymous RSS MB)
    started = time.monotonic()
    next_sample = started
    index, loops, first = 0, 0, messages[0].log_time_ns
    while time.monotonic() - started < args.seconds:
        message = messages[index]
        recorded_s = (message.log_time_ns - first) * 1e-9 + loops * span_s
        delay = started + recorded_s / args.speed - time.monotonic()
        if delay > 0.002:
            time.sleep(delay)
        publishers[message.topic].publish(message.data)
        index += 1
        if index == len(messages):
            index, loops = 0, loops + 1
        if time.monotonic() >= next_sample:
            rows.append((recorded_s, anonymous_rss_mb(recorder.pid)))
            next_sample += args.sample_period
    recorder.send_signal(2)
    status = recorder.wait(60)
    log.close()
    node.destroy_node()
    rclpy.try_shutdown(context=context)
    t, rss = np.array(rows).T
    steady = t >= args.warm_up
    slope = float(np.polyfit(t[steady], rss[steady], 1)[0]) * 60.0 if steady.sum() >= 3 else float('nan')
    return {'case': label, 'recorder_args': recorder_args, 'recorded_s': float(t[-1]), 'samples': len(rows),
            'anon_start_mb': float(rss[steady][0]) if steady.any() else float('nan'), 'anon_end_mb': float(rss[-1]),
            'slope_mb_per_recorded_min': slope, 'exit_status': status}


def _domain() -> int:
    from aeropend_ros.testing import private_domain_id
    return private_domain_id()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('bag', help='a bag recorded from the full graph (bench/load_test.py --keep-bag)')
    parser.add_argument('--speed', type=float, default=5.0, help='replay speed (default 5x)')
    parser.add_argument('--seconds', type=float, default=100.0, help='wall seconds per case (default 100)')
    parser.add_argument('--warm-up', type=float, default=100.0, help='recorded seconds before the slope (default 100)')
    parser.add_argument('--sample-period', type=float, default=2.0, help='wall seconds between RSS samples')
    parser.add_argument('--chunk-size', type=int, action='append', default=[], help='extra case(s) with this '
                        'chunk_size [bytes] (repeatable)')
    parser.add_argument('--json', help='write the results here')
    args = parser.parse_args(argv)
    ensure_ros_environment(local_only=True)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    from aeropend_core.io.bag import read_messages
    everything = [m for m in read_messages(args.bag)
                  if not (m.topic == '/diagnostics' and b'recorder_node' in m.data[:200])]   # not its own status
    cases = [('samples', [m for m in everything if m.topic == SAMPLES], []), ('all', everything, [])]
    cases += [(f'all, chunk_size:={size}', everything, ['-p', f'chunk_size:={size}']) for size in args.chunk_size]
    results = []
    for label, messages, recorder_args in cases:
        result = replay_case(messages, recorder_args, args, label)
        results.append(result)
        print(f'{label:28s} {result["recorded_s"]:6.0f} s recorded, anonymous RSS {result["anon_start_mb"]:.2f} -> '
              f'{result["anon_end_mb"]:.2f} MB, slope {result["slope_mb_per_recorded_min"]:+.3f} MB per recorded '
              'minute', flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
