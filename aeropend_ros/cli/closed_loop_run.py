"""``aeropend run --controller FILE [--reference FILE]``: play a reference schedule in closed loop.

The simulator runs the controller law itself (:class:`aeropend_ros.sim_node.SimNode` in ``control_mode``
``closed_loop``, gains and feedforward model from the controller file) on the schedule (``--reference``, or the
default 20, 40, 60, 30 deg, 5 s each after 2 s at rest); no excitation node is started. On the rig (``--port``) the
firmware runs the law (:class:`aeropend_ros.serial_bridge_node.SerialBridgeNode` in ``closed_loop``, the gains sent
as parameters) and :class:`ReferencePlayer` plays the schedule on ``aeropend/reference`` (reference and the
controller model's feedforward, one message per change), timed by the device's sample counter from the first sample
the law answered. The run lasts the schedule (``--duration`` cuts or extends it: after the schedule the last step is
held). The bag holds the control telemetry
(``/aeropend/control``), the controller's configuration (``/aeropend/controller``) and, in its metadata, the
controller file and the schedule with their sha256 (:func:`aeropend_core.control.record.closed_loop_metadata`).
While the run lasts, each completed step is judged against the controller's template (one line each); a run cut
short names the steps it did not complete. The identification node runs as in open loop.
"""
from __future__ import annotations

import argparse
import math
import sys

from aeropend_core.errors import AeropendError

#: Longest wait [s] on the rig for the law's first answer (the gains acknowledged, the loop closed) before the run
#: ends without the schedule.
RIG_START_LIMIT = 30.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The closed-loop options of ``aeropend run``."""
    parser.add_argument('--controller', metavar='GAINS.yaml', default=None,
                        help='close the loop with this controller file (gains and design model, written by '
                             '`aeropend control design`) and play a reference schedule instead of the excitation '
                             '(the simulator runs the law; with --port the rig\'s firmware, protocol 2)')
    parser.add_argument('--reference', metavar='STEPS.yaml', default=None,
                        help='with --controller: the reference schedule (steps: [{angle_deg: 20, hold: 5}, ...]); '
                             'default 20, 40, 60, 30 deg held 5 s each after 2 s at rest; the run lasts the '
                             'schedule unless --duration is given')


def check_conflicts(args) -> None:
    """Options that cannot go with the closed loop, refused before the other checks read their files."""
    if getattr(args, 'reference', None) and not getattr(args, 'controller', None):
        raise AeropendError('--reference is the closed loop\'s schedule: give the controller too (--controller '
                            'GAINS.yaml, written by `aeropend control design`)')
    if getattr(args, 'controller', None) and (getattr(args, 'experiment', None) or
                                              getattr(args, 'until_decided', False)):
        raise AeropendError('--controller plays a reference schedule in closed loop; it cannot be combined with '
                            '--experiment or --until-decided (open-loop duty schedules)')


def _one_line(error: AeropendError) -> AeropendError:
    """The same error on one line (a YAML parser's message spans several)."""
    return AeropendError(' '.join(str(error).split()))


def check_arguments(args, duration_given: bool) -> None:
    """Refuse what cannot work before any node starts (AeropendError: one line, exit 2); on success
    ``args.closed_loop`` holds the controller, the schedule and where they came from (None without --controller)."""
    args.closed_loop = None
    controller_path, reference_path = getattr(args, 'controller', None), getattr(args, 'reference', None)
    check_conflicts(args)
    if not controller_path:
        return
    from aeropend_core.control.controller_file import Controller
    from aeropend_core.control.record import default_schedule, default_schedule_text, read_schedule_file
    try:
        controller = Controller.load(controller_path)
        designed = None if reference_path else controller.schedule
        schedule = read_schedule_file(reference_path) if reference_path else (designed or default_schedule())
    except AeropendError as error:
        raise _one_line(error) from None
    gains = controller.gains
    angles = [schedule.start_angle, *(step.angle for step in schedule.steps)]
    for angle in angles:
        low, high = angle - schedule.dither_amplitude, angle + schedule.dither_amplitude
        if not (gains.angle_min < low and high < gains.angle_max):
            raise AeropendError(f'the schedule asks for {math.degrees(angle):.1f} deg, outside the controller\'s '
                                f'safety limits ({math.degrees(gains.angle_min):.1f} .. '
                                f'{math.degrees(gains.angle_max):.1f} deg: angle_min/angle_max): the law would trip')
    from aeropend_core.control.loop import FeedforwardMap      # numba: once the files are read and checked
    feedforward = FeedforwardMap(controller.parameters, controller.effects)
    for angle in angles:
        feedforward(angle)          # AeropendError when no duty holds it under the controller's model
    if not duration_given:
        args.duration = schedule.duration
    args.closed_loop = {'controller': controller, 'controller_path': controller_path, 'schedule': schedule,
                        'reference_path': reference_path,
                        'reference_text': reference_path or (designed_schedule_text(designed) if designed else
                                                             default_schedule_text())}


def designed_schedule_text(schedule) -> str:
    """The controller file's design schedule in words (console, metadata)."""
    steps = ', '.join(f'{math.degrees(step.angle):.1f}' for step in schedule.steps)
    return (f"the controller's design schedule: {math.degrees(schedule.start_angle):.1f} deg approached in "
            f'{schedule.start_hold:g} s, then {steps} deg, {schedule.steps[0].hold:g} s each')


class ClosedLoopClock:
    """Ends a closed-loop run: on the simulator when it has published its `duration` (``stop_after``); on the rig
    when the player has seen `duration` [s] of samples since the schedule's start (or the law never answered within
    RIG_START_LIMIT s). Says where the schedule starts and whether it was played whole (the bag's metadata, the keys
    of ``--experiment``). `player` is the simulator itself or the :class:`ReferencePlayer`."""

    def __init__(self, source, player, duration: float, use_sim: bool = True) -> None:
        import time
        self.source, self.player, self.duration, self.use_sim = source, player, float(duration), use_sim
        self.started = time.monotonic()
        self.never_started = False

    def over(self) -> bool:
        import time
        if self.use_sim:
            return bool(self.source.finished)
        player = self.player
        if not player.started:
            self.never_started = time.monotonic() - self.started > RIG_START_LIMIT
            return self.never_started
        return (player.sequence - player.schedule_start) * player.sample_time >= self.duration - 1e-9

    def metadata(self) -> dict[str, str]:
        player = self.player
        data = {'aeropend.schedule_seconds': f'{player.schedule.duration:.6f}',
                'aeropend.schedule_complete': 'true' if player.schedule_done() else 'false'}
        if not getattr(player, 'started', True):
            return data
        start = player.schedule_start
        if self.use_sim:
            offset = start * player.sample_time
            data.update({'aeropend.schedule_start_stamp_ns': str(int(player.start_ns + round(offset * 1e9))),
                         'aeropend.schedule_offset_s': f'{offset:.6f}'})
        else:
            data['aeropend.schedule_start_stamp_ns'] = str(int(player.start_stamp_ns))
        data['aeropend.schedule_start_sample'] = str(int(start))
        return data


def make_reference_player(schedule, controller, namespace: str, sample_time: float):
    """A :class:`ReferencePlayer` node (rclpy imported here)."""
    import numpy as np
    from rclpy.node import Node
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    from aeropend_core.control.loop import FeedforwardMap
    from aeropend_ros import topics

    class ReferencePlayer(Node):
        """Plays a reference schedule on ``aeropend/reference`` for a rig whose firmware runs the law: the schedule
        starts at the first sample the law answered (the first ``aeropend/control`` message) and is timed by the
        device's sample counter; a message goes out when the reference changes (the firmware restarts a tripped
        law on each accepted reference; an untripped one keeps its integral). A reference reaches the device some
        samples after it is sent (bridge, serial link): the player measures that latency on the telemetry (the
        sample whose ``reference`` is the new one) and sends the next changes that many samples early (the median
        of those measured), so the steps land on the schedule's times. Keeps the angle and duty of the schedule's
        samples for the console (:meth:`schedule_series`)."""

        def __init__(self) -> None:
            super().__init__('reference_player', namespace=namespace, start_parameter_services=False)
            self.schedule = schedule
            self.sample_time = float(sample_time)
            self.feedforward = FeedforwardMap(controller.parameters, controller.effects)
            self._reference = schedule.reference(None, self.sample_time)
            self._feedforward = np.array([self.feedforward(value) for value in self._reference])
            self.started = False
            self.schedule_start = 0
            self.start_stamp_ns = 0
            self.sequence = 0                 # one past the last sample seen
            self._last_sent: float | None = None
            self._pending: tuple[int, float] | None = None     # (sample it is meant for, reference) not seen yet
            self.latencies: list[int] = []                     # samples from meant to applied, per change
            self.lead = 0                                      # samples a change is sent early
            self._angles: list[tuple[int, float, float]] = []
            self.publisher = self.create_publisher(Float64MultiArray, topics.REFERENCE, topics.command_qos())
            self.create_subscription(JointState, topics.CONTROL, self._on_control, topics.samples_qos())
            self.create_subscription(JointState, topics.SAMPLES, self._on_sample, topics.samples_qos())

        @property
        def schedule_samples(self) -> int:
            return int(self._reference.size)

        def schedule_done(self) -> bool:
            return self.started and self.sequence - self.schedule_start >= self.schedule_samples

        def _on_control(self, msg) -> None:
            sequence = int(msg.position[-1])
            if not self.started:
                self.started = True
                self.schedule_start = sequence
                self.start_stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                self.get_logger().info(f'the law answers: the schedule starts at sample {sequence}')
            self.sequence = max(self.sequence, sequence + 1)
            if self._pending is not None and abs(msg.position[0] - self._pending[1]) < 1e-6:   # float32 on the device
                self.latencies.append(max(sequence - self._pending[0], 0))
                self.lead = int(np.median(self.latencies))
                self._pending = None
            # the reference of the next sample (the device applies it from then), `lead` samples ahead
            meant = sequence + 1 + self.lead
            index = min(max(meant - self.schedule_start, 0), self.schedule_samples - 1)
            reference = float(self._reference[index])
            if reference != self._last_sent:
                self._last_sent = reference
                if meant - self.schedule_start < self.schedule_samples:
                    self._pending = (meant, reference)
                self.publisher.publish(Float64MultiArray(data=[reference, float(self._feedforward[index])]))

        def _on_sample(self, msg) -> None:
            if self.started:
                sequence = int(msg.position[4])
                if sequence >= self.schedule_start:
                    self._angles.append((sequence, float(msg.position[0]), float(msg.position[3])))

        def schedule_series(self):
            """(time from the schedule's start [s], angle [rad], duty [fraction]) of the samples seen so far."""
            rows = np.array(list(self._angles), dtype=float).reshape(-1, 3)
            rows = rows[np.argsort(rows[:, 0], kind='stable')]
            return (rows[:, 0] - self.schedule_start) * self.sample_time, rows[:, 1], rows[:, 2]

    return ReferencePlayer()


def _judged(value: float, limit: float | None, text: str, operator: str = '<=') -> str:
    if limit is None:
        return text
    return f'{text} ({operator} {limit:g} {"ok" if value <= limit else "MISSED"})'


def step_line(number: int, metrics, template) -> str:
    """``step 2: 20.0 -> 40.0 deg: overshoot 6.1 % (<= 10 ok), settling 1.42 s (<= 2 ok), error 0.8 % (< 5 ok),
    peak duty 0.74 (<= 0.8 ok)``; without a template the numbers alone."""
    limits = template.as_dict() if template is not None else dict.fromkeys(('settling', 'overshoot', 'error',
                                                                            'duty'))
    head = f'step {number}: {math.degrees(metrics.initial):.1f} -> {math.degrees(metrics.target):.1f} deg: '
    overshoot = _judged(metrics.overshoot, limits['overshoot'], f'overshoot {metrics.overshoot:.1f} %')
    if metrics.settled:
        settling = _judged(metrics.settling_time, limits['settling'], f'settling {metrics.settling_time:.2f} s')
    else:
        settling = f'settling: not settled in {metrics.hold:g} s' + (
            f' (<= {limits["settling"]:g} MISSED)' if limits['settling'] is not None else '')
    error = abs(metrics.steady_state_error)
    error_text = f'error {metrics.steady_state_error:.1f} %'
    if limits['error'] is not None:
        error_text += f' (< {limits["error"]:g} {"ok" if error <= limits["error"] else "MISSED"})'
    duty = _judged(metrics.peak_duty, limits['duty'], f'peak duty {metrics.peak_duty:.2f}')
    return head + ', '.join((overshoot, settling, error_text, duty))


class StepPrinter:
    """The live console of a closed-loop run: one line per completed step of the schedule (measured metrics
    against the controller's template), read from the simulator's log of the schedule."""

    def __init__(self, source, schedule, template) -> None:
        # `source`: the simulator or the ReferencePlayer (sequence, schedule_start, sample_time, schedule_series())
        self.source, self.schedule, self.template = source, schedule, template
        self.spans = schedule.step_times()
        self.next = 0
        self.results: list[dict] = []

    def update(self) -> None:
        source = self.source
        if not getattr(source, 'started', True):
            return
        played = (source.sequence - source.schedule_start) * source.sample_time
        while self.next < len(self.spans) and played >= self.spans[self.next][1] - 1e-9:
            self._judge(self.next)
            self.next += 1

    def _judge(self, index: int) -> None:
        from aeropend_core.control.metrics import step_metrics
        start, end, before, after = self.spans[index]
        if before == after:
            self.results.append({'step': index + 1, 'completed': True, 'metrics': None})
            return
        time, angle, duty = self.source.schedule_series()
        try:
            metrics = step_metrics(time, angle, duty, start, end, before, after)
        except AeropendError as error:
            print(f'step {index + 1}: {error}', flush=True)
            self.results.append({'step': index + 1, 'completed': True, 'metrics': None})
            return
        print(step_line(index + 1, metrics, self.template), flush=True)
        self.results.append({'step': index + 1, 'completed': True, 'metrics': metrics.as_dict(),
                             'misses': metrics.misses(self.template) if self.template is not None else {}})

    def finish(self) -> None:
        """The steps not completed (a run cut short), in one line; then a tally against the template."""
        self.update()
        missing = [f'step {index + 1} ({math.degrees(before):.1f} -> {math.degrees(after):.1f} deg)'
                   for index, (_, _, before, after) in enumerate(self.spans) if index >= self.next]
        if missing:
            print(f'not completed: {", ".join(missing)} (the run ended before their holds did)', flush=True)
            self.results += [{'step': index + 1, 'completed': False} for index in range(self.next, len(self.spans))]
        judged = [entry for entry in self.results if entry.get('metrics')]
        if judged and self.template is not None:
            met = sum(1 for entry in judged if not entry['misses'])
            print(f'closed loop: {met} of {len(judged)} completed step(s) met the template ({self.template.text()})',
                  flush=True)
        if getattr(self.source, 'loop', None) is not None and self.source.loop.controller.tripped:
            print('closed loop: SAFETY TRIP: the measured angle left the controller\'s angle_min..angle_max; the '
                  'duty was held at 0 from then on', file=sys.stderr, flush=True)


__all__ = ['ClosedLoopClock', 'RIG_START_LIMIT', 'StepPrinter', 'add_arguments', 'check_arguments', 'check_conflicts',
           'make_reference_player', 'step_line']
