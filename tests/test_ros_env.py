"""ensure_ros_environment: the venv prefix joins AMENT_PREFIX_PATH once; the discovery range is only set on request."""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from aeropend_ros._ros_env import ensure_ros_environment, local_ros_environment

HAS_INDEX = Path(sys.prefix, 'share', 'ament_index').is_dir()


@pytest.fixture
def clean_env(monkeypatch):
    monkeypatch.delenv('AMENT_PREFIX_PATH', raising=False)
    monkeypatch.delenv('ROS_AUTOMATIC_DISCOVERY_RANGE', raising=False)
    return monkeypatch


@pytest.mark.skipif(not HAS_INDEX, reason='ROS not installed as pip wheels in this prefix')
def test_prefix_added_once(clean_env):
    clean_env.setenv('AMENT_PREFIX_PATH', '/opt/somewhere')
    ensure_ros_environment()
    ensure_ros_environment()
    parts = os.environ['AMENT_PREFIX_PATH'].split(os.pathsep)
    assert parts == ['/opt/somewhere', sys.prefix]
    assert 'ROS_AUTOMATIC_DISCOVERY_RANGE' not in os.environ      # a user's node never changes discovery silently
    from ament_index_python.packages import get_package_share_directory
    assert Path(get_package_share_directory('sensor_msgs'), 'msg', 'JointState.msg').is_file()


def test_local_only_respects_user_choice(clean_env):
    ensure_ros_environment(local_only=True)
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    clean_env.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'SUBNET')
    ensure_ros_environment(local_only=True)
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SUBNET'


def test_child_environment(clean_env):
    before = dict(os.environ)
    env = local_ros_environment(base={'PATH': '/bin'}, domain_id=42)
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST' and env['ROS_DOMAIN_ID'] == '42'
    assert env['PATH'] == '/bin' and dict(os.environ) == before       # the caller's environment is untouched
    if HAS_INDEX:
        assert env['AMENT_PREFIX_PATH'].split(os.pathsep) == [sys.prefix]
