"""sim_node -> recorder_node over DDS, both real processes: SIGINT finalises a bag that rosbags and mcap_ros2 read,
with no sample missing and stamps exactly k*Ts apart; SIGKILL mid-chunk and a full disk keep every complete chunk.

Synchronisation is by the recorder's own /diagnostics (its per-topic receive and on-disk counts), never by fixed
sleeps.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from tests.ros_helpers import NodeProcess, ROOT, own_context, private_domain_id, use_domain, wait_for

DOMAIN_ID = private_domain_id()
use_domain(DOMAIN_ID)

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor

from aeropend_core.io.bag import read_samples
from aeropend_core.model.parameters import SAMPLE_TIME
from aeropend_ros import topics
from aeropend_ros._ros_env import local_ros_environment

pytestmark = pytest.mark.timeout(150)
DISCOVERY_TIMEOUT = 20.0
RECORD_SECONDS = 4.0


class RecorderWatch:
    """In-test node reading the recorder's /diagnostics (what it has received per topic)."""

    def __init__(self, context) -> None:
        self.node = rclpy.create_node('test_recorder_watch', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.values: dict[str, dict[str, str]] = {}     # bag folder (hardware_id) -> status values
        self.status: dict[str, tuple[int, str]] = {}     # bag folder -> (level, message) of the latest status
        self.history: dict[str, list[tuple[int, str]]] = {}  # bag folder -> every (level, message) seen
        self.node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS_TOPIC, self._on_diagnostics,
                                      topics.diagnostics_qos())
        self._publisher = None

    def _on_diagnostics(self, msg) -> None:
        for status in msg.status:
            if status.name.startswith('recorder_node'):
                self.values[status.hardware_id] = {kv.key: kv.value for kv in status.values}
                self.status[status.hardware_id] = (int.from_bytes(status.level, 'little')
                                                   if isinstance(status.level, bytes) else int(status.level),
                                                   status.message)
                self.history.setdefault(status.hardware_id, []).append(self.status[status.hardware_id])

    def value(self, bag: Path, key: str, default: int = -1) -> int:
        return int(self.values.get(str(bag), {}).get(key, default))

    def publish_sample(self, sequence: int) -> None:
        """One more /aeropend/samples message from this test node (SensorData QoS, like the sim)."""
        if self._publisher is None:
            from sensor_msgs.msg import JointState
            self._publisher = self.node.create_publisher(JointState, topics.SAMPLES_TOPIC, topics.samples_qos())
        stamp = time.time_ns()
        self._publisher.publish(topics.sample_to_msg(topics.Sample(stamp, 0.1, 1.0, 0.2, 0.3, sequence)))

    def received(self, bag: Path, topic: str) -> int:
        """Messages on `topic` received so far by the recorder writing `bag` (from its /diagnostics)."""
        return int(self.values.get(str(bag), {}).get(f'received {topic}', 0))

    def wait_for(self, condition, timeout: float) -> bool:
        return wait_for(condition, timeout, executor=self.executor)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()


@pytest.fixture(scope='module')
def watch():
    with own_context(DOMAIN_ID) as context:
        watch = RecorderWatch(context)
        yield watch
        watch.close()


def test_sim_to_recorder_no_sample_missing(tmp_path, watch):
    bag = tmp_path / 'sim_run'
    recorder_args = ['-p', f'output:={bag}', '-p', 'diagnostics_period:=0.2', '-p', 'chunk_size:=65536']
    with NodeProcess('aeropend_ros.recorder_node', recorder_args, DOMAIN_ID) as recorder, \
            NodeProcess('aeropend_ros.sim_node', ['-p', 'psnr_db:=40.0'], DOMAIN_ID) as sim:
        need = int(RECORD_SECONDS / SAMPLE_TIME)
        assert watch.wait_for(lambda: watch.received(bag, topics.SAMPLES_TOPIC) > 0, DISCOVERY_TIMEOUT), \
            recorder.output() + sim.output()
        assert watch.wait_for(lambda: watch.received(bag, topics.SAMPLES_TOPIC) >= need, RECORD_SECONDS * 3 + 10), \
            recorder.output()
        status = recorder.stop()                         # SIGINT, like Ctrl-C
        output = recorder.output()
        assert status == 0, output
        assert 'finalised' in output, output
        sim.stop()

    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    counts = {t['topic_metadata']['name']: t['message_count'] for t in info['topics_with_message_count']}
    assert counts[topics.SAMPLES_TOPIC] >= need
    qos = info['topics_with_message_count'][[t['topic_metadata']['name'] for t in
                                              info['topics_with_message_count']].index(topics.SAMPLES_TOPIC)]
    assert qos['topic_metadata']['offered_qos_profiles'][0]['reliability'] == 'best_effort'   # SensorData

    ours = read_samples(bag)
    sequence = ours['sequence']
    assert len(sequence) == counts[topics.SAMPLES_TOPIC]
    np.testing.assert_array_equal(np.diff(sequence), 1, err_msg='a sample is missing or repeated')
    spacing_ns = np.diff(ours['stamp_ns'])
    assert np.all(np.abs(spacing_ns - SAMPLE_TIME * 1e9) <= 1.0), 'stamps are not k*Ts apart'
    assert np.all(np.isfinite(ours['angle'])) and np.all(np.isfinite(ours['armature_current']))

    # independent reader 1: rosbags on the folder
    from rosbags.highlevel import AnyReader
    with AnyReader([bag]) as reader:
        connections = [c for c in reader.connections if c.topic == topics.SAMPLES_TOPIC]
        stamps = [(m := reader.deserialize(raw, c.msgtype)).header.stamp.sec * 1_000_000_000
                  + m.header.stamp.nanosec for c, _, raw in reader.messages(connections=connections)]
    np.testing.assert_array_equal(stamps, ours['stamp_ns'])

    # independent reader 2: mcap_ros2 on the file(s)
    from mcap_ros2.reader import read_ros2_messages
    positions = [list(m.ros_msg.position) for f in sorted(bag.glob('*.mcap'))
                 for m in read_ros2_messages(str(f), topics=[topics.SAMPLES_TOPIC])]
    assert [int(p[4]) for p in positions] == sequence.tolist()
    np.testing.assert_array_equal([p[0] for p in positions], ours['angle'])


@pytest.mark.parametrize('parameter, message', [
    ('compression:=gzip', "one of 'zstd', 'lz4', 'none'"),
    ('chunk_size:=0', 'out of range'),
    ('poll_period:=nan', 'not a finite number'),
    ('chunck_size:=4096', "did you mean 'chunk_size'"),
    ('output:=/proc/no/bag', 'cannot create bag folder'),
])
def test_recorder_refuses_bad_parameters_in_one_line(tmp_path, parameter, message):
    arguments = ['-p', parameter] + ([] if parameter.startswith('output') else ['-p', f'output:={tmp_path / "b"}'])
    result = subprocess.run([sys.executable, '-m', 'aeropend_ros.recorder_node', '--ros-args', *arguments],
                            capture_output=True, text=True, timeout=60, env=local_ros_environment(domain_id=DOMAIN_ID),
                            cwd=ROOT, check=False)
    assert result.returncode == 2, result.stderr
    assert message in result.stderr and 'Traceback' not in result.stderr, result.stderr
    assert result.stderr.count('error') == 1 and not (tmp_path / 'b').exists(), result.stderr


def test_recorder_refuses_existing_bag(tmp_path):
    (tmp_path / 'taken').mkdir()
    (tmp_path / 'taken' / 'x.mcap').write_bytes(b'')
    result = subprocess.run([sys.executable, '-m', 'aeropend_ros.recorder_node', '--ros-args',
                             '-p', f'output:={tmp_path / "taken"}'], capture_output=True, text=True, timeout=60,
                            env=local_ros_environment(domain_id=DOMAIN_ID), cwd=Path(__file__).parents[1],
                            check=False)
    assert result.returncode == 2, result.stderr
    assert 'already exists' in result.stderr and 'Traceback' not in result.stderr


ONLY_SAMPLES = ['-p', f"topics:=['{topics.SAMPLES_TOPIC}']", '-p', f'include_regex:=^{topics.SAMPLES_TOPIC}$']


def test_killed_recorder_leaves_readable_bag_and_recovers(tmp_path, watch):
    """SIGKILL while samples wait in the unfinished chunk: the bag reads back exactly the samples of its complete
    chunks (the count the recorder reported on disk, by our reader and the mcap stream reader); `aeropend
    bag-recover` finalises it for rosbags."""
    from tests.test_bag import mcap_stream_count
    samples = topics.SAMPLES_TOPIC
    bag = tmp_path / 'killed_run'
    recorder_args = ['-p', f'output:={bag}', '-p', 'diagnostics_period:=0.2', '-p', 'chunk_size:=16384',
                     '-p', 'chunk_duration:=0.0', *ONLY_SAMPLES]      # chunks closed by size only here
    with NodeProcess('aeropend_ros.recorder_node', recorder_args, DOMAIN_ID) as recorder, \
            NodeProcess('aeropend_ros.sim_node', ['-p', 'psnr_db:=40.0'], DOMAIN_ID) as sim:
        assert watch.wait_for(lambda: watch.received(bag, samples) >= 1500, DISCOVERY_TIMEOUT + 10), \
            recorder.output() + sim.output()
        sim.stop()                                       # no more samples: what the recorder holds is now fixed
        seen = {'received': -1, 'since': time.monotonic()}

        def settled() -> bool:
            received = watch.received(bag, samples)
            if received != seen['received']:
                seen.update(received=received, since=time.monotonic())
            return (time.monotonic() - seen['since'] > 0.6 and watch.value(bag, 'messages_written') == received
                    and watch.value(bag, 'queue_length') == 0)
        assert watch.wait_for(settled, 20.0), recorder.output()
        extra = 0
        while watch.value(bag, f'on disk {samples}') == watch.received(bag, samples):
            # the last sample happened to close a chunk: add samples until one waits in the next chunk
            before = watch.received(bag, samples)
            extra += 1
            watch.publish_sample(10**6 + extra)
            watch.wait_for(lambda: watch.received(bag, samples) > before
                           and watch.value(bag, 'messages_written') == watch.received(bag, samples), 20.0)
            assert extra < 100, 'the recorder does not receive the extra samples'
        on_disk, received = watch.value(bag, f'on disk {samples}'), watch.received(bag, samples)
        assert 0 < on_disk < received, (on_disk, received)
        recorder.process.kill()                          # SIGKILL: no chance to finalise
        recorder.process.wait(10)

    with pytest.warns(UserWarning, match='bag-recover'):
        partial = read_samples(bag)
    kept = len(partial['sequence'])
    # exactly the complete chunks survive: no fewer samples than the recorder had on disk, and the unfinished
    # chunk's samples (received - on_disk) are the only loss
    assert kept == on_disk, (kept, on_disk, received)
    np.testing.assert_array_equal(np.diff(partial['sequence']), 1)
    assert mcap_stream_count(next(bag.glob('*.mcap')), samples) == kept

    result = subprocess.run([sys.executable, '-c', 'import sys; from aeropend_core.cli import main; sys.exit(main())',
                             'bag-recover', str(bag)], capture_output=True, text=True, timeout=60,
                            cwd=Path(__file__).parents[1], check=False)
    assert result.returncode == 0, result.stderr
    recovered = bag.with_name(bag.name + '_recovered')          # the original is left as it was
    repaired = read_samples(recovered, on_incomplete='raise')
    np.testing.assert_array_equal(repaired['sequence'], partial['sequence'])
    from rosbags.highlevel import AnyReader
    with AnyReader([recovered]) as reader:
        connections = [c for c in reader.connections if c.topic == samples]
        assert sum(c.msgcount for c in connections) == kept
        assert sum(1 for _ in reader.messages(connections=connections)) == kept


def test_full_disk_stops_the_recorder_with_a_clear_error_and_keeps_what_was_written(tmp_path, watch):
    """The recorder's disk fills up: an ERROR on /diagnostics and in the log, exit status 1, no traceback; the bag
    holds every complete chunk (as many samples as the recorder reported on disk) and bag-recover finalises it once
    space is freed."""
    from tests.test_bag import mcap_stream_count, small_disk
    samples = topics.SAMPLES_TOPIC
    with small_disk(tmp_path, 320 * 1024) as (disk, preexec, how):
        print(f'full disk simulated with {how}')
        ballast = disk / 'ballast'
        if preexec is None:                              # a tmpfs: most of it is taken by another file
            ballast.write_bytes(b'\0' * 160 * 1024)
        bag = disk / 'bag'
        command = [sys.executable, '-m', 'aeropend_ros.recorder_node', '--ros-args', '-p', f'output:={bag}',
                   '-p', 'diagnostics_period:=0.2', '-p', 'chunk_size:=16384', '-p', 'compression:=none',
                   *ONLY_SAMPLES]
        recorder = subprocess.Popen(command, env=local_ros_environment(domain_id=DOMAIN_ID), cwd=ROOT,
                                    stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                    preexec_fn=preexec)
        try:
            # the sim starts only once this test hears the recorder's /diagnostics: the recorder dies within a
            # second of the first samples, and its ERROR must find a matched listener (it waits for the ack)
            assert watch.wait_for(lambda: str(bag) in watch.values or recorder.poll() is not None,
                                  DISCOVERY_TIMEOUT + 40), 'the recorder never published /diagnostics'
            assert recorder.poll() is None, recorder.communicate(timeout=10)[0]
            with NodeProcess('aeropend_ros.sim_node', ['-p', 'psnr_db:=40.0', '-p', 'realtime_factor:=4.0'],
                             DOMAIN_ID) as sim:
                assert watch.wait_for(lambda: recorder.poll() is not None, 90.0), sim.output()
                sim.stop()
            output = recorder.communicate(timeout=10)[0]
        finally:
            if recorder.poll() is None:
                recorder.kill()
        assert recorder.returncode == 1, (how, output)
        assert 'Traceback' not in output, output
        assert 'No space left on device' in output or 'File too large' in output, (how, output)
        assert 'bag-recover' in output and 'NOT finalised' in output, output
        watch.wait_for(lambda: watch.status.get(str(bag), (0, ''))[0] == 2, 20.0)
        level, message = watch.status.get(str(bag), (0, ''))
        assert level == 2 and 'writing failed' in message, (level, message)   # DiagnosticStatus.ERROR
        on_disk = watch.value(bag, f'on disk {samples}')

        with pytest.warns(UserWarning, match='incomplete'):
            partial = read_samples(bag)
        kept = len(partial['sequence'])
        assert kept == on_disk > 0, (kept, on_disk, how)
        np.testing.assert_array_equal(np.diff(partial['sequence']), 1)
        assert mcap_stream_count(next(bag.glob('*.mcap')), samples) == kept
        ballast.unlink(missing_ok=True)                  # free space, then repair in place
        result = subprocess.run([sys.executable, '-c', 'import sys; from aeropend_core.cli import main; '
                                 'sys.exit(main())', 'bag-recover', str(bag), '--in-place'], capture_output=True,
                                text=True, timeout=60, cwd=ROOT, check=False)
        assert result.returncode == 0, result.stderr
        from rosbags.highlevel import AnyReader
        with AnyReader([bag]) as reader:
            connections = [c for c in reader.connections if c.topic == samples]
            assert sum(1 for _ in reader.messages(connections=connections)) == kept


def test_stalled_recorder_counts_every_gap_as_lost(tmp_path, watch):
    """The recorder stopped (SIGSTOP, standing in for starvation) for 5 s with a 500-message DDS history while the
    sim publishes 490 Hz: the samples that overflowed the history are lost, and the recorder says so by sequence
    number (never '0 dropped'): a WARN on /diagnostics, a log line, and metadata.yaml's custom_data, each equal to
    the gaps in the bag's sample counter. A topic whose type is not in allowed_types is not recorded (nor its
    module imported)."""
    from std_msgs.msg import String
    samples = topics.SAMPLES_TOPIC
    bag = tmp_path / 'stalled'
    stall, depth = 5.0, 500
    unlisted = watch.node.create_publisher(String, '/aeropend/unlisted_type', 10)
    recorder_args = ['-p', f'output:={bag}', '-p', 'diagnostics_period:=0.2', '-p', f'queue_depth:={depth}']
    try:
        with NodeProcess('aeropend_ros.recorder_node', recorder_args, DOMAIN_ID) as recorder, \
                NodeProcess('aeropend_ros.sim_node', ['-p', 'psnr_db:=40.0'], DOMAIN_ID) as sim:
            assert watch.wait_for(lambda: watch.received(bag, samples) >= 500, DISCOVERY_TIMEOUT + 10), \
                recorder.output() + sim.output()
            assert watch.value(bag, 'samples_lost') == 0
            os.kill(recorder.process.pid, signal.SIGSTOP)     # the stimulus: a stall, not a synchronisation sleep
            time.sleep(stall)
            os.kill(recorder.process.pid, signal.SIGCONT)
            assert watch.wait_for(lambda: watch.value(bag, 'samples_lost') > 0, 30.0), recorder.output()
            resumed = watch.received(bag, samples)
            assert watch.wait_for(lambda: watch.received(bag, samples) > resumed + 200, 30.0), recorder.output()
            sim.stop()
            seen = {'received': -1, 'since': time.monotonic()}

            def settled() -> bool:
                received = watch.received(bag, samples)
                if received != seen['received']:
                    seen.update(received=received, since=time.monotonic())
                return time.monotonic() - seen['since'] > 0.6 and watch.value(bag, 'queue_length') == 0
            assert watch.wait_for(settled, 20.0), recorder.output()
            reported = watch.value(bag, 'samples_lost')
            assert recorder.stop() == 0, recorder.output()
            output = recorder.output()
    finally:
        watch.node.destroy_publisher(unlisted)
    sequence = read_samples(bag, on_incomplete='raise')['sequence']
    gaps = int(np.sum(np.diff(sequence) - 1))
    assert np.all(np.diff(sequence) >= 1)
    # the stall overflowed the history: at least the samples published beyond its depth are missing
    assert gaps >= 0.5 * (stall * 490 - depth), (gaps, output)
    assert reported == gaps, (reported, gaps)
    warnings = [message for level, message in watch.history[str(bag)] if level == 1]
    assert any('lost since the last report' in m for m in warnings), watch.history[str(bag)]
    assert 'message(s) lost since the last report' in output and 'sample counter' in output, output
    assert f'{gaps} lost by sequence gaps' in output and 'the 0 message(s) dropped here' in output, output
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['custom_data'][f'aeropend.lost {samples}'] == str(gaps), info['custom_data']
    assert 'sample counter' in info['custom_data']['aeropend.loss_accounting']
    # the unlisted type: refused by name, not recorded
    assert 'not recording /aeropend/unlisted_type (std_msgs/msg/String)' in output and 'allowed_types' in output
    from aeropend_core.io.bag import bag_topics
    assert '/aeropend/unlisted_type' not in bag_topics(bag)


def test_message_class_refuses_types_outside_the_allow_list_before_importing():
    from aeropend_ros.recorder_node import DEFAULT_ALLOWED_TYPES, message_class
    with pytest.raises(ValueError, match='allowed_types'):
        message_class('aeropend_not_a_package/msg/Anything', frozenset(DEFAULT_ALLOWED_TYPES))
    assert 'aeropend_not_a_package' not in sys.modules
    assert message_class('std_msgs/msg/Float64', frozenset(DEFAULT_ALLOWED_TYPES)).__name__ == 'Float64'


def test_repeated_interrupts_while_finishing_leave_a_finished_bag_and_no_traceback(tmp_path, watch):
    """Ctrl-C pressed again and again while the recorder finalises: it says to wait, finishes the bag, exit 0."""
    samples = topics.SAMPLES_TOPIC
    bag = tmp_path / 'interrupted'
    recorder_args = ['-p', f'output:={bag}', '-p', 'diagnostics_period:=0.2', '-p', 'chunk_size:=16777216',
                     *ONLY_SAMPLES]
    with NodeProcess('aeropend_ros.recorder_node', recorder_args, DOMAIN_ID) as recorder, \
            NodeProcess('aeropend_ros.sim_node', ['-p', 'psnr_db:=40.0', '-p', 'realtime_factor:=4.0'],
                        DOMAIN_ID) as sim:
        assert watch.wait_for(lambda: watch.received(bag, samples) >= 5000, DISCOVERY_TIMEOUT + 30), \
            recorder.output() + sim.output()
        for _ in range(6):                       # the first starts the shutdown, the others land during it
            recorder.process.send_signal(signal.SIGINT)
            time.sleep(0.01)
        assert recorder.process.wait(60) == 0, recorder.output()
        output = recorder.output()
        sim.stop()
    assert 'Traceback' not in output and 'KeyboardInterrupt' not in output, output
    assert 'finalised' in output, output
    assert len(read_samples(bag, on_incomplete='raise')['sequence']) >= 5000
