"""Many rigs on one network: each rig's graph in its own namespace, recorded and identified separately.

1. Two rigs on one ROS domain (``aeropend run --rig rigA`` and ``--rig rigB`` side by side, two processes over DDS):
   the sims hide opposite angle-sensor offsets (+0.1 / -0.1 rad); each bag holds only its rig's topics and
   statuses, its samples are contiguous and come from its own sim, and each identification reports its own offset.
2. The graph split across two network namespaces joined by a veth pair (the rig's computer: sim_node; the analysis
   computer: excitation, recorder, identification), with ROS 2's default discovery (no LOCALHOST range) and the
   UDP transport only: no sample is lost on the way, and the samples crossed the veth link.

The bags are read back with an independent reader (rosbags).
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from aeropend_ros._ros_env import local_ros_environment
from tests.ros_helpers import ROOT, private_domain_id, wait_for

AEROPEND = [sys.executable, '-c', 'import sys; from aeropend_core.cli import main; sys.exit(main())']
SAMPLE_RATE = 490.0


def read_bag(folder: Path) -> tuple[dict[str, list], dict[str, str]]:
    """({topic: [deserialised messages]}, metadata custom_data) of a bag folder, read with rosbags."""
    from rosbags.highlevel import AnyReader
    messages: dict[str, list] = {}
    with AnyReader([folder]) as reader:
        for connection, _, raw in reader.messages():
            messages.setdefault(connection.topic, []).append(reader.deserialize(raw, connection.msgtype))
    metadata = yaml.safe_load((folder / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    return messages, metadata.get('custom_data') or {}


def named(msg) -> dict[str, tuple[float, float]]:
    """A JointState of named values (identification outputs) as {name: (value, 1 sigma)}."""
    return {name: (value, sigma) for name, value, sigma in zip(msg.name, msg.position, msg.velocity)}


@pytest.mark.timeout(300)
def test_two_rigs_on_one_domain_record_and_identify_separately(tmp_path):
    import rclpy

    from aeropend_ros.testing import own_context
    domain_id = private_domain_id()
    env = local_ros_environment(domain_id=domain_id)
    offsets = {'rigA': 0.1, 'rigB': -0.1}
    runs = {}
    for seed, (rig, offset) in enumerate(offsets.items(), start=1):
        arguments = ['run', '--rig', rig, '--duration', '26', '--no-diagnose',
                     '--record', str(tmp_path), '--effect', f'angle_offset={offset}', '--add', 'angle_offset',
                     '--window', '12', '--hop', '4', '--seed', str(seed)]
        runs[rig] = subprocess.Popen(AEROPEND + arguments, env=env, cwd=ROOT, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True)
    # `aeropend monitor --rig NAME` watches one rig's identification among the two.
    monitors = {rig: subprocess.Popen(AEROPEND + ['monitor', '--rig', rig, '--once', '--timeout', '200', '--no-plot',
                                                  '--json', '-'],
                                      env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                for rig in offsets}
    outputs = {}
    seen: set[str] = set()          # every topic of the domain while the rigs run (a third party's view)
    try:
        with own_context(domain_id) as context:
            watcher = rclpy.create_node('topic_watcher', context=context)
            deadline = time.monotonic() + 240
            while any(run.poll() is None for run in runs.values()) and time.monotonic() < deadline:
                seen.update(name for name, _ in watcher.get_topic_names_and_types())
                time.sleep(0.2)
            watcher.destroy_node()
        for rig, run in runs.items():
            outputs[rig], _ = run.communicate(timeout=60)
        monitored = {rig: monitor.communicate(timeout=240) for rig, monitor in monitors.items()}
    finally:
        for run in [*runs.values(), *monitors.values()]:
            if run.poll() is None:
                run.kill()
    # No aeropend topic outside the two rigs' namespaces: a recorder of the default graph (^/aeropend/) would
    # otherwise take a rig's messages.
    stray = sorted(t for t in seen if 'aeropend' in t and not t.startswith(('/rigA/aeropend/', '/rigB/aeropend/')))
    assert not stray and {'/rigA/aeropend/samples', '/rigB/aeropend/samples'} <= seen, (stray, sorted(seen))
    for rig, run in runs.items():
        assert run.returncode == 0 and 'Traceback' not in outputs[rig], outputs[rig]
        assert f'as rig {rig} (namespace /{rig}' in outputs[rig], outputs[rig]
    for rig, offset in offsets.items():
        out, err = monitored[rig]
        assert monitors[rig].returncode == 0, err + out
        window = [o for o in map(json.loads, out.splitlines()) if 'window' in o][-1]['window']
        assert window['parameters']['angle_offset']['value'] == pytest.approx(offset, abs=0.01), (rig, window)
    for rig, offset in offsets.items():
        folders = list(tmp_path.glob(f'aeropend_{rig}_*'))
        assert len(folders) == 1, (sorted(p.name for p in tmp_path.iterdir()), outputs[rig])
        messages, custom = read_bag(folders[0])
        # Only this rig's topics, and /diagnostics with only this rig's statuses.
        assert set(messages) - {'/diagnostics'} and all(t.startswith(f'/{rig}/aeropend/') for t in messages
                                                        if t != '/diagnostics'), sorted(messages)
        names = {status.name for array in messages['/diagnostics'] for status in array.status}
        assert f'{rig}/recorder_node: bag' in names and all(n.startswith(f'{rig}/') for n in names), names
        assert custom['aeropend.rig'] == rig and custom['aeropend.namespace'] == f'/{rig}', custom
        # The two rigs shared the domain: the other rig's statuses reached this recorder and were left out.
        assert int(custom['aeropend.diagnostics_of_other_rigs']) > 0, custom
        # Samples: every one of the 26 s, contiguous counter (one source: two sims would repeat the numbers),
        # values of this rig's sim (at rest before the excitation starts the angle reads the hidden offset).
        samples = messages[f'/{rig}/aeropend/samples']
        sequence = np.array([m.position[4] for m in samples])
        assert sequence.size == round(26 * SAMPLE_RATE) and np.all(np.diff(sequence) == 1), sequence[:10]
        at_rest = np.median([m.position[0] for m in samples[:200]])
        assert at_rest == pytest.approx(offset, abs=0.02), (rig, at_rest)
        # The identification of this rig reports this rig's offset (every window, 12 s each; up to four windows,
        # fewer when a loaded machine delays the identification past the end of the run).
        windows = [named(m) for m in messages.get(f'/{rig}/aeropend/identification/parameters', [])]
        assert windows, (sorted(messages), outputs[rig])
        for parameters in windows:
            assert parameters['angle_offset'][0] == pytest.approx(offset, abs=0.01), (rig, parameters)
        # aeropend's own reader finds the rig's samples topic in the bag.
        from aeropend_core.io.bag import read_samples
        assert np.array_equal(read_samples(folders[0])['sequence'], sequence.astype(np.int64))


def test_rig_name_must_be_a_ros_name(tmp_path):
    env = local_ros_environment(domain_id=private_domain_id())
    for name, message in [('rig-1', 'is not a ROS name'), ('aeropend', 'is the default graph')]:
        result = subprocess.run(AEROPEND + ['run', '--rig', name, '--record', str(tmp_path)], env=env, cwd=ROOT,
                                capture_output=True, text=True, timeout=60)
        assert result.returncode == 2 and message in result.stderr and 'Traceback' not in result.stderr, \
            result.stderr


def test_rig_names_namespaces_and_status_names():
    from aeropend_core.errors import AeropendError
    from aeropend_ros import topics
    assert topics.rig_namespace(None) == topics.rig_namespace('') == '/'
    assert topics.rig_namespace('rig1') == '/rig1' and topics.rig_name('/rig1') == 'rig1'
    assert topics.rig_name('/') == 'aeropend'
    for bad in ('1rig', 'rig/1', 'rig 1', 'aeropend'):
        with pytest.raises(AeropendError):
            topics.rig_namespace(bad)
    # status names carry the rig, and the recorder reads it back from them
    assert topics.status_prefix('/') == '' and topics.status_prefix('/rig1') == 'rig1/'
    for namespace in ('/', '/rig1', '/lab/rig2'):
        name = topics.status_prefix(namespace) + 'recorder_node: bag'
        assert topics.status_namespace(name) == namespace
    assert topics.status_namespace('aeropend: identification') == '/'
    assert topics.status_namespace('rig1/aeropend: identification') == '/rig1'
    assert topics.relative_topic('/rig1/aeropend/samples', '/rig1') == topics.SAMPLES
    assert topics.relative_topic('/diagnostics', '/rig1') == '/diagnostics'
    assert topics.relative_topic('/aeropend/samples', '/') == topics.SAMPLES


def test_reading_a_bag_of_one_rig_and_refusing_a_bag_of_two(tmp_path):
    """aeropend's reader takes a rig's samples topic when the bag has no /aeropend/samples, never two rigs'."""
    from aeropend_ros._ros_env import ensure_ros_environment
    ensure_ros_environment(local_only=True)
    from aeropend_core.errors import AeropendError
    from aeropend_core.io.bag import read_samples
    from aeropend_core.io.bag_writer import BagWriter
    from aeropend_core.io.mcap_format import msg_file_loader, ros2msg_definition
    from aeropend_ros import topics
    from aeropend_ros._ros_env import ament_prefixes
    from tests.test_bag import cdr_joint_state
    schema = ros2msg_definition(topics.SAMPLES_TYPE, msg_file_loader(ament_prefixes()))

    def bag(name: str, rigs: dict[str, float]) -> Path:
        writer = BagWriter(tmp_path / name)
        for rig in rigs:
            writer.add_topic(f'/{rig}/aeropend/samples', topics.SAMPLES_TYPE, schema)
        for k in range(50):
            for rig, angle in rigs.items():
                stamp = 1_000_000_000 + k * 2_040_816
                data = cdr_joint_state(stamp, [angle, 1.0, 0.5, 0.3, float(k)])     # exact CDR, as from DDS
                writer.write(f'/{rig}/aeropend/samples', data, stamp, stamp)
        writer.finish()
        return tmp_path / name

    one = read_samples(bag('one', {'rig1': 0.25}))
    assert np.array_equal(one['sequence'], np.arange(50)) and np.all(one['angle'] == 0.25)
    with pytest.raises(AeropendError, match='several rigs') as error:
        read_samples(bag('two', {'rig1': 0.25, 'rig2': -0.25}))
    assert '/rig1/aeropend/samples' in str(error.value) and '/rig2/aeropend/samples' in str(error.value)


def test_launch_namespace_agrees_with_run_rig():
    """The launch files' ``namespace`` is the rig as in ``aeropend run --rig``: '' (default) = the root namespace,
    the default graph; every node of a launch file in it (launch_ros makes ``rig1`` absolute: ``/rig1``)."""
    import ast
    for name in ('sim.launch.py', 'rig.launch.py'):
        tree = ast.parse((ROOT / 'launch' / name).read_text())
        calls = [node for node in ast.walk(tree) if isinstance(node, ast.Call)]
        declared = {ast.literal_eval(c.args[0]): {k.arg: k.value for k in c.keywords} for c in calls
                    if getattr(c.func, 'id', '') == 'DeclareLaunchArgument'}
        assert ast.literal_eval(declared['namespace']['default_value']) == '', name
        nodes = [c for c in calls if getattr(c.func, 'id', '') == 'Node']
        spaces = [next(k.value for k in c.keywords if k.arg == 'namespace') for c in nodes]
        assert nodes and all(ast.literal_eval(v.args[0]) == 'namespace' for v in spaces), name


def test_shipped_parameter_files_pin_no_rig():
    """The YAML files apply in every namespace (``/**/node``): a full /aeropend/ name in them would make every rig's
    recorder or Foxglove server take the default graph's topics."""
    def strings(value):
        if isinstance(value, str):
            yield value
        elif isinstance(value, dict):
            for item in value.values():
                yield from strings(item)
        elif isinstance(value, list):
            for item in value:
                yield from strings(item)
    for path in sorted((ROOT / 'config').glob('*_node.yaml')):
        pinned = [text for text in strings(yaml.safe_load(path.read_text())) if '/aeropend/' in text]
        assert not pinned, f'{path.name}: {pinned}'


# ------------------------------------------------------------------------------------------- network namespaces

#: Watches the identification results on the analysis side; prints each window's parameters as a JSON line.
_PROBE = '''
import json, sys
import rclpy
from sensor_msgs.msg import JointState
from aeropend_ros.identification_node import PARAMETERS_TOPIC, results_qos
rclpy.init()
node = rclpy.create_node('probe')
node.create_subscription(JointState, PARAMETERS_TOPIC, lambda m: print(json.dumps(dict(zip(m.name, m.position))),
                         flush=True), results_qos())
try:
    rclpy.spin(node)
except Exception:
    pass
'''


def _ip(*arguments: str) -> subprocess.CompletedProcess:
    return subprocess.run(['ip', *arguments], capture_output=True, text=True, timeout=30)


@pytest.fixture()
def veth_namespaces():
    """Two network namespaces ``(rig, analysis)`` joined by a veth pair (10.77.x.1 and .2/24, multicast routed).

    Skipped where they cannot be made (not root, no ``ip``, no netns support). Removed on the way out, whatever
    happened (removing a namespace removes its end of the veth pair, and with it the pair).
    """
    if shutil.which('ip') is None:
        pytest.skip('network namespaces need the ip command (iproute2), which is not installed')
    if os.geteuid() != 0:
        pytest.skip('network namespaces need root (ip netns add); run as root to test the split graph')
    tag = f'{os.getpid() % 100000}'
    rig, analysis = f'aerorig{tag}', f'aeroana{tag}'
    made = []
    try:
        for name in (rig, analysis):
            result = _ip('netns', 'add', name)
            if result.returncode != 0:
                pytest.skip(f'cannot create a network namespace here: {result.stderr.strip()}')
            made.append(name)
        subnet = f'10.77.{os.getpid() % 250}'
        commands = [('link', 'add', f'vr{tag}', 'type', 'veth', 'peer', 'name', f'va{tag}'),
                    ('link', 'set', f'vr{tag}', 'netns', rig), ('link', 'set', f'va{tag}', 'netns', analysis)]
        for name, device, address in ((rig, f'vr{tag}', f'{subnet}.1'), (analysis, f'va{tag}', f'{subnet}.2')):
            commands += [('-n', name, 'link', 'set', 'lo', 'up'),
                         ('-n', name, 'addr', 'add', f'{address}/24', 'dev', device),
                         ('-n', name, 'link', 'set', device, 'up', 'multicast', 'on'),
                         ('-n', name, 'route', 'add', '224.0.0.0/4', 'dev', device)]
        for command in commands:
            result = _ip(*command)
            assert result.returncode == 0, f'ip {" ".join(command)}: {result.stderr}'
        yield {'rig': rig, 'analysis': analysis, 'analysis_device': f'va{tag}'}
    finally:
        for name in made:
            _ip('netns', 'del', name)


class _InNamespace:
    """A process started with ``ip netns exec NAMESPACE ...``, output to a file, stopped with SIGTERM (which the
    nodes handle like Ctrl-C; SIGINT may be ignored by a test run started in the background)."""

    def __init__(self, namespace: str, command: list[str], env: dict[str, str], log: Path) -> None:
        self.log = log
        self.file = log.open('w')
        self.process = subprocess.Popen(['ip', 'netns', 'exec', namespace, *command], env=env, cwd=ROOT,
                                        stdout=self.file, stderr=subprocess.STDOUT)

    def output(self) -> str:
        self.file.flush()
        return self.log.read_text(errors='replace')

    def stop(self, timeout: float = 30.0) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.file.close()
        return self.process.returncode


def _udp_errors(namespace: str) -> dict[str, int]:
    """The namespace's UDP error counters (``/proc/net/snmp``: RcvbufErrors, SndbufErrors, InErrors)."""
    text = subprocess.run(['ip', 'netns', 'exec', namespace, 'cat', '/proc/net/snmp'], capture_output=True,
                          text=True, timeout=30).stdout
    names, values = [line.split()[1:] for line in text.splitlines() if line.startswith('Udp:')][:2]
    counters = dict(zip(names, map(int, values)))
    return {k: counters.get(k, 0) for k in ('RcvbufErrors', 'SndbufErrors', 'InErrors')}


def _received_bytes(namespace: str, device: str) -> int:
    result = _ip('-n', namespace, '-s', '-j', 'link', 'show', device)
    return int(json.loads(result.stdout)[0]['stats64']['rx']['bytes'])


@pytest.mark.timeout(300)
def test_graph_split_across_network_namespaces_loses_nothing(veth_namespaces, tmp_path):
    env = {k: v for k, v in local_ros_environment(domain_id=private_domain_id()).items()
           if k != 'ROS_AUTOMATIC_DISCOVERY_RANGE'}                # ROS 2's default discovery (subnet)
    # UDP only (both sides share this host's /dev/shm: shared memory would bypass the veth link), with the receive
    # buffers the README recommends for the analysis side (the default 212992 bytes overflowed when a subscriber
    # was starved on this loaded 2-core machine: UDP RcvbufErrors, samples lost)
    env['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(ROOT / 'config' / 'fastdds_udp_large_buffers.xml')
    before = _received_bytes(veth_namespaces['analysis'], veth_namespaces['analysis_device'])
    duration = 24.0
    bag = tmp_path / 'split_bag'
    python = [sys.executable, '-m']
    processes = {}
    try:
        on_analysis = veth_namespaces['analysis']
        processes['recorder'] = _InNamespace(on_analysis, python + ['aeropend_ros.recorder_node', '--ros-args', '-p',
                                             f'output:={bag}'], env, tmp_path / 'recorder.log')
        processes['identification'] = _InNamespace(on_analysis, python + [
            'aeropend_ros.identification_node', '--ros-args', '-p', 'window_s:=12.0', '-p', 'hop_s:=4.0'],
            env, tmp_path / 'identification.log')
        processes['excitation'] = _InNamespace(on_analysis, python + [
            'aeropend_ros.excitation_node', '--ros-args', '-p', 'duration:=600.0', '-p', 'seed:=3'],
            env, tmp_path / 'excitation.log')
        processes['probe'] = _InNamespace(on_analysis, [sys.executable, '-c', _PROBE], env, tmp_path / 'probe.log')
        # The rig side: the sim starts publishing once the recorder, the identification and the excitation (its
        # time base) are matched across the link, so the bag must hold every sample from number 0.
        processes['sim'] = _InNamespace(veth_namespaces['rig'], python + [
            'aeropend_ros.sim_node', '--ros-args', '-p', 'realtime_factor:=1.0', '-p', f'stop_after:={duration}',
            '-p', 'wait_for_subscribers:=3'], env, tmp_path / 'sim.log')
        sim, probe = processes['sim'], processes['probe']
        logs = lambda: '\n'.join(f'--- {k}\n{p.output()[-3000:]}' for k, p in processes.items())  # noqa: E731
        assert wait_for(lambda: 'stop_after reached' in sim.output(), 200.0), logs()
        # a window identified from the samples that crossed the link (three are due; the first may be late)
        assert wait_for(lambda: probe.output().count('gravity_stiffness') >= 1, 120.0), logs()
        assert processes['recorder'].stop() == 0, logs()
    finally:
        for process in processes.values():
            process.stop()
    expected = round(duration * SAMPLE_RATE)
    messages, custom = read_bag(bag)
    sequence = np.array([m.position[4] for m in messages['/aeropend/samples']])
    udp = {side: _udp_errors(veth_namespaces[side]) for side in ('rig', 'analysis')}
    assert sequence.size == expected and np.array_equal(sequence, np.arange(expected)), \
        (f'{sequence.size} of {expected} samples; first {sequence[:5]}, gaps at '
         f'{np.flatnonzero(np.diff(sequence) != 1)}; UDP errors {udp}')
    assert custom['aeropend.lost /aeropend/samples'] == '0', custom
    # the duty commands crossed the other way and drove the sim
    assert np.ptp([m.position[3] for m in messages['/aeropend/samples']]) > 0.2
    # the identification on the analysis side fitted the rig: Ra within 5 % and the static thrust-to-angle map
    # (thrust gain / gravity stiffness) within 5 % in every window (12 s windows; test_nodes: 3 % with 25 s)
    from aeropend_core.model.parameters import DEFAULT_PARAMETERS as truth
    windows = [named(m) for m in messages['/aeropend/identification/parameters']]
    print('windows: ' + '; '.join(', '.join(f'{k} {v:.4g}' for k, (v, _) in w.items()) for w in windows))
    assert windows
    for w in windows:
        assert w['armature_resistance'][0] == pytest.approx(truth.armature_resistance, rel=0.05), w
        assert w['thrust_gain'][0] / w['gravity_stiffness'][0] == pytest.approx(
            truth.thrust_gain / truth.gravity_stiffness, rel=0.05), w
    # and the samples did travel over the veth link (JointState samples are ~150 bytes on the wire)
    crossed = _received_bytes(veth_namespaces['analysis'], veth_namespaces['analysis_device']) - before
    print(f'{sequence.size} samples recorded across the veth link, none lost; {crossed} bytes received over it; '
          f'{len(windows)} windows identified; UDP errors {udp}')
    assert crossed > expected * 100, f'only {crossed} bytes arrived over the veth link for {expected} samples'
