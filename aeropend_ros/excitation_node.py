"""excitation_node: plays a duty-step schedule on ``aeropend/duty_cmd``, then returns the duty to 0.

Topic names are relative to the rig's namespace (``/aeropend/duty_cmd`` in the default graph, see
:mod:`aeropend_ros.topics`).

The schedule is a Latin hypercube over (duty, dwell) from :func:`aeropend_core.sim.excitation.lhc_schedule`
(``schedule: lhc``), or a list of ``[duty, dwell_s]`` steps (``schedule: steps``) given either as the flat
parameter ``steps: [duty0, dwell0, duty1, dwell1, ...]`` or in a YAML file named by ``steps_file``::

    steps:
      - [0.30, 1.5]     # duty fraction, dwell [s]
      - [0.55, 2.0]

Every duty is clamped to ``duty_cap`` (safety). ``start_delay`` seconds at duty 0 precede the first step.

Time base (``time_source``): ``samples`` (default) follows the acquisition stamps on ``/aeropend/samples``, so the
schedule keeps its dwell times in *rig/simulation time* even when the sim runs faster than real time; ``wall``
uses the node clock (times ``time_scale``). Playing starts once the duty topic has a subscriber (and, with
``samples``, a sample has arrived). The current duty is re-sent every ``republish_period`` seconds for late
joiners. When the schedule ends the duty goes to 0 and ``/aeropend/excitation/done`` (``std_msgs/Bool``,
transient local) becomes true; with ``exit_when_done`` the process then exits. Destroying the node (Ctrl-C)
also sends duty 0.
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from aeropend_ros._node_util import (  # first: prepares the ROS environment  # isort: skip
    ParameterError,
    check_unknown_overrides,
    declare,
    run_node,
)
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64

from aeropend_core.errors import AeropendError
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_ros import topics

_STAMP = struct.Struct('<iI')

#: Topic on which the node reports that the schedule has finished (std_msgs/Bool, transient local), relative to
#: the rig's namespace (``/aeropend/excitation/done`` in the default graph).
DONE_TOPIC = 'aeropend/excitation/done'


def done_qos() -> QoSProfile:
    """Reliable, transient local, depth 1: a late subscriber still learns whether the excitation is done."""
    return QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def read_steps_file(path: str | Path) -> np.ndarray:
    """Read ``steps: [[duty, dwell_s], ...]`` from a YAML file; returns shape (n_steps, 2)."""
    import yaml

    from aeropend_core.io.inputs import load_yaml
    path = Path(path)
    try:
        document = load_yaml(path, 'the steps file')     # a FIFO, device or a too deep YAML: refused
    except OSError as error:
        raise AeropendError(f'cannot read the steps file {path}: {error.strerror}') from None
    except yaml.YAMLError as error:
        raise AeropendError(f'steps file {path} is not valid YAML: {error}') from None
    steps = document.get('steps') if isinstance(document, dict) else None
    if not isinstance(steps, list):
        raise AeropendError(f'steps file {path} needs a list "steps: [[duty, dwell_s], ...]"')
    return check_steps(steps, str(path))


def check_steps(steps, origin: str) -> np.ndarray:
    """Validate a list of ``[duty, dwell_s]`` pairs; returns float array of shape (n_steps, 2)."""
    try:
        array = np.asarray(steps, dtype=float).reshape(-1, 2)
    except (TypeError, ValueError):
        raise AeropendError(f'{origin}: steps must be pairs [duty fraction, dwell seconds]') from None
    if array.size == 0:
        raise AeropendError(f'{origin}: no steps given')
    if not np.all(np.isfinite(array)) or np.any(array[:, 0] < 0) or np.any(array[:, 0] > 1):
        raise AeropendError(f'{origin}: every duty must be a fraction in [0, 1] (0.7 for 70 %)')
    if np.any(array[:, 1] <= 0):
        raise AeropendError(f'{origin}: every dwell must be a positive number of seconds')
    return array


class ExcitationNode(Node):
    """Plays a step schedule on the duty command topic, with a safety cap, then sends 0 and reports done."""

    def __init__(self, node_name: str = 'excitation_node', **kwargs) -> None:
        super().__init__(node_name, **kwargs)
        kind = declare(self, 'schedule', 'lhc', "'lhc' (Latin hypercube) or 'steps' (steps / steps_file)",
                       read_only=True, choices=('lhc', 'steps'))
        duration = declare(self, 'duration', 60.0, 'length of the Latin-hypercube schedule [s]', read_only=True,
                           low=0.5, high=86400.0)
        seed = declare(self, 'seed', 1, 'seed of the Latin hypercube', read_only=True, low=0, high=2**31 - 1,
                       integer=True)
        n_strata = declare(self, 'n_strata', 10, 'steps per hypercube (strata of duty and dwell)',
                           read_only=True, low=1, high=1000, integer=True)
        duty_min = declare(self, 'duty_min', 0.0, 'lowest step duty fraction', read_only=True, low=0.0, high=1.0)
        duty_max = declare(self, 'duty_max', 0.7, 'highest step duty fraction', read_only=True, low=0.0,
                           high=1.0)
        dwell_min = declare(self, 'dwell_min', 0.6, 'shortest dwell [s]', read_only=True, low=0.01, high=3600.0)
        dwell_max = declare(self, 'dwell_max', 2.0, 'longest dwell [s]', read_only=True, low=0.01, high=3600.0)
        flat_steps = declare(self, 'steps', [0.0], 'flat list [duty0, dwell0, duty1, dwell1, ...] for '
                             "schedule 'steps'", read_only=True)
        steps_file = declare(self, 'steps_file', '', "YAML file with 'steps: [[duty, dwell_s], ...]'",
                             read_only=True)
        self.duty_cap = declare(self, 'duty_cap', 0.7, 'safety cap on every commanded duty', read_only=True,
                                low=0.0, high=1.0)
        start_delay = declare(self, 'start_delay', 1.0, 'rest at duty 0 before the first step [s]',
                              read_only=True, low=0.0, high=3600.0)
        self.time_source = declare(self, 'time_source', 'samples', "'samples' (acquisition stamps) or 'wall'",
                                   read_only=True, choices=('samples', 'wall'))
        self.time_scale = declare(self, 'time_scale', 1.0, "with time_source 'wall': schedule seconds per wall "
                                  'second (the realtime factor of a sim whose samples are not followed)',
                                  read_only=True, low=0.01, high=1000.0)
        republish_period = declare(self, 'republish_period', 0.5, 're-send the current duty this often [s]',
                                   read_only=True, low=0.05, high=60.0)
        self.exit_when_done = declare(self, 'exit_when_done', True, 'exit the process when the schedule ends',
                                      read_only=True)
        check_unknown_overrides(self)
        name = self.get_name()
        # The step list and file are checked even when the schedule is 'lhc' (a mistake there is still a mistake).
        try:
            listed = check_steps(flat_steps, 'parameter steps') if list(flat_steps) != [0.0] else None
        except AeropendError as error:
            raise ParameterError(f'{name}: {error}; fix -p steps:=[duty0, dwell0, ...] or the params file') \
                from None
        try:
            from_file = read_steps_file(steps_file) if steps_file else None
        except AeropendError as error:
            raise ParameterError(f'{name}: parameter steps_file: {error}') from None

        if kind == 'lhc':
            # The hypercube spreads the steps over [min, max]: both ranges must be open intervals.
            if not duty_min < duty_max:
                raise ParameterError(f'{name}: duty_min ({duty_min:g}) must be below duty_max ({duty_max:g}), the '
                                     "range the Latin hypercube spreads the steps over; for fixed steps use "
                                     "schedule 'steps'")
            if not dwell_min < dwell_max:
                raise ParameterError(f'{name}: dwell_min ({dwell_min:g} s) must be below dwell_max '
                                     f"({dwell_max:g} s), the range of the step lengths; for fixed steps use "
                                     "schedule 'steps'")
            try:
                schedule = lhc_schedule(duration, int(n_strata), (duty_min, duty_max), (dwell_min, dwell_max),
                                        seed=int(seed), duty_cap=1.0)
            except (AeropendError, ValueError) as error:
                raise ParameterError(f'{name}: no Latin-hypercube schedule from duration, n_strata, duty_min/max '
                                     f'and dwell_min/max: {error}') from None
            steps = np.column_stack((schedule.amplitudes, schedule.dwells))
            steps = steps[np.concatenate(([0.0], np.cumsum(steps[:, 1])[:-1])) < duration]
        else:
            steps = from_file if from_file is not None else listed
            if steps is None:
                raise ParameterError(f"{name}: schedule 'steps' needs steps:=[duty0, dwell0, duty1, dwell1, ...] "
                                     'or steps_file (a YAML file with steps: [[duty, dwell_s], ...])')
        if np.any(steps[:, 0] > self.duty_cap):
            self.get_logger().warning(f'{int(np.sum(steps[:, 0] > self.duty_cap))} step(s) above duty_cap '
                                      f'{self.duty_cap:g}: clamped')
        self.duties = np.minimum(steps[:, 0], self.duty_cap)
        self.dwells = steps[:, 1]
        #: End time of each step [s] from the start of playing (the start delay is a leading zero step).
        self.step_ends = start_delay + np.cumsum(self.dwells)
        self.start_delay = start_delay
        self.total_time = float(self.step_ends[-1])

        self.duty_publisher = self.create_publisher(Float64, topics.DUTY_COMMAND, topics.command_qos())
        self.done_publisher = self.create_publisher(Bool, DONE_TOPIC, done_qos())
        self.done_publisher.publish(Bool(data=False))
        self.started = False
        self.done = False
        self.current_duty = 0.0
        self.step_index = -1
        self._start_ns = None
        self._follow_clock = None
        self._last_sent_ns = 0
        self._republish_ns = int(republish_period * 1e9)
        if self.time_source == 'samples':
            # Raw subscription: only the stamp is needed, read straight from the CDR bytes (cheap at 490 Hz and
            # faster). Bytes 0-3 are the encapsulation header, then header.stamp (int32 sec, uint32 nanosec).
            self.create_subscription(JointState, topics.SAMPLES, self._on_sample, topics.samples_qos(),
                                     raw=True)
        self.create_timer(0.005, self._on_timer)
        self.get_logger().info(f'excitation: {len(self.duties)} steps, {self.total_time:.1f} s '
                               f'(duty cap {self.duty_cap:g}, time from {self.time_source})')

    # ------------------------------------------------------------------------------------------------------------
    def _ready(self) -> bool:
        return self.duty_publisher.get_subscription_count() > 0

    def _on_sample(self, data: bytes) -> None:
        if len(data) < 12 or data[1] != 1:          # not little-endian CDR: ignore
            return
        sec, nanosec = _STAMP.unpack_from(data, 4)
        stamp_ns = sec * 1_000_000_000 + nanosec
        if not self.started:
            if not self._ready():
                return
            self._begin(stamp_ns)
        self._advance((stamp_ns - self._start_ns) * 1e-9)

    def follow(self, clock) -> None:
        """Play on `clock` instead of the wall clock: a callable giving seconds [s], e.g. the in-process simulator's
        published samples x Ts (``aeropend run``), so the schedule keeps its dwells in simulated time even when the
        simulator lags or catches up. The start (``_start_ns``) is then that clock's reading, in ns."""
        self._follow_clock = clock

    def _on_timer(self) -> None:
        now_ns = self.get_clock().now().nanoseconds
        if self._follow_clock is not None and not self.done:
            now_clock_ns = round(self._follow_clock() * 1e9)
            if not self.started:
                if not self._ready():
                    return
                self._begin(now_clock_ns)
            self._advance((now_clock_ns - self._start_ns) * 1e-9)
        elif self.time_source == 'wall' and not self.done:
            if not self.started:
                if not self._ready():
                    return
                self._begin(now_ns)
            self._advance((now_ns - self._start_ns) * 1e-9 * self.time_scale)
        if self.started and not self.done and now_ns - self._last_sent_ns >= self._republish_ns:
            self._send(self.current_duty)

    def _begin(self, start_ns: int) -> None:
        self.started = True
        self._start_ns = start_ns
        self.get_logger().info('duty subscriber found: excitation starts')
        self._send(0.0)

    def _advance(self, elapsed: float) -> None:
        """Send the duty of the step running at `elapsed` seconds [s] since the start, or finish."""
        if self.done:
            return
        if elapsed < self.start_delay:
            return
        index = int(np.searchsorted(self.step_ends, elapsed, side='right'))
        if index >= len(self.duties):
            self.finish()
            return
        if index != self.step_index:
            self.step_index = index
            self.current_duty = float(self.duties[index])
            self._send(self.current_duty)

    def _send(self, duty: float) -> None:
        self.duty_publisher.publish(Float64(data=float(min(max(duty, 0.0), self.duty_cap))))
        self._last_sent_ns = self.get_clock().now().nanoseconds

    def finish(self) -> None:
        """Return the duty to 0 and report done."""
        self.current_duty = 0.0
        self._send(0.0)
        self.done = True
        self.done_publisher.publish(Bool(data=True))
        self.get_logger().info(f'excitation done after {len(self.duties)} steps: duty back to 0')

    def destroy_node(self) -> None:
        """Send duty 0 before going away (safety), then destroy."""
        try:
            if self.started and not self.done:
                self._send(0.0)
            for publisher in (self.duty_publisher, self.done_publisher):
                publisher.wait_for_all_acked(Duration(seconds=5.0))     # returns once acked; a busy host is slow
        except Exception:  # noqa: BLE001 - the context may already be shut down; nothing else to do
            pass
        super().destroy_node()


def main(args=None) -> int:
    """Run the excitation node until the schedule ends (``exit_when_done``) or Ctrl-C."""
    return run_node(ExcitationNode, args, until=lambda node: node.done and node.exit_when_done)


if __name__ == '__main__':
    raise SystemExit(main())
