"""Make rclpy usable in the current process, whether ROS 2 comes from apt or from pip wheels in a venv.

Call :func:`ensure_ros_environment` before ``import rclpy``. On a normal Jazzy install (``source
/opt/ros/jazzy/setup.bash``) it changes nothing. With the ROS 2 pip wheels installed into a virtual environment
(see scripts/setup.sh) the message packages put their ``share/`` folder and the ament resource index into the
venv prefix, but nothing adds that prefix to ``AMENT_PREFIX_PATH``; without it the ament index (package share
folders, ``.msg`` files) cannot be found. The wheels' own start-up hook already sets ``LD_LIBRARY_PATH``.

Discovery range: ROS 2 Jazzy discovers peers on the whole subnet by default. Tests and demos must keep traffic on
this machine; they pass ``local_only=True`` (which sets ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` unless the
user set it). Nodes started by a user never change the user's discovery choice silently.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

__all__ = ['ament_prefixes', 'ensure_ros_environment', 'local_ros_environment']


def ament_prefixes() -> list[Path]:
    """Prefixes listed in ``AMENT_PREFIX_PATH``, in order (empty entries dropped)."""
    return [Path(part) for part in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if part]


def ensure_ros_environment(local_only: bool = False) -> None:
    """Prepare ``os.environ`` of this process so that rclpy and the ament index work.

    Parameters
    ----------
    local_only
        When true and the user has not chosen a discovery range, set ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``
        (tests, demos). Never set for plain node start-up.

    Notes
    -----
    Idempotent. Adds ``sys.prefix`` to ``AMENT_PREFIX_PATH`` only when ``sys.prefix/share/ament_index`` exists
    (ROS from pip wheels in a venv) and it is not already listed.
    """
    prefix = Path(sys.prefix)
    if (prefix / 'share' / 'ament_index').is_dir():
        listed = {str(p.resolve()) for p in ament_prefixes() if p.exists()}
        if str(prefix.resolve()) not in listed:
            current = os.environ.get('AMENT_PREFIX_PATH', '')
            os.environ['AMENT_PREFIX_PATH'] = os.pathsep.join(filter(None, [current, str(prefix)]))
    if local_only:
        os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')


def local_ros_environment(base: dict[str, str] | None = None, domain_id: int | None = None) -> dict[str, str]:
    """An environment for a child ROS process in a test or demo: local discovery, venv prefix in the index.

    Parameters
    ----------
    base
        Environment to start from (default: a copy of ``os.environ``).
    domain_id
        ``ROS_DOMAIN_ID`` to set (tests use a private one so parallel runs do not see each other).

    Returns
    -------
    dict
        A new environment mapping; ``base`` is not modified.
    """
    env = dict(os.environ if base is None else base)
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    prefix = Path(sys.prefix)
    if (prefix / 'share' / 'ament_index').is_dir():
        parts = [p for p in env.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
        if str(prefix) not in parts:
            env['AMENT_PREFIX_PATH'] = os.pathsep.join(parts + [str(prefix)])
    if domain_id is not None:
        env['ROS_DOMAIN_ID'] = str(int(domain_id))
    env.setdefault('PYTHONUNBUFFERED', '1')
    return env
