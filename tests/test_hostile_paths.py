"""Hostile input paths of issue 43: a named pipe, a device or a socket given where a file is read, and a YAML nested
100,000 deep, are refused in one line with exit status 2 and at once (before: a FIFO hung every input for ever,
silently, and the deep YAML ended in "this is a bug in aeropend").

Every file input of the command line is listed here; the shared checks are ``aeropend_core.io.inputs``.
"""
from __future__ import annotations

import json
import os
import signal
import socket
import time
from pathlib import Path

import pytest

from aeropend_core import cli
from aeropend_core.errors import AeropendError
from aeropend_core.io import inputs

REPO = Path(__file__).resolve().parents[1]
BAG = str(REPO / 'bags' / 'sample_sim')
PROFILE = str(REPO / 'config' / 'profiles' / 'arduino_logger.yaml')

#: Every command-line file input: (arguments with X for the hostile path, whether X is read as YAML).
INPUTS = [
    (['identify', 'X'], False),
    (['diagnose', 'X'], False),
    (['diagnose', BAG, '--validate', 'X'], False),
    (['bag-recover', 'X'], False),
    (['identify', BAG, '--profile', 'X'], True),
    (['identify', BAG, '--calibration', 'X'], True),
    (['diagnose', BAG, '--calibration', 'X'], True),
    (['calibrate', 'zero', '--port', '/dev/null', '--config', 'X'], True),
    (['effects', '--write-discovered', 'OUT.py', '--from-json', 'X'], False),
    (['import', 'X', '--profile', PROFILE, '-o', 'OUT.csv'], False),
    (['run', '--experiment', 'X'], True),
    (['run', '--calibration', 'X'], True),
]


@pytest.fixture(autouse=True)
def _no_debug(monkeypatch):
    monkeypatch.delenv('AEROPEND_DEBUG', raising=False)


class _Hung(Exception):
    pass


def run_bounded(argv: list[str], capsys, seconds: int = 60) -> tuple[int, str, float]:
    """cli.main(argv) with an alarm: a hang fails the test instead of hanging it. The bound is for a hang, not a
    speed target (a 100,000-deep YAML was refused in 11 s at a load average of 20; speed belongs in bench/)."""
    def alarm(*_):
        raise _Hung(f'{argv} did not return within {seconds} s')
    previous = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(seconds)
    start = time.monotonic()
    try:
        status = cli.main(argv)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    captured = capsys.readouterr()
    return status, captured.err, time.monotonic() - start


def _argv(template: list[str], hostile: str, tmp_path: Path) -> list[str]:
    return [hostile if a == 'X' else str(tmp_path / a) if a.startswith('OUT') else a for a in template]


@pytest.fixture
def fifo(tmp_path):
    path = tmp_path / 'pipe.yaml'
    os.mkfifo(path)
    return path


@pytest.mark.parametrize('template', [t for t, _ in INPUTS], ids=lambda t: ' '.join(t[:1] + t[-2:-1]))
def test_a_named_pipe_is_refused_at_once_in_every_input(tmp_path, capsys, fifo, template):
    status, err, _ = run_bounded(_argv(template, str(fifo), tmp_path), capsys)
    assert status == 2, err
    assert 'named pipe (FIFO)' in err and str(fifo) in err
    assert len(err.strip().splitlines()) == 1 and 'Traceback' not in err


@pytest.mark.parametrize('template', [t for t, _ in INPUTS if t[0] in ('identify', 'bag-recover', 'effects')
                                      or '--calibration' in t], ids=lambda t: ' '.join(t[:1] + t[-2:-1]))
def test_a_device_is_refused(tmp_path, capsys, template):
    status, err, _ = run_bounded(_argv(template, '/dev/zero', tmp_path), capsys)
    assert status == 2, err
    assert 'character device' in err and len(err.strip().splitlines()) == 1


def test_a_socket_is_refused(tmp_path, capsys):
    path = tmp_path / 's.yaml'
    server = socket.socket(socket.AF_UNIX)
    server.bind(str(path))
    try:
        for template in ([t for t, _ in INPUTS if t[0] == 'identify' and len(t) == 2][0],
                         ['identify', BAG, '--calibration', 'X']):
            status, err, _ = run_bounded(_argv(template, str(path), tmp_path), capsys)
            assert status == 2 and 'a socket' in err and len(err.strip().splitlines()) == 1, err
    finally:
        server.close()


@pytest.mark.parametrize('template', [t for t, yaml_input in INPUTS if yaml_input] +
                         [['calibrate', 'angle-filter', '--write', 'X']], ids=lambda t: ' '.join(t[:1] + t[-2:-1]))
def test_a_yaml_nested_100000_deep_is_refused_in_one_line(tmp_path, capsys, template):
    deep = tmp_path / 'deep.yaml'
    deep.write_text('a: ' + '[' * 100_000 + ']' * 100_000 + '\n')
    status, err, _ = run_bounded(_argv(template, str(deep), tmp_path), capsys)
    assert status == 2, err
    assert 'nests more than' in err and 'bug' not in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize('libyaml', [True, False], ids=['libyaml', 'pyyaml'])
def test_yaml_limits_aliases_and_size(libyaml, monkeypatch):
    """The same limits whichever parser reads the events (s25: libyaml's where there is one, PyYAML's else and
    where libyaml refuses a text)."""
    import yaml
    if not libyaml:
        monkeypatch.delattr(yaml, 'CSafeLoader', raising=False)
    deep = 'a: ' + '[' * (inputs.YAML_MAX_DEPTH + 5) + ']' * (inputs.YAML_MAX_DEPTH + 5) + '\n'
    with pytest.raises(AeropendError, match='nests more than'):
        inputs.check_yaml_text(deep)
    bomb = 'a: &a [x, x]\n' + ''.join(f'{chr(98 + k)}: &{chr(98 + k)} [*{chr(97 + k)}, *{chr(97 + k)}]\n'
                                      for k in range(20)) + 'z: [' + ', '.join(['*a'] * 300) + ']\n'
    with pytest.raises(AeropendError, match='aliases'):
        inputs.check_yaml_text(bomb)
    with pytest.raises(AeropendError, match='larger than'):
        inputs.check_yaml_text('a: 1\n' * (inputs.YAML_MAX_BYTES // 4))
    inputs.check_yaml_text('a: [1, {b: [2, 3]}]\n')             # ordinary YAML passes
    inputs.check_yaml_text('a: [1, 2\n')                        # a syntax error is left to the loader


def test_a_json_nested_too_deep_is_refused(tmp_path, capsys):
    deep = tmp_path / 'deep.json'
    deep.write_text('[' * 100_000 + ']' * 100_000)
    status, err, _ = run_bounded(['effects', '--write-discovered', str(tmp_path / 'o.py'), '--from-json',
                                  str(deep)], capsys)
    assert status == 2 and 'nests too deep' in err and len(err.strip().splitlines()) == 1, err


def test_open_input_never_blocks_on_a_fifo_swapped_in_after_the_check(tmp_path, monkeypatch):
    fifo = tmp_path / 'late'
    os.mkfifo(fifo)
    monkeypatch.setattr(inputs, 'check_input', lambda *a, **k: Path(a[0]))     # the check passed earlier
    with pytest.raises(AeropendError, match='named pipe'):
        inputs.open_input(fifo, 'x')


def test_regular_files_still_read(tmp_path):
    path = tmp_path / 'ok.json'
    path.write_text(json.dumps({'a': 1}))
    assert inputs.read_input_text(path, 'x') == '{"a": 1}'
    assert inputs.check_input(tmp_path, 'bag', folder=True) == tmp_path
    with pytest.raises(AeropendError, match='is a folder'):
        inputs.check_input(tmp_path, 'file')


def test_deep_yaml_or_json_inside_a_recording_is_no_bug(tmp_path, capsys):
    """Nested text inside the data: a bag channel's QoS YAML (read by bag-recover) and the import comment of a CSV."""
    from mcap.writer import Writer

    from aeropend_core.io.bag_recover import recover_bag
    bag = tmp_path / 'deep_qos.mcap'
    with open(bag, 'wb') as stream:
        writer = Writer(stream)
        writer.start(profile='ros2', library='test')
        schema = writer.register_schema('std_msgs/msg/Float64', 'ros2msg', b'float64 data\n')
        channel = writer.register_channel('/x', 'cdr', schema,
                                          {'offered_qos_profiles': '[' * 100_000 + ']' * 100_000})
        writer.add_message(channel, 1, b'\x00\x01\x00\x00' + bytes(8), 1, 1)
        writer.finish()
    data = bag.read_bytes()
    bag.write_bytes(data[:-10])                 # cut: bag-recover rewrites it and reads the QoS
    report = recover_bag(bag)
    assert report.message_count == 1
    csv = tmp_path / 'deep_comment.csv'
    csv.write_text('# aeropend-import: ' + '[' * 100_000 + ']' * 100_000 + '\n'
                   't,duty,armature_voltage,armature_current,angle\n0,0,1,0.1,0\n')
    status, err, _ = run_bounded(['identify', str(csv)], capsys)
    assert status == 2 and 'bug' not in err and len(err.strip().splitlines()) == 1, err
