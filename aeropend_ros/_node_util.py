"""Small helpers shared by the aeropend nodes: parameter declaration with descriptors and the Jazzy ``main``.

Imports rclpy (call :func:`aeropend_ros._ros_env.ensure_ros_environment` first; the node modules do).
"""
from __future__ import annotations

import math
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


def checked_duty(node, duty: float, limit_parameter: str) -> tuple[float, bool]:
    """A duty command made safe: not a number -> 0, outside [0, limit] -> clamped (both logged).

    Returns the duty to apply and whether it was clamped; `limit_parameter` names the node's cap parameter.
    """
    limit = float(node.get_parameter(limit_parameter).value)
    if not math.isfinite(duty):
        node.get_logger().warning(f'duty command {duty!r} is not a number: duty set to 0')
        duty = 0.0
    if 0.0 <= duty <= limit:
        return duty, False
    node.get_logger().warning(f'duty command {duty:.3f} outside [0, {limit:.3f}] ({limit_parameter}): clamped',
                              throttle_duration_sec=2.0)
    return min(max(duty, 0.0), limit), True


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


def _raise_keyboard_interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def run_node(node_factory: Callable[[], object], args=None, prefer_events: bool = True,
             until: Callable[[object], bool] | None = None) -> int:
    """Jazzy-style ``main``: init, build the node, spin until Ctrl-C (or ``until(node)``), destroy, shut down.

    Ctrl-C (SIGINT) and SIGTERM become a ``KeyboardInterrupt`` in this thread while the ROS context is still up,
    so that ``destroy_node`` can still publish (the excitation node sends duty 0 on the way out); rclpy's own
    signal handler would shut the context down first. A user mistake in the node's parameters
    (:class:`AeropendError` from the constructor) prints one line and returns 2 instead of a traceback.
    """
    import signal

    from rclpy.signals import SignalHandlerOptions
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    previous_sigterm = signal.signal(signal.SIGTERM, _raise_keyboard_interrupt)
    node = None
    status = 0
    try:
        node = node_factory()
        executor = make_executor(prefer_events)
        executor.add_node(node)
        # spin_once with a timeout returns to Python regularly, so the interrupt is delivered promptly.
        while rclpy.ok() and not (until is not None and until(node)):
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except AeropendError as error:
        print(f'error: {error}', file=sys.stderr)
        status = 2
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)      # a second Ctrl-C must not cut the clean-up short
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        signal.signal(signal.SIGTERM, previous_sigterm)
        signal.signal(signal.SIGINT, signal.default_int_handler)
    return status
