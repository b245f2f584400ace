"""MCAP bags without ROS: writer -> two independent readers (rosbags, mcap_ros2) and our own; splits; kills; repair.

CDR bytes are produced here by a hand-written encoder (a third implementation), so a bug shared by the bag writer
and a reader cannot hide.
"""
from __future__ import annotations

import contextlib
import os
import signal
import struct
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml

from aeropend_core.io.bag import read_messages, read_samples
from aeropend_core.io.bag_recover import recover_bag
from aeropend_core.io.bag_writer import BagWriter
from aeropend_core.io.mcap_format import msg_file_loader, msg_type_hash, offered_qos, ros2msg_definition
from aeropend_core.errors import AeropendError

ROOT = Path(__file__).resolve().parents[1]
PREFIXES = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p] + [sys.prefix]
LOAD_MSG = msg_file_loader(PREFIXES)
NAMES = ['angle', 'armature_voltage', 'armature_current', 'duty', 'sequence']
TS_NS = 2_040_816                        # 1/490 s in ns
T0_NS = 1_763_700_000_123_456_789        # an epoch stamp with a non-zero nanosecond part
SAMPLES, DUTY = '/aeropend/samples', '/aeropend/duty_cmd'
JOINT_STATE, FLOAT64 = 'sensor_msgs/msg/JointState', 'std_msgs/msg/Float64'
#: the `aeropend` command, run as a fresh process
AEROPEND = [sys.executable, '-c', 'import sys; from aeropend_core.cli import main; sys.exit(main())']


def cdr_joint_state(stamp_ns: int, position: list[float], frame_id: str = 'aeropend',
                    names: list[str] = NAMES) -> bytes:
    """JointState as little-endian CDR (encapsulation 00 01 00 00), empty velocity and effort."""
    out = bytearray(b'\x00\x01\x00\x00')

    def align(n: int) -> None:
        out.extend(b'\x00' * (-(len(out) - 4) % n))

    def string(text: str) -> None:
        align(4)
        raw = text.encode() + b'\x00'
        out.extend(struct.pack('<I', len(raw)) + raw)

    out.extend(struct.pack('<iI', *divmod(stamp_ns, 1_000_000_000)))
    string(frame_id)
    align(4)
    out.extend(struct.pack('<I', len(names)))
    for name in names:
        string(name)
    align(4)
    out.extend(struct.pack('<I', len(position)))
    align(8)
    out.extend(struct.pack(f'<{len(position)}d', *position))
    for _ in range(2):                       # velocity, effort: empty
        align(4)
        out.extend(struct.pack('<I', 0))
    return bytes(out)


def cdr_float64(value: float) -> bytes:
    return b'\x00\x01\x00\x00' + struct.pack('<d', value)


def sample_values(k: int) -> list[float]:
    """Known, distinct values of sample k: angle, Va, Ia, duty, sequence."""
    return [0.001 * k - 0.5, 1.0 + 0.0001 * k, 0.25 + 1e-5 * k, (k % 100) / 100.0, float(k)]


def write_bag(folder: Path, n: int, **writer_options) -> BagWriter:
    writer = BagWriter(folder, **writer_options)
    writer.add_topic(SAMPLES, JOINT_STATE, ros2msg_definition(JOINT_STATE, LOAD_MSG),
                     [offered_qos('best_effort', depth=5)], msg_type_hash(JOINT_STATE, PREFIXES))
    writer.add_topic(DUTY, FLOAT64, ros2msg_definition(FLOAT64, LOAD_MSG), [offered_qos('reliable', depth=10)],
                     msg_type_hash(FLOAT64, PREFIXES))
    for k in range(n):
        stamp = T0_NS + k * TS_NS
        writer.write(SAMPLES, cdr_joint_state(stamp, sample_values(k)), log_time_ns=stamp + 300_000,
                     publish_time_ns=stamp + 100_000, sequence=k + 1)
        if k % 49 == 0:
            writer.write(DUTY, cdr_float64(k / n), log_time_ns=stamp + 200_000)
    return writer


def rosbags_samples(folder: Path) -> tuple[list[int], np.ndarray, dict]:
    """(stamps ns, positions, {topic: count}) read with the rosbags library from a bag folder."""
    from rosbags.highlevel import AnyReader
    stamps, positions, counts = [], [], {}
    with AnyReader([folder]) as reader:
        for connection in reader.connections:
            counts[connection.topic] = connection.msgcount
        for connection, _, raw in reader.messages():
            if connection.topic == SAMPLES:
                msg = reader.deserialize(raw, connection.msgtype)
                stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
                positions.append(list(msg.position))
                assert list(msg.name) == NAMES and msg.header.frame_id == 'aeropend'
                assert len(msg.velocity) == 0 and len(msg.effort) == 0
    return stamps, np.array(positions), counts


def mcap_ros2_samples(folder: Path) -> tuple[list[int], np.ndarray, list[int]]:
    """(stamps ns, positions, log times) decoded by mcap_ros2 from every file of the folder in split order."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    stamps, positions, log_times = [], [], []
    files = sorted(folder.glob('*.mcap'), key=lambda p: int(p.stem.rsplit('_', 1)[1]))
    for file in files:
        with open(file, 'rb') as stream:
            reader = make_reader(stream, decoder_factories=[DecoderFactory()])
            for _, channel, message, msg in reader.iter_decoded_messages(topics=[SAMPLES]):
                stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
                positions.append(list(msg.position))
                log_times.append(message.log_time)
    return stamps, np.array(positions), log_times


def test_round_trip_with_two_independent_readers(tmp_path):
    n = 3000
    folder = tmp_path / 'run1'
    writer = write_bag(folder, n, chunk_size=32 * 1024)
    writer.finish()
    writer.finish()                                             # idempotent
    with pytest.raises(AeropendError, match='finished'):
        writer.write(SAMPLES, b'', 0)

    expected = np.array([sample_values(k) for k in range(n)])
    expected_stamps = [T0_NS + k * TS_NS for k in range(n)]
    n_duty = len(range(0, n, 49))

    stamps, positions, counts = rosbags_samples(folder)
    assert stamps == expected_stamps
    np.testing.assert_array_equal(positions, expected)
    assert counts == {SAMPLES: n, DUTY: n_duty}

    stamps2, positions2, log_times = mcap_ros2_samples(folder)
    assert stamps2 == expected_stamps
    np.testing.assert_array_equal(positions2, expected)
    assert log_times == [s + 300_000 for s in expected_stamps]   # log time = receive time, integer ns

    ours = read_samples(folder)
    np.testing.assert_array_equal(ours['sequence'], np.arange(n))
    np.testing.assert_array_equal(ours['angle'], expected[:, 0])
    np.testing.assert_array_equal(ours['armature_current'], expected[:, 2])
    np.testing.assert_array_equal(ours['stamp_ns'], expected_stamps)
    np.testing.assert_allclose(np.diff(ours['time']), TS_NS * 1e-9, rtol=1e-9)
    assert ours['time'][0] == 0.0
    # the single .mcap file opens on its own too
    single = read_samples(folder / 'run1_0.mcap')
    np.testing.assert_array_equal(single['angle'], ours['angle'])


def test_other_topics_are_read_in_the_samples_pass_as_read_messages_gives_them(tmp_path):
    """read_samples(..., others=): a closed-loop record's control telemetry comes out of the one pass over the file,
    the same bytes in the same order as read_messages gives them (s24: load_closed_loop read the file twice)."""
    n = 2000
    folder = tmp_path / 'run1'
    write_bag(folder, n, chunk_size=16 * 1024).finish()
    duty: list[bytes] = []
    ours = read_samples(folder, others={DUTY: duty})
    assert duty == [message.data for message in read_messages(folder, [DUTY])]
    assert len(duty) == len(range(0, n, 49)) and duty[1] == cdr_float64(49 / n)
    np.testing.assert_array_equal(ours['angle'], read_samples(folder)['angle'])


def test_joint_state_store_decodes_as_the_jazzy_store(tmp_path):
    """The bag readers decode JointState with a store of its three types only (s25: the whole Jazzy store cost
    0.15-0.4 s of every bag read); its definitions are Jazzy's, and a sample decodes to the same fields."""
    from rosbags.typesys import Stores, get_typestore

    from aeropend_core.io.bag import joint_state_store
    jazzy, ours = get_typestore(Stores.ROS2_JAZZY), joint_state_store()
    for name in ('builtin_interfaces/msg/Time', 'std_msgs/msg/Header', 'sensor_msgs/msg/JointState'):
        assert ours.fielddefs[name] == jazzy.fielddefs[name]
    folder = tmp_path / 'run1'
    write_bag(folder, 50).finish()
    data = next(iter(read_messages(folder, [SAMPLES]))).data
    a, b = (store.deserialize_cdr(data, 'sensor_msgs/msg/JointState') for store in (jazzy, ours))
    assert (a.header.stamp.sec, a.header.stamp.nanosec, a.header.frame_id, list(a.name)) == \
        (b.header.stamp.sec, b.header.stamp.nanosec, b.header.frame_id, list(b.name))
    np.testing.assert_array_equal(a.position, b.position)
    assert list(a.position) == sample_values(0)


def test_file_follows_rosbag2_conventions(tmp_path):
    folder = tmp_path / 'conv'
    write_bag(folder, 200).finish()
    from mcap.reader import make_reader
    with open(folder / 'conv_0.mcap', 'rb') as stream:
        reader = make_reader(stream)
        header = reader.get_header()
        summary = reader.get_summary()
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert header.profile == 'ros2'
    schemas = {s.name: s for s in summary.schemas.values()}
    assert set(schemas) == {JOINT_STATE, FLOAT64}
    text = schemas[JOINT_STATE].data.decode()
    assert schemas[JOINT_STATE].encoding == 'ros2msg'
    assert text.startswith(LOAD_MSG(JOINT_STATE))
    assert '\n' + '=' * 80 + '\nMSG: std_msgs/Header\n' in text
    assert '\n' + '=' * 80 + '\nMSG: builtin_interfaces/Time\n' in text
    assert len(summary.chunk_indexes) >= 1 and {c.compression for c in summary.chunk_indexes} == {'zstd'}
    for channel in summary.channels.values():
        assert channel.message_encoding == 'cdr'
        assert channel.metadata['topic_type_hash'].startswith('RIHS01_')
        qos = yaml.safe_load(channel.metadata['offered_qos_profiles'])
        assert qos[0]['reliability'] == ('best_effort' if channel.topic == SAMPLES else 'reliable')
    assert 'serialized_metadata' in metadata['rosbag2']
    info = yaml.safe_load((folder / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['version'] == 9 and info['storage_identifier'] == 'mcap'
    assert info['relative_file_paths'] == ['conv_0.mcap']
    assert info['message_count'] == 200 + len(range(0, 200, 49))
    # first message: the duty command logged at T0 + 200 us; last: sample 199 logged at its stamp + 300 us
    assert info['starting_time']['nanoseconds_since_epoch'] == T0_NS + 200_000
    assert info['duration']['nanoseconds'] == 199 * TS_NS + 100_000


def test_dependencies_of_nested_types():
    text = ros2msg_definition('diagnostic_msgs/msg/DiagnosticArray', LOAD_MSG)
    headers = [line for line in text.splitlines() if line.startswith('MSG: ')]
    assert headers == ['MSG: std_msgs/Header', 'MSG: builtin_interfaces/Time', 'MSG: diagnostic_msgs/DiagnosticStatus',
                       'MSG: diagnostic_msgs/KeyValue']
    with pytest.raises(AeropendError, match='no definition'):
        ros2msg_definition('nonexistent_msgs/msg/Nothing', LOAD_MSG)


@pytest.mark.parametrize('split', [{'max_file_bytes': 20_000}, {'max_file_duration': 1.0}])
def test_split_files_read_as_one_bag(tmp_path, split):
    n = 2000                                                      # 4.1 s of samples
    folder = tmp_path / 'split'
    writer = write_bag(folder, n, chunk_size=8 * 1024, **split)
    writer.finish()
    files = sorted(folder.glob('*.mcap'))
    assert len(files) >= 3
    info = yaml.safe_load((folder / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['relative_file_paths'] == [f'split_{i}.mcap' for i in range(len(files))]
    assert sum(f['message_count'] for f in info['files']) == info['message_count']
    if 'max_file_duration' in split:
        for entry in info['files']:
            assert entry['duration']['nanoseconds'] < 1_000_000_000
    stamps, _, counts = rosbags_samples(folder)
    assert stamps == [T0_NS + k * TS_NS for k in range(n)] and counts[SAMPLES] == n
    stamps2, _, _ = mcap_ros2_samples(folder)
    assert stamps2 == stamps
    np.testing.assert_array_equal(read_samples(folder)['sequence'], np.arange(n))


KILLED_WRITER = textwrap.dedent('''
    import json, os, sys, time
    sys.path.insert(0, {tests!r})
    from test_bag import write_bag, SAMPLES, DUTY, cdr_joint_state, cdr_float64, sample_values, T0_NS, TS_NS
    from pathlib import Path
    writer = write_bag(Path({folder!r}), 0, chunk_size=16 * 1024)
    file = writer.paths[0]
    size, samples_on_disk = os.path.getsize(file), 0
    for k in range({n}):                       # as write_bag, watching the file: it grows when a chunk is written
        stamp = T0_NS + k * TS_NS
        writer.write(SAMPLES, cdr_joint_state(stamp, sample_values(k)), log_time_ns=stamp + 300_000,
                     publish_time_ns=stamp + 100_000, sequence=k + 1)
        if k % 49 == 0:
            writer.write(DUTY, cdr_float64(k / {n}), log_time_ns=stamp + 200_000)
        if os.path.getsize(file) != size:
            size, samples_on_disk = os.path.getsize(file), k + 1
    print(json.dumps({{'written': writer.message_count, 'samples_on_disk': samples_on_disk,
                      'writer_says': writer.messages_on_disk_by_topic().get(SAMPLES, 0)}}), flush=True)
    time.sleep(60)                             # not finished: killed while recording
''')


def mcap_stream_count(file: Path, topic: str = SAMPLES) -> int:
    """Messages on `topic` of a (possibly cut) .mcap file read record by record by the mcap library's stream reader
    (an independent reader), up to where the file is cut."""
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader
    channels, count = {}, 0
    with open(file, 'rb') as stream:
        try:
            for record in StreamReader(stream).records:
                if isinstance(record, Channel):
                    channels[record.id] = record.topic
                elif isinstance(record, Message) and channels.get(record.channel_id) == topic:
                    count += 1
        except Exception:  # noqa: BLE001 - the cut record at the end (struct.error, EndOfFile...)
            pass
    return count


def test_killed_recording_readable_to_last_chunk_and_recovered(tmp_path):
    """SIGKILL while samples wait in an unfinished chunk: exactly the samples of the complete chunks are read back
    (counted independently from the file's growth while writing), by our reader and the mcap stream reader; then
    `aeropend bag-recover` makes a bag that rosbags and mcap_ros2 open."""
    import json
    folder, n = tmp_path / 'killed', 1500
    child = subprocess.Popen([sys.executable, '-c', KILLED_WRITER.format(tests=str(ROOT / 'tests'),
                                                                         folder=str(folder), n=n)],
                             stdout=subprocess.PIPE, text=True, cwd=ROOT)
    report = json.loads(child.stdout.readline())
    child.send_signal(signal.SIGKILL)
    child.wait(10)
    child.stdout.close()
    assert report['written'] == n + len(range(0, n, 49))
    on_disk = report['samples_on_disk']
    # the kill hit mid-chunk: samples were waiting in the unfinished chunk (16 KiB ~ 80 samples)
    assert 0 < on_disk < n and n - on_disk < 100, report
    assert report['writer_says'] == on_disk, 'BagWriter.messages_on_disk disagrees with the file growth'

    with pytest.warns(UserWarning, match='bag-recover'):
        partial = read_samples(folder)
    kept = len(partial['sequence'])
    # every sample of a complete chunk survives, in order, and only the unfinished chunk is lost: no fewer, no more
    assert kept == on_disk, (kept, report)
    np.testing.assert_array_equal(partial['sequence'], np.arange(kept))
    assert mcap_stream_count(folder / 'killed_0.mcap') == kept
    with pytest.raises(AeropendError, match='incomplete'):
        read_samples(folder, on_incomplete='raise')

    result = subprocess.run([*AEROPEND, 'bag-recover', str(folder)], check=False,
                            capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert result.returncode == 0, result.stderr
    assert 'repaired killed_0.mcap' in result.stdout
    assert 'the original is unchanged' in result.stdout
    with pytest.warns(UserWarning, match='bag-recover'):      # the original is left as it was
        assert len(read_samples(folder)['sequence']) == kept
    folder = folder.with_name('killed_recovered')

    with warnings.catch_warnings():
        warnings.simplefilter('error')
        repaired = read_samples(folder, on_incomplete='raise')
    np.testing.assert_array_equal(repaired['sequence'], partial['sequence'])
    stamps, _, counts = rosbags_samples(folder)
    assert len(stamps) == kept and counts[SAMPLES] == kept
    stamps2, _, _ = mcap_ros2_samples(folder)
    assert stamps2 == stamps
    info = yaml.safe_load((folder / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['topics_with_message_count'][0]['message_count'] == kept


@contextlib.contextmanager
def small_disk(tmp_path: Path, free_bytes: int):
    """A folder on which writing stops with an OSError after about `free_bytes`, like a full disk.

    As root (and where mounting is allowed) a tmpfs of that size is mounted on it (ENOSPC, 'No space left on
    device'), unmounted afterwards. Otherwise the writing child process gets RLIMIT_FSIZE = `free_bytes` (EFBIG,
    'File too large', per file). Yields ``(folder, preexec_fn for the child or None, description of the method)``.
    """
    import resource
    import shutil
    folder = tmp_path / 'small_disk'
    folder.mkdir()
    if os.geteuid() == 0 and shutil.which('mount'):
        size = max(free_bytes, 64 * 1024)
        mounted = subprocess.run(['mount', '-t', 'tmpfs', '-o', f'size={size}', 'tmpfs', str(folder)],
                                 capture_output=True, text=True, check=False)
        if mounted.returncode == 0:
            try:
                yield folder, None, f'tmpfs of {size} bytes (ENOSPC)'
            finally:
                subprocess.run(['umount', '-l', str(folder)], capture_output=True, check=False)
            return

    def limit_file_size() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (free_bytes, free_bytes))
    yield folder, limit_file_size, f'RLIMIT_FSIZE of {free_bytes} bytes (EFBIG; mounting a tmpfs was not possible)'


FULL_DISK_WRITER = textwrap.dedent('''
    import json, os, sys
    sys.path.insert(0, {tests!r})
    from test_bag import write_bag, SAMPLES, cdr_joint_state, sample_values, T0_NS, TS_NS
    from aeropend_core.errors import AeropendError
    from pathlib import Path
    writer = write_bag(Path({folder!r}), 0, chunk_size=8 * 1024)
    file = writer.paths[0]
    size, samples_on_disk, error = os.path.getsize(file), 0, ''
    try:
        for k in range(10**6):
            stamp = T0_NS + k * TS_NS
            writer.write(SAMPLES, cdr_joint_state(stamp, sample_values(k)), log_time_ns=stamp)
            if os.path.getsize(file) != size:
                size, samples_on_disk = os.path.getsize(file), k + 1
        writer.finish()
    except AeropendError as failure:
        error = str(failure)
        writer.finish()                        # after a failure: leaves the file as it is, raises nothing
    print(json.dumps({{'error': error, 'samples_on_disk': samples_on_disk, 'attempted': k + 1,
                      'writer_says': writer.messages_on_disk}}), flush=True)
''')


def test_full_disk_stops_with_a_clear_error_and_keeps_every_complete_chunk(tmp_path):
    """The plain core writer on a full disk: AeropendError naming the problem and bag-recover, the earlier chunks
    intact (our reader, the mcap stream reader), and bag-recover finalises the bag once there is room."""
    import json
    import shutil
    with small_disk(tmp_path, 96 * 1024) as (disk, preexec, how):
        print(f'full disk simulated with {how}')
        folder = disk / 'full'
        result = subprocess.run([sys.executable, '-c', FULL_DISK_WRITER.format(tests=str(ROOT / 'tests'),
                                                                               folder=str(folder))],
                                capture_output=True, text=True, cwd=ROOT, timeout=120, preexec_fn=preexec,
                                check=False)
        assert result.returncode == 0 and 'Traceback' not in result.stderr, (how, result.stderr)
        report = json.loads(result.stdout)
        assert ('No space left on device' in report['error'] or 'File too large' in report['error']), (how, report)
        assert 'bag-recover' in report['error'] and 'complete chunks are kept' in report['error'], report
        on_disk = report['samples_on_disk']
        assert 0 < on_disk < report['attempted'] and report['writer_says'] == on_disk, (how, report)
        # everything that reached the disk before the failure reads back, exactly
        with pytest.warns(UserWarning, match='incomplete'):
            partial = read_samples(folder)
        np.testing.assert_array_equal(partial['sequence'], np.arange(on_disk))
        assert mcap_stream_count(folder / 'full_0.mcap') == on_disk
        # repairing on the full disk itself fails cleanly (the cut file untouched) ...
        before = (folder / 'full_0.mcap').read_bytes()
        if preexec is None:
            filler = disk / 'filler'
            with open(filler, 'wb') as stream, contextlib.suppress(OSError):
                stream.write(b'x' * 256 * 1024)             # whatever room was left is now taken
            with pytest.raises(AeropendError, match='cannot repair'):
                recover_bag(folder)
            assert (folder / 'full_0.mcap').read_bytes() == before
            assert not list(folder.glob('*.recovering'))
        # ... and works once there is room: here, a copy on a disk with space
        copy = tmp_path / 'copied'
        shutil.copytree(folder, copy)
    result = subprocess.run([*AEROPEND, 'bag-recover', str(copy)], check=False, capture_output=True, text=True,
                            cwd=ROOT, timeout=60)
    assert result.returncode == 0, result.stderr
    stamps, _, counts = rosbags_samples(copy.with_name('copied_recovered'))
    assert counts[SAMPLES] == on_disk and stamps == [T0_NS + k * TS_NS for k in range(on_disk)]


def test_bad_files_give_clear_errors(tmp_path):
    garbage = tmp_path / 'garbage.mcap'
    garbage.write_bytes(b'this is not a bag' * 100)
    with pytest.raises(AeropendError, match='not an MCAP file'):
        read_samples(garbage)
    empty = tmp_path / 'empty.mcap'
    empty.write_bytes(b'')
    with pytest.raises(AeropendError, match='not an MCAP file'):
        read_samples(empty)
    with pytest.raises(AeropendError, match='does not exist'):
        read_samples(tmp_path / 'missing')
    (tmp_path / 'nobag').mkdir()
    with pytest.raises(AeropendError, match='no .mcap file'):
        read_samples(tmp_path / 'nobag')

    # a file cut right after its header holds no sample: the error says so
    write_bag(tmp_path / 'full', 500, chunk_size=4096).finish()
    data = (tmp_path / 'full' / 'full_0.mcap').read_bytes()
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(data[:60])
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        with pytest.raises(AeropendError, match='no /aeropend/samples message .* before it is cut short'):
            read_samples(cut)
    # corrupted bytes in the middle: read up to the damaged chunk, or refuse when asked to be strict
    from mcap.reader import make_reader
    with open(tmp_path / 'full' / 'full_0.mcap', 'rb') as stream:
        chunks = sorted(make_reader(stream).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert len(chunks) >= 4
    damaged = bytearray(data)
    third = chunks[2]
    inside = third.chunk_start_offset + third.chunk_length - 32          # inside its compressed data
    damaged[inside:inside + 16] = bytes(b ^ 0xFF for b in damaged[inside:inside + 16])
    bad = tmp_path / 'damaged.mcap'
    bad.write_bytes(bytes(damaged))
    # corrupted bytes in one chunk: that chunk is skipped, the chunks after it are read, the loss is stated
    from aeropend_core.io.bag import SampleDamage
    found: list[SampleDamage] = []
    with pytest.warns(UserWarning, match='is damaged.*chunk unreadable'):
        rest = read_samples(bad, damage=found)
    in_third = [m.sequence for m in read_messages(tmp_path / 'full', topics=[SAMPLES])
                if third.message_start_time <= m.log_time_ns <= third.message_end_time]
    expected = np.setdiff1d(np.arange(500), np.asarray(in_third) - 1)      # MCAP sequence = k + 1
    assert len(in_third) > 0
    np.testing.assert_array_equal(rest['sequence'], expected)
    lost = [d for d in found if d.damage.lost]
    assert len(lost) == 1 and lost[0].samples == len(in_third), [d.line() for d in found]
    assert lost[0].t_start < lost[0].t_stop and f'{lost[0].samples} sample(s) lost between' in lost[0].line()
    with pytest.raises(AeropendError, match='damaged'):
        read_samples(bad, on_incomplete='raise')

    # other topics: right error for the wrong type
    with pytest.raises(AeropendError, match='not sensor_msgs/msg/JointState'):
        read_samples(tmp_path / 'full', topic=DUTY)
    assert sum(1 for m in read_messages(tmp_path / 'full', topics=[DUTY])) == len(range(0, 500, 49))

    with pytest.raises(AeropendError, match='already exists'):
        BagWriter(tmp_path / 'full')
    with pytest.raises(AeropendError, match='compression'):
        BagWriter(tmp_path / 'new', compression='gzip')
    result = subprocess.run([*AEROPEND, 'bag-recover', str(garbage)], check=False,
                            capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert result.returncode == 2 and 'not an MCAP file' in result.stderr and 'Traceback' not in result.stderr


def test_recover_leaves_intact_bag_alone(tmp_path):
    write_bag(tmp_path / 'ok', 300).finish()
    before = (tmp_path / 'ok' / 'ok_0.mcap').read_bytes()
    report = recover_bag(tmp_path / 'ok')
    assert report.repaired == [] and len(report.intact) == 1
    assert (tmp_path / 'ok' / 'ok_0.mcap').read_bytes() == before
    assert report.message_count == 300 + len(range(0, 300, 49))


def test_load_recording_accepts_bags(tmp_path):
    """`aeropend identify/diagnose` load recordings through load_recording: a bag folder or .mcap works."""
    from aeropend_core.io.recording import load_recording
    write_bag(tmp_path / 'rec', 600).finish()
    for path in (tmp_path / 'rec', tmp_path / 'rec' / 'rec_0.mcap'):
        recording = load_recording(path)
        assert len(recording) == 600
        np.testing.assert_allclose(np.diff(recording.time), TS_NS * 1e-9, rtol=1e-9)
        np.testing.assert_array_equal(recording.signal('angle'), [sample_values(k)[0] for k in range(600)])
        np.testing.assert_array_equal(recording.signal('armature_voltage'), [sample_values(k)[1] for k in range(600)])
        np.testing.assert_array_equal(recording.signal('duty'), [sample_values(k)[3] for k in range(600)])


def test_samples_found_by_name_whatever_the_layout(tmp_path):
    """Messages whose frame_id, name order or extra channels differ are decoded by name, in recording order."""
    writer = BagWriter(tmp_path / 'mixed')
    writer.add_topic(SAMPLES, JOINT_STATE, ros2msg_definition(JOINT_STATE, LOAD_MSG))
    order = [3, 0, 4, 1, 2]
    for k in range(300):
        values = sample_values(k)
        stamp = T0_NS + k * TS_NS
        if k % 3 == 1:       # permuted channels
            data = cdr_joint_state(stamp, [values[i] for i in order], names=[NAMES[i] for i in order])
        elif k % 3 == 2:     # another frame id and one extra channel
            data = cdr_joint_state(stamp, [*values, 42.0], frame_id='rig_b', names=[*NAMES, 'extra'])
        else:
            data = cdr_joint_state(stamp, values)
        writer.write(SAMPLES, data, stamp)
    writer.finish()
    samples = read_samples(tmp_path / 'mixed')
    expected = np.array([sample_values(k) for k in range(300)])
    for column, name in enumerate(NAMES):
        np.testing.assert_array_equal(samples[name], expected[:, column])
    np.testing.assert_array_equal(samples['stamp_ns'], [T0_NS + k * TS_NS for k in range(300)])


@pytest.mark.parametrize('compression', ['lz4', 'none'])
def test_other_compressions_read_by_both_readers(tmp_path, compression):
    folder = tmp_path / f'c_{compression}'
    write_bag(folder, 400, chunk_size=8 * 1024, compression=compression).finish()
    from mcap.reader import make_reader
    with open(folder / f'c_{compression}_0.mcap', 'rb') as stream:
        used = {c.compression for c in make_reader(stream).get_summary().chunk_indexes}
    assert used == {'' if compression == 'none' else compression}
    stamps, _, counts = rosbags_samples(folder)
    assert stamps == [T0_NS + k * TS_NS for k in range(400)] and counts[SAMPLES] == 400
    assert mcap_ros2_samples(folder)[0] == stamps
    np.testing.assert_array_equal(read_samples(folder)['sequence'], np.arange(400))


LIVE_WRITER = textwrap.dedent('''
    import json, sys
    sys.path.insert(0, {tests!r})
    from test_bag import write_bag, SAMPLES, cdr_joint_state
    from pathlib import Path
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.simulate import simulate
    run = simulate(lhc_schedule(12.0, seed=3).duty(duration=12.0), seed=3)
    columns = run.columns(with_truth=False)
    writer = write_bag(Path({folder!r}), 0, chunk_size=16 * 1024)
    for k in range(len(columns['t'])):
        stamp = 1_763_700_000_000_000_000 + round(columns['t'][k] * 1e9)
        values = [columns[name][k] for name in ('angle', 'armature_voltage', 'armature_current', 'duty')]
        writer.write(SAMPLES, cdr_joint_state(stamp, [*values, float(k)]), log_time_ns=stamp, sequence=k + 1)
    print(json.dumps({{'on_disk': writer.messages_on_disk_by_topic()[SAMPLES], 'written': k + 1}}), flush=True)
    if sys.stdin.readline().strip() == 'finish':   # still recording until told
        writer.finish()
        print('finished', flush=True)
''')


def start_live_writer(folder: Path) -> tuple[subprocess.Popen, dict]:
    """A process recording a 12 s simulated run into `folder` that stops before finishing (its chunk in progress
    not on disk) and waits for a line on its standard input: 'finish' finalises the bag."""
    import json
    child = subprocess.Popen([sys.executable, '-c', LIVE_WRITER.format(tests=str(ROOT / 'tests'),
                                                                       folder=str(folder))],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT)
    return child, json.loads(child.stdout.readline())


@pytest.mark.slow
def test_live_bag_is_marked_refused_by_recover_and_read_without_repair_advice(tmp_path):
    """While a bag is written: its writer holds the lock (naming the process); bag-recover refuses it (exit 2,
    naming the pid) and changes nothing; readers and `aeropend identify` read it up to its last complete chunk with a
    note that never advises a repair. Finished: the lock is gone. Killed: the kernel released the lock, the file is
    stale and bag-recover recovers the bag into <bag>_recovered and removes the lock file."""
    from aeropend_core.io import bag_lock
    folder = tmp_path / 'live'
    child, report = start_live_writer(folder)
    try:
        lock = bag_lock.read_lock(folder)
        assert lock is not None and lock.pid == child.pid and lock.is_live(), lock
        assert 0 < report['on_disk'] < report['written'], report
        mcap = folder / 'live_0.mcap'
        before = mcap.read_bytes()
        result = subprocess.run([*AEROPEND, 'bag-recover', str(folder)], check=False, capture_output=True,
                                text=True, cwd=ROOT, timeout=60)
        assert result.returncode == 2, result.stderr
        assert f'being written by process {child.pid}' in result.stderr and 'Traceback' not in result.stderr
        assert len(result.stderr.strip().splitlines()) == 1, result.stderr
        assert mcap.read_bytes() == before and not list(folder.glob('*.recovering')), 'bag-recover touched it'
        with pytest.raises(AeropendError, match='being written'):
            recover_bag(mcap)

        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter('always')
            samples = read_samples(folder)
        notes = [str(w.message) for w in caught]
        assert any(f'still being recorded by process {child.pid}' in n for n in notes), notes
        assert not any('bag-recover' in n for n in notes), notes
        assert len(samples['sequence']) == report['on_disk']
        np.testing.assert_array_equal(samples['sequence'], np.arange(report['on_disk']))

        # --weak-only: what is promised here is how a live bag is read (the note, no repair advice); the
        # output-error cross-check it skips reads nothing more and is tested in test_identify and test_cli_json
        result = subprocess.run([*AEROPEND, 'identify', str(folder), '--json', '--weak-only'], check=False,
                                capture_output=True, text=True, cwd=ROOT, timeout=120)
        assert result.returncode == 0, result.stderr
        assert 'still being recorded' in result.stderr and 'bag-recover' not in result.stderr + result.stdout, \
            result.stderr

        child.stdin.write('finish\n')
        child.stdin.flush()
        assert child.stdout.readline().strip() == 'finished'
        assert child.wait(30) == 0
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert bag_lock.read_lock(folder) is None, 'the lock outlived the finished bag'
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        assert len(read_samples(folder, on_incomplete='raise')['sequence']) == report['written']

    # killed while writing: the lock stays but is stale; reading advises the repair, which removes the lock
    killed = tmp_path / 'killed_live'
    child, report = start_live_writer(killed)
    child.kill()
    child.wait()
    lock = bag_lock.read_lock(killed)
    assert lock is not None and not lock.is_live()
    with pytest.warns(UserWarning, match='bag-recover'):
        read_samples(killed)
    result = subprocess.run([*AEROPEND, 'bag-recover', str(killed)], check=False, capture_output=True, text=True,
                            cwd=ROOT, timeout=60)
    assert result.returncode == 0, result.stderr
    assert f'removed the recording lock of process {child.pid}' in result.stdout, result.stdout
    assert bag_lock.read_lock(killed) is None
    recovered = killed.with_name('killed_live_recovered')
    assert len(read_samples(recovered, on_incomplete='raise')['sequence']) == report['on_disk']


LOCK_HOLDER = textwrap.dedent('''
    import sys
    from aeropend_core.io import bag_lock
    bag_lock.acquire({folder!r})
    with open({folder!r} + '/recording.lock', 'w') as garbage:
        garbage.write('pid: [')        # what the file says does not matter: the flock does
    print('locked', flush=True)
    sys.stdin.readline()
''')


REPAIR_HOLDER = textwrap.dedent('''
    import sys
    from aeropend_core.io import bag_lock
    with bag_lock.hold({folder!r}):
        print('holding', flush=True)
        sys.stdin.readline()
''')


def test_lock_is_the_flock_not_what_the_file_says(tmp_path):
    """Live means: a process holds the flock. A lock file naming this very process, another host or garbage but
    held by nobody is stale (bag-recover removes it); a held lock with garbage content is live (refused); the
    kernel drops the lock of a SIGKILLed holder at once; a recorder starting while a repair holds its folder waits
    for the repair instead of failing."""
    import socket
    import threading
    from aeropend_core.io import bag_lock
    write_bag(tmp_path / 'b', 200).finish()
    lock_file = tmp_path / 'b' / bag_lock.LOCK_NAME
    for content in (yaml.safe_dump({'pid': os.getpid(), 'host': socket.gethostname()}),
                    yaml.safe_dump({'pid': 1, 'host': 'rig-pc-elsewhere'}), 'pid: ['):
        lock_file.write_text(content)
        assert not bag_lock.read_lock(tmp_path / 'b').is_live(), content
        assert recover_bag(tmp_path / 'b').removed_lock and not lock_file.exists(), content

    child = subprocess.Popen([sys.executable, '-c', LOCK_HOLDER.format(folder=str(tmp_path / 'b'))],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert child.stdout.readline().strip() == 'locked'
        assert bag_lock.read_lock(tmp_path / 'b').is_live()
        with pytest.raises(AeropendError, match='being written by process 0'):
            recover_bag(tmp_path / 'b')
        child.kill()
        child.wait(30)
        assert not bag_lock.read_lock(tmp_path / 'b').is_live()       # released by the kernel, not by a guess
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()

    # a repair (another process) holds a fresh folder: a recorder starting there waits for it, then records
    (tmp_path / 'new').mkdir()
    repair = subprocess.Popen([sys.executable, '-c', REPAIR_HOLDER.format(folder=str(tmp_path / 'new'))],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert repair.stdout.readline().strip() == 'holding'
        result: dict = {}
        thread = threading.Thread(target=lambda: result.update(writer=write_bag(tmp_path / 'new', 100)))
        thread.start()
        thread.join(1.0)
        assert thread.is_alive() and not result, 'the recorder did not wait for the repair'
        repair.stdin.write('done\n')
        repair.stdin.flush()
        thread.join(60)
    finally:
        if repair.poll() is None:
            repair.kill()
        repair.wait()
    assert 'writer' in result, result
    result['writer'].finish()
    assert len(read_samples(tmp_path / 'new', on_incomplete='raise')['sequence']) == 100
