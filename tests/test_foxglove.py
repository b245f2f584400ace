"""The live graph in Foxglove: `aeropend run --foxglove` serves the graph over Foxglove's WebSocket protocol.

A real WebSocket client (the ``websockets`` package) connects to the running graph, sees ``/aeropend/samples``
advertised (CDR with its ros2msg schema, as in the bags), subscribes, receives binary message frames and decodes them
with rclpy's own CDR deserialiser. Also: the shipped Foxglove and PlotJuggler layouts are the generated ones and name
only topics and fields the graph publishes; a busy port is a one-line error (exit 2).
"""
from __future__ import annotations

import json
import re
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import pytest

from aeropend_ros._ros_env import ensure_ros_environment, local_ros_environment
from tests.ros_helpers import ROOT, private_domain_id

pytest.importorskip('foxglove', reason='foxglove-sdk is not installed (pip install foxglove-sdk)')
websockets_sync = pytest.importorskip('websockets.sync.client', reason='websockets is not installed')

AEROPEND = [sys.executable, '-c', 'import sys; from aeropend_core.cli import main; sys.exit(main())']
#: foxglove-sdk's server speaks Foxglove's WebSocket protocol under the subprotocol name 'foxglove.sdk.v1'
#: (0.30); the Foxglove app offers it. The classic name is offered too: whichever the server accepts.
SUBPROTOCOLS = ['foxglove.sdk.v1', 'foxglove.websocket.v1']
MESSAGE_DATA = 0x01          # server -> client binary opcode of a message on a subscription


class OutputReader:
    """Collects a process's output lines in a thread (so the pipe never fills while the test waits)."""

    def __init__(self, process: subprocess.Popen) -> None:
        self.lines: list[str] = []
        self.thread = threading.Thread(target=self._read, args=(process.stdout,), daemon=True)
        self.thread.start()

    def _read(self, stream) -> None:
        for line in stream:
            self.lines.append(line)

    def text(self) -> str:
        return ''.join(self.lines)

    def wait_for(self, pattern: str, timeout: float) -> re.Match | None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            match = re.search(pattern, self.text())
            if match:
                return match
            time.sleep(0.1)
        return None


def receive_json(ws, timeout: float) -> dict | None:
    """The next text (JSON) frame; binary frames in between are skipped."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            frame = ws.recv(timeout=max(0.05, deadline - time.monotonic()))
        except TimeoutError:
            return None
        if isinstance(frame, str):
            return json.loads(frame)
    return None


@pytest.mark.timeout(180)
def test_run_foxglove_serves_the_live_graph():
    ensure_ros_environment()
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState

    from aeropend_ros.topics import SAMPLE_NAMES

    env = local_ros_environment(domain_id=private_domain_id())
    run = subprocess.Popen(AEROPEND + ['run', '--foxglove', '0', '--duration', '120', '--no-record', '--no-diagnose'],
                           env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    output = OutputReader(run)
    try:
        match = output.wait_for(r'Foxglove WebSocket connection to (ws://127\.0\.0\.1:(\d+))', 60)
        assert match, output.text()
        url = match.group(1)
        with websockets_sync.connect(url, subprotocols=SUBPROTOCOLS, open_timeout=20) as ws:
            assert ws.subprotocol in SUBPROTOCOLS
            info = receive_json(ws, 20)
            assert info and info['op'] == 'serverInfo' and info['name'] == 'aeropend', info
            # Channels are advertised as the node discovers the topics: wait for the samples and a parameter's own
            # topic (what the shipped layout plots each band from; advertised from the identification node's start).
            channels: dict[str, dict] = {}
            wanted = {'/aeropend/samples', '/aeropend/parameters/thrust_gain'}
            deadline = time.monotonic() + 60
            while not wanted <= set(channels) and time.monotonic() < deadline:
                message = receive_json(ws, deadline - time.monotonic())
                if message and message['op'] == 'advertise':
                    channels.update({c['topic']: c for c in message['channels']})
            samples = channels.get('/aeropend/samples')
            assert samples is not None, f'/aeropend/samples never advertised; got {sorted(channels)}\n' + output.text()
            assert samples['encoding'] == 'cdr' and samples['schemaName'] == 'sensor_msgs/msg/JointState'
            assert samples['schemaEncoding'] == 'ros2msg' and 'float64[] position' in samples['schema']
            assert 'MSG: std_msgs/Header' in samples['schema']          # dependencies included, as in the bags
            gain = channels.get('/aeropend/parameters/thrust_gain')
            assert gain is not None and gain['schemaName'] == 'sensor_msgs/msg/JointState', sorted(channels)
            ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [{'id': 11, 'channelId': samples['id']}]}))
            received = []
            deadline = time.monotonic() + 60
            while len(received) < 200 and time.monotonic() < deadline:
                try:
                    frame = ws.recv(timeout=5)
                except TimeoutError:
                    continue
                if isinstance(frame, bytes) and frame[0] == MESSAGE_DATA:
                    subscription, log_time = struct.unpack_from('<IQ', frame, 1)
                    assert subscription == 11
                    received.append((log_time, deserialize_message(frame[13:], JointState)))
    finally:
        if run.poll() is None:
            run.send_signal(signal.SIGINT)
        try:
            run.wait(30)
        except subprocess.TimeoutExpired:
            run.kill()
            run.wait()
        output.thread.join(5)
    assert len(received) >= 200, f'{len(received)} messages received\n' + output.text()
    messages = [m for _, m in received]
    assert all(tuple(m.name) == SAMPLE_NAMES for m in messages)
    sequence = [m.position[SAMPLE_NAMES.index('sequence')] for m in messages]
    stamps = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in messages]
    assert all(b > a for a, b in zip(sequence, sequence[1:])), 'samples in order, none twice'
    assert all(b > a for a, b in zip(stamps, stamps[1:]))
    assert all(abs(m.position[0]) < 3.2 for m in messages)               # an angle in rad
    log_times = [t for t, _ in received]
    assert abs(log_times[-1] * 1e-9 - time.time()) < 120                  # log time = receive time (ns, epoch)
    assert run.returncode == 130, output.text()                           # Ctrl-C: interrupted, cleaned up
    assert 'Traceback' not in output.text()


def test_busy_port_and_bad_port_are_one_line_errors():
    env = local_ros_environment(domain_id=private_domain_id())
    with socket.socket() as busy:
        busy.bind(('127.0.0.1', 0))
        busy.listen()
        port = busy.getsockname()[1]
        result = subprocess.run(AEROPEND + ['run', '--foxglove', str(port), '--duration', '5', '--no-record',
                                            '--no-diagnose'], env=env, cwd=ROOT, capture_output=True, text=True,
                                timeout=120)
    assert result.returncode == 2, result.stdout + result.stderr
    assert f'cannot serve Foxglove on 127.0.0.1:{port}' in result.stderr and 'another port' in result.stderr
    assert 'Traceback' not in result.stderr
    result = subprocess.run(AEROPEND + ['run', '--foxglove', '70000'], env=env, cwd=ROOT, capture_output=True,
                            text=True, timeout=60)
    assert result.returncode == 2 and '--foxglove PORT must be in [0, 65535]' in result.stderr, result.stderr


# -- the shipped layouts --------------------------------------------------------------------------------------------

def test_shipped_layouts_are_the_generated_ones(scoped_catalog):
    from aeropend_ros import layouts
    assert (ROOT / 'config' / layouts.FOXGLOVE_FILE).read_text() == layouts.foxglove_layout_json()
    assert (ROOT / 'config' / layouts.PLOTJUGGLER_FILE).read_text() == layouts.plotjuggler_layout_xml()
    # an effect registered in this process (a user module, a discovered term) does not change the shipped layouts
    from aeropend_core.model.effects import EffectParameter, register_effect
    probe = [EffectParameter('layout_probe_k', '1/s^2', 'k', 1.0, 0.0, 2.0)]
    register_effect('layout_probe', 'a probe', parameters=probe)(lambda angle, angular_rate, layout_probe_k: 0.0)
    assert 'layout_probe_k' not in layouts.band_parameters()


def test_layout_names_are_the_published_ones():
    """The names the layouts rely on come from the publishers, not from the layout module itself."""
    import ast

    from aeropend_core.diagnosis.output_error import NOMINAL_PARAMETERS
    from aeropend_core.model.effects import CATALOG
    from aeropend_ros import layouts
    expected = set(NOMINAL_PARAMETERS) | {'thrust_coefficient'} | {p.name for e in CATALOG.values() if e.builtin
                                                                     for p in e.parameters}
    assert set(layouts.BAND_PARAMETERS) == expected
    # the fit message's names, in order, as identification_node builds it (fit = {...})
    tree = ast.parse((ROOT / 'aeropend_ros' / 'identification_node.py').read_text())
    fits = [node.value for node in ast.walk(tree) if isinstance(node, ast.Assign) and isinstance(node.value, ast.Dict)
            and any(isinstance(t, ast.Name) and t.id == 'fit' for t in node.targets)]
    assert len(fits) == 1 and tuple(ast.literal_eval(k) for k in fits[0].keys) == layouts.FIT_NAMES


def test_layouts_name_only_published_fields():
    """Every plotted path is a topic of the graph and a field/name that the nodes publish."""
    from aeropend_ros import layouts
    known = layouts.published_fields()
    document = json.loads((ROOT / 'config' / layouts.FOXGLOVE_FILE).read_text())
    paths = re.findall(r'"value":"([^"]+)"', json.dumps(document['content'], separators=(',', ':')))
    assert paths, 'no plot series in the Foxglove layout'
    for path in paths:
        topic, _, field = path.partition('.')
        assert topic in known, path
        assert re.fullmatch(r'position\[(\d+)\]', field), path
        index = int(field[9:-1])
        assert index < len(known[topic]), path
    # the ±1σ band of every identified parameter is plotted from its own topic: value, upper and lower
    from aeropend_ros.topics import PARAMETER_FIELDS, parameter_topic
    for name in layouts.BAND_PARAMETERS:
        for part in ('value', 'upper', 'lower'):
            assert f'{parameter_topic(name)}.position[{PARAMETER_FIELDS.index(part)}]' in paths, (name, part)
    assert 'userScripts' not in document or not document['userScripts']

    tree = ElementTree.parse(ROOT / 'config' / layouts.PLOTJUGGLER_FILE)
    curves = [curve.get('name') for curve in tree.iter('curve')]
    assert curves and not list(tree.iter('snippet'))
    for curve in curves:
        topic, name, field = curve.rsplit('/', 2)
        assert topic in known and name in known[topic] and field == 'position', curve
    for name in layouts.BAND_PARAMETERS:
        for part in ('value', 'upper', 'lower'):
            assert f'{parameter_topic(name)}/{part}/position' in curves, (name, part)
    selected = {topic.get('name') for topic in tree.iter('topic')}
    assert {parameter_topic(name) for name in layouts.BAND_PARAMETERS} <= selected
    assert Path(ROOT / 'config' / layouts.PLOTJUGGLER_FILE).read_text().startswith('<?xml')


def test_foxglove_node_refuses_bad_parameters_in_one_line():
    ensure_ros_environment(local_only=True)
    from rclpy.parameter import Parameter

    from aeropend_ros._node_util import ParameterError
    from aeropend_ros.foxglove_node import FoxgloveNode
    from tests.ros_helpers import own_context
    cases = [({'include_regex': '(unclosed'}, 'include_regex'), ({'port': 70000}, 'port'),
             ({'prot': 0}, "has no parameter 'prot' (did you mean 'port'?")]
    with own_context(private_domain_id()) as context:
        for values, expected in cases:
            with pytest.raises(ParameterError, match=re.escape(expected)) as error:
                FoxgloveNode(context=context, parameter_overrides=[Parameter(k, value=v) for k, v in values.items()])
            assert '\n' not in str(error.value)
        node = FoxgloveNode(context=context, parameter_overrides=[Parameter('port', value=0)])
        try:
            assert node.port > 0 and node.url == f'ws://127.0.0.1:{node.port}'
            with pytest.raises(ParameterError, match='cannot serve Foxglove on 127.0.0.1'):
                FoxgloveNode(context=context, node_name='second', parameter_overrides=[
                    Parameter('port', value=node.port)])
        finally:
            node.destroy_node()
