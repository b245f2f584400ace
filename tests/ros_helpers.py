"""Helpers for tests that run real ROS 2 nodes as separate processes over DDS (local discovery only).

``wait_for(condition, timeout, node)`` polls (spinning the in-test node) instead of sleeping fixed times;
``NodeProcess`` starts ``python -m aeropend_ros.<module> --ros-args ...`` with a private ROS_DOMAIN_ID and stops it
with SIGINT (like Ctrl-C), keeping its output for failure messages.
"""
from __future__ import annotations

import contextlib
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from aeropend_ros._ros_env import ensure_ros_environment, local_ros_environment

ROOT = Path(__file__).resolve().parents[1]


#: Domains handed out in this process (never twice).
_USED_DOMAINS: set[int] = set()


def private_domain_id(probe_seconds: float = 1.0) -> int:
    """A ROS_DOMAIN_ID (1..100) that nobody else on this machine is using right now.

    Random candidates are probed: a throw-away node joins the domain and watches the ROS graph for
    `probe_seconds`; the first domain where no other node shows up is taken. Several test runs share this
    machine, and two sims on one domain would interleave their samples.
    """
    rng = random.Random(os.getpid() * 7919 + time.monotonic_ns())
    candidates = [d for d in rng.sample(range(1, 101), 100) if d not in _USED_DOMAINS]
    chosen = candidates[0]
    for domain_id in candidates[:10]:
        if _domain_is_quiet(domain_id, probe_seconds):
            chosen = domain_id
            break
    _USED_DOMAINS.add(chosen)
    return chosen


def _domain_is_quiet(domain_id: int, seconds: float) -> bool:
    """True when no other ROS node appears on `domain_id` within `seconds` (local discovery)."""
    ensure_ros_environment(local_only=True)
    import rclpy
    with own_context(domain_id) as context:
        node = rclpy.create_node('domain_probe', context=context)
        try:
            deadline = time.monotonic() + seconds
            while time.monotonic() < deadline:
                if len(node.get_node_names()) > 1:
                    return False
                time.sleep(0.05)
            return True
        finally:
            node.destroy_node()


@contextlib.contextmanager
def own_context(domain_id: int):
    """An rclpy context of its own on `domain_id` (tests never touch the global one), shut down on exit."""
    import rclpy
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


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
