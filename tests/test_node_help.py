"""Every node executable answers --help without starting: its parameters with defaults and units, its topics, exit 0,
no file created, no node on the graph. `--ros-args` still reaches ROS (issue #24 item 3).

Before: `recorder_node --help` started a recorder that wrote a bag into bags/ and ran until killed.
"""
from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from aeropend_ros._ros_env import local_ros_environment
from tests.ros_helpers import ROOT, private_domain_id

pytestmark = pytest.mark.ros


def executables() -> dict[str, str]:
    """console_scripts of setup.py that are nodes: executable -> module."""
    text = (ROOT / 'setup.py').read_text(encoding='utf-8')
    return dict(re.findall(r"'(\w+_node) = (aeropend_ros\.\w+):main'", text))


def declared_names(module: str) -> set[str]:
    """Parameter names a node module declares with a literal name (declare(self, 'name', ...))."""
    path = ROOT / (module.replace('.', '/') + '.py')
    names = set()
    for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
        if isinstance(node, ast.Call) and getattr(node.func, 'id', '') == 'declare' and len(node.args) >= 2 and \
                isinstance(node.args[1], ast.Constant):
            names.add(node.args[1].value)
    return names


def start(executable: str, module: str, *arguments: str, cwd: Path, env: dict) -> subprocess.CompletedProcess:
    """The installed console script when there is one (what `ros2 run` executes), else its main() by module."""
    script = Path(sys.executable).with_name(executable)
    command = [str(script)] if script.exists() else [sys.executable, '-c',
                                                     f'import sys; from {module} import main; sys.exit(main())']
    env = {**env, 'PYTHONPATH': os.pathsep.join([str(ROOT), env.get('PYTHONPATH', '')])}
    return subprocess.run([*command, *arguments], cwd=cwd, env=env, capture_output=True, text=True, timeout=120,
                          check=False)


def test_every_node_executable_is_covered():
    assert set(executables()) == {'sim_node', 'excitation_node', 'recorder_node', 'identification_node',
                                  'serial_bridge_node', 'foxglove_node'}


@pytest.mark.parametrize('executable', sorted(executables()))
@pytest.mark.parametrize('flag', ['--help', '-h'])
def test_node_help_lists_parameters_and_topics_and_starts_nothing(tmp_path, executable, flag):
    module = executables()[executable]
    env = local_ros_environment(domain_id=private_domain_id())
    result = start(executable, module, flag, cwd=tmp_path, env=env)
    assert result.returncode == 0, result.stderr
    assert result.stderr == '', result.stderr               # no node started: not one log line
    assert list(tmp_path.iterdir()) == []                   # no bag folder, no file of any kind
    out = result.stdout
    assert out.startswith(f'usage: {executable} ')
    listed = set(re.findall(r'^  (\w+) \(default ', out, flags=re.MULTILINE))
    assert declared_names(module) <= listed, declared_names(module) - listed
    assert 'publishes' in out or 'subscribes to' in out
    assert re.search(r'\[(s|Hz|dB|rad|V|A|bytes|1)[^\]]*\]', out), 'no unit in the parameter descriptions'


def test_recorder_help_shows_its_default_output_and_topics(tmp_path):
    result = start('recorder_node', 'aeropend_ros.recorder_node', '--help', cwd=tmp_path,
                   env=local_ros_environment(domain_id=private_domain_id()))
    assert "output (default ''; start-up only)" in result.stdout
    assert "topics (default ['aeropend/samples', 'aeropend/duty_cmd', '/diagnostics']" in result.stdout
    assert not (tmp_path / 'bags').exists()


def test_ros_args_still_reach_ros_and_help_after_them_is_not_ours(tmp_path):
    """A bad value after --ros-args is judged by the node (exit 2, one line naming the parameter), i.e. the node was
    built from the ROS arguments, not answered with our help."""
    env = local_ros_environment(domain_id=private_domain_id())
    result = start('sim_node', 'aeropend_ros.sim_node', '--ros-args', '-p', 'psnr_db:=-5.0', cwd=tmp_path, env=env)
    assert result.returncode == 2, result.stdout + result.stderr
    assert 'psnr_db' in result.stderr and 'usage:' not in result.stdout
