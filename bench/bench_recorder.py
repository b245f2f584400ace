"""Recorder throughput: can recorder_node record >= 20,000 msg/s without losing one?

Run:  .venv/bin/python bench/bench_recorder.py [--rates 20000 40000] [--seconds 5] [--reliable] [--queue-depth N]
                                              [--fastdds-profile config/fastdds_deep_shm.xml] [--json PATH]
(~20 s with the defaults)

For each offered rate a publisher process publishes ``/aeropend/samples`` JointState messages (the real message,
SensorData QoS unless --reliable) numbered 0..N-1, paced at the rate, after the recorder (a separate process,
``python -m aeropend_ros.recorder_node``) has subscribed. The recorder is then stopped with SIGINT and the bag is read
back: loss = published - recorded, and the recorded sequence numbers must be 0..N-1 without gap.

Baseline, measured in the same run: the same CDR bytes written straight to ``aeropend_core.io.bag.BagWriter`` (no ROS,
no DDS) — the cost of the bag writing alone. Printed ratios: recorded rate / offered rate, and recorder CPU per
message against the baseline's CPU per message.
"""
from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import add_json_argument, figure, write_json

from aeropend_ros._ros_env import ensure_ros_environment, local_ros_environment


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process (Linux /proc)."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def sample_bytes(count: int) -> list[bytes]:
    """CDR of `count` JointState samples as the contract defines them (made with rclpy, no empty-array padding
    issue here: velocity/effort are empty, and what rclpy publishes is what the recorder receives)."""
    ensure_ros_environment(local_only=True)
    from rclpy.serialization import serialize_message

    from aeropend_ros.topics import Sample, sample_to_msg
    return [serialize_message(sample_to_msg(Sample(1_700_000_000_000_000_000 + k * 2_040_816, 0.1, 1.5, 0.4, 0.3, k)))
            for k in range(count)]


def baseline(count: int, folder: Path) -> tuple[float, float]:
    """(msg/s, CPU s per message) writing `count` sample messages straight to BagWriter."""
    from aeropend_core.io.bag_writer import BagWriter
    from aeropend_core.io.mcap_format import msg_file_loader, ros2msg_definition
    from aeropend_ros._ros_env import ament_prefixes
    data = sample_bytes(count)
    writer = BagWriter(folder, chunk_size=256 * 1024)
    loader = msg_file_loader(ament_prefixes() or [sys.prefix])
    writer.add_topic('/aeropend/samples', 'sensor_msgs/msg/JointState',
                     ros2msg_definition('sensor_msgs/msg/JointState', loader))
    cpu0, t0 = time.process_time(), time.perf_counter()
    for k, raw in enumerate(data):
        writer.write('/aeropend/samples', raw, 1_700_000_000_000_000_000 + k * 50_000)
    writer.finish()
    elapsed, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    return count / elapsed, cpu / count


def rosbags_sample_bytes(count: int) -> list[bytes]:
    """CDR of `count` JointState samples serialised by ``rosbags`` (rclpy's bytes of this bench's samples carry a
    tail that the rosbags deserialiser, and so read_samples, refuses as a size mismatch)."""
    import numpy as np
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    types = store.types
    joint_state, header, stamp = (types['sensor_msgs/msg/JointState'], types['std_msgs/msg/Header'],
                                  types['builtin_interfaces/msg/Time'])
    out = []
    for k in range(count):
        ns = 1_700_000_000_000_000_000 + k * 2_040_816
        message = joint_state(header=header(stamp=stamp(sec=ns // 10**9, nanosec=ns % 10**9), frame_id='aeropend'),
                              name=['angle', 'armature_voltage', 'armature_current', 'duty', 'sequence'],
                              position=np.array([0.1 + 1e-4 * (k % 1000), 1.5, 0.4, 0.3, float(k)]),
                              velocity=np.array([], dtype=float), effort=np.array([], dtype=float))
        out.append(bytes(store.serialize_cdr(message, joint_state.__msgtype__)))
    return out


def write_cost(count: int, folder: Path, chunk_duration: float, rate: float = 490.0) -> dict:
    """Cost of closing chunks on time (issue 43): `count` samples written to BagWriter as if they came at `rate` Hz
    (the writer's monotonic clock advances 1/rate per message), 256 KiB chunks also closed after `chunk_duration` s
    (0: on size only). Returns CPU per message written and read back (read_samples), bytes on disk per message and
    the number of chunks closed on time."""
    from aeropend_core.io import bag_writer
    from aeropend_core.io.bag_writer import BagWriter
    from aeropend_core.io.mcap_format import msg_file_loader, ros2msg_definition
    from aeropend_ros._ros_env import ament_prefixes
    data = rosbags_sample_bytes(count)
    clock = [0.0]
    real = bag_writer.time.monotonic
    bag_writer.time.monotonic = lambda: clock[0]
    try:
        writer = BagWriter(folder, chunk_size=256 * 1024, max_chunk_duration=chunk_duration)
        loader = msg_file_loader(ament_prefixes() or [sys.prefix])
        writer.add_topic('/aeropend/samples', 'sensor_msgs/msg/JointState',
                         ros2msg_definition('sensor_msgs/msg/JointState', loader))
        step_ns = round(1e9 / rate)
        cpu0 = time.process_time()
        for k, raw in enumerate(data):
            clock[0] = k / rate
            writer.write('/aeropend/samples', raw, 1_700_000_000_000_000_000 + k * step_ns)
        writer.finish()
        cpu = time.process_time() - cpu0
    finally:
        bag_writer.time.monotonic = real
    size = sum(p.stat().st_size for p in folder.glob('*.mcap'))
    from aeropend_core.io.bag import read_samples
    read_cpu = []
    for _ in range(2):                              # best of 2: the reader's cost per message of such a bag
        cpu0 = time.process_time()
        assert len(read_samples(folder, on_incomplete='raise')['time']) == count
        read_cpu.append(time.process_time() - cpu0)
    return {'chunk_duration_s': chunk_duration, 'cpu_s_per_msg': cpu / count, 'bytes_per_msg': size / count,
            'chunks_closed_on_time': writer.chunks_closed_on_time, 'read_cpu_s_per_msg': min(read_cpu) / count}


def print_write_cost(work: Path, count: int = 100_000) -> list[dict]:
    """Write cost of 256 KiB chunks closed on size only against also on time (0.75 s, the recorder's default)."""
    rows = [write_cost(count, work / f'cost_{d}', d) for d in (0.0, 0.75, 0.25)]
    for r in rows:
        how = f'after {r["chunk_duration_s"]} s' if r['chunk_duration_s'] else 'on size only'
        print(f'write cost at 490 Hz, chunks closed {how:>13}: '
              f'{r["cpu_s_per_msg"] * 1e6:5.2f} us CPU/msg, {r["bytes_per_msg"]:6.1f} bytes/msg on disk, '
              f'{r["chunks_closed_on_time"]} chunks closed on time; read_samples {r["read_cpu_s_per_msg"] * 1e6:.2f} '
              'us CPU/msg', flush=True)
    return rows


def publisher(rate: float, seconds: float, reliable: bool) -> None:
    """Publisher role (own process): wait for the recorder's subscription, publish N numbered samples at `rate`."""
    ensure_ros_environment(local_only=True)
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState

    from aeropend_ros.topics import SAMPLES_TOPIC, Sample, sample_to_msg, samples_qos
    rclpy.init()
    node = rclpy.create_node('bench_publisher')
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE) if reliable else samples_qos()
    pub = node.create_publisher(JointState, SAMPLES_TOPIC, qos)
    deadline = time.monotonic() + 30
    while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
        time.sleep(0.01)
    if pub.get_subscription_count() == 0:
        print('ERROR no subscriber', flush=True)
        return
    time.sleep(0.5)   # let the matched subscription settle on both sides (endpoint matching is asynchronous)
    count = int(rate * seconds)
    msg = JointState()
    step = 2_040_816
    start = time.perf_counter()
    for k in range(count):
        sample_to_msg(Sample(1_700_000_000_000_000_000 + k * step, 0.1, 1.5, 0.4, 0.3, k), msg)
        pub.publish(msg)
        if k % 64 == 0:                               # pace in small bursts
            ahead = start + k / rate - time.perf_counter()
            if ahead > 0:
                time.sleep(ahead)
    elapsed = time.perf_counter() - start
    print(f'PUBLISHED {count} {elapsed:.6f}', flush=True)
    time.sleep(1.0)   # keep the writer alive while the last messages are delivered
    node.destroy_node()
    rclpy.try_shutdown()


def run_rate(rate: float, seconds: float, reliable: bool, work: Path, domain_id: int, queue_depth: int) -> dict:
    import numpy as np

    from aeropend_core.io.bag import read_samples
    bag = work / f'bench_{int(rate)}{"_rel" if reliable else ""}'
    env = local_ros_environment(domain_id=domain_id)
    recorder = subprocess.Popen([sys.executable, '-m', 'aeropend_ros.recorder_node', '--ros-args',
                                 '-p', f'output:={bag}', '-p', 'topics:=[/aeropend/samples]',
                                 '-p', "include_regex:=''", '-p', f'queue_depth:={queue_depth}'],
                                env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    pub = subprocess.run([sys.executable, __file__, '--role', 'publisher', '--rate', str(rate),
                          '--seconds', str(seconds)] + (['--reliable'] if reliable else []),
                         env=env, cwd=ROOT, capture_output=True, text=True, timeout=seconds * 10 + 60, check=False)
    cpu = cpu_seconds(recorder.pid)
    recorder.send_signal(signal.SIGINT)
    log, _ = recorder.communicate(timeout=120)
    line = [x for x in pub.stdout.splitlines() if x.startswith('PUBLISHED')]
    if not line:
        raise SystemExit(f'publisher failed:\n{pub.stdout}\n{pub.stderr}\nrecorder:\n{log}')
    published, elapsed = int(line[0].split()[1]), float(line[0].split()[2])
    samples = read_samples(bag)
    sequence = samples['sequence']
    recorded = len(sequence)
    gaps = int(np.sum(np.diff(sequence) > 1)) if recorded > 1 else 0
    return {'rate': rate, 'published': published, 'offered_rate': published / elapsed, 'recorded': recorded,
            'lost': published - recorded, 'gaps': gaps, 'recorder_cpu_per_msg': cpu / max(recorded, 1),
            'bag_bytes': sum(p.stat().st_size for p in bag.glob('*.mcap'))}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--rates', type=float, nargs='+', default=[20000.0, 40000.0], help='offered msg/s')
    parser.add_argument('--seconds', type=float, default=5.0, help='publishing time per rate')
    parser.add_argument('--reliable', action='store_true', help='reliable QoS instead of SensorData (best effort)')
    parser.add_argument('--fastdds-profile', default=None, metavar='XML',
                        help='Fast DDS profile for both processes, e.g. config/fastdds_deep_shm.xml')
    parser.add_argument('--queue-depth', type=int, default=50000,
                        help='recorder queue_depth parameter (subscription history; absorbs CPU stalls)')
    add_json_argument(parser)
    parser.add_argument('--write-cost', action='store_true',
                        help='only measure the cost of closing chunks on time (BagWriter alone, no ROS; ~20 s)')
    parser.add_argument('--role', default='bench', choices=['bench', 'publisher'], help=argparse.SUPPRESS)
    parser.add_argument('--rate', type=float, default=20000.0, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role == 'publisher':
        publisher(args.rate, args.seconds, args.reliable)
        return 0

    import random
    if args.fastdds_profile:
        os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(Path(args.fastdds_profile).resolve())
    work = Path(tempfile.mkdtemp(prefix='bench_recorder_'))
    try:
        cost = print_write_cost(work)
        if args.write_cost:
            write_json(args.json, 'bench_recorder_write_cost', [
                figure(f'bag writing at 490 Hz, chunks closed after {r["chunk_duration_s"]} s: CPU per message',
                       r['cpu_s_per_msg'] * 1e6, 'us/msg', baseline=cost[0]['cpu_s_per_msg'] * 1e6,
                       baseline_name='chunks closed on size only') for r in cost[1:]], runs=cost)
            return 0
        base_rate, base_cpu = baseline(100_000, work / 'baseline')
        print(f'baseline  BagWriter alone: {base_rate:,.0f} msg/s, {base_cpu * 1e6:.1f} us CPU/msg')
        print(f'{"offered":>9} {"achieved":>9} {"published":>9} {"recorded":>9} {"lost":>6} {"gaps":>5} '
              f'{"rec/offer":>9} {"CPU us/msg":>10} {"CPU vs baseline":>15}')
        worst_loss = 0
        results = []
        for rate in args.rates:
            r = run_rate(rate, args.seconds, args.reliable, work, random.randint(101, 200), args.queue_depth)
            worst_loss = max(worst_loss, r['lost'])
            results.append(r)
            print(f'{r["rate"]:9,.0f} {r["offered_rate"]:9,.0f} {r["published"]:9d} {r["recorded"]:9d} '
                  f'{r["lost"]:6d} {r["gaps"]:5d} {r["recorded"] / r["published"]:9.4f} '
                  f'{r["recorder_cpu_per_msg"] * 1e6:10.1f} {r["recorder_cpu_per_msg"] / base_cpu:14.2f}x',
                  flush=True)
        print(f'QoS: {"reliable" if args.reliable else "SensorData (best effort)"}, recorder queue_depth '
              f'{args.queue_depth}, Fast DDS profile {args.fastdds_profile or "default"}; worst loss {worst_loss} '
              f'messages; load average {os.getloadavg()[0]:.1f} '
              f'on {os.cpu_count()} cores')
        figures = []
        for r in results:
            received_rate = r['recorded'] / r['published'] * r['offered_rate']
            # the target: >= 20,000 msg/s recorded without a loss (1 % allowance for the publisher's pacing)
            at_target = r['rate'] == 20000
            figures.append(figure(f'recorder at {r["rate"]:,.0f} msg/s offered: recorded rate', received_rate, 'msg/s',
                                  baseline=r['offered_rate'], baseline_name='achieved publish rate',
                                  ratio_meaning='recorded / published',
                                  target='>= 20,000 msg/s (-1 %), 0 lost' if at_target else '',
                                  met=(r['lost'] == 0 and r['gaps'] == 0 and received_rate >= 19800)
                                  if at_target else None))
            figures.append(figure(f'recorder at {r["rate"]:,.0f} msg/s offered: messages lost', r['lost'], 'messages',
                                  target='0' if r['rate'] == 20000 else '', met=(r['lost'] == 0)
                                  if r['rate'] == 20000 else None))
            figures.append(figure(f'recorder at {r["rate"]:,.0f} msg/s offered: CPU per message',
                                  r['recorder_cpu_per_msg'] * 1e6, 'us/msg', baseline=base_cpu * 1e6,
                                  baseline_name='BagWriter alone (no ROS, no DDS)',
                                  ratio_meaning='recorder / bag writing alone'))
        figures.append(figure('bag writing alone (baseline)', base_rate, 'msg/s'))
        write_json(args.json, 'bench_recorder', figures, runs=results, seconds=args.seconds,
                   qos='reliable' if args.reliable else 'sensor_data', queue_depth=args.queue_depth,
                   fastdds_profile=args.fastdds_profile, baseline={'msg_per_s': base_rate, 'cpu_s_per_msg': base_cpu})
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
