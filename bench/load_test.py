"""Load test: the full node graph on the simulator at 490 Hz for --duration seconds, recording and identifying.

Starts the graph as separate processes, as a user would (the console scripts of the venv, a private
ROS_DOMAIN_ID, ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST):

- ``sim_node``: 490 Hz, real time, the default hidden effect of ``aeropend run`` (angle_offset=0.05), 50 dB,
  ``stop_after`` = --duration (so exactly round(duration / Ts) samples are published, numbered from 0) and
  ``wait_for_subscribers`` = 3 (publishing starts once the recorder, the identification and the excitation listen);
- ``excitation_node``: a Latin-hypercube schedule longer than the run, so the duty keeps stepping until the end;
- ``recorder_node``: everything under /aeropend/ and /diagnostics to an MCAP bag (a temporary folder unless
  --keep-bag);
- ``identification_node``: online weak SINDy + output-error windows (25 s every 5 s by default) in its worker
  process.

Measured while it runs (every --sample-period seconds, from /proc, no extra dependency): resident memory (RSS and
its anonymous part) and CPU time of every process and of its child processes (the identification worker is
reported on its own), and the machine's load average. A listener in this process (rclpy) records /diagnostics and
the identification outputs. After the sim has published its last sample and the identification has reported its
last window, every node gets SIGINT (Ctrl-C: the recorder finalises its bag).

Reported (JSON + markdown summary, and a PNG when matplotlib is available, in --out):

- memory per process: RSS after the warm-up (--warm-up s after start) and at the end of the run, the growth, the
  slope of a least-squares line over the steady part [MB/min] and the peak;
- lost samples: the bag read with ``aeropend_core.io.bag.read_samples`` and, independently, with the ``mcap`` reader
  and a CDR decoder written here: samples recorded vs published, sequence gaps, duplicates, out-of-order; the
  samples the identification node received and missed (its /diagnostics);
- identification keeping up: compute time per window (mean, p95, max), duty ratio compute / hop, latency from the
  window's end (its acquisition stamp) to the estimate's arrival here, windows expected / reported / skipped;
- the sim node's rate over the run from the recorder's receive times (rate, slope, p99 and max inter-arrival
  interval, stamp-to-receive delay).

Usage::

    .venv/bin/python bench/load_test.py                      # 10 min (about 11 min with start-up and analysis)
    .venv/bin/python bench/load_test.py --duration 60        # a short check (about 1.5 min)

Exit status 0 when the run completed and was measured (the verdicts are in the JSON and the summary), 1 with
--strict when a verdict failed, 2 when the graph could not be run.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from aeropend_core.signals.sequence import sequence_report

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from aeropend_ros._ros_env import ensure_ros_environment, local_ros_environment  # noqa: E402
from aeropend_ros.testing import interrupt  # noqa: E402

SAMPLE_TIME = 1.0 / 490.0          # same as aeropend_core.model.parameters.SAMPLE_TIME (checked in main)
SAMPLES_TOPIC = '/aeropend/samples'
FIT_TOPIC = '/aeropend/identification/fit'
IDENTIFICATION_STATUS = 'aeropend: identification'
RECORDER_STATUS = 'recorder_node: bag'
#: Memory is "flat" when the steady-part slope, projected over one hour, stays below this [MB] ...
FLAT_MB_PER_HOUR = 10.0
#: ... or the growth from the warm-up to the end stays below this fraction of the warm-up RSS.
FLAT_FRACTION = 0.02
NODES = ('sim_node', 'excitation_node', 'recorder_node', 'identification_node')


# ------------------------------------------------------------------------------------------------------ /proc
def _children_map() -> dict[int, list[int]]:
    children: dict[int, list[int]] = {}
    for entry in os.scandir('/proc'):
        if not entry.name.isdigit():
            continue
        try:
            text = Path(entry.path, 'stat').read_text()
        except OSError:
            continue
        ppid = int(text.rsplit(')', 1)[1].split()[1])
        children.setdefault(ppid, []).append(int(entry.name))
    return children


def descendants(pid: int, children: dict[int, list[int]]) -> list[int]:
    """All descendants of `pid` (children, grandchildren, ...)."""
    out, todo = [], list(children.get(pid, []))
    while todo:
        child = todo.pop()
        out.append(child)
        todo.extend(children.get(child, []))
    return out


def process_usage(pid: int) -> tuple[float, float, float] | None:
    """(RSS [MB], anonymous RSS [MB], user + system CPU time [s]) of one process, or None when it is gone."""
    try:
        status = Path(f'/proc/{pid}/status').read_text()
        stat = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except OSError:
        return None
    values = {}
    for line in status.splitlines():
        key, _, rest = line.partition(':')
        if key in ('VmRSS', 'RssAnon'):
            values[key] = int(rest.split()[0]) / 1024.0
    cpu = (int(stat[11]) + int(stat[12])) / os.sysconf('SC_CLK_TCK')
    return values.get('VmRSS', 0.0), values.get('RssAnon', 0.0), cpu


def machine_cpu_seconds() -> tuple[float, float]:
    """(busy, total) CPU time of the whole machine [s, summed over CPUs] from /proc/stat."""
    fields = [int(v) for v in Path('/proc/stat').read_text().split('\n', 1)[0].split()[1:]]
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0)
    total = sum(fields[:8])
    return (total - idle) / os.sysconf('SC_CLK_TCK'), total / os.sysconf('SC_CLK_TCK')


def _command_line(pid: int) -> str:
    try:
        return Path(f'/proc/{pid}/cmdline').read_bytes().replace(b'\0', b' ').decode(errors='replace').strip()
    except OSError:
        return ''


# ---------------------------------------------------------------------------------------------------- listener
class Listener:
    """rclpy node in this process: records /diagnostics and the identification's fit messages with arrival times."""

    def __init__(self, domain_id: int) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState

        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node('load_test_listener', context=self.context)
        self.identification: list[dict] = []
        self.recorder: list[dict] = []
        self.fits: list[dict] = []
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, reliable)
        self.node.create_subscription(JointState, FIT_TOPIC, self._on_fit, latched)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True, name='listener')
        self._running = True
        self._thread.start()

    def _spin(self) -> None:
        while self._running:
            try:
                self.executor.spin_once(timeout_sec=0.1)
            except Exception:  # noqa: BLE001 - context shut down while stopping
                return

    def _on_diagnostics(self, msg) -> None:
        now_ns = time.time_ns()
        for status in msg.status:
            entry = {'received_ns': now_ns, 'level': int.from_bytes(bytes(status.level), 'little')
                     if isinstance(status.level, (bytes, bytearray)) else int(status.level),
                     'message': status.message, 'values': {kv.key: kv.value for kv in status.values}}
            if status.name == IDENTIFICATION_STATUS:
                self.identification.append(entry)
            elif status.name == RECORDER_STATUS:
                self.recorder.append(entry)

    def _on_fit(self, msg) -> None:
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self.fits.append({'received_ns': time.time_ns(), 'stamp_ns': stamp_ns,
                          **{name: float(value) for name, value in zip(msg.name, msg.position)}})

    def close(self) -> None:
        import rclpy
        self._running = False
        self._thread.join(timeout=2.0)
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


# ------------------------------------------------------------------------------------------------------- graph
def _executable(name: str) -> list[str]:
    """The console script of the venv (what a user runs), or ``python -m aeropend_ros.<name>``."""
    script = Path(sys.prefix) / 'bin' / name
    return [str(script)] if script.exists() else [sys.executable, '-m', f'aeropend_ros.{name}']


def start_graph(args, domain_id: int, bag_folder: Path, log_folder: Path) -> dict[str, subprocess.Popen]:
    env = local_ros_environment(domain_id=domain_id)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    ros_args = {
        'recorder_node': ['-p', f'output:={bag_folder}', *(a for p in args.recorder_param for a in ('-p', p))],
        'identification_node': ['-p', f'window_s:={float(args.window)!r}', '-p', f'hop_s:={float(args.hop)!r}'],
        # Longer than the run: the duty keeps stepping until the sim stops (exit_when_done false: the load test
        # stops every node itself).
        'excitation_node': ['-p', f'duration:={float(args.duration + 60.0)!r}', '-p', 'seed:=1',
                            '-p', 'exit_when_done:=false'],
        'sim_node': ['-p', f'stop_after:={float(args.duration)!r}', '-p', 'wait_for_subscribers:=3',
                     '-p', f'psnr_db:={float(args.psnr)!r}', '-p', 'seed:=1',
                     '-p', f'effects:=[{",".join(repr(e) for e in args.effect)}]' if args.effect
                     else 'effects:=[\'\']'],
    }
    processes = {}
    for name in ('recorder_node', 'identification_node', 'excitation_node', 'sim_node'):
        log = open(log_folder / f'{name}.log', 'w')      # noqa: SIM115 - closed with the process
        command = _executable(name) + ['--ros-args', *ros_args[name]]
        if name == 'recorder_node' and args.trace_memory:
            command = [sys.executable, str(ROOT / 'bench' / '_traced_node.py'), str(log_folder / 'tracemalloc.txt'),
                       str(args.trace_memory), 'aeropend_ros.recorder_node', '--ros-args', *ros_args[name]]
        processes[name] = subprocess.Popen(command, env=env, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
        log.close()
    return processes


# ------------------------------------------------------------------------------------------------ measurements
def sample_usage(processes: dict[str, subprocess.Popen], t: float) -> dict:
    """One row: per role RSS / anonymous RSS [MB] and CPU [s] (identification_worker = the node's children)."""
    children = _children_map()
    row = {'t': t, 'load_average': os.getloadavg()[0], 'machine_cpu': machine_cpu_seconds(), 'roles': {}}
    for name, process in processes.items():
        own = process_usage(process.pid) if process.poll() is None else None
        if own is None:
            continue
        kids = [(pid, process_usage(pid)) for pid in descendants(process.pid, children)]
        kids = [(pid, usage) for pid, usage in kids if usage is not None]
        if name == 'identification_node':
            # The spawned analysis worker on its own; other children (multiprocessing's resource tracker) count
            # with the node.
            workers = [(pid, usage) for pid, usage in kids if 'spawn_main' in _command_line(pid)]
            others = [usage for pid, usage in kids if pid not in dict(workers)]
            row['roles'][name] = tuple(float(own[i] + sum(u[i] for u in others)) for i in range(3))
            if workers:
                row['roles']['identification_worker'] = tuple(float(sum(u[i] for _, u in workers))
                                                              for i in range(3))
            if kids:
                row.setdefault('child_processes', [f'{pid}: {_command_line(pid)[:100]}' for pid, _ in kids])
        else:
            row['roles'][name] = tuple(float(own[i] + sum(u[i] for _, u in kids)) for i in range(3))
    return row


def memory_report(rows: list[dict], warm_up: float, end_time: float) -> dict:
    """Per role: RSS at warm-up and end, growth, steady slope [MB/min], peak; anonymous RSS likewise; CPU %."""
    roles = sorted({role for row in rows for role in row['roles']})
    report = {}
    for role in roles:
        series = [(row['t'], *row['roles'][role]) for row in rows if role in row['roles'] and row['t'] <= end_time]
        if len(series) < 3:
            continue
        t, rss, anon, cpu = (np.array(column) for column in zip(*series))
        steady = t >= warm_up
        if steady.sum() < 3:
            steady = t >= t[len(t) // 2]
        i0 = int(np.argmax(steady))
        entry = {'samples': int(steady.sum()), 'warm_up_s': float(t[i0]), 'end_s': float(t[-1])}
        late = t >= (t[i0] + t[-1]) / 2
        for label, values in (('rss', rss), ('anon', anon)):
            slope = float(np.polyfit(t[steady], values[steady], 1)[0]) * 60.0
            entry.update({f'{label}_warm_mb': float(values[i0]), f'{label}_end_mb': float(values[-1]),
                          f'{label}_growth_mb': float(values[-1] - values[i0]),
                          f'{label}_slope_mb_per_min': slope, f'{label}_peak_mb': float(values.max())})
            if late.sum() >= 3:
                entry[f'{label}_slope_late_mb_per_min'] = float(np.polyfit(t[late], values[late], 1)[0]) * 60.0
        span = t[-1] - t[i0]
        entry['cpu_percent'] = float(100.0 * (cpu[-1] - cpu[i0]) / span) if span > 0 else float('nan')
        growth_ok = entry['rss_growth_mb'] <= max(FLAT_FRACTION * entry['rss_warm_mb'], 1.0)
        slope_ok = entry['rss_slope_mb_per_min'] * 60.0 <= FLAT_MB_PER_HOUR
        entry['flat'] = bool(growth_ok or slope_ok)
        report[role] = entry
    return report


def read_bag_independently(bag_folder: Path) -> dict[str, np.ndarray]:
    """Sequence, acquisition stamp and receive time of every sample, with the ``mcap`` reader and a CDR decoder
    written here (nothing from aeropend_core.io.bag)."""
    from mcap.reader import make_reader
    sequence, stamp, received = [], [], []
    u32 = struct.Struct('<I')
    for path in sorted(bag_folder.glob('*.mcap')):
        with open(path, 'rb') as stream:
            for _, channel, message in make_reader(stream).iter_messages(topics=[SAMPLES_TOPIC]):
                data = message.data
                if data[:2] != b'\x00\x01':
                    raise ValueError(f'{path.name}: a sample is not little-endian CDR')
                body = memoryview(data)[4:]            # CDR alignment counts from the end of the 4-byte header
                sec, nanosec = struct.unpack_from('<iI', body, 0)
                offset = 8
                length = u32.unpack_from(body, offset)[0]
                offset += 4 + length                   # frame_id (with its NUL)
                offset = (offset + 3) & ~3
                names = u32.unpack_from(body, offset)[0]
                offset += 4
                for _ in range(names):
                    offset = (offset + 3) & ~3
                    offset += 4 + u32.unpack_from(body, offset)[0]
                offset = (offset + 3) & ~3
                count = u32.unpack_from(body, offset)[0]
                offset = (offset + 4 + 7) & ~7
                position = struct.unpack_from(f'<{count}d', body, offset)
                sequence.append(round(position[4]))
                stamp.append(sec * 1_000_000_000 + nanosec)
                received.append(message.log_time)
    order = np.argsort(np.array(received, dtype=np.int64), kind='stable')
    return {'sequence': np.array(sequence, dtype=np.int64)[order], 'stamp_ns': np.array(stamp, dtype=np.int64)[order],
            'receive_time_ns': np.array(received, dtype=np.int64)[order]}


def rate_report(sequence: np.ndarray, stamp_ns: np.ndarray, received_ns: np.ndarray) -> dict:
    """The sim node's rate as the recorder saw it: receive-time rate, slope, intervals, stamp-to-receive delay."""
    from scipy.stats import theilslopes
    seconds = (received_ns - received_ns[0]) * 1e-9
    intervals_ms = np.diff(seconds) * 1e3
    pick = np.linspace(0, sequence.size - 1, min(sequence.size, 2000)).astype(int)
    delay_ms = (received_ns - stamp_ns) * 1e-6
    spacing_ns = np.diff(stamp_ns) - np.diff(sequence) * SAMPLE_TIME * 1e9
    settled = stamp_ns >= stamp_ns[0] + 2_000_000_000       # after the start-up (discovery, first catch-up)
    settled_span = seconds[settled][-1] - seconds[settled][0] if settled.sum() > 1 else float('nan')
    return {'rate_by_receive_hz': float((sequence.size - 1) / seconds[-1]) if seconds[-1] > 0 else float('nan'),
            'rate_by_receive_after_start_hz': float((settled.sum() - 1) / settled_span),
            'rate_by_sequence_hz': float((sequence[-1] - sequence[0]) / seconds[-1]) if seconds[-1] > 0
            else float('nan'),
            'rate_by_slope_hz': float(theilslopes(sequence[pick], seconds[pick])[0]),
            'rate_by_stamps_hz': float((sequence[-1] - sequence[0]) / ((stamp_ns[-1] - stamp_ns[0]) * 1e-9)),
            'interval_p50_ms': float(np.percentile(intervals_ms, 50)),
            'interval_p99_ms': float(np.percentile(intervals_ms, 99)),
            'interval_max_ms': float(intervals_ms.max()),
            'delay_p50_ms': float(np.percentile(delay_ms, 50)), 'delay_p99_ms': float(np.percentile(delay_ms, 99)),
            'delay_max_ms': float(delay_ms.max()),
            'stamp_spacing_error_max_ns': float(np.max(np.abs(spacing_ns))) if spacing_ns.size else 0.0,
            'receive_span_s': float(seconds[-1])}


def identification_report(listener: Listener, args, published: int, first_stamp_ns: int) -> dict:
    """Compute time per window, duty ratio, latency window end -> estimate here, windows expected/reported/skipped."""
    fits = sorted(listener.fits, key=lambda f: f['stamp_ns'])
    statuses = listener.identification
    last_values = statuses[-1]['values'] if statuses else {}
    data_seconds = (published - 1) * SAMPLE_TIME
    expected = int(np.floor((data_seconds - args.window) / args.hop + 1e-9)) + 1 if data_seconds >= args.window \
        else 0
    compute = np.array([f.get('compute_time', np.nan) for f in fits])
    latency = np.array([(f['received_ns'] - f['stamp_ns']) * 1e-9 for f in fits])
    window_reports = [s for s in statuses if 'windows_done' in s['values'] and 'samples' in s['values']]
    not_fitted = [s['message'] for s in window_reports if s['values'].get('compute_time_s') is None]

    def stats(values: np.ndarray) -> dict:
        values = values[np.isfinite(values)]
        if not values.size:
            return {}
        return {'mean': float(values.mean()), 'p50': float(np.percentile(values, 50)),
                'p95': float(np.percentile(values, 95)), 'max': float(values.max()), 'min': float(values.min())}

    lost_per_window = [int(s['values']['lost_samples']) for s in window_reports if 'lost_samples' in s['values']]
    report = {
        'window_s': args.window, 'hop_s': args.hop, 'windows_expected': expected,
        'estimates_published': len(fits), 'windows_reported': len(window_reports),
        'windows_not_fitted': len(not_fitted), 'not_fitted_reasons': sorted(set(not_fitted))[:5],
        'windows_done': int(last_values.get('windows_done', len(fits))),
        'windows_skipped': int(last_values['windows_skipped']) if 'windows_skipped' in last_values else None,
        'compute_time_s': stats(compute), 'duty_ratio': stats(compute / args.hop),
        'latency_s': stats(latency),
        # latency - compute: sample delivery, the window's snapshot, hand-over to the worker and back, publishing
        'latency_minus_compute_s': stats(latency - compute),
        'lost_samples_per_window_max': max(lost_per_window) if lost_per_window else None,
        'fit_percent': stats(np.array([f.get('fit_percent', np.nan) for f in fits])),
    }
    for key in ('samples_received', 'samples_missed'):
        values = [int(s['values'][key]) for s in statuses if key in s['values']]
        report[key] = max(values) if values else None
    report['keeps_up'] = bool(report['windows_skipped'] == 0 and len(fits) + len(not_fitted) >= expected
                              and report['compute_time_s'] and report['compute_time_s']['max'] < args.hop)
    report['per_window'] = [{'window_end_s': (f['stamp_ns'] - first_stamp_ns) * 1e-9,
                             'compute_time_s': f.get('compute_time'),
                             'latency_s': (f['received_ns'] - f['stamp_ns']) * 1e-9,
                             'fit_percent': f.get('fit_percent')} for f in fits]
    return report


# ----------------------------------------------------------------------------------------------------- output
def write_summary(result: dict, path: Path) -> None:
    m, s, i, r = result['memory'], result['samples'], result['identification'], result['sim_rate']
    lines = [f'# Load test: full graph on the simulator, {result["duration_s"]:g} s at 490 Hz',
             '',
             f'{result["date"]}, {result["machine"]}; load average during the run {result["load_average"]["mean"]:.2f}'
             f' (max {result["load_average"]["max"]:.2f}) on {result["cpus"]} CPUs'
             + (' — other jobs were running, so these are loaded-machine figures' if result['load_average']['mean']
                > 1.5 else '') + '.',
             f'The machine was busy {result["machine_busy_cores"]:.2f} cores on average, of which the graph '
             f'used {result["graph_cores"]:.2f}.',
             f'Command: `{result["command"]}`; run time {result["wall_time_s"]:.0f} s.', '',
             '## Memory (RSS) per process', '',
             '| process | RSS at warm-up [MB] | RSS at end [MB] | growth [MB] | steady slope [MB/min] '
             '| second-half slope [MB/min] | peak [MB] | anon growth [MB] | CPU [% of a core] | flat |',
             '| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |']
    for role, e in m.items():
        lines.append(f'| {role} | {e["rss_warm_mb"]:.1f} | {e["rss_end_mb"]:.1f} | {e["rss_growth_mb"]:+.1f} | '
                     f'{e["rss_slope_mb_per_min"]:+.3f} | {e.get("rss_slope_late_mb_per_min", float("nan")):+.3f} | '
                     f'{e["rss_peak_mb"]:.1f} | {e["anon_growth_mb"]:+.1f} | '
                     f'{e["cpu_percent"]:.1f} | {"yes" if e["flat"] else "NO"} |')
    warm = next(iter(m.values()))['warm_up_s'] if m else float('nan')
    lines += ['', f'Warm-up point {warm:.0f} s after start; slope = least-squares line over the rest. '
              f'"flat": growth <= {FLAT_FRACTION:.0%} of the warm-up RSS (at least 1 MB), or the slope projects to '
              f'<= {FLAT_MB_PER_HOUR:g} MB per hour.'
              + (' This run is too short for the memory verdict: the worker is still filling its caches (it is '
                 'flat from ~2 min on); use --duration 600.' if result['duration_s'] < 300 else ''), '',
              '## Samples', '',
              '| reader | published | recorded | missing | gaps | duplicates | out of order |',
              '| --- | ---: | ---: | ---: | ---: | ---: | ---: |']
    for reader in ('read_samples', 'independent'):
        e = s[reader]
        lines.append(f'| {reader} | {e["published"]} | {e["recorded"]} | {e["missing"]} | {e["gaps"]} | '
                     f'{e["duplicates"]} | {e["out_of_order"]} |')
    lines += ['', f'Identification node: {i["samples_received"]} samples received, {i["samples_missed"]} missed '
              '(sequence gaps it saw); recorder: '
              f'{result["recorder"].get("messages_dropped", "?")} messages dropped, '
              f'{result["recorder"].get("samples_lost", "?")} samples lost (its sequence-gap count), queue length max '
              f'{result["recorder"].get("queue_length_max", "?")}.', '',
              '## Identification', '',
              '| windows expected | estimates | not fitted | skipped | compute per window mean / p95 / max [s] '
              '| duty ratio max | latency window end → estimate mean / max [s] |',
              '| ---: | ---: | ---: | ---: | --- | ---: | --- |']
    c, lat, d = i['compute_time_s'], i['latency_s'], i['duty_ratio']
    lines.append(f'| {i["windows_expected"]} | {i["estimates_published"]} | {i["windows_not_fitted"]} | '
                 f'{i["windows_skipped"]} | {c.get("mean", float("nan")):.2f} / {c.get("p95", float("nan")):.2f} / '
                 f'{c.get("max", float("nan")):.2f} | {d.get("max", float("nan")):.2f} | '
                 f'{lat.get("mean", float("nan")):.2f} / {lat.get("max", float("nan")):.2f} |')
    extra = i.get('latency_minus_compute_s') or {}
    lines += ['', f'Windows of {i["window_s"]:g} s every {i["hop_s"]:g} s; keeps up: '
              f'{"yes" if i["keeps_up"] else "NO"}. Latency minus compute time (delivery, hand-over to the worker '
              f'and back, publishing): mean {extra.get("mean", float("nan")) * 1e3:.0f} ms, max '
              f'{extra.get("max", float("nan")) * 1e3:.0f} ms.', '',
              '## Sim node rate (recorder receive times)', '',
              f'{r["rate_by_receive_hz"]:.3f} Hz by receive count ({r["rate_by_receive_after_start_hz"]:.3f} Hz '
              f'after the first 2 s), {r["rate_by_slope_hz"]:.3f} Hz as the slope of '
              f'the counter against receive time; inter-arrival p50 {r["interval_p50_ms"]:.2f} ms, p99 '
              f'{r["interval_p99_ms"]:.2f} ms, max {r["interval_max_ms"]:.1f} ms; stamp-to-receive delay p50 '
              f'{r["delay_p50_ms"]:.2f} ms, p99 {r["delay_p99_ms"]:.2f} ms, max {r["delay_max_ms"]:.1f} ms.', '',
              '## Verdicts', '']
    lines += [f'- {name}: {"pass" if ok else "FAIL"}' for name, ok in result['verdicts'].items()]
    path.write_text('\n'.join(lines) + '\n')


def write_plot(rows: list[dict], identification: dict, path: Path) -> bool:
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    figure, (top, bottom) = plt.subplots(2, 1, figsize=(9, 7), sharex=False)
    roles = sorted({role for row in rows for role in row['roles']})
    for role in roles:
        points = [(row['t'], row['roles'][role][0]) for row in rows if role in row['roles']]
        top.plot(*zip(*points), label=role)
    top.set_xlabel('time since start [s]')
    top.set_ylabel('RSS [MB]')
    top.set_title('Resident memory per process')
    top.legend(fontsize='small')
    top.grid(alpha=0.3)
    windows = identification['per_window']
    if windows:
        ends = [w['window_end_s'] for w in windows]
        bottom.plot(ends, [w['compute_time_s'] for w in windows], 'o-', label='compute time per window')
        bottom.plot(ends, [w['latency_s'] for w in windows], 's-', label='window end → estimate received')
        bottom.axhline(identification['hop_s'], color='k', linestyle='--', label='hop (window period)')
    bottom.set_xlabel('window end [s of acquisition time]')
    bottom.set_ylabel('[s]')
    bottom.set_title('Online identification')
    bottom.legend(fontsize='small')
    bottom.grid(alpha=0.3)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return True


# ------------------------------------------------------------------------------------------------------- main
def _pick_domain() -> int:
    from aeropend_ros.testing import private_domain_id
    return private_domain_id()


def run(args) -> dict:
    from aeropend_core.model.parameters import SAMPLE_TIME as core_sample_time
    assert abs(core_sample_time - SAMPLE_TIME) < 1e-15
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix='aeropend_load_test_'))     # removed after a successful run
    logs = (out if args.keep_bag else work) / 'logs'
    logs.mkdir(exist_ok=True)
    bag_folder = (out if args.keep_bag else work) / 'bag'
    if bag_folder.exists():
        shutil.rmtree(bag_folder)
    domain_id = _pick_domain()
    os.environ['ROS_DOMAIN_ID'] = str(domain_id)
    ensure_ros_environment(local_only=True)
    published = int(round(args.duration / SAMPLE_TIME))
    print(f'load test: {args.duration:g} s at 490 Hz ({published} samples), domain {domain_id}, bag {bag_folder}, '
          f'logs {logs}', flush=True)
    listener = Listener(domain_id)
    started = time.monotonic()
    processes = start_graph(args, domain_id, bag_folder, logs)
    rows = []
    sim_end = None
    exit_codes = {}
    try:
        next_sample = started
        deadline = started + args.duration + args.start_timeout
        while True:
            now = time.monotonic()
            if now >= next_sample:
                rows.append(sample_usage(processes, now - started))
                next_sample += args.sample_period
                if len(rows) % max(1, int(60 / args.sample_period)) == 0:
                    roles = rows[-1]['roles']
                    print(f'  t = {now - started:5.0f} s: RSS ' + ', '.join(f'{k} {v[0]:.0f} MB'
                                                                           for k, v in roles.items())
                          + f'; {len(listener.fits)} estimates', flush=True)
            for name, process in processes.items():
                if name != 'sim_node' and process.poll() is not None:
                    raise RuntimeError(f'{name} exited early with status {process.returncode}; see {logs}/{name}.log')
            if processes['sim_node'].poll() is not None:
                sim_end = now - started
                rows.append(sample_usage(processes, sim_end))
                break
            if now > deadline:
                raise RuntimeError(f'the sim did not finish within {args.duration + args.start_timeout:g} s; '
                                   f'see {logs}/sim_node.log')
            time.sleep(min(0.2, max(0.0, next_sample - time.monotonic())))
        exit_codes['sim_node'] = processes['sim_node'].returncode
        # The window that came due with the last samples is still computing: wait for its report.
        expected = int(np.floor(((published - 1) * SAMPLE_TIME - args.window) / args.hop + 1e-9)) + 1
        settle = time.monotonic() + args.hop + 30.0
        while time.monotonic() < settle:
            reported = [s for s in listener.identification if 'samples' in s['values']]
            if len(reported) >= expected:
                break
            time.sleep(0.2)
        time.sleep(1.0)
    finally:
        for name in ('excitation_node', 'identification_node', 'recorder_node', 'sim_node'):
            if name in processes:
                exit_codes[name] = interrupt(processes[name])
        listener.close()
    wall = time.monotonic() - started
    print(f'graph stopped after {wall:.0f} s (exit codes {exit_codes}); reading the bag', flush=True)

    from aeropend_core.io.bag import read_samples
    ours = read_samples(bag_folder)
    independent = read_bag_independently(bag_folder)
    if not np.array_equal(np.sort(ours['sequence']), np.sort(independent['sequence'])):
        raise RuntimeError('the two readers disagree on the recorded sample counters')
    samples = {'read_samples': sequence_report(ours['sequence'], published),
               'independent': sequence_report(independent['sequence'], published)}
    sim_rate = rate_report(independent['sequence'], independent['stamp_ns'], independent['receive_time_ns'])
    recorder_status = [s['values'] for s in listener.recorder]
    recorder = {}
    if recorder_status:
        recorder = {'messages_written': int(recorder_status[-1].get('messages_written', 0)),
                    'messages_dropped': int(recorder_status[-1].get('messages_dropped', 0)),
                    'samples_lost': int(recorder_status[-1].get('samples_lost', 0)),
                    'queue_length_max': max(int(v.get('queue_length', 0)) for v in recorder_status)}
    identification = identification_report(listener, args, published, int(independent['stamp_ns'].min()))
    end_time = sim_end if sim_end is not None else rows[-1]['t']
    memory = memory_report(rows, min(args.warm_up, end_time / 2), end_time)
    loads = [row['load_average'] for row in rows]
    graph_cpu = sum(e['cpu_percent'] for e in memory.values()) / 100.0
    (busy0, total0), (busy1, total1) = rows[0]['machine_cpu'], rows[-1]['machine_cpu']
    machine_busy = (busy1 - busy0) / (total1 - total0) * (os.cpu_count() or 1) if total1 > total0 else float('nan')
    result = {
        'date': time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime()),
        'machine': f'{os.uname().machine}, {os.cpu_count()} CPUs, Linux {os.uname().release}',
        'cpus': os.cpu_count(), 'command': ' '.join(['.venv/bin/python', 'bench/load_test.py', *sys.argv[1:]]),
        'duration_s': args.duration, 'wall_time_s': wall, 'sim_end_s': sim_end, 'domain_id': domain_id,
        'load_average': {'mean': float(np.mean(loads)), 'max': float(np.max(loads))},
        # CPUs busy over the run (all processes) and the part the graph itself used (steady part), in cores.
        'machine_busy_cores': float(machine_busy), 'graph_cores': float(graph_cpu),
        'exit_codes': exit_codes, 'memory': memory, 'samples': samples, 'sim_rate': sim_rate,
        'recorder': recorder, 'identification': identification,
        'child_processes': next((row['child_processes'] for row in rows if 'child_processes' in row), []),
        'usage': [{'t': row['t'], 'load_average': row['load_average'],
                   **{role: {'rss_mb': v[0], 'anon_mb': v[1], 'cpu_s': v[2]} for role, v in row['roles'].items()}}
                  for row in rows],
    }
    result['verdicts'] = {
        'memory flat (every process)': all(e['flat'] for e in memory.values()),
        'no lost samples in the bag': samples['independent']['missing'] == 0
        and samples['independent']['duplicates'] == 0,
        'identification node missed no samples': identification['samples_missed'] == 0,
        'identification keeps up (no skipped window, compute < hop)': identification['keeps_up'],
        'sim rate within 490 Hz +- 1 %': abs(sim_rate['rate_by_slope_hz'] - 490.0) <= 4.9,
        'nodes exited cleanly on SIGINT': all(code == 0 for code in exit_codes.values()),
    }
    shutil.rmtree(work, ignore_errors=True)
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--duration', type=float, default=600.0, help='seconds of samples at 490 Hz (default 600)')
    parser.add_argument('--out', default=str(ROOT / 'bench' / 'results' / 'load_test'),
                        help='folder for load_test.json, load_test.md and load_test.png')
    parser.add_argument('--json', default=None, help='also write the JSON result here')
    parser.add_argument('--sample-period', type=float, default=5.0, help='seconds between /proc samples')
    parser.add_argument('--warm-up', type=float, default=120.0,
                        help='memory growth is measured from this many seconds after start (at most half the run; '
                             'the identification worker fills its bounded kernel caches over its first ~20 '
                             'windows)')
    parser.add_argument('--window', type=float, default=25.0, help="identification window_s [s]")
    parser.add_argument('--hop', type=float, default=5.0, help='identification hop_s [s]')
    parser.add_argument('--psnr', type=float, default=50.0, help='sim measurement noise [dB]')
    parser.add_argument('--effect', action='append', default=None, metavar='NAME=VALUE',
                        help='hidden sim effect (repeatable; default angle_offset=0.05 like aeropend run)')
    parser.add_argument('--start-timeout', type=float, default=60.0,
                        help='seconds allowed for start-up and discovery on top of the duration')
    parser.add_argument('--keep-bag', action='store_true',
                        help='keep the bag and the node logs in --out (default: a temporary folder, removed after a '
                             'successful run and kept after a failed one)')
    parser.add_argument('--recorder-param', action='append', default=[], metavar='NAME:=VALUE',
                        help='a recorder_node parameter (repeatable), e.g. chunk_size:=65536 for memory experiments')
    parser.add_argument('--trace-memory', type=float, default=0.0, metavar='SECONDS',
                        help='run the recorder under tracemalloc and write, every SECONDS, the source lines whose '
                             'Python allocations grew to <logs>/tracemalloc.txt (use with --keep-bag)')
    parser.add_argument('--strict', action='store_true', help='exit 1 when a verdict fails')
    args = parser.parse_args(argv)
    if args.effect is None:
        args.effect = ['angle_offset=0.05']
    if not args.duration >= 10 or not args.sample_period > 0:
        parser.error('--duration must be >= 10 s and --sample-period positive')
    from aeropend_core.errors import AeropendError
    try:
        result = run(args)
    except (RuntimeError, OSError, AeropendError) as error:
        print(f'load test: error: {error}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print('load test: interrupted; the nodes were stopped, nothing written', file=sys.stderr)
        return 130
    out = Path(args.out)
    (out / 'load_test.json').write_text(json.dumps(result, indent=1))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(result, indent=1))
    write_summary(result, out / 'load_test.md')
    write_plot([{'t': u['t'], 'roles': {k: (v['rss_mb'],) for k, v in u.items() if isinstance(v, dict)}}
                for u in result['usage']], result['identification'], out / 'load_test.png')
    print((out / 'load_test.md').read_text())
    return 1 if args.strict and not all(result['verdicts'].values()) else 0


if __name__ == '__main__':
    sys.exit(main())
