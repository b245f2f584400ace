"""Small helpers shared by the aeropend nodes: parameter declaration with descriptors and the Jazzy ``main``.

Imports rclpy (call :func:`aeropend_ros._ros_env.ensure_ros_environment` first; the node modules do).
"""
from __future__ import annotations

import sys
from collections.abc import Callable

from aeropend_ros._ros_env import ensure_ros_environment

ensure_ros_environment()

import rclpy  # noqa: E402
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor  # noqa: E402
from rclpy.executors import ExternalShutdownException  # noqa: E402

from aeropend_core.errors import AeropendError  # noqa: E402


def describe(description: str, *, read_only: bool = False, low: float | None = None, high: float | None = None,
             integer: bool = False) -> ParameterDescriptor:
    """A ``ParameterDescriptor`` with a description and, optionally, an inclusive range (enforced by rclpy)."""
    descriptor = ParameterDescriptor(description=description, read_only=read_only)
    if low is not None and high is not None:
        if integer:
            descriptor.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=0)]
        else:
            descriptor.floating_point_range = [FloatingPointRange(from_value=float(low), to_value=float(high),
                                                                  step=0.0)]
    return descriptor


def declare(node, name: str, default, description: str, **range_and_flags):
    """Declare one parameter with a descriptor and return its current value (default or from YAML/CLI)."""
    node.declare_parameter(name, default, describe(description, **range_and_flags))
    return node.get_parameter(name).value


def make_executor(prefer_events: bool = True):
    """An executor for one node: ``rclpy.experimental.EventsExecutor`` (less CPU) when available."""
    if prefer_events:
        try:
            from rclpy.experimental import EventsExecutor
            return EventsExecutor()
        except ImportError:  # pragma: no cover - older rclpy
            pass
    from rclpy.executors import SingleThreadedExecutor
    return SingleThreadedExecutor()


def run_node(node_factory: Callable[[], object], args=None, prefer_events: bool = True,
             until: Callable[[object], bool] | None = None) -> int:
    """Jazzy-style ``main``: init, build the node, spin until Ctrl-C (or ``until(node)``), destroy, shut down.

    A user mistake in the node's parameters (:class:`AeropendError` from the constructor) prints one line and
    returns 2 instead of a traceback.
    """
    rclpy.init(args=args)
    node = None
    status = 0
    try:
        node = node_factory()
        executor = make_executor(prefer_events)
        executor.add_node(node)
        if until is None:
            executor.spin()
        else:
            while rclpy.ok() and not until(node):
                executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except AeropendError as error:
        print(f'error: {error}', file=sys.stderr)
        status = 2
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return status
