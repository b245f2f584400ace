"""Helpers for tests that run real ROS 2 nodes as separate processes over DDS (local discovery only).

``wait_for(condition, timeout, node)`` polls (spinning the in-test node) instead of sleeping fixed times;
``NodeProcess`` starts ``python -m aeropend_ros.<module> --ros-args ...`` with a private ROS_DOMAIN_ID and stops it
with SIGINT (like Ctrl-C), keeping its output for failure messages.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from aeropend_ros._ros_env import ensure_ros_environment, local_ros_environment
from aeropend_ros.testing import own_context, private_domain_id  # noqa: F401 - re-exported for the tests

ROOT = Path(__file__).resolve().parents[1]


def use_domain(domain_id: int) -> None:
    """Put this (test) process on `domain_id` with local discovery, before ``rclpy.init``."""
    ensure_ros_environment(local_only=True)
    os.environ['ROS_DOMAIN_ID'] = str(domain_id)


def wait_for(condition, timeout: float, node=None, executor=None, period: float = 0.02) -> bool:
    """Poll `condition()` until true or `timeout` [s] passes, spinning `executor` (or `node`) meanwhile."""
    import rclpy
    deadline = time.monotonic() + timeout
    while True:
        if condition():
            return True
        if time.monotonic() > deadline:
            return False
        if executor is not None:
            executor.spin_once(timeout_sec=period)
        elif node is not None:
            rclpy.spin_once(node, timeout_sec=period)
        else:
            time.sleep(period)


class NodeProcess:
    """A node started as its own process: ``python -m aeropend_ros.<module> --ros-args <ros_args>``."""

    def __init__(self, module: str, ros_args: list[str] = (), domain_id: int | None = None,
                 extra_args: list[str] = ()) -> None:
        self.module = module
        env = local_ros_environment(domain_id=domain_id)
        self.log = tempfile.NamedTemporaryFile('w+', prefix=f'{module.rsplit(".", 1)[-1]}_', suffix='.log',
                                               delete=False)
        command = [sys.executable, '-m', module, *extra_args]
        if ros_args:
            command += ['--ros-args', *ros_args]
        self.process = subprocess.Popen(command, env=env, cwd=ROOT, stdout=self.log, stderr=subprocess.STDOUT)

    def output(self) -> str:
        self.log.flush()
        return Path(self.log.name).read_text(errors='replace')

    def stop(self, timeout: float = 10.0) -> int:
        """SIGINT (Ctrl-C), then SIGKILL after `timeout` [s]; returns the exit status."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        return self.process.returncode

    def __enter__(self) -> NodeProcess:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
        self.log.close()
        os.unlink(self.log.name)
