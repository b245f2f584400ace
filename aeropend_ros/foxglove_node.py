"""foxglove_node: serve the live aeropend graph to Foxglove over its WebSocket protocol (``foxglove-sdk``).

Every topic whose name matches ``include_regex`` (default: this rig's topics, ``^<namespace>/aeropend/``, and
``/diagnostics``; :func:`default_include`) is subscribed
as soon as a publisher of it is discovered, with the publishers' QoS (best effort for the SensorData samples,
transient local when every publisher is), and each message is forwarded **as received**: the raw CDR bytes, with
the type's ``ros2msg`` definition as the channel schema (the same schema text the recorder writes into the bags).
Foxglove decodes CDR natively, so the live view shows exactly the field paths of a recorded bag
(``/aeropend/samples.position[0]`` is the angle) and one layout (``config/aeropend.foxglove.json``) serves both;
nothing is deserialised or converted in Python. JSON encoding would cost a
conversion per message and give different field paths live and in the bags.

The server listens on ``ws://<host>:<port>`` (default ``ws://127.0.0.1:8765``, Foxglove's default: open
Foxglove, *Open connection*, *Foxglove WebSocket*). ``port`` 0 takes any free port (logged). On a full ROS 2
install the official C++ ``foxglove_bridge`` (``apt install ros-jazzy-foxglove-bridge``;
``ros2 launch foxglove_bridge foxglove_bridge_launch.xml``) does the same for every topic; this node exists for
the pip-installed graph, which has no such bridge.

Usage::

    ros2 run aeropend_ros foxglove_node --ros-args --params-file config/foxglove_node.yaml
    aeropend run --foxglove            # the whole graph with this node inside
"""
from __future__ import annotations

import re
import sys
import time

from aeropend_ros._ros_env import ament_prefixes, ensure_ros_environment

ensure_ros_environment()

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from aeropend_core.errors import AeropendError
from aeropend_core.io.mcap_format import MESSAGE_ENCODING, SCHEMA_ENCODING, msg_file_loader, ros2msg_definition
from aeropend_ros._node_util import ParameterError, check_unknown_overrides, declare, run_node

#: Topics forwarded by default in the default graph (root namespace): its aeropend topics and the diagnostics.
DEFAULT_INCLUDE = r'^/aeropend/|^/diagnostics$'


def default_include(namespace: str) -> str:
    """The default ``include_regex`` of a node in `namespace`: that rig's topics (``^/rig1/aeropend/`` in ``/rig1``)
    and ``/diagnostics``; never another rig's topics."""
    return '^' + re.escape(namespace.rstrip('/') + '/aeropend/') + '|^/diagnostics$'

#: What to tell a user who has no foxglove-sdk.
INSTALL_HINT = ('install it with `pip install foxglove-sdk` (it is in requirements.txt), or on a ROS 2 install use '
                'the official bridge: apt install ros-jazzy-foxglove-bridge')


def foxglove_sdk():
    """The ``foxglove`` module of foxglove-sdk, or :class:`AeropendError` saying how to install it."""
    try:
        import foxglove
        foxglove.start_server       # noqa: B018 - the SDK, not another module of that name
    except (ImportError, AttributeError):
        raise AeropendError(f'the Foxglove server needs the foxglove-sdk package: {INSTALL_HINT}') from None
    return foxglove


class FoxgloveNode(Node):
    """Forwards the graph's topics to a Foxglove WebSocket server; see the module docstring."""

    def __init__(self, node_name: str = 'foxglove_node', **kwargs) -> None:
        super().__init__(node_name, **kwargs)
        host = declare(self, 'host', '127.0.0.1', 'address the WebSocket server listens on (0.0.0.0: every '
                       'interface, e.g. Foxglove on another machine)', read_only=True)
        port = declare(self, 'port', 8765, 'TCP port of the WebSocket server (8765 is Foxglove\'s default; 0: any '
                       'free port)', read_only=True, low=0, high=65535, integer=True)
        include = declare(self, 'include_regex', default_include(self.get_namespace()), 'forward every topic whose '
                          'full name matches this regular expression (default: this rig\'s topics, '
                          '^<namespace>/aeropend/, and /diagnostics)', read_only=True)
        discovery_period = declare(self, 'discovery_period', 0.5, 'seconds between checks for new topics',
                                   read_only=True, low=0.05, high=60.0)
        declare(self, 'queue_depth', 100, 'subscription history depth per topic', read_only=True, low=1,
                high=10000, integer=True)
        check_unknown_overrides(self)
        try:
            self._include = re.compile(include)
        except re.error as error:
            raise ParameterError(f'{self.get_name()}: parameter include_regex = {include!r} is not a regular '
                                 f'expression: {error}') from None
        foxglove = foxglove_sdk()
        self._foxglove = foxglove
        self._fox_context = foxglove.Context()       # our own: two servers in one process never share channels
        try:
            self.server = foxglove.start_server(name='aeropend', host=host, port=port, context=self._fox_context)
        except Exception as error:  # noqa: BLE001 - the SDK raises its own error types for a busy port
            raise ParameterError(f'{self.get_name()}: cannot serve Foxglove on {host}:{port}: {error}; choose '
                                 'another port (-p port:=8766, or aeropend run --foxglove 8766) or stop the '
                                 'program using it') from None
        self.port = int(self.server.port)          # the bound port (the one chosen when port was 0)
        self.url = f'ws://{host}:{self.port}'
        self._load_msg = msg_file_loader(ament_prefixes() or [sys.prefix])
        self._channels: dict[str, object] = {}
        self._forwarded: dict[str, int] = {}
        self._subscriptions_by_topic: dict[str, object] = {}
        self._timer = self.create_timer(discovery_period, self._discover)
        self.get_logger().info(f'Foxglove WebSocket server on {self.url} (topics matching {include!r})')
        self._discover()

    def _discover(self) -> None:
        for topic, types in self.get_topic_names_and_types():
            if topic in self._subscriptions_by_topic or not self._include.search(topic):
                continue
            publishers = [info for info in self.get_publishers_info_by_topic(topic)
                          if info.node_name != self.get_name()]
            if not publishers:
                continue
            if len(types) != 1:
                self.get_logger().warning(f'not forwarding {topic}: several types {types}')
                self._subscriptions_by_topic[topic] = None
                continue
            self._forward(topic, types[0], publishers)

    def _forward(self, topic: str, type_name: str, publishers) -> None:
        from aeropend_ros.recorder_node import message_class
        try:
            msg_type = message_class(type_name)
            schema_text = ros2msg_definition(type_name, self._load_msg)
        except (ImportError, AttributeError, ValueError, AeropendError) as error:
            self.get_logger().error(f'not forwarding {topic} ({type_name}): {error}')
            self._subscriptions_by_topic[topic] = None
            return
        profiles = [info.qos_profile for info in publishers]
        best_effort = any(p.reliability == ReliabilityPolicy.BEST_EFFORT for p in profiles)
        transient = all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in profiles)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=self.get_parameter('queue_depth').value,
                         reliability=ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL if transient else DurabilityPolicy.VOLATILE)
        schema = self._foxglove.Schema(name=type_name, encoding=SCHEMA_ENCODING, data=schema_text.encode('utf-8'))
        channel = self._foxglove.Channel(topic, schema=schema, message_encoding=MESSAGE_ENCODING,
                                         context=self._fox_context)
        self._channels[topic] = channel
        self._forwarded[topic] = 0

        def forward(data: bytes, channel=channel, topic=topic) -> None:
            if channel.has_sinks():                 # a client subscribed to this channel
                channel.log(data, log_time=time.time_ns())
                self._forwarded[topic] += 1

        self._subscriptions_by_topic[topic] = self.create_subscription(msg_type, topic, forward, qos, raw=True)
        self.get_logger().info(f'forwarding {topic} [{type_name}] to Foxglove')

    @property
    def forwarded(self) -> dict[str, int]:
        """Messages sent to Foxglove clients so far, per topic."""
        return dict(self._forwarded)

    def destroy_node(self) -> None:
        server = getattr(self, 'server', None)
        if server is not None:
            server.stop()
            self.server = None
        for channel in getattr(self, '_channels', {}).values():
            channel.close()
        super().destroy_node()


def main(args=None) -> int:
    """Entry point of ``foxglove_node`` (``ros2 run aeropend_ros foxglove_node``)."""
    return run_node(FoxgloveNode, args, prefer_events=False)


if __name__ == '__main__':
    sys.exit(main())


__all__ = ['DEFAULT_INCLUDE', 'FoxgloveNode', 'default_include', 'foxglove_sdk', 'main']
