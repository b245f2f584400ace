"""Helpers for running real ROS 2 nodes in tests and benchmarks: a private ROS_DOMAIN_ID, an rclpy context of one's own.

Shipped with the package (the load test in bench/ uses them too); importing this module imports no rclpy until a
helper is called.
"""
from __future__ import annotations

import contextlib
import os
import random
import time

from aeropend_ros._ros_env import ensure_ros_environment


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


__all__ = ['own_context', 'private_domain_id']
