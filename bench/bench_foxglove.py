"""Benchmark: what forwarding the live graph to Foxglove costs (foxglove_node), against a bare subscriber.

The sim node publishes ``/aeropend/samples`` at 490 Hz in its own process (local discovery, a private
ROS_DOMAIN_ID). For --seconds each, one after the other, a consumer process receives them:

- **foxglove_node** with one WebSocket client (this process, the ``websockets`` package) subscribed to every channel:
  raw CDR in, Foxglove frames out;
- **baseline**: a plain rclpy raw subscription with the same QoS that only counts the messages (the least a consumer
  can cost).

Reported: CPU of the consumer process [% of one core] from /proc and per message [us], samples that reached the
WebSocket client per second and the ones lost on the way (gaps in the decoded sequence numbers), and the ratio of the
two CPU costs. Usage::

    .venv/bin/python bench/bench_foxglove.py [--seconds 20] [--json PATH]      (~1 min with the defaults)
"""
from __future__ import annotations

import argparse
import json
import os
import re
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import add_json_argument, figure, write_json

from aeropend_ros._ros_env import ensure_ros_environment, local_ros_environment
from aeropend_ros.testing import interrupt


def bare_subscriber() -> int:
    """The baseline consumer: a raw subscription to the samples that counts them (prints the count on exit)."""
    ensure_ros_environment()
    import rclpy
    from sensor_msgs.msg import JointState

    from aeropend_ros import topics
    rclpy.init()
    node = rclpy.create_node('bare_subscriber')
    count = [0]
    node.create_subscription(JointState, topics.SAMPLES_TOPIC, lambda data: count.__setitem__(0, count[0] + 1),
                             topics.samples_qos(), raw=True)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, Exception):  # noqa: BLE001 - ExternalShutdownException on SIGINT
        pass
    print(f'received {count[0]}', flush=True)
    return 0


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process [s] from /proc/<pid>/stat."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def start(command: list[str], env: dict) -> tuple[subprocess.Popen, object]:
    log = tempfile.TemporaryFile('w+')
    return subprocess.Popen(command, env=env, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, text=True), log


def stop(process: subprocess.Popen, log) -> str:
    """Ctrl-C the process (SIGKILL after 15 s) and return its log."""
    interrupt(process, 15)
    log.seek(0)
    return log.read()


def measure(kind: str, seconds: float, domain: int) -> dict:
    """Run the sim and one consumer for `seconds`; CPU of the consumer and, for foxglove, what the client got."""
    env = local_ros_environment(domain_id=domain)
    python = sys.executable
    sim, sim_log = start([python, '-m', 'aeropend_ros.sim_node', '--ros-args', '-p', 'effects:=[angle_offset=0.05]'],
                         env)
    if kind == 'foxglove':
        consumer, log = start([python, '-m', 'aeropend_ros.foxglove_node', '--ros-args', '-p', 'port:=0'], env)
    else:
        consumer, log = start([python, str(Path(__file__)), '--bare-subscriber'], env)
    received: list[tuple[float, int]] = []
    try:
        url = None
        deadline = time.monotonic() + 60
        while kind == 'foxglove' and url is None and time.monotonic() < deadline:
            log.seek(0)
            match = re.search(r'ws://[\d.]+:\d+', log.read())
            url = match.group(0) if match else None
            time.sleep(0.2)
        stop_event = threading.Event()
        if kind == 'foxglove':
            if url is None:
                raise RuntimeError('foxglove_node printed no address')
            thread = threading.Thread(target=client, args=(url, received, stop_event), daemon=True)
            thread.start()
            deadline = time.monotonic() + 60                  # measure from the first forwarded sample on
            while not received and time.monotonic() < deadline:
                time.sleep(0.1)
        else:
            time.sleep(5.0)                                   # discovery, then measure
        cpu0, t0, n0 = cpu_seconds(consumer.pid), time.monotonic(), len(received)
        time.sleep(seconds)
        cpu1, t1, n1 = cpu_seconds(consumer.pid), time.monotonic(), len(received)
        stop_event.set()
    finally:
        output = stop(consumer, log)
        stop(sim, sim_log)
    result = {'cpu_fraction': (cpu1 - cpu0) / (t1 - t0), 'seconds': t1 - t0}
    if kind == 'foxglove':
        window = received[n0:n1]
        sequence = [s for _, s in window]
        result['client_rate_hz'] = (n1 - n0) / (t1 - t0)
        result['lost'] = sum(b - a - 1 for a, b in zip(sequence, sequence[1:]) if b > a + 1)
        result['messages'] = n1 - n0
    else:
        match = re.search(r'received (\d+)', output)
        result['messages'] = int(match.group(1)) if match else None
        result['client_rate_hz'] = 490.0
    return result


def client(url: str, received: list, stop_event: threading.Event) -> None:
    """Subscribe to every channel; record (receive time, sample sequence number) of each /aeropend/samples frame."""
    from websockets.sync.client import connect
    with connect(url, subprotocols=['foxglove.sdk.v1', 'foxglove.websocket.v1']) as ws:
        samples_subscription = None
        subscribed: set[int] = set()
        next_id = 1
        while not stop_event.is_set():
            try:
                frame = ws.recv(timeout=0.5)
            except TimeoutError:
                continue
            if isinstance(frame, str):
                message = json.loads(frame)
                new = [c for c in message.get('channels', []) if c['id'] not in subscribed]
                if message.get('op') == 'advertise' and new:
                    subscriptions = []
                    for channel in new:
                        subscriptions.append({'id': next_id, 'channelId': channel['id']})
                        if channel['topic'] == '/aeropend/samples':
                            samples_subscription = next_id
                        subscribed.add(channel['id'])
                        next_id += 1
                    ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subscriptions}))
            elif frame[0] == 1 and struct.unpack_from('<I', frame, 1)[0] == samples_subscription:
                # the sequence number is position[4], the last float64 of the CDR payload's position array
                received.append((time.monotonic(), sequence_from_cdr(frame[13:])))


def sequence_from_cdr(payload: bytes) -> int:
    ensure_ros_environment()
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState
    return int(deserialize_message(payload, JointState).position[4])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=20.0, help='measuring time per consumer [s]')
    parser.add_argument('--bare-subscriber', action='store_true', help=argparse.SUPPRESS)
    add_json_argument(parser)
    args = parser.parse_args()
    if args.bare_subscriber:
        return bare_subscriber()
    ensure_ros_environment(local_only=True)
    from aeropend_ros.testing import private_domain_id
    baseline = measure('bare', args.seconds, private_domain_id())
    foxglove = measure('foxglove', args.seconds, private_domain_id())
    per_message = {k: r['cpu_fraction'] / 490.0 * 1e6 for k, r in (('bare', baseline), ('foxglove', foxglove))}
    print(f'bare raw subscriber : {baseline["cpu_fraction"] * 100:5.1f} % of a core '
          f'({per_message["bare"]:.0f} us per sample)')
    print(f'foxglove_node       : {foxglove["cpu_fraction"] * 100:5.1f} % of a core '
          f'({per_message["foxglove"]:.0f} us per sample, {foxglove["cpu_fraction"] / baseline["cpu_fraction"]:.1f}x '
          f'the bare subscriber); client received {foxglove["client_rate_hz"]:.1f} samples/s, '
          f'{foxglove["lost"]} lost of {foxglove["messages"]}')
    print(f'load average {os.getloadavg()[0]:.2f}')
    write_json(args.json, 'bench_foxglove', [
        figure('foxglove_node CPU', foxglove['cpu_fraction'] * 100, '% of a core',
               baseline=baseline['cpu_fraction'] * 100, baseline_name='bare raw subscriber',
               ratio_meaning='foxglove_node CPU / bare subscriber CPU'),
        figure('samples reaching the Foxglove client', foxglove['client_rate_hz'], 'Hz', target='490 Hz, 0 lost',
               met=abs(foxglove['client_rate_hz'] - 490) < 5 and foxglove['lost'] == 0),
        figure('samples lost on the way to the client', foxglove['lost'], 'samples'),
    ], seconds=args.seconds, baseline=baseline, foxglove=foxglove)
    return 0


if __name__ == '__main__':
    sys.exit(main())
