"""`colcon build` of the package into a temporary workspace, then run the installed
``install/aeropend_ros/lib/aeropend_ros/recorder_node`` (exactly what ``ros2 run aeropend_ros recorder_node``
executes) with the environment the install's setup script would give: it starts, logs, records, and exits cleanly
on SIGINT with a finalised bag.

ROS from pip wheels has no ``/opt/ros/jazzy/setup.bash``, so the environment is made by hand: AMENT_PREFIX_PATH =
the install prefix + the ROS prefix, PYTHONPATH = the install's site-packages.
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from aeropend_ros._ros_env import local_ros_environment
from tests.ros_helpers import private_domain_id, wait_for

ROOT = Path(__file__).resolve().parents[1]
PACKAGE_FILES = ['package.xml', 'setup.py', 'setup.cfg', 'requirements.txt', 'requirements-dev.txt', 'resource',
                 'aeropend_ros', 'aeropend_core', 'config', 'launch']
COLCON = shutil.which('colcon', path=str(Path(sys.executable).parent)) or shutil.which('colcon')

pytestmark = [pytest.mark.timeout(240),
              pytest.mark.skipif(COLCON is None, reason='colcon not installed (pip install colcon-common-extensions)')]


@pytest.fixture(scope='module')
def workspace(tmp_path_factory) -> Path:
    """A colcon workspace with this package in src/, built (plain copy install, like a user's first build)."""
    ws = tmp_path_factory.mktemp('colcon_ws')
    package = ws / 'src' / 'aeropend_ros'
    package.mkdir(parents=True)
    for name in PACKAGE_FILES:
        source = ROOT / name
        if source.is_dir():
            shutil.copytree(source, package / name, ignore=shutil.ignore_patterns('__pycache__', '*.pyc'))
        else:
            shutil.copy2(source, package / name)
    env = dict(os.environ, PATH=f'{Path(sys.executable).parent}{os.pathsep}{os.environ.get("PATH", "")}')
    result = subprocess.run([COLCON, 'build', '--base-paths', 'src', '--event-handlers', 'console_direct-'],
                            cwd=ws, env=env, capture_output=True, text=True, timeout=180, check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    return ws


def installed_environment(ws: Path) -> dict[str, str]:
    """What `source install/setup.bash` on top of a Jazzy install provides, made by hand."""
    install = ws / 'install' / 'aeropend_ros'
    site = install / 'lib' / f'python{sys.version_info.major}.{sys.version_info.minor}' / 'site-packages'
    env = local_ros_environment(domain_id=private_domain_id())
    prefixes = [str(install)] + [p for p in env.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    if Path(sys.prefix, 'share', 'ament_index').is_dir() and sys.prefix not in prefixes:
        prefixes.append(sys.prefix)
    env['AMENT_PREFIX_PATH'] = os.pathsep.join(prefixes)
    env['PYTHONPATH'] = os.pathsep.join([str(site)] + [p for p in env.get('PYTHONPATH', '').split(os.pathsep) if p])
    return env


def test_install_layout(workspace):
    install = workspace / 'install' / 'aeropend_ros'
    for executable in ['sim_node', 'excitation_node', 'recorder_node', 'identification_node', 'serial_bridge_node']:
        path = install / 'lib' / 'aeropend_ros' / executable
        assert path.is_file() and os.access(path, os.X_OK), f'{executable} not installed where ros2 run looks'
    assert (install / 'share' / 'aeropend_ros' / 'package.xml').is_file()
    assert (install / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'aeropend_ros').is_file()
    assert (install / 'share' / 'aeropend_ros' / 'config' / 'recorder_node.yaml').is_file()
    # ros2 launch aeropend_ros sim.launch.py / rig.launch.py find them here; the layouts ship next to the YAML
    share = install / 'share' / 'aeropend_ros'
    assert sorted(p.name for p in (share / 'launch').glob('*.launch.py')) == \
        sorted(p.name for p in (ROOT / 'launch').glob('*.launch.py')) == ['rig.launch.py', 'sim.launch.py']
    for name in ['foxglove_node.yaml', 'aeropend.foxglove.json', 'aeropend.plotjuggler.xml']:
        assert (share / 'config' / name).is_file(), name
    path = install / 'lib' / 'aeropend_ros' / 'foxglove_node'
    assert path.is_file() and os.access(path, os.X_OK), 'foxglove_node not installed where ros2 run looks'
    # the installed copy, not the source tree, is what the environment imports
    probe = subprocess.run([sys.executable, '-c', 'import aeropend_ros.recorder_node as m; print(m.__file__)'],
                           env=installed_environment(workspace), capture_output=True, text=True, timeout=60,
                           cwd=workspace, check=False)
    assert probe.returncode == 0, probe.stderr
    assert Path(probe.stdout.strip()).is_relative_to(install), probe.stdout


def test_installed_recorder_node_runs_and_stops_on_sigint(workspace, tmp_path):
    install = workspace / 'install' / 'aeropend_ros'
    bag = tmp_path / 'colcon_bag'
    log = tmp_path / 'recorder.log'
    params = install / 'share' / 'aeropend_ros' / 'config' / 'recorder_node.yaml'
    command = [str(install / 'lib' / 'aeropend_ros' / 'recorder_node'), '--ros-args',
               '--params-file', str(params), '-p', f'output:={bag}', '-p', 'diagnostics_period:=0.2',
               '-p', 'chunk_size:=1024']
    with open(log, 'w') as out:
        process = subprocess.Popen(command, env=installed_environment(workspace), cwd=tmp_path, stdout=out,
                                   stderr=subprocess.STDOUT)
        try:
            # it logs its start, then records its own /diagnostics (its publisher is discovered like any other)
            assert wait_for(lambda: 'recording /diagnostics' in log.read_text(), 30), log.read_text()
            assert wait_for(lambda: process.poll() is None and (bag / 'metadata.yaml').is_file(), 60)
            # a 1 KiB chunk goes to disk after a diagnostics message or two: wait until the file grows by one
            mcap = next(bag.glob('*.mcap'))
            empty = mcap.stat().st_size
            assert wait_for(lambda: mcap.stat().st_size > empty, 60), log.read_text()
            process.send_signal(signal.SIGINT)
            status = process.wait(30)
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
    output = log.read_text()
    assert status == 0, output
    assert f'recording to {bag}' in output and 'finalised' in output, output
    assert 'Traceback' not in output, output
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    counts = {t['topic_metadata']['name']: t['message_count'] for t in info['topics_with_message_count']}
    assert counts.get('/diagnostics', 0) >= 1, info
    from rosbags.highlevel import AnyReader
    with AnyReader([bag]) as reader:
        assert reader.message_count == info['message_count']
    shebang = (install / 'lib' / 'aeropend_ros' / 'recorder_node').read_text().splitlines()[0]
    assert shebang.startswith('#!') and Path(shebang[2:].split()[0]).name.startswith('python')
