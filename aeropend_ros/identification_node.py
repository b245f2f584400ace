"""identification_node: weak SINDy on sliding windows of ``/aeropend/samples``, live.

Samples wait in the subscription's DDS history (``QUEUE_DEPTH``, ~20 s at 490 Hz) and a timer takes all of them every
``POLL_PERIOD_S`` (one executor turn per batch, as the recorder does), so a busy machine delays the node rather than
making it lose samples. Every ``hop_s`` seconds of acquisition time, the last ``window_s`` seconds of samples are
analysed in a worker process (spawned, so the DDS threads are not forked; a worker thread would hold the GIL for
most of a fit and the executor would drop samples). The executor keeps receiving meanwhile; a window that comes
due while the previous one is still being computed is skipped, counted, logged and reported on ``/diagnostics``
(WARN, with its time span and the reason). The analysis is
:func:`aeropend_core.diagnosis.online.analyze_window`: weak SINDy on the first part of the window, output-error
refinement with the model's ``effects``, and a free-run fit on the held-out end.

Published (names relative to the rig's namespace, shown as in the default graph; all ``sensor_msgs/JointState`` so
that every value is plottable by name; ``header.stamp`` = end of the window in acquisition time; ``name`` = quantity
names, ``position`` = values, ``velocity`` = 1σ standard errors):

- ``/aeropend/identification/coefficients`` — weak-SINDy coefficients of d²angle/dt² [rad/s² per unit term]
- ``/aeropend/identification/parameters`` — physical parameters of the refined model, SI
- ``/aeropend/identification/fit`` — ``fit_percent`` [%], ``rms_error`` [rad], ``noise_rms`` [rad],
  ``held_out_seconds`` [s], ``compute_time`` [s], ``window_start`` [s] (velocity empty)
- ``/aeropend/parameters/<name>`` — one topic per parameter of the refined model, plottable by name as three
  lines (value and its ±1σ band): ``name`` = :data:`aeropend_ros.topics.PARAMETER_FIELDS` (``value``, ``lower``,
  ``upper``, ``sigma``, ``data_flagged``, ``trend_change``, ``drifting``), ``header.frame_id`` =
  ``estimator=<output_error|motor_observer>;unit=<SI unit>;data=<clean|flagged:codes>``;
  ``/aeropend/parameters/weak_sindy/<name>`` — the same for weak SINDy's value of the quantity
- ``/diagnostics`` — window health (samples, lost samples), excitation sufficient or not and why, compute time,
  skipped windows, the model's effects, which estimator gave each parameter (``estimators``), and the drift
  test (``drift`` = ``none`` or the sentence, ``trend_<name>``); also once a second while waiting for data.

**Drift.** The nominal parameters (``TREND_PARAMETERS``) of the windows that do not overlap are tested for a
straight-line trend against their scatter (:class:`aeropend_core.diagnosis.online.ParameterTrends`, the diagnosis's
own :func:`~aeropend_core.diagnosis.drift.trend_test`: p < 0.001 and a change over 5 %): a drift makes the window's
status WARN with "parameter drift: thrust gain -15 % over 120 s (...). Likely causes: ..." and sets ``drifting``
on that parameter's topic. The test restarts when the stream restarts, the effects or the window length change.

Bad samples are never analysed. A sample with a NaN/inf angle, voltage or current, a duplicated sequence number, an
older sequence number and stamp (out of order), a stamp that does not advance with the sequence number, or that
cannot be read is rejected: counted (``rejected_<reason>`` on /diagnostics), logged, and reported as WARN within a
second. A rejected sample counts as lost. Lost samples are not filled: the window is split at each gap of the
sequence numbers into pieces, as the offline diagnosis does (the weak form on the pieces together, the
output-error segments and the held-out simulation restarting after each gap); its status then says how many
samples were lost, in how many gaps, the longest, and why (WARN; ``lost_samples``, ``gaps``, ``longest_gap_s``).
A window missing more than 30 % of its samples, or left with too little training or held-out data between its
gaps, is not analysed (saying so). A sequence number that goes back with a later stamp (the source restarted) or stamps
that jump against the sequence numbers (by more than 0.1 s + 5 %) clear the buffer: the windows start again (WARN).
A window whose excitation is insufficient (e.g. constant duty) is refused with the reason (WARN), and a result with
a non-finite value is not published (ERROR).

Every window passes the data-quality gate (:func:`aeropend_core.signals.quality.check_recording`, the same as for
files) before it is analysed: a refused window (a frozen sensor, stamps that disagree with the sequence numbers and
the 490 Hz rate, an angle jump no repair explains, ...) is not analysed and said at ERROR, naming the finding; a
repaired or warned window (a wrap unwrapped, an outlier interpolated, lost samples segmented) is analysed and
published with its status at WARN and the findings in ``data_quality`` / ``data_quality_detail``.

Each window that comes due leaves one :class:`WindowEvent` in ``window_events`` (clean, flagged, withheld, refused,
skipped or failed, with its lost samples and gaps): ``aeropend run`` prints one console line per event.

Parameters: ``window_s``, ``hop_s``, ``holdout_fraction`` and ``effects`` (string array of catalog effect names)
are changeable at runtime (``ros2 param set /identification_node effects "['NAME']"``, names from
``aeropend effects``); unknown effect names are rejected with the reason. The new values apply from the next window.
``sample_rate`` [Hz] (read at start-up; the rig's 490 by default, 20 to 2000 for another rig's logger) sets the
sample period that windows, gaps, stamps and the analysis use.
"""
from __future__ import annotations

import math
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from aeropend_ros._node_util import (  # first: prepares the ROS environment  # isort: skip
    ParameterError,
    check_unknown_overrides,
    declare,
    run_node,
)
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from aeropend_core.errors import AeropendError, InsufficientDataError
from aeropend_core.identify.plausibility import check_parameters, verdict_line
from aeropend_core.model.parameters import SAMPLE_TIME
from aeropend_core.signals.quality import DataQualityError, check_recording
from aeropend_ros import topics
from aeropend_core.diagnosis.compare import MAX_LOST_FRACTION as _OFFLINE_MAX_LOST_FRACTION
from aeropend_core.diagnosis.sample_windows import (  # noqa: F401  (re-exported: the stream's rules)
    REJECTIONS, STABLE_AFTER_RESTART, STAMP_JUMP_TOLERANCE, SampleWindows)
from aeropend_core.diagnosis.online import (TREND_PARAMETERS, ParameterTrends, WindowResult, analyze_window,
                                            trend_message, trend_text)
from aeropend_core.model.effects import parameter_unit
from aeropend_core.model.effects import check_effect_names
from aeropend_core.io.recording import Recording

#: Result topics, relative to the rig's namespace (``/aeropend/identification/...`` in the default graph).
COEFFICIENTS_TOPIC = 'aeropend/identification/coefficients'
PARAMETERS_TOPIC = 'aeropend/identification/parameters'
FIT_TOPIC = 'aeropend/identification/fit'
#: Name of the node's status in /diagnostics.
DIAGNOSTIC_NAME = 'aeropend: identification'
#: Fraction of lost samples above which a window is not analysed (the offline diagnosis's limit). Below it the
#: window is split at its gaps (nothing is interpolated: an interpolated second of current once shifted the
#: parameters by 4 sigma); any lost sample makes the window WARN.
MAX_LOST_FRACTION = _OFFLINE_MAX_LOST_FRACTION
#: Depth of the samples subscription's DDS history [messages]: ~20 s at 490 Hz wait there while the node is busy.
QUEUE_DEPTH = 10000
#: Period [s] of the timer that takes the waiting samples in one batch.
POLL_PERIOD_S = 0.02
@dataclass(frozen=True)
class WindowEvent:
    """What became of one window, in the order the windows ended (``aeropend run`` prints one line per event).

    Attributes
    ----------
    start_s, stop_s : float
        The window's span, acquisition time since the first sample the node received [s].
    state : str
        ``'clean'`` (published, nothing lost or repaired), ``'flagged'`` (published with its doubts: lost samples,
        repairs), ``'withheld'`` (not published: data too damaged, or the fit diverged), ``'refused'`` (not
        analysed: excitation insufficient, too little data between gaps), ``'skipped'`` (not computed: the
        previous window was still being computed) or ``'failed'`` (the analysis raised).
    message : str
        The window's /diagnostics status message.
    result : WindowResult or None
        The published result (``'clean'`` and ``'flagged'`` only).
    lost_samples : int
        Samples missing from the window by sequence number, rejected ones included (-1: not counted, a skipped
        window) [-].
    gaps : int
        Gaps in the window's sequence numbers [-].
    data : str
        The doubts about the data (``'lost_samples'``, data-quality codes), comma-separated; '' when clean.
    """

    start_s: float
    stop_s: float
    state: str
    message: str
    result: WindowResult | None = None
    lost_samples: int = 0
    gaps: int = 0
    data: str = ''


def results_qos() -> QoSProfile:
    """Reliable, keep last 10, transient local: a monitor started late still gets the latest results."""
    return QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def named_values_msg(stamp_ns: int, values: dict[str, tuple[float, float]] | dict[str, float],
                     with_errors: bool = True) -> JointState:
    """A JointState with ``name`` = keys, ``position`` = values and (optionally) ``velocity`` = standard errors."""
    msg = JointState()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
    msg.header.frame_id = topics.SAMPLE_FRAME_ID
    msg.name = list(values)
    if with_errors:
        msg.position = [float(v[0]) for v in values.values()]
        msg.velocity = [float(v[1]) for v in values.values()]
    else:
        msg.position = [float(v) for v in values.values()]
    return msg


def msg_to_named_values(msg: JointState) -> dict[str, tuple[float, float]]:
    """Inverse of :func:`named_values_msg`: ``{name: (value, standard_error or nan)}``."""
    errors = list(msg.velocity) if len(msg.velocity) == len(msg.name) else [float('nan')] * len(msg.name)
    return {name: (float(value), float(error)) for name, value, error in zip(msg.name, msg.position, errors)}


class RawSampleParser:
    """Fast reading of ``/aeropend/samples`` from raw CDR bytes (a raw subscription skips building Python messages).

    The first message (and any message whose layout differs) is deserialised in full; its layout is remembered:
    where the five position values start, and the constant bytes before them (frame id, channel names, array
    length). Later messages with the same length and the same constant bytes are read with one ``struct`` call.
    """

    def __init__(self) -> None:
        import struct
        from rclpy.serialization import deserialize_message
        self._deserialize = deserialize_message
        self._stamp = struct.Struct('<iI')
        self._values = struct.Struct('<5d')
        self._length = -1
        self._offset = 0
        self._constant = b''

    def parse(self, data: bytes) -> topics.Sample:
        if len(data) == self._length and data[12:self._offset] == self._constant and data[:2] == b'\x00\x01':
            sec, nanosec = self._stamp.unpack_from(data, 4)
            angle, voltage, current, duty, sequence = self._values.unpack_from(data, self._offset)
            return topics.Sample(sec * 1_000_000_000 + nanosec, angle, voltage, current, duty,
                                 topics.sequence_number(sequence))
        msg = self._deserialize(data, JointState)
        sample = topics.msg_to_sample(msg)
        self._learn(data, msg)
        return sample

    def _learn(self, data: bytes, msg: JointState) -> None:
        self._length = -1
        if list(msg.name) != list(topics.SAMPLE_NAMES) or len(msg.position) != 5 or data[:2] != b'\x00\x01':
            return
        offset = data.find(self._values.pack(*msg.position), 12)
        if offset < 0 or data.find(self._values.pack(*msg.position), offset + 1) >= 0:
            return
        self._length, self._offset, self._constant = len(data), offset, bytes(data[12:offset])


def _never_called(_message) -> None:
    """Callback of the polled subscription: its node is never spun (:meth:`IdentificationNode._take_samples`)."""


def _analyze_in_worker(*args, **keywords) -> WindowResult:
    """Run :func:`analyze_window` in the worker process with single-threaded BLAS (2 shared cores); the caller
    passes ``sample_time`` (the node's sample_rate)."""
    from threadpoolctl import threadpool_limits
    with threadpool_limits(1):
        return analyze_window(*args, **keywords)


def _ignore_interrupts() -> None:
    """Worker start-up: Ctrl-C goes to the whole process group; the node shuts the worker down itself."""
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)



def _worker_start(parent_pid: int) -> None:
    """Worker start-up: die with the node's process (:func:`aeropend_ros._lifetime.die_with_parent`), leave Ctrl-C
    to the node."""
    from aeropend_ros._lifetime import die_with_parent
    die_with_parent(parent_pid)
    _ignore_interrupts()


def _warm_up() -> None:
    """Import the analysis stack in the worker process ahead of the first window (spawn start-up takes seconds)."""
    import aeropend_core.identify.pendulum  # noqa: F401
    import aeropend_core.diagnosis.output_error  # noqa: F401
    import aeropend_core.signals.preprocess  # noqa: F401


def _of_stream(name: str) -> property:
    """A read-only view of the stream's attribute `name` (:class:`SampleWindows`), kept on the node for callers."""
    return property(lambda node: getattr(node.stream, name), doc=f"The stream's ``{name}`` (SampleWindows).")


class IdentificationNode(Node):
    """Sliding-window identification of the rig from the sample stream."""

    lock, sequence, stamps, signals = (_of_stream(n) for n in ('lock', 'sequence', 'stamps', 'signals'))
    first_stamp_ns, samples_received, samples_missed = (_of_stream(n) for n in ('first_stamp_ns', 'samples_received',
                                                                                 'samples_missed'))
    rejected, restarts, windows_due = (_of_stream(n) for n in ('rejected', 'restarts', 'windows_due'))

    def __init__(self, node_name: str = 'identification_node', **kwargs) -> None:
        super().__init__(node_name, **kwargs)
        declare(self, 'window_s', 25.0, 'window length [s] of acquisition time (>= 20 s: held-out fit by compare)',
                low=4.0, high=600.0)
        declare(self, 'hop_s', 5.0, 'a new window every hop_s seconds of acquisition time', low=0.5, high=600.0)
        declare(self, 'holdout_fraction', 0.25, 'end fraction of each window held out for the fit score',
                low=0.05, high=0.5)
        effects = declare(self, 'effects', [''], 'catalog effects in the model (names; aeropend effects)')
        #: The source's sample period [s] (the rig's 1/490 s; another rig's logger: its own rate, 20 Hz to 2 kHz).
        self.sample_time = 1.0 / float(declare(self, 'sample_rate', 1.0 / SAMPLE_TIME, 'sample rate of the source '
                                               '[Hz] (the rig: 490; 20 to 2000)', low=20.0, high=2000.0,
                                               read_only=True))
        check_unknown_overrides(self)
        try:
            self.effects = check_effect_names(effects, 'effects')
        except AeropendError as error:
            raise ParameterError(f'{self.get_name()}: parameter effects: {error}; fix -p "effects:=[\'NAME\']" or '
                                 'the params file') from None
        self.add_on_set_parameters_callback(self._validate_parameters)      # check only
        self.add_post_set_parameters_callback(self._apply_parameters)       # then apply

        #: The samples buffered and cut into windows, the counts of received, missed and rejected samples and of
        #: restarts (:class:`aeropend_core.diagnosis.sample_windows.SampleWindows`, plain Python, tested without ROS).
        self.stream = SampleWindows(self.sample_time)
        # The analysis runs in a worker *process* (spawned: no fork of the DDS threads): a worker thread would
        # hold the GIL for most of a window's fit and starve the executor, which then drops samples.
        self.worker = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context('spawn'),
                                          initializer=_worker_start, initargs=(os.getpid(),))
        self.pending = self.worker.submit(_warm_up)
        self.windows_done = 0
        self.windows_skipped = 0
        self.windows_submitted = 0
        #: The rejected-sample counts at the last window and at the last status (what changed is said).
        self._rejected_at_window = dict(self.rejected)
        self._rejected_at_status = dict(self.rejected)
        self.last_result: WindowResult | None = None
        #: The drift test over the windows (the nominal parameters' trend, windows that do not overlap); restarted
        #: when the stream restarts (``stream.generation`` counts them: a window from before one is not added),
        #: the model's effects or the window length change.
        self.trends = ParameterTrends(self._window_s())
        self._trend_key: tuple | None = None
        #: Ends [s] of the trended windows whose data were repaired, filled or warned about (said with a drift).
        self._flagged_stops: set[float] = set()
        #: Publishers of /aeropend/parameters/<name> (and .../weak_sindy/<name>), created as names appear.
        self.parameter_publishers: dict[str, object] = {}
        self.last_status = ('waiting for samples', DiagnosticStatus.OK)
        #: One :class:`WindowEvent` per window that came due, in order (appended only; a console reads it by
        #: index), and the messages of the non-window WARN/ERROR statuses (rejected samples, restarts).
        self.window_events: list[WindowEvent] = []
        self.notices: list[str] = []

        # Best effort like the publisher, with a deep queue (QUEUE_DEPTH samples, ~20 s at 490 Hz) taken in
        # batches: the subscription sits on an internal node that no executor spins, and a timer takes every waiting
        # sample each POLL_PERIOD_S (one executor turn per batch instead of one per sample, as the recorder does).
        # One callback per sample from a 2000-deep queue lost 13,866 and 23,148 of 29,400 samples beside stress-ng at
        # load 23-34 while the recorder lost none; batched takes lost none (bench/results/2026-11-27-live).
        deep = QoSProfile(depth=QUEUE_DEPTH, reliability=ReliabilityPolicy.BEST_EFFORT)
        # Raw subscription: the bytes are read directly (RawSampleParser), which costs a fraction of building a
        # JointState per sample.
        self.parser = RawSampleParser()
        self._io_node = Node(f'{self.get_name()}_io', namespace=self.get_namespace(), context=self.context,
                             use_global_arguments=False, enable_rosout=False, start_parameter_services=False)
        # the name as this node resolves it (its remappings apply; the internal node takes no global arguments)
        self._samples_subscription = self._io_node.create_subscription(
            JointState, self.resolve_topic_name(topics.SAMPLES), _never_called, deep, raw=True)
        self.create_timer(POLL_PERIOD_S, self._take_samples)
        self.coefficients_publisher = self.create_publisher(JointState, COEFFICIENTS_TOPIC, results_qos())
        self.parameters_publisher = self.create_publisher(JointState, PARAMETERS_TOPIC, results_qos())
        self.fit_publisher = self.create_publisher(JointState, FIT_TOPIC, results_qos())
        self.diagnostics_publisher = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS_TOPIC,
                                                           topics.diagnostics_qos())
        self._ensure_parameter_publishers(self.effects)
        self.create_timer(1.0, self._on_status_timer)
        self.get_logger().info(f'identifying on {self._window_s():g} s windows every {self._hop_s():g} s, '
                               f'effects {list(self.effects) or "none"}')

    # -------------------------------------------------------------------------------------------- parameters
    def _window_s(self) -> float:
        return float(self.get_parameter('window_s').value)

    def _hop_s(self) -> float:
        return float(self.get_parameter('hop_s').value)

    def _validate_parameters(self, parameters) -> SetParametersResult:
        """Reject unknown effect names (with the reason); change nothing (:meth:`_apply_parameters` applies)."""
        try:
            [check_effect_names(list(p.value or [])) for p in parameters if p.name == 'effects']
        except AeropendError as error:
            return SetParametersResult(successful=False, reason=f'effects: {error}; the model is unchanged')
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters) -> None:
        """Apply a set every check accepted: new effects from the next window."""
        for effects in [check_effect_names(list(p.value or [])) for p in parameters if p.name == 'effects']:
            self.effects = effects
            self._ensure_parameter_publishers(effects)
            self.get_logger().info(f'model effects now {list(effects) or "none"} (from the next window)')

    # --------------------------------------------------------------------------------------------- samples
    def _take_samples(self) -> None:
        """Take every sample waiting in the subscription's DDS history (one executor turn per batch)."""
        handle = self._samples_subscription.handle
        with handle:
            while True:
                taken = handle.take_message(JointState, True)
                if taken is None:
                    return
                self._on_sample(taken[0])

    def _on_sample(self, data: bytes) -> None:
        try:
            sample = self.parser.parse(data)
        except (ValueError, OverflowError) as error:
            self._say_rejected(self.stream.reject('unreadable', str(error)))
            return
        arrival = self.stream.add(sample.sequence, sample.stamp_ns, sample.armature_voltage, sample.armature_current,
                                  sample.angle)
        if arrival.rejected:
            self._say_rejected(arrival)
            return
        if arrival.restart:
            message = f'{arrival.restart}; buffer cleared, windows start again'
            self.get_logger().warning(message, throttle_duration_sec=5.0)
            if arrival.new_condition:      # one WARN per condition: restarts while it lasts are only counted
                self._report(message, DiagnosticStatus.WARN, {}, effects=self.effects)
                self.notices.append(message)
        if arrival.stable_again:                 # the end of a restart condition is a change too: say so once
            self._report(f'samples in order again after {arrival.restarts_in_condition} restart(s); '
                         'windows start from here', DiagnosticStatus.OK, {}, effects=self.effects)
        self._maybe_start_window(sample.stamp_ns)

    def _say_rejected(self, arrival) -> None:
        """Log a sample the stream did not buffer (counted there, see REJECTIONS); /diagnostics reports the counts."""
        self.get_logger().warning(f'sample rejected, {REJECTIONS[arrival.rejected]}: {arrival.detail}',
                                  throttle_duration_sec=5.0)

    @staticmethod
    def _rejected_text(now: dict[str, int], before: dict[str, int]) -> tuple[int, str]:
        """Rejected samples between two counter snapshots: (total, 'n reason, ...')."""
        changes = {key: now[key] - before[key] for key in now if now[key] > before[key]}
        return sum(changes.values()), ', '.join(f'{count} {REJECTIONS[key]}' for key, count in changes.items())

    def _maybe_start_window(self, now_ns: int) -> None:
        snapshot = self.stream.due_window(now_ns, self._window_s(), self._hop_s())
        if snapshot is None:
            return
        if self.pending is not None and not self.pending.done():
            self._skip_window(now_ns, int(self._window_s() * 1e9))
            return
        self._submit(snapshot, self.effects, float(self.get_parameter('holdout_fraction').value))

    def _skip_window(self, now_ns: int, window_ns: int) -> None:
        """A window came due while the previous one is still computed: counted, logged and said on /diagnostics."""
        self.windows_skipped += 1
        if self.windows_submitted == 0:
            busy = 'the analysis worker is still starting (imports, loading the compiled kernels)'
            advice = 'scripts/setup.sh compiles the kernels ahead (scripts/warm_numba_cache.py)'
        else:
            busy = 'the previous window is still being computed'
            advice = 'a longer hop_s or a less loaded machine avoids it'
        origin = self.first_stamp_ns if self.first_stamp_ns is not None else now_ns - window_ns
        start_s, stop_s = (now_ns - window_ns - origin) * 1e-9, (now_ns - origin) * 1e-9
        message = (f'window {start_s:.1f}-{stop_s:.1f} s skipped: {busy} ({self.windows_skipped} skipped so far); '
                   f'{advice}')
        self.get_logger().warning(message)
        self.window_events.append(WindowEvent(start_s, stop_s, 'skipped', message, lost_samples=-1))
        self._report(message, DiagnosticStatus.WARN, {'window_stop_ns': str(now_ns + round(SAMPLE_TIME * 1e9)),
                                                      'skipped_window_start_s': f'{start_s:.3f}',
                                                      'skipped_window_stop_s': f'{stop_s:.3f}',
                                                      'skip_reason': busy}, effects=self.effects)

    # ---------------------------------------------------------------------------------------------- worker
    def _submit(self, snapshot: dict, effects: tuple[str, ...], holdout_fraction: float) -> None:
        sequence = snapshot['sequence']
        stop_ns = int(snapshot['stamp_ns'][-1] + round(self.sample_time * 1e9))
        health = {'samples': str(sequence.size), 'window_stop_ns': str(stop_ns)}
        origin = self.first_stamp_ns if self.first_stamp_ns is not None else int(snapshot['stamp_ns'][0])
        health['stream_start_ns'] = str(origin)        # acquisition time 0 of the run (its console's t = 0)
        health['window_s'] = f'{self._window_s():g}'
        span = ((stop_ns - origin) * 1e-9 - self._window_s(), (stop_ns - origin) * 1e-9)
        rejected, rejected_text = self._rejected_text(self.rejected, self._rejected_at_window)
        self._rejected_at_window = dict(self.rejected)
        health['rejected_samples'] = str(rejected)
        # The data-quality gate, the same as for files: stamps against sequence numbers and the rate, units,
        # wraps and jumps, outliers, stuck sensors. A refusal withholds the window (ERROR); repairs and warnings
        # let it through, flagged (WARN, data_quality in the key/values).
        findings = ()
        if self.first_stamp_ns is not None:
            window = Recording((snapshot['stamp_ns'] - self.first_stamp_ns) * 1e-9,
                               {**{k: snapshot[k] for k in self.signals}, 'sequence': sequence.astype(float)},
                               source='window')
            try:
                report = check_recording(window, sample_time=self.sample_time, context='window')
            except DataQualityError as error:
                health['data_quality'] = f'{error.finding.code}:refused'
                message = f'window not analysed, data quality: {error}'
                self._report(message, DiagnosticStatus.ERROR, health, effects=effects)
                self.window_events.append(WindowEvent(*span, 'withheld', message, data=error.finding.code))
                return
            findings = tuple(report.recording.findings)
            sequence = report.recording.signals['sequence'].astype(np.int64)
            snapshot = {**snapshot, **{k: report.recording.signals[k] for k in self.signals}}
        # Lost samples: gaps in the sequence numbers (the window is split there, nothing is filled in), and the
        # samples missing from the whole window (also before its first received sample), rejected ones included.
        steps = np.diff(sequence)
        inside = int(np.sum(steps - 1)) if sequence.size > 1 else 0
        expected = int(round(self._window_s() / self.sample_time))
        longest_gap = int(np.max(steps) - 1) if sequence.size > 1 else 0
        missing = max(inside, expected - int(sequence.size))
        health['lost_samples'] = str(missing)
        health['gaps'] = str(int(np.count_nonzero(steps > 1)))
        health['longest_gap_s'] = f'{longest_gap * self.sample_time:.4f}'
        if missing > MAX_LOST_FRACTION * expected:
            why = f'{missing} of {expected} samples lost (> {MAX_LOST_FRACTION:.0%}): too little remains'
            message = (f'window not analysed: {why}' + (f', of them rejected: {rejected_text}' if rejected else '')
                       + '; check the link, the load or the source')
            self._report(message, DiagnosticStatus.ERROR, health, effects=effects)
            self.window_events.append(WindowEvent(*span, 'withheld', message, lost_samples=missing,
                                                  gaps=int(health['gaps']), data='lost_samples'))
            return
        if findings:
            health['data_quality'] = ','.join(f'{f.code}:{f.severity}' for f in findings)
            health['data_quality_detail'] = ' | '.join(f.message for f in findings)
        if rejected:
            health['rejected'] = rejected_text
        # Times from the window start: epoch seconds (~1.8e9 s) in float64 would jitter the 2 ms steps by ~2e-4.
        # Gaps stay gaps: the times skip the lost samples' slots, and the sequence numbers go with them.
        start_s = int(snapshot['stamp_ns'][0]) * 1e-9
        time = (sequence - sequence[0]) * self.sample_time
        self.windows_submitted += 1
        self.pending = self.worker.submit(_analyze_in_worker, time, snapshot['armature_voltage'],
                                          snapshot['armature_current'], snapshot['angle'], effects, holdout_fraction,
                                          sequence=sequence, sample_time=self.sample_time)
        trend_key = (self.stream.generation, tuple(effects), self._window_s())
        self.pending.add_done_callback(lambda future: self._on_result(future, stop_ns, health, effects, start_s,
                                                                      findings, trend_key, span))

    @staticmethod
    def _non_finite(result: WindowResult) -> list[str]:
        """Names of the values of a result that are not finite (standard errors may be NaN: unknown)."""
        values = {f'coefficient {k}': v for k, (v, _) in result.coefficients.items()}
        values.update({f'parameter {k}': v for k, (v, _) in result.parameters.items()})
        values.update({'fit_percent': result.fit_percent, 'rms_error': result.rms_error})
        return [name for name, value in values.items() if not math.isfinite(value)]

    def _on_result(self, future, stop_ns: int, health: dict, effects: tuple[str, ...], start_s: float = 0.0,
                   findings: tuple = (), trend_key: tuple | None = None,
                   span: tuple[float, float] = (math.nan, math.nan)) -> None:
        counts = {'lost_samples': int(health.get('lost_samples', '0')), 'gaps': int(health.get('gaps', '0'))}
        try:
            result = future.result()
            result.start += start_s          # back to acquisition time
            result.stop += start_s
        except InsufficientDataError as error:
            self._report(str(error), DiagnosticStatus.WARN, health, excitation=str(error), effects=effects)
            self.window_events.append(WindowEvent(*span, 'refused', str(error), **counts))
            return
        except Exception as error:  # noqa: BLE001 - a failed window must not kill the node; report it
            self._report(f'window failed: {error}', DiagnosticStatus.ERROR, health, effects=effects)
            self.get_logger().error(f'window analysis failed: {error!r}')
            self.window_events.append(WindowEvent(*span, 'failed', f'window failed: {error}', **counts))
            return
        seen = {f.code for f in findings}
        findings = tuple(findings) + tuple(f for f in result.findings if f.code not in seen)
        if findings:
            health['data_quality'] = ','.join(f'{f.code}:{f.severity}' for f in findings)
            health['data_quality_detail'] = ' | '.join(f.message for f in findings)
        bad = self._non_finite(result)
        if bad:
            message = f'window not published: {", ".join(bad)} not finite (the fit diverged)'
            self._report(message, DiagnosticStatus.ERROR, health, effects=effects)
            self.window_events.append(WindowEvent(*span, 'withheld', message, **counts))
            return
        self.windows_done += 1
        self.last_result = result
        doubts = [f.code for f in findings]
        if health.get('lost_samples', '0') != '0' or 'rejected' in health:
            doubts.insert(0, 'lost_samples')
        trends, drift = self._trend(result, trend_key, flagged=bool(doubts))
        # never an impossible number unflagged: each parameter checked against its physical sign and range
        failed = check_parameters({k: v for k, (v, _) in result.parameters.items()},
                                  {k: sigma for k, (_, sigma) in result.parameters.items()})
        self.coefficients_publisher.publish(named_values_msg(stop_ns, result.coefficients))
        self.parameters_publisher.publish(named_values_msg(stop_ns, result.parameters))
        self._publish_parameters(stop_ns, result, 'flagged:' + ','.join(doubts) if doubts else 'clean', trends,
                                 failed)
        fit = {'fit_percent': result.fit_percent, 'rms_error': result.rms_error, 'noise_rms': result.noise_rms,
               'held_out_seconds': result.held_out_seconds, 'compute_time': result.compute_time,
               'window_start': result.start}
        self.fit_publisher.publish(named_values_msg(stop_ns, fit, with_errors=False))
        health['compute_time_s'] = f'{result.compute_time:.3f}'
        health['fit_method'] = result.method
        health['fit_percent'] = f'{result.fit_percent:.2f}'
        health['rms_error_rad'] = f'{result.rms_error:.5f}'
        health['noise_rms_rad'] = f'{result.noise_rms:.5f}'
        message = f'fit {result.fit_percent:.1f} % on {result.held_out_seconds:.1f} s held out'
        level = DiagnosticStatus.OK
        lost = (f'{health.get("lost_samples", "0")} samples lost in {result.gap_count} gap(s) (the longest '
                f'{result.longest_gap_seconds:.3f} s): the fits were split at the gaps, nothing filled in')
        if 'rejected' in health:
            message += f'; {lost}, rejected: {health["rejected"]}'
            level = DiagnosticStatus.WARN
        elif health.get('lost_samples', '0') != '0':
            message += f'; {lost}'
            level = DiagnosticStatus.WARN
        if findings:      # the numbers are published, flagged: every doubt about the data goes with them
            message += '; data quality: ' + '; '.join(f'{f.code} ({f.severity})' for f in findings)
            level = DiagnosticStatus.WARN
        health['estimators'] = ','.join(f'{name}:{estimator}' for name, estimator in result.estimators.items())
        health['drift'] = drift or 'none'
        health.update({f'trend_{name}': trend_text(row) or 'fewer than 4 windows that do not overlap'
                       for name, row in trends.items()})
        if drift:
            message += f'; {drift}'
            level = DiagnosticStatus.WARN
        if failed:
            health['parameter_warnings'] = ' | '.join(f'{name}: {text}' for name, text in failed.items())
            message += f'; {verdict_line(failed)}'
            level = DiagnosticStatus.WARN
        self._report(message, level, health, excitation='sufficient', effects=effects)
        self.window_events.append(WindowEvent(*span, 'flagged' if doubts else 'clean', message, result,
                                              data=','.join(doubts), **counts))

    def _trend(self, result: WindowResult, trend_key: tuple | None, flagged: bool = False
               ) -> tuple[dict[str, dict], str]:
        """Add the window to the drift test; returns ``({name: trend row}, drift sentence or '')``. A drift tested
        on windows whose data were repaired or filled says how many."""
        values = {name: result.parameters[name] for name in TREND_PARAMETERS if name in result.parameters}
        if trend_key is None or trend_key[0] != self.stream.generation:
            return {}, ''             # a window from before the stream restarted: published, not trended
        if trend_key != self._trend_key:
            self.trends.reset(trend_key[2])
            self._flagged_stops = set()
            self._trend_key = trend_key
        if flagged:
            self._flagged_stops.add(result.stop)
        rows = self.trends.add(result.stop, values)
        message = trend_message(rows, {name: parameter_unit(name) for name in rows})
        tested = self.trends.tested_stops()
        doubtful = sum(stop in self._flagged_stops for stop in tested)
        if message and doubtful:
            message += (f' {doubtful} of the {len(tested)} windows tested had repaired, filled or flagged data '
                        '(data_quality on their statuses).')
        return rows, message

    def _ensure_parameter_publishers(self, effects: tuple[str, ...]) -> None:
        """Create the per-parameter publishers of the model with `effects` (in the executor's thread: the results
        arrive in the worker's callback thread, which only publishes)."""
        from aeropend_core.model.effects import get_effect
        from aeropend_core.model.names import NOMINAL_PARAMETERS
        names = [*NOMINAL_PARAMETERS, 'thrust_coefficient',
                 *(parameter.name for effect in effects for parameter in get_effect(effect).parameters)]
        for name in names:
            for estimator in ('output_error', 'weak_sindy'):
                topic = topics.parameter_topic(name, estimator).removeprefix('/')  # relative: in the rig's namespace
                if topic not in self.parameter_publishers:
                    self.parameter_publishers[topic] = self.create_publisher(JointState, topic, results_qos())

    def _publish_parameters(self, stop_ns: int, result: WindowResult, data: str, trends: dict[str, dict],
                            failed: dict[str, str] | None = None) -> None:
        """One message per parameter on aeropend/parameters/<name> (and weak SINDy's on .../weak_sindy/<name>); a
        parameter that fails a physical check carries ``data=failed_check`` (the text is in /diagnostics)."""
        failed = failed or {}
        estimates = [(name, value, sigma, result.estimators.get(name, 'output_error'))
                     for name, (value, sigma) in result.parameters.items()]
        estimates += [(name, value, sigma, 'weak_sindy') for name, (value, sigma) in result.weak_parameters.items()]
        for name, value, sigma, estimator in estimates:
            topic = topics.parameter_topic(name, estimator).removeprefix('/')  # relative: in the rig's namespace
            publisher = self.parameter_publishers.get(topic)
            if publisher is None:
                publisher = self.parameter_publishers[topic] = self.create_publisher(JointState, topic,
                                                                                     results_qos())
            row = trends.get(name, {}) if estimator != 'weak_sindy' else {}
            change = row.get('change', float('nan')) if row.get('stretches', 0) >= 4 else float('nan')
            flag = 'failed_check' if name in failed and estimator != 'weak_sindy' else data
            publisher.publish(topics.parameter_to_msg(topics.ParameterEstimate(
                name, stop_ns, value, sigma, estimator, parameter_unit(name), flag, change,
                bool(row.get('drifting', False)))))

    def _report(self, message: str, level: bytes, values: dict[str, str], excitation: str = '',
                effects: tuple[str, ...] = ()) -> None:
        values = dict(values)
        if excitation:
            values['excitation'] = excitation if excitation == 'sufficient' else f'insufficient: {excitation}'
        values['effects'] = ','.join(effects) or 'none'
        values['windows_done'] = str(self.windows_done)
        values['windows_skipped'] = str(self.windows_skipped)
        values['samples_received'] = str(self.samples_received)
        values['samples_missed'] = str(self.samples_missed)
        values.update({f'rejected_{key}': str(count) for key, count in self.rejected.items()})
        values['restarts'] = str(self.restarts)
        self.last_status = (message, level)
        self._publish_status(message, level, values)

    def _publish_status(self, message: str, level: bytes, values: dict[str, str]) -> None:
        namespace = self.get_namespace()
        status = DiagnosticStatus(level=level, name=topics.status_prefix(namespace) + DIAGNOSTIC_NAME,
                                  message=message, hardware_id=topics.rig_name(namespace))
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [status]
        self.diagnostics_publisher.publish(array)

    def _on_status_timer(self) -> None:
        buffered = self.stream.buffered_span()
        rejected, rejected_text = self._rejected_text(self.rejected, self._rejected_at_status)
        self._rejected_at_status = dict(self.rejected)
        if rejected:       # said at once, not only with the next window (which may never come)
            message = f'{rejected} samples rejected in the last second: {rejected_text}'
            self._report(message, DiagnosticStatus.WARN, {'rejected_samples': str(rejected)}, effects=self.effects)
            self.notices.append(message)
            return
        if self.windows_done == 0 and self.last_status[0] == 'waiting for samples':
            # said from the start, also while the analysis worker starts (tens of seconds on a loaded machine)
            starting = self.windows_submitted == 0 and self.pending is not None and not self.pending.done()
            computing = self.windows_submitted > 0 and self.pending is not None and not self.pending.done()
            self._publish_status(f'waiting for data: {buffered:.1f} of {self._window_s():g} s buffered'
                                 + ('; the analysis worker is still starting' if starting else '')
                                 + ('; computing the first window' if computing else ''),
                                 DiagnosticStatus.OK, {'effects': ','.join(self.effects) or 'none'})

    def buffered_seconds(self) -> float:
        """Acquisition time [s] spanned by the samples buffered now (before the first window: how far it is)."""
        return self.stream.buffered_span() + SAMPLE_TIME if self.stream.stamps else 0.0

    def destroy_node(self) -> None:
        self.worker.shutdown(wait=True, cancel_futures=True)
        self._io_node.destroy_node()
        super().destroy_node()


def main(args=None) -> int:
    """Run the identification node until Ctrl-C."""
    return run_node(IdentificationNode, args, prefer_events=False)


if __name__ == '__main__':
    raise SystemExit(main())
