"""Bag reading speed: the ``mcap``-library reader (today's ``read_samples``) against the hand parser it replaced.

Writes a 1-hour recording (``--seconds 3600`` at 490 Hz: 1.76 M JointState samples plus a duty command every 49
samples, the recorder's 1 MiB zstd chunks), then reads its samples with

- ``new``: :func:`aeropend_core.io.bag.read_samples` (records by the ``mcap`` package; each chunk decompressed and
  CRC-checked by the library, its message records split by the self-checked ``struct`` splitter),
- ``library_only``: the same with ``mcap_scan.FAST_MESSAGES = False`` (every chunk through ``breakup_chunk``), and
- ``old``: the same function from the commit before the change (``--baseline``, default ``6e4c844``), which parsed
  the records by hand, loaded from git into a private module,

alternately ``--repeats`` times each, and reports the CPU seconds (``time.process_time``, less sensitive to other
load than wall time) of the best run of each and their ratio, measured in the same run. Both must return the same
arrays. Also measured: the memory the ``mcap`` writer keeps per chunk index until a file is finished (the
reason the old writer replaced a private list), as MB per recorded hour.

Usage::

    nice -n 10 .venv/bin/python bench/bench_bag_read.py --seconds 3600
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from aeropend_core.io import bag as new_bag  # noqa: E402
from aeropend_core.io.bag_writer import BagWriter  # noqa: E402

SAMPLES, DUTY = '/aeropend/samples', '/aeropend/duty_cmd'
TS_NS = 2_040_816
T0_NS = 1_763_700_000_000_000_000


def old_reader(commit: str):
    """The ``aeropend_core.io.bag`` module of ``commit``, imported under a private name."""
    text = subprocess.run(['git', 'show', f'{commit}:aeropend_core/io/bag.py'], cwd=ROOT, check=True,
                          capture_output=True, text=True).stdout
    path = Path(tempfile.mkdtemp()) / 'old_bag.py'
    path.write_text(text)
    spec = importlib.util.spec_from_file_location('old_bag', path)
    module = importlib.util.module_from_spec(spec)
    sys.modules['old_bag'] = module                 # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def write_hour(folder: Path, seconds: float) -> int:
    """A recording of ``seconds`` at 490 Hz, CDR bytes from a template (the layout every sample of one publisher
    has), written by the project's BagWriter."""
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    js = store.types['sensor_msgs/msg/JointState']
    template = bytearray(store.serialize_cdr(js(
        header=store.types['std_msgs/msg/Header'](stamp=store.types['builtin_interfaces/msg/Time'](sec=0, nanosec=0),
                                                  frame_id='aeropend'),
        name=['angle', 'armature_voltage', 'armature_current', 'duty', 'sequence'],
        position=np.zeros(5), velocity=np.zeros(0), effort=np.zeros(0)), js.__msgtype__))
    position, _ = new_bag._joint_state_layout(bytes(template))     # byte offset of position[0]
    duty = bytes(store.serialize_cdr(store.types['std_msgs/msg/Float64'](data=0.5), 'std_msgs/msg/Float64'))
    n = round(seconds * 490)
    writer = BagWriter(folder)
    writer.add_topic(SAMPLES, 'sensor_msgs/msg/JointState', '')
    writer.add_topic(DUTY, 'std_msgs/msg/Float64', '')
    rng = np.random.default_rng(0)
    values = rng.uniform(-1, 1, size=(n, 5))
    values[:, 4] = np.arange(n)
    for k in range(n):
        stamp = T0_NS + k * TS_NS
        template[4:8] = (stamp // 10**9).to_bytes(4, 'little')
        template[8:12] = (stamp % 10**9).to_bytes(4, 'little')
        template[position:position + 40] = values[k].tobytes()
        writer.write(SAMPLES, bytes(template), stamp + 300_000, stamp + 100_000, k + 1)
        if k % 49 == 0:
            writer.write(DUTY, duty, stamp + 200_000)
    writer.finish()
    return n


def chunk_index_memory(chunks: int) -> float:
    """Bytes held by ``chunks`` ChunkIndex objects as the mcap writer keeps them (two channels each)."""
    from mcap.records import ChunkIndex
    tracemalloc.start()
    kept = [ChunkIndex(message_start_time=T0_NS + i, message_end_time=T0_NS + i + 1, chunk_start_offset=i * 9999,
                       chunk_length=9999, message_index_offsets={1: i * 9999 + 1, 2: i * 9999 + 2},
                       message_index_length=99, compression='zstd', compressed_size=9000, uncompressed_size=1 << 20)
            for i in range(chunks)]
    size, _ = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    del kept
    return float(size)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0], allow_abbrev=False)
    parser.add_argument('--seconds', type=float, default=3600.0, help='recorded time [s]')
    parser.add_argument('--repeats', type=int, default=2, help='runs of each reader')
    parser.add_argument('--baseline', default='6e4c844', help='commit whose hand parser is the baseline')
    args = parser.parse_args(argv)
    old = old_reader(args.baseline)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / 'hour'
        start = time.perf_counter()
        n = write_hour(folder, args.seconds)
        size = sum(p.stat().st_size for p in folder.glob('*.mcap'))
        print(f'wrote {n} samples ({size / 1e6:.1f} MB) in {time.perf_counter() - start:.1f} s', flush=True)
        from aeropend_core.io import mcap_scan
        cpu = {'new': [], 'library_only': [], 'old': []}
        results = {}
        for _ in range(args.repeats):
            for name, module in (('new', new_bag), ('library_only', new_bag), ('old', old)):
                mcap_scan.FAST_MESSAGES = name != 'library_only'
                start = time.process_time()
                results[name] = module.read_samples(folder)
                cpu[name].append(time.process_time() - start)
                print(f'{name}: {cpu[name][-1]:.2f} s CPU', flush=True)
        mcap_scan.FAST_MESSAGES = True
        for name in ('new', 'library_only'):
            for key in results['old']:
                np.testing.assert_array_equal(results[name][key], results['old'][key])
        chunks = 0
        from aeropend_core.io.mcap_scan import FileScan, scan_file
        for file in folder.glob('*.mcap'):
            scan = FileScan(file)
            for _ in scan_file(file, scan):
                pass
            chunks += scan.chunks_read
    per_hour = chunks * 3600.0 / args.seconds
    index_bytes = chunk_index_memory(round(per_hour))
    summary = {'samples': n, 'file_mb': round(size / 1e6, 1), 'new_cpu_s': round(min(cpu['new']), 2),
               'library_only_cpu_s': round(min(cpu['library_only']), 2), 'old_cpu_s': round(min(cpu['old']), 2),
               'new_over_old': round(min(cpu['new']) / min(cpu['old']), 2),
               'library_only_over_old': round(min(cpu['library_only']) / min(cpu['old']), 2),
               'same_arrays': True, 'chunks_per_hour': round(per_hour),
               'chunk_index_mb_per_hour': round(index_bytes / 1e6, 2)}
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
