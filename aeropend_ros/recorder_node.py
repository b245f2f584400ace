"""recorder_node: record chosen topics to a rosbag2-compatible MCAP bag folder (raw CDR bytes, no re-serialisation).

Topics are the ``topics`` parameter (relative names resolve in the node's namespace: ``aeropend/samples`` is
``/aeropend/samples`` in the default graph, ``/rig1/aeropend/samples`` in the namespace ``/rig1``) plus every topic
whose full name matches ``include_regex`` (default ``^<namespace>/aeropend/``, i.e. ``^/aeropend/`` in the default
graph: this rig's topics, the identification outputs too, and never another rig's, whose topics lie under
``/<name>/aeropend/``). ``/diagnostics`` is shared by every rig on the domain: a DiagnosticArray is recorded only
when one of its statuses belongs to this namespace (its name starts with ``<name>/`` in ``/<name>``, has no
namespace in the root one; :func:`aeropend_ros.topics.status_namespace`); the others are counted
(``diagnostics_of_other_rigs``). The bag's ``metadata.yaml`` names the rig and namespace (``custom_data``:
``aeropend.rig``, ``aeropend.namespace``). A topic is subscribed as soon as a publisher of it is discovered, with the
publishers' QoS (best effort if any publisher is best effort, as ``/aeropend/samples`` with SensorData QoS;
reliable otherwise) and a deep queue. Subscriptions are raw: the exact CDR bytes as received go to the bag, stamped
with receive time (log time) and send time (publish time).

Messages wait in the DDS history of each subscription (``queue_depth`` deep); every ``poll_period`` one timer
callback takes all of them (the subscriptions sit on an internal node that no executor spins, so there is one
executor turn per poll, not per message) and queues the bytes; a writer thread chunks, compresses and writes them.
That keeps the cost near 15-20 us of CPU per message at 20,000 msg/s and ~4 % of a core at 490 Hz
(bench/bench_recorder.py). SIGINT or SIGTERM finalise
the bag (summary, footer, metadata.yaml). After a SIGKILL, run ``aeropend bag-recover <bag folder>``.

The node publishes its own ``/diagnostics`` (messages written per topic, messages safe on disk, queue length,
drops, lost messages, current file) once per ``diagnostics_period``.

Loss accounting by sequence number: every gap in the acquisition counter of the samples (``position[4]``
of each JointState) is counted as lost, whoever lost it (the link, the transport, or a recorder stalled so long
that the DDS history of ``queue_depth`` messages overflowed); so is every gap in the DDS publication sequence
number of a topic while it has a single publisher. Losses go to ``/diagnostics`` (``samples_lost``,
``lost <topic>``; WARN while they grow), to the log (one line per diagnostics period with new losses) and into the
bag's ``metadata.yaml`` (``custom_data``: ``aeropend.lost <topic>``, ``aeropend.loss_accounting``).

Only messages of the types in ``allowed_types`` are recorded (by default the types of the aeropend topics and
``/diagnostics``): a topic's type names a Python module the recorder would import, and any DDS participant can
announce a topic under ``/aeropend/``.

When the bag cannot be written (disk full, file size limit, permissions) the node logs the error, publishes an
ERROR status on ``/diagnostics`` for a second, and exits with status 1. The file keeps every complete chunk
(it is cut back to the last complete record); free space and run ``aeropend bag-recover <bag folder>``.

Usage::

    ros2 run aeropend_ros recorder_node --ros-args -p output:=bags/run1
    ros2 run aeropend_ros recorder_node --ros-args --params-file config/recorder_node.yaml
"""
from __future__ import annotations

import collections
import ctypes
import importlib
import re
import signal
import sys
import threading
import time

from aeropend_ros._ros_env import ament_prefixes, ensure_ros_environment

ensure_ros_environment()

import rclpy
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)

from aeropend_core.io.bag_writer import BagWriter
from aeropend_core.io.mcap_format import msg_file_loader, msg_type_hash, offered_qos, ros2msg_definition
from aeropend_core.errors import AeropendError
from aeropend_core.io.sequence_gaps import SequenceGaps, joint_state_position
from aeropend_ros import topics as contract
from aeropend_ros._node_util import check_unknown_overrides, declare

#: Topics recorded by default (relative names resolve in the node's namespace).
DEFAULT_TOPICS = [contract.SAMPLES, contract.DUTY_COMMAND, contract.DIAGNOSTICS_TOPIC]
#: Message types recorded by default: those of the aeropend topics (samples and identification outputs are
#: JointState, the duty command Float64, the excitation's done flag Bool) and /diagnostics.
DEFAULT_ALLOWED_TYPES = [contract.SAMPLES_TYPE, contract.DUTY_COMMAND_TYPE, 'std_msgs/msg/Bool',
                         contract.DIAGNOSTICS_TYPE]
#: Index of the acquisition counter in a sample's ``position`` (topics.SAMPLE_NAMES).
_SEQUENCE_INDEX = contract.SAMPLE_NAMES.index('sequence')


#: glibc mallopt parameters (malloc.h) and the values the recorder sets, see steady_allocator().
_M_MMAP_THRESHOLD, _M_ARENA_MAX = -3, -8
MMAP_THRESHOLD_BYTES = 64 * 1024


def steady_allocator() -> bool:
    """Keep the recorder's memory flat: fixed glibc mmap threshold (64 KiB), one malloc arena.

    Why: every chunk passes through buffers of about ``chunk_size`` and more (the chunk being built, its
    compressed copy, zstd's workspace). glibc serves such blocks with mmap and returns them on free, but its
    *dynamic* threshold rises to the size of the first one freed, after which they come from the heap, where they
    interleave with the small allocations of the messages and fragment it: the heap only grows (0.13-0.4 MB/min in
    the full graph at 490 Hz, more with larger chunks, about a third with 64 KiB chunks; replaying a recorded
    full-graph bag to a recorder reproduces it per message, not per second, and malloc_trim does not give it
    back). A fixed threshold keeps those buffers in mmap; one arena keeps the writer thread's blocks with the
    others. Measured in bench/load_test.py (bench/results/README.md#load-test). No effect (returns False) outside glibc.
    """
    try:
        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(mallopt(_M_ARENA_MAX, 1))


def _never_called(_msg) -> None:  # the I/O node is never spun; _poll takes the messages
    raise AssertionError('recorder I/O subscriptions are polled, not spun')


def message_class(type_name: str, allowed: frozenset[str] | set[str] | None = None):
    """The Python message class of ``pkg/msg/Type`` (imports ``pkg.msg``).

    With ``allowed``, a type outside it raises ValueError before anything is imported.
    """
    if allowed is not None and type_name not in allowed:
        raise ValueError(f'type {type_name} is not in allowed_types ({", ".join(sorted(allowed))}); add it to '
                         'the parameter allowed_types if you trust the packages that define it')
    package, kind, name = type_name.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), name)


def _qos_dict(profile) -> dict:
    """An rclpy QoSProfile as one entry of rosbag2's ``offered_qos_profiles`` (policy names in lower case)."""
    def name(policy, default: str) -> str:
        return policy.name.lower() if hasattr(policy, 'name') else default
    return offered_qos(reliability=name(profile.reliability, 'reliable'),
                       durability=name(profile.durability, 'volatile'),
                       history=name(profile.history, 'keep_last'), depth=profile.depth,
                       liveliness=name(profile.liveliness, 'automatic'))


class RecorderNode(Node):
    """Records topics into an MCAP bag folder; see the module docstring."""

    def __init__(self, **kwargs):
        steady_allocator()              # before the writer thread and its buffers exist (see its docstring)
        super().__init__('recorder_node', **kwargs)
        self._declare_parameters()
        get = self.get_parameter
        output = get('output').value or f'bags/aeropend_{time.strftime("%Y%m%d_%H%M%S")}'
        empty = [index for index, name in enumerate(get('topics').value or []) if not name.strip()]
        if empty:
            raise AeropendError(f'topics {list(get("topics").value)!r}: entry {empty[0] + 1} is an empty topic name '
                                "(nothing would be recorded under it); write names like 'aeropend/samples' or "
                                "'/diagnostics', or leave topics at its default")
        try:
            self._topics_wanted = {self.resolve_topic_name(t) for t in get('topics').value or []}
        except Exception as error:  # noqa: BLE001 - rclpy raises its own name-validation errors
            raise AeropendError(f'topics {get("topics").value!r}: a name is not a valid ROS topic name ({error}); '
                                "write names like 'aeropend/samples' or '/diagnostics'") from None
        self._namespace = self.get_namespace()
        #: the samples topic of this rig (its counter is the loss accounting)
        self._samples_topic = self.resolve_topic_name(contract.SAMPLES)
        self._other_diagnostics = 0
        try:
            self._include = re.compile(get('include_regex').value) if get('include_regex').value else None
        except re.error as error:
            raise AeropendError(f'include_regex {get("include_regex").value!r} is not a regular expression: '
                                f'{error}') from None
        self._queue_depth = get('queue_depth').value
        self._allowed_types = frozenset(t for t in get('allowed_types').value or [] if t)
        #: loss accounting: the sample counter of the samples topic, DDS publication numbers of other topics
        self._sample_gaps = SequenceGaps()
        self._publication_gaps: dict[str, SequenceGaps] = {}
        self._single_publisher: dict[str, bool] = {}
        self._lost_reported = 0
        self.writer = BagWriter(output, max_file_bytes=get('max_file_bytes').value,
                                max_file_duration=get('max_file_duration').value,
                                chunk_size=get('chunk_size').value, compression=get('compression').value,
                                max_chunk_duration=get('chunk_duration').value)
        self.writer.custom_data.update({'aeropend.rig': contract.rig_name(self._namespace),
                                        'aeropend.namespace': self._namespace})
        self._load_msg = msg_file_loader(ament_prefixes() or [sys.prefix])
        self._subscriptions_by_topic: dict[str, object] = {}
        self._polled: list[tuple[str, object, type]] = []
        # subscriptions are made on this node, which is never spun (see _subscribe); no global remapping for it
        self._io_node = Node(f'{self.get_name()}_io', namespace=self.get_namespace(), context=self.context,
                             use_global_arguments=False, enable_rosout=False, start_parameter_services=False)
        self._received: dict[str, int] = collections.Counter()
        self._queue: collections.deque = collections.deque()
        self._wake = threading.Event()
        self._stop = False
        self._written = 0
        self._write_error: str = ''
        self._failed = threading.Event()
        self._max_queue = get('max_queue').value
        self._dropped = 0
        self._thread = threading.Thread(target=self._write_loop, name='bag_writer', daemon=True)
        self._thread.start()
        self._finished = False

        from diagnostic_msgs.msg import DiagnosticArray
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS_TOPIC,
                                                      contract.diagnostics_qos())
        self._discovery_timer = self.create_timer(get('discovery_period').value, self._discover)
        self._poll_timer = self.create_timer(get('poll_period').value, self._poll)
        self._diagnostics_timer = self.create_timer(get('diagnostics_period').value, self._publish_diagnostics)
        self.add_post_set_parameters_callback(self._apply_parameters)     # validated by the declared ranges
        self.get_logger().info(f'recording to {self.writer.folder} (topics {sorted(self._topics_wanted)}'
                               f'{", regex " + self._include.pattern if self._include else ""})')
        self._discover()

    # -- parameters ----------------------------------------------------------------------------------------------
    def _declare_parameters(self) -> None:
        """Declare every parameter with its range; a bad start-up value is a one-line ParameterError (exit 2)."""
        declare(self, 'output', '', 'bag folder to create (must not exist); empty: bags/aeropend_<date>_<time>',
                read_only=True)
        declare(self, 'topics', DEFAULT_TOPICS, 'topics to record (recorded when a publisher appears); relative '
                'names resolve in the node namespace (the rig)', read_only=True)
        own = '^' + re.escape(self.get_namespace().rstrip('/') + '/aeropend/')
        declare(self, 'include_regex', own, 'also record every topic whose full name matches this regular '
                'expression (empty: none); default ^<namespace>/aeropend/: this rig\'s topics', read_only=True)
        declare(self, 'allowed_types', DEFAULT_ALLOWED_TYPES, 'message types that may be recorded (pkg/msg/Type); '
                'a topic of another type is not recorded: its type would name a module to import', read_only=True)
        declare(self, 'max_file_bytes', 0, 'start a new .mcap file at this size in bytes (0: never)', read_only=True,
                low=0, high=2**62, integer=True)
        declare(self, 'max_file_duration', 0.0, 'start a new .mcap file after this many seconds of recording '
                '(0: never)', read_only=True, low=0.0, high=1e9)
        declare(self, 'chunk_size', 256 * 1024, 'uncompressed bytes per MCAP chunk; a kill loses at most the chunk '
                'in progress', read_only=True, low=1024, high=64 * 1024 * 1024, integer=True)
        declare(self, 'chunk_duration', 0.75, 'seconds after which the chunk in progress goes to disk whatever its '
                'size (0: by size only); a kill loses at most about this much', read_only=True, low=0.0, high=3600.0)
        declare(self, 'compression', 'zstd', 'chunk compression', read_only=True, choices=('zstd', 'lz4', 'none'))
        declare(self, 'queue_depth', 10000, 'subscription history depth: messages DDS buffers while the recorder is '
                'busy (10000 = 20 s at 490 Hz)', read_only=True, low=1, high=100000, integer=True)
        declare(self, 'max_queue', 100_000, 'messages waiting for the writer thread before new ones are dropped '
                '(and counted); 100000 = 200 s at 490 Hz, about 40 MB', read_only=True, low=1000, high=100_000_000,
                integer=True)
        declare(self, 'discovery_period', 0.2, 'seconds between checks for new topics to record', low=0.01,
                high=60.0)
        declare(self, 'poll_period', 0.02, 'seconds between takes of the waiting messages (they wait in the DDS '
                'history, queue_depth deep)', low=0.001, high=1.0)
        declare(self, 'diagnostics_period', 1.0, 'seconds between /diagnostics messages', low=0.05, high=60.0)
        check_unknown_overrides(self)

    def _apply_parameters(self, params) -> None:
        """Apply the periods of a set every check accepted (the ranges declared with each parameter, and
        :func:`aeropend_ros._node_util.declare`'s run-time check, validate before; nothing is changed by a set that
        one of them refuses)."""
        for param in params:
            if param.name == 'discovery_period':
                self._discovery_timer.timer_period_ns = int(param.value * 1e9)
            elif param.name == 'poll_period':
                self._poll_timer.timer_period_ns = int(param.value * 1e9)
            elif param.name == 'diagnostics_period':
                self._diagnostics_timer.timer_period_ns = int(param.value * 1e9)

    # -- discovery and subscriptions -------------------------------------------------------------------------------
    def _wants(self, topic: str) -> bool:
        return topic in self._topics_wanted or bool(self._include and self._include.search(topic))

    def _discover(self) -> None:
        for topic, types in self.get_topic_names_and_types():
            if topic in self._subscriptions_by_topic or not self._wants(topic):
                continue
            me = (self.get_name(), self.get_namespace())
            publishers = [info for info in self.get_publishers_info_by_topic(topic)
                          if (info.node_name, info.node_namespace) != me or topic != contract.DIAGNOSTICS_TOPIC]
            if not publishers and topic != contract.DIAGNOSTICS_TOPIC:
                continue
            if len(types) != 1:
                self.get_logger().warning(f'not recording {topic}: several types {types}')
                self._subscriptions_by_topic[topic] = None
                continue
            self._subscribe(topic, types[0], publishers)

    def _subscribe(self, topic: str, type_name: str, publishers) -> None:
        try:
            msg_type = message_class(type_name, self._allowed_types)
            schema_text = ros2msg_definition(type_name, self._load_msg)
        except (ImportError, AttributeError, ValueError, AeropendError) as error:
            self.get_logger().error(f'not recording {topic} ({type_name}): {error}')
            self._subscriptions_by_topic[topic] = None
            return
        profiles = [info.qos_profile for info in publishers]
        best_effort = any(p.reliability == ReliabilityPolicy.BEST_EFFORT for p in profiles)
        transient = bool(profiles) and all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in profiles)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=self._queue_depth,
                         reliability=ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL if transient else DurabilityPolicy.VOLATILE)
        hashes = {str(info.topic_type_hash) for info in publishers} - {'INVALID', ''}
        type_hash = hashes.pop() if len(hashes) == 1 else msg_type_hash(type_name, ament_prefixes())
        self._queue.append(('topic', topic, type_name, schema_text, [_qos_dict(p) for p in profiles], type_hash))
        # The subscription lives on the internal I/O node, which no executor spins: messages wait in the DDS
        # history (queue_depth deep) and _poll takes them all every poll_period. One executor turn per poll
        # instead of one per message.
        subscription = self._io_node.create_subscription(msg_type, topic, _never_called, qos, raw=True)
        self._polled.append((topic, subscription, msg_type))
        self._subscriptions_by_topic[topic] = subscription
        self.get_logger().info(f'recording {topic} [{type_name}] '
                               f'({"best effort" if best_effort else "reliable"}, depth {self._queue_depth})')

    def _poll(self) -> None:
        taken_any = False
        for topic, subscription, msg_type in self._polled:
            single = subscription.get_publisher_count() == 1
            if single != self._single_publisher.get(topic):
                self._single_publisher[topic] = single
                self._publication_gaps.setdefault(topic, SequenceGaps()).reset()
            handle = subscription.handle
            with handle:
                while True:
                    taken = handle.take_message(msg_type, True)
                    if taken is None:
                        break
                    if topic == contract.DIAGNOSTICS_TOPIC and not self._own_diagnostics(taken[0], msg_type):
                        self._other_diagnostics += 1
                        continue
                    self._enqueue(topic, taken[0], taken[1])
                    taken_any = True
        if taken_any:
            self._wake.set()

    def _own_diagnostics(self, data: bytes, msg_type) -> bool:
        """Whether a /diagnostics message (CDR bytes) has a status of this rig (namespace); the topic is global."""
        from rclpy.serialization import deserialize_message
        try:
            array = deserialize_message(data, msg_type)
        except Exception:  # noqa: BLE001 - unreadable bytes: record them (nothing is dropped unseen)
            return True
        return any(contract.status_namespace(status.name) == self._namespace for status in array.status)

    def _enqueue(self, topic: str, data: bytes, info: dict) -> None:
        if len(self._queue) >= self._max_queue or self._failed.is_set():
            # received, not written: counted as both, so that whoever waits for the in-flight messages to arrive
            # (aeropend run's drain) sees them arrive after a failed write too (it waited its whole 30 s before)
            self._received[topic] += 1
            self._dropped += 1
            return
        received = info.get('received_timestamp') or time.time_ns()
        publication = info.get('publication_sequence_number') or 0
        if publication and self._single_publisher.get(topic) and topic != self._samples_topic:
            self._publication_gaps[topic].observe(publication)
        self._queue.append((topic, data, received, info.get('source_timestamp') or received, publication))
        self._received[topic] += 1

    # -- writer thread -----------------------------------------------------------------------------------------------
    def _write_loop(self) -> None:
        queue = self._queue
        writer = self.writer
        while True:
            self._wake.wait(0.05)
            self._wake.clear()
            try:
                writer.tick()                   # the chunk in progress goes to disk on time, messages or not
                while queue:
                    item = queue.popleft()
                    if item[0] == 'topic' and len(item) == 6:
                        _, topic, type_name, schema_text, qos, type_hash = item
                        writer.add_topic(topic, type_name, schema_text, qos, type_hash)
                        continue
                    topic, data, received, sent, sequence = item
                    if topic == self._samples_topic:
                        counter = joint_state_position(data, _SEQUENCE_INDEX)
                        if counter is not None:
                            self._sample_gaps.observe(int(counter))
                    writer.write(topic, data, received, sent, sequence)
                    self._written += 1
            except Exception as error:  # noqa: BLE001 - disk full, permissions...: report it, then main() exits 1
                self._write_error = str(error) if isinstance(error, AeropendError) else \
                    f'{type(error).__name__}: {error}'
                self.get_logger().error(f'bag writing failed: {self._write_error}')
                queue.clear()
                self._failed.set()
                return
            if self._stop and not queue:
                return

    @property
    def received_counts(self) -> dict[str, int]:
        """Messages received so far per topic (a copy)."""
        return dict(self._received)

    def lost_counts(self) -> dict[str, int]:
        """Messages lost per topic by sequence number (gaps), see the module docstring."""
        counts = {self._samples_topic: self._sample_gaps.lost} if self._sample_gaps.last is not None else {}
        counts.update({topic: gaps.lost for topic, gaps in self._publication_gaps.items() if gaps.lost})
        return counts

    @property
    def messages_lost(self) -> int:
        """Messages lost so far (all topics), counted by sequence gaps."""
        return sum(self.lost_counts().values())

    def _loss_details(self) -> str:
        parts = []
        if self._sample_gaps.last is not None:
            parts.append(f'{self._samples_topic} (sample counter): {self._sample_gaps.describe()}')
        parts += [f'{topic} (publication numbers): {gaps.describe()}'
                  for topic, gaps in sorted(self._publication_gaps.items()) if gaps.lost]
        return '; '.join(parts) or 'nothing tracked yet'

    def _loss_metadata(self) -> dict[str, str]:
        """The loss accounting as metadata.yaml custom_data (string -> string)."""
        data = {f'aeropend.lost {topic}': str(count) for topic, count in self.lost_counts().items()}
        data['aeropend.dropped'] = str(self._dropped)
        data['aeropend.diagnostics_of_other_rigs'] = str(self._other_diagnostics)
        data['aeropend.loss_accounting'] = (
            f'lost = gaps in the sample counter (position[{_SEQUENCE_INDEX}]) of {self._samples_topic} and in '
            'the DDS publication sequence numbers of topics while they had a single publisher, whoever lost them; '
            'dropped = taken but not written (queue full or writing failed), which shows among the gaps too. '
            f'{self._loss_details()}')
        return data

    @property
    def messages_written(self) -> int:
        """Messages handed to the bag writer so far (all topics)."""
        return self._written

    @property
    def failed(self) -> bool:
        """True once writing the bag failed (see :attr:`write_error`); the node should then stop."""
        return self._failed.is_set()

    @property
    def write_error(self) -> str:
        """Why writing the bag failed ('' while healthy)."""
        return self._write_error

    def finish(self) -> None:
        """Take what is waiting, write everything queued and finalise the bag (idempotent)."""
        if self._finished:
            return
        self._finished = True
        try:
            self._poll()
        except Exception as error:  # noqa: BLE001 - after Ctrl-C the context may be gone; the queue is still written
            print(f'[WARN] [recorder_node]: could not take the last waiting messages: {error}', file=sys.stderr)
        self._stop = True
        self._wake.set()
        self._thread.join()
        self.writer.custom_data.update(self._loss_metadata())
        try:
            self.writer.finish()
        except AeropendError as error:          # the disk filled up while writing the last chunk or the summary
            self._write_error = str(error)
            self._failed.set()
        if self._write_error:
            text = (f'bag {self.writer.folder} NOT finalised: {self._write_error}')
        else:
            lost = self.messages_lost
            text = (f'bag {self.writer.folder} finalised: {self._written} messages, {lost} lost by sequence gaps '
                    f'({self._loss_details()}; gaps count whatever lost them: the link, the transport, a stall, or '
                    f'the {self._dropped} message(s) dropped here because the queue was full), '
                    f'files {[p.name for p in self.writer.paths]}')
        if rclpy.ok():
            (self.get_logger().error if self._write_error else self.get_logger().info)(text)
        else:  # after Ctrl-C the context is gone and /rosout with it
            print(f'[INFO] [recorder_node]: {text}', file=sys.stderr, flush=True)

    def destroy_node(self) -> None:
        self.finish()
        self._io_node.destroy_node()
        super().destroy_node()

    # -- diagnostics ---------------------------------------------------------------------------------------------------
    def _publish_diagnostics(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
        status = DiagnosticStatus(name=f'{contract.status_prefix(self._namespace)}{self.get_name()}: bag',
                                  hardware_id=str(self.writer.folder))
        lost = self.lost_counts()
        total_lost = sum(lost.values())
        new_lost, self._lost_reported = total_lost - self._lost_reported, total_lost
        if new_lost:
            self.get_logger().warning(f'{new_lost} message(s) lost since the last report, {total_lost} in all '
                                      f'({self._loss_details()}): the recorder was stalled longer than its DDS '
                                      'history holds (queue_depth), its queue was full (messages_dropped), or '
                                      'the link or transport dropped them')
        if self._write_error:
            status.level, status.message = DiagnosticStatus.ERROR, f'writing failed: {self._write_error}'
        elif self._dropped or new_lost:
            problems = [f'{new_lost} messages lost since the last report (sequence gaps; {total_lost} in all)'] \
                if new_lost else []
            problems += [f'{self._dropped} messages dropped (queue full)'] if self._dropped else []
            status.level, status.message = DiagnosticStatus.WARN, '; '.join(problems)
        else:
            status.level, status.message = DiagnosticStatus.OK, 'recording' + (
                f' ({total_lost} messages lost earlier, sequence gaps)' if total_lost else '')
        values = [('messages_written', self._written), ('messages_on_disk', self.writer.messages_on_disk),
                  ('messages_dropped', self._dropped), ('messages_lost', total_lost),
                  ('samples_lost', lost.get(self._samples_topic, 0)),
                  ('diagnostics_of_other_rigs', self._other_diagnostics),
                  ('queue_length', len(self._queue)), ('file', self.writer.paths[-1].name if self.writer.paths else ''),
                  ('files', len(self.writer.paths))]
        values += [(f'received {topic}', count) for topic, count in sorted(self._received.items())]
        values += [(f'lost {topic}', count) for topic, count in sorted(lost.items())]
        on_disk = self.writer.messages_on_disk_by_topic()
        values += [(f'on disk {topic}', count) for topic, count in sorted(on_disk.items())]
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values]
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics_pub.publish(array)


def _ignore_further_interrupts(quietly: bool = False) -> None:
    """While the bag is finalised, another Ctrl-C (or SIGTERM) only says to wait: finishing is what saves the
    data, and an exception raised in the middle of it would print a traceback and leave the bag unfinished.
    ``quietly``: ignore them without a word (once the bag is finished, on the way out)."""
    def wait(signum, _frame) -> None:
        print(f'[WARN] [recorder_node]: {signal.Signals(signum).name} ignored: finalising the bag, please wait '
              '(SIGKILL would leave it for aeropend bag-recover)', file=sys.stderr, flush=True)
    for signum in (signal.SIGINT, signal.SIGTERM):
        try:
            signal.signal(signum, signal.SIG_IGN if quietly else wait)
        except (ValueError, OSError):   # not the main thread (e.g. inside `aeropend run`): nothing to do here
            pass


def main(args=None) -> int:
    """Entry point of ``recorder_node`` (``ros2 run aeropend_ros recorder_node``); ``--help``: its parameters."""
    from aeropend_ros.node_help import print_node_help, wants_help
    if wants_help(args):            # nothing is started, no bag is created
        return print_node_help('recorder_node', __name__)
    steady_allocator()                  # before rclpy starts the DDS threads
    rclpy.init(args=args)
    try:
        node = RecorderNode()
    except AeropendError as error:      # a bad parameter (its message names the node) or an unusable output
        print(f'{"" if str(error).startswith("recorder_node") else "recorder_node: "}error: {error}', file=sys.stderr)
        rclpy.try_shutdown()
        return error.exit_status        # 2: fix the parameter; 1: the system refused (permissions, disk)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        while rclpy.ok() and not node.failed:
            executor.spin_once(timeout_sec=0.1)
        if node.failed:
            # tell /diagnostics listeners (a supervisor, `aeropend monitor`) for a second before exiting, and make
            # sure every matched listener has the ERROR (reliable delivery) even on a busy machine
            node._publish_diagnostics()
            deadline = time.monotonic() + 1.0
            while rclpy.ok() and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.1)
            node._diagnostics_pub.wait_for_all_acked(Duration(seconds=10.0))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except _rclpy.RCLError:
        # a Ctrl-C shut the context down between rclpy.ok() and the executor's wait set: an interrupt, not a fault
        if rclpy.ok():
            raise
    finally:
        _ignore_further_interrupts()
        node.finish()
        node.destroy_node()
        rclpy.try_shutdown()
        _ignore_further_interrupts(quietly=True)    # rclpy's shutdown and the interpreter's exit would put the
        #                                             default handler back: a late Ctrl-C would end us by a signal
    if node.failed:
        print(f'recorder_node: error: {node.write_error}', file=sys.stderr, flush=True)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())


__all__ = ['DEFAULT_ALLOWED_TYPES', 'DEFAULT_TOPICS', 'RecorderNode', 'main', 'message_class', 'steady_allocator']
