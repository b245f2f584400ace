"""Result files are written to regular files only: through a symbolic link (the link stays, its target is replaced),
never onto a device, a named pipe or a socket, never through a link loop; a regular file is replaced atomically
(written under a temporary name, renamed when complete: a new inode, the old mode kept)."""
from __future__ import annotations

import os
import socket
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from aeropend_core.errors import AeropendError
from aeropend_core.io.paths import output_target, write_atomically
from aeropend_core.io.recording import load_csv

ROOT = Path(__file__).resolve().parents[1]
AEROPEND = [sys.executable, '-c', 'import sys; from aeropend_core.cli import main; sys.exit(main())']


def simulate(output: Path | str) -> subprocess.CompletedProcess:
    return subprocess.run([*AEROPEND, 'simulate', '-o', str(output), '--duration', '0.2', '--seed', '1'],
                          capture_output=True, text=True, timeout=120, cwd=ROOT, check=False)


def one_line_error(result: subprocess.CompletedProcess, status: int = 2) -> str:
    assert result.returncode == status, result.stderr
    assert 'Traceback' not in result.stderr and len(result.stderr.strip().splitlines()) == 1, result.stderr
    return result.stderr


@pytest.mark.slow
def test_simulate_writes_through_a_symlink_and_keeps_it(tmp_path):
    (tmp_path / 'data').mkdir()
    target = tmp_path / 'data' / 'run.csv'
    target.write_text('old\n')
    link = tmp_path / 'latest.csv'
    link.symlink_to(target)
    result = simulate(link)
    assert result.returncode == 0, result.stderr
    assert link.is_symlink() and Path(os.readlink(link)) == target
    assert len(load_csv(target)) == 98 and not list((tmp_path / 'data').glob('.*partial'))
    dangling = tmp_path / 'new.csv'                   # a link to a file not there yet: the file is created
    dangling.symlink_to(tmp_path / 'data' / 'fresh.csv')
    assert simulate(dangling).returncode == 0
    assert dangling.is_symlink() and len(load_csv(tmp_path / 'data' / 'fresh.csv')) == 98


def test_regular_file_is_replaced_atomically_with_its_mode(tmp_path):
    target = tmp_path / 'run.csv'
    target.write_text('old\n')
    target.chmod(0o640)
    inode = target.stat().st_ino
    assert simulate(target).returncode == 0
    assert target.stat().st_ino != inode, 'not renamed onto the file: written in place'
    assert stat.S_IMODE(target.stat().st_mode) == 0o640 and len(load_csv(target)) == 98
    assert [p.name for p in tmp_path.iterdir()] == ['run.csv']


def test_symlink_loop_is_named(tmp_path):
    (tmp_path / 'a.csv').symlink_to(tmp_path / 'b.csv')
    (tmp_path / 'b.csv').symlink_to(tmp_path / 'a.csv')
    assert 'symbolic link loop' in one_line_error(simulate(tmp_path / 'a.csv'))
    assert (tmp_path / 'a.csv').is_symlink() and (tmp_path / 'b.csv').is_symlink()


def test_fifo_socket_and_device_are_refused_untouched(tmp_path):
    fifo = tmp_path / 'pipe.csv'
    os.mkfifo(fifo)
    assert 'named pipe (FIFO)' in one_line_error(simulate(fifo))      # refused before opening: no blocking
    assert stat.S_ISFIFO(fifo.lstat().st_mode)
    link = tmp_path / 'to_pipe.csv'
    link.symlink_to(fifo)
    assert 'symbolic link points to' in one_line_error(simulate(link))
    with socket.socket(socket.AF_UNIX) as server:
        server.bind(str(tmp_path / 'sock'))
        assert 'a socket' in one_line_error(simulate(tmp_path / 'sock'))
    if os.geteuid() == 0:           # a device node of our own (never the system's) when we may create one
        device = tmp_path / 'null_device'
        os.mknod(device, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    else:                           # without root the system's device cannot be replaced anyway
        device = Path('/dev/null')
    message = one_line_error(simulate(device))
    assert 'character device' in message and '- for standard output' in message, message
    assert stat.S_ISCHR(device.lstat().st_mode)


def test_report_and_calibration_writers_follow_the_same_rules(tmp_path):
    fifo = tmp_path / 'report.html'
    os.mkfifo(fifo)
    result = subprocess.run([*AEROPEND, 'diagnose', str(ROOT / 'bags' / 'exercise.csv'), '--report', str(fifo)],
                            capture_output=True, text=True, timeout=120, cwd=ROOT, check=False)
    assert 'named pipe' in one_line_error(result) and '--report' in result.stderr
    from aeropend_core.cli.calibrate import write_values
    config = tmp_path / 'real.yaml'
    config.write_text('serial_bridge_node:\n  ros__parameters:\n    angle_zero: 500.0  # counts\n')
    link = tmp_path / 'bridge.yaml'
    link.symlink_to(config)
    write_values(link, {'angle_zero': 512.0})
    assert link.is_symlink() and 'angle_zero: 512.0  # counts' in config.read_text()
    with pytest.raises(AeropendError, match='named pipe'):
        write_values(fifo, {'angle_zero': 1.0})
    with pytest.raises(AeropendError, match='is a folder'):
        output_target(tmp_path)
    with pytest.raises(AeropendError, match='does not exist'):
        write_atomically(tmp_path / 'missing' / 'x.csv', lambda handle: handle.write('x'))


def test_symlink_loop_and_permissions_get_the_same_rules_when_reading(tmp_path):
    """A recording given through a symbolic link loop is named as a loop (not 'no such file'); a file the system
    will not let us read is exit status 1 (the system refused), like a full disk; a missing one is 2."""
    (tmp_path / 'a.csv').symlink_to(tmp_path / 'b.csv')
    (tmp_path / 'b.csv').symlink_to(tmp_path / 'a.csv')
    (tmp_path / 'bag').symlink_to(tmp_path / 'bag')
    for verb, path in (('identify', 'a.csv'), ('diagnose', 'a.csv'), ('bag-recover', 'bag')):
        result = subprocess.run([*AEROPEND, verb, str(tmp_path / path)], capture_output=True, text=True,
                                timeout=120, cwd=ROOT, check=False)
        assert 'symbolic link loop' in one_line_error(result), (verb, result.stderr)
    result = subprocess.run([*AEROPEND, 'diagnose', str(ROOT / 'bags' / 'exercise.csv'), '--effects-module',
                             str(tmp_path / 'a.csv')], capture_output=True, text=True, timeout=120, cwd=ROOT,
                            check=False)
    assert 'symbolic link loop' in one_line_error(result)
    missing = subprocess.run([*AEROPEND, 'identify', str(tmp_path / 'missing.csv')], capture_output=True, text=True,
                             timeout=120, cwd=ROOT, check=False)
    assert 'no such file' in one_line_error(missing, 2)
    if os.geteuid() != 0:               # root reads anything: the refusal cannot be staged
        locked = tmp_path / 'locked.csv'
        locked.write_text('t,duty,armature_voltage,armature_current,angle\n0,0,0,0,0\n')
        locked.chmod(0)
        result = subprocess.run([*AEROPEND, 'identify', str(locked)], capture_output=True, text=True, timeout=120,
                                cwd=ROOT, check=False)
        assert 'Permission denied' in one_line_error(result, 1)
    from aeropend_core.errors import StorageError
    from aeropend_core.io.paths import storage_error
    assert isinstance(storage_error(PermissionError(13, 'Permission denied'), 'x'), StorageError)
    assert not isinstance(storage_error(FileNotFoundError(2, 'No such file'), 'x'), StorageError)
