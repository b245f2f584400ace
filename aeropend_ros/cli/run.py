"""Start the whole node graph in one process: sim (or the rig), excitation, recorder, online identification.

By default the simulator stands in for the rig (with a hidden effect the model does not know about), a
Latin-hypercube duty schedule excites it, everything is recorded to an MCAP bag under bags/, the identification
node fits the model on sliding windows (its held-out fit is printed as windows complete), and at the end the
diagnosis of the recording says which physical effect is missing.

Examples:
  aeropend run                                   # sim, 60 s, record to bags/, diagnose
  aeropend run --duration 120 --add angle_offset   # the model includes angle_offset from the start
  aeropend run --report report.html --json run.json
  aeropend run --effect coulomb_friction=4 --realtime-factor 4
  aeropend run --port /dev/ttyACM0 --duration 90 # the real rig through the serial bridge
  aeropend run --foxglove                        # also serve the live graph to Foxglove on ws://127.0.0.1:8765
  aeropend run --rig rig1                        # one of several rigs on a network: namespace /rig1
  aeropend run --experiment experiment.yaml      # play a designed schedule file instead of the hypercube
  aeropend run --until-decided --effect thrust_lag=0.02   # diagnose, design, run again until decided
  aeropend run --controller gains.yaml --reference steps.yaml   # closed loop: the law tracks a reference schedule

One graph per rig: before any node starts, a run takes a lock for its rig (namespace) and ROS domain on this host
and looks at the ROS graph for another graph's nodes on the rig's topics; either refuses the run, naming the running
one and the --rig / ROS_DOMAIN_ID to use (two graphs on one rig would each drive the other's motor). While the run
lasts it keeps looking, every second: another graph that discovery shows later stops it with the same refusal.

ROS_AUTOMATIC_DISCOVERY_RANGE is set to LOCALHOST for this demo unless you set it yourself (SUBNET to reach the
other machines of a lab; docs/graph.md#many-rigs-on-one-network).
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import time
from pathlib import Path

from aeropend_core.errors import AeropendError
from aeropend_ros.cli.rig_guard import (UNNAMED_NODE, check_graph_is_free, claim_rig, foreign_publishers,
                                         graph_in_use, refusal_due, watched_topics)
from aeropend_ros.cli.run_json import write_run_json

#: Hidden effect of the default simulation (documented in README, not printed: finding it is the job).
DEFAULT_HIDDEN_EFFECTS = ['angle_offset=0.05']


def add_arguments(parser: argparse.ArgumentParser) -> None:
    source = parser.add_mutually_exclusive_group()
    source.add_argument('--sim', action='store_true', help='use the simulator (default)')
    source.add_argument('--port', metavar='DEVICE', help='use the rig on this serial port (e.g. /dev/ttyACM0)')
    parser.add_argument('--rig', metavar='NAME', default=None,
                        help='run the whole graph in the ROS namespace /NAME (topics /NAME/aeropend/samples, ...; '
                             'one name per rig on a shared network; default: the root namespace, /aeropend/...)')
    parser.add_argument('--record', metavar='DIR', default='bags',
                        help='folder in which the bag folder is created (default: bags)')
    parser.add_argument('--no-record', action='store_true', help='do not record (diagnose the samples in memory)')
    parser.add_argument('--duration', type=float, default=None, metavar='S',
                        help='length of the experiment [s] (default 60, or the --experiment / --reference '
                             'schedule\'s; the diagnosis needs >= 20 s)')
    parser.add_argument('--effect', action='append', default=None, metavar='NAME=VALUE',
                        help='hidden effect of the simulator (repeatable; replaces the default hidden effect); '
                             '--effect none for a clean simulator')
    parser.add_argument('--add', dest='model_effect', action='append', default=[], metavar='EFFECT',
                        help='effect included in the identified model from the start (repeatable; the same flag '
                             'as `aeropend diagnose --add`)')
    # the old name, kept working for scripts: hidden from the help, one deprecation line when used
    parser.add_argument('--model-effect', dest='deprecated_model_effect', action='append', default=[],
                        help=argparse.SUPPRESS)
    parser.add_argument('--realtime-factor', type=float, default=1.0, metavar='F',
                        help='simulation speed: 1 = real time, 4 = four times faster (sim only)')
    parser.add_argument('--window', type=float, default=25.0, metavar='S', help='identification window [s]')
    parser.add_argument('--hop', type=float, default=5.0, metavar='S', help='identification hop [s]')
    parser.add_argument('--psnr', type=float, default=50.0, metavar='DB',
                        help='simulated measurement noise [dB] (0 = none)')
    parser.add_argument('--seed', type=int, default=1, help='seed of the excitation and the simulated noise')
    parser.add_argument('--duty-cap', type=float, default=None, metavar='FRACTION',
                        help='safety cap on the duty (default 0.7; with --controller, the controller\'s u_clamp_max)')
    parser.add_argument('--no-diagnose', action='store_true', help='skip the diagnosis at the end')
    parser.add_argument('--report', metavar='FILE.html', help='write the diagnosis as a self-contained HTML report')
    parser.add_argument('--json', nargs='?', const='-', default=None, metavar='FILE',
                        help='write the run and its diagnosis as one JSON object to FILE (- or no FILE: to standard '
                             'output, which then carries the JSON only; the text goes to standard error)')
    from aeropend_core.cli._checks import add_calibration_argument, add_fix_argument
    add_calibration_argument(parser)
    add_fix_argument(parser)
    parser.add_argument('--quiet', action='store_true',
                        help='no progress on standard error (the start line, the diagnosis\'s steps)')
    parser.add_argument('--foxglove', nargs='?', type=int, const=8765, default=None, metavar='PORT',
                        help='serve the live graph to Foxglove on ws://127.0.0.1:PORT (default 8765; 0 = any free '
                             'port); layout: config/aeropend.foxglove.json')
    from aeropend_ros.cli.experiment_loop import add_arguments as add_experiment_arguments
    add_experiment_arguments(parser)
    from aeropend_ros.cli.closed_loop_run import add_arguments as add_closed_loop_arguments
    add_closed_loop_arguments(parser)


def _check_arguments(args) -> None:
    import math

    from aeropend_ros.topics import rig_namespace
    args.namespace = rig_namespace(getattr(args, 'rig', None))      # AeropendError (exit 2) for a bad name
    duration_given = args.duration is not None
    if not duration_given:
        args.duration = 60.0
    from aeropend_ros.cli.closed_loop_run import check_conflicts
    check_conflicts(args)           # --controller with --experiment, --reference without --controller
    if args.duty_cap is None and not getattr(args, 'controller', None):
        args.duty_cap = 0.7         # the paper's cap: the rod stays below 90 deg
    from aeropend_ros.cli.experiment_loop import check_arguments as check_experiment
    check_experiment(args)          # --experiment sets the duration from its schedule
    if duration_given and not 0 < args.duration < math.inf:
        raise AeropendError(f'--duration must be a positive number of seconds, got {args.duration}')
    from aeropend_ros.cli.closed_loop_run import check_arguments as check_closed_loop
    check_closed_loop(args, duration_given)     # --controller: the schedule's duration unless --duration is given
    if args.duty_cap is None:       # with --controller: the controller's own cap (it was designed with it)
        args.duty_cap = args.closed_loop['controller'].gains.u_clamp_max if args.closed_loop else 0.7
    if not 0 < args.duration < math.inf:
        raise AeropendError(f'--duration must be a positive number of seconds, got {args.duration}')
    from aeropend_core.diagnosis import MIN_DURATION
    args.diagnosis_skipped = None
    if args.closed_loop is not None and not args.no_diagnose and args.duration < MIN_DURATION + 1.0 \
            and not (args.report or args.json):
        # a short closed-loop schedule is still worth running: the diagnosis is skipped, said, not refused
        args.no_diagnose = True
        args.diagnosis_skipped = (f'no diagnosis at the end: the {args.duration:g} s run is shorter than the '
                                  f'{MIN_DURATION + 1:g} s it needs')
    # the recording starts a moment after the run (discovery), so a second of margin over the diagnosis's minimum
    if not args.no_diagnose and args.duration < MIN_DURATION + 1.0:
        raise AeropendError(f'--duration {args.duration:g} s is too short for the diagnosis at the end (it needs a '
                            f'recording of {MIN_DURATION:g} s, so --duration >= {MIN_DURATION + 1:g}); run longer, '
                            'or add --no-diagnose to only record and identify')
    if args.no_diagnose and (args.report or args.json):
        raise AeropendError('--report and --json describe the diagnosis; they cannot be used with --no-diagnose')
    from aeropend_core.cli._checks import check_report_path
    check_report_path(args.report)
    if args.json and args.json != '-':
        check_report_path(args.json, '--json')
    if not 0 <= args.psnr <= 200:
        raise AeropendError(f'--psnr must be in [0, 200] dB (0 = no noise), got {args.psnr}')
    if not 0 <= args.seed <= 2**31 - 1:
        raise AeropendError(f'--seed must be a whole number in [0, 2147483647], got {args.seed}')
    if args.port is not None and args.realtime_factor != 1.0:
        raise AeropendError('--realtime-factor only applies to the simulator; the rig runs in real time')
    if not 0 < args.realtime_factor <= 100:
        raise AeropendError(f'--realtime-factor must be in (0, 100], got {args.realtime_factor}')
    if not 0 < args.duty_cap <= 1:
        raise AeropendError(f'--duty-cap must be a fraction in (0, 1], got {args.duty_cap}')
    if not 4 <= args.window <= 600 or not 0.5 <= args.hop <= 600:
        raise AeropendError(f'--window must be in [4, 600] s and --hop in [0.5, 600] s, got --window {args.window} '
                            f'--hop {args.hop}')
    if args.port is not None and not Path(args.port).exists():
        raise AeropendError(f'serial port {args.port} does not exist: is the Arduino plugged in? '
                            '(ls /dev/ttyACM* /dev/serial/by-id/), or run the simulator with --sim')
    from aeropend_core.model.effects import parse_effect_assignments
    from aeropend_core.model.effects import check_effect_names
    if args.effect and args.effect != ['none']:
        parse_effect_assignments(args.effect)
    if args.deprecated_model_effect:
        print('aeropend run: warning: --model-effect is deprecated; write --add (the same flag as diagnose and '
              'identify)', file=sys.stderr)
        args.model_effect = [*args.model_effect, *args.deprecated_model_effect]
    check_effect_names(args.model_effect, '--add')
    from aeropend_core.cli._checks import fixed_effects
    fixed_effects(args.fix, args.model_effect)          # refused now, not after the run
    if args.calibration:         # a bad file is refused before any node starts
        from aeropend_core.cli._checks import calibration_fixed
        fixed, _, _ = calibration_fixed(args.calibration, {})
        both = sorted(set(fixed) & set(args.model_effect))
        if both:
            raise AeropendError(f'{", ".join(both)} given with --add and fixed by --calibration {args.calibration}; '
                                'drop the --add (the calibration file already puts it in the model)')
    if args.foxglove is not None:
        if not 0 <= args.foxglove <= 65535:
            raise AeropendError(f'--foxglove PORT must be in [0, 65535] (0 = any free port), got {args.foxglove}')
        from aeropend_ros.foxglove_node import foxglove_sdk
        foxglove_sdk()
    if not args.no_record:
        _check_record_folder(Path(args.record))


def _check_record_folder(folder: Path) -> None:
    """The folder for the bag exists (or is created) and is writable, before any node starts."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise AeropendError(f'cannot create the --record folder {folder}: {error.strerror or error}; choose another '
                            'folder (or --no-record)') from None
    if not folder.is_dir() or not os.access(folder, os.W_OK | os.X_OK):
        raise AeropendError(f'--record {folder} is not a writable folder; choose another folder (or --no-record)')


def main(args) -> int:
    _check_arguments(args)
    # Demo traffic stays on this machine unless the user chose otherwise.
    from aeropend_ros._ros_env import ensure_ros_environment
    ensure_ros_environment(local_only=True)
    lock = claim_rig(args.namespace)        # one graph per rig and domain on this host
    try:
        if args.json == '-':
            # standard output carries the JSON object only; everything a person reads goes to standard error
            import contextlib
            with contextlib.redirect_stdout(sys.stderr):
                return _run_or_loop(args)
        return _run_or_loop(args)
    finally:
        lock.close()


def _run_or_loop(args) -> int:
    if not args.until_decided:
        return _run(args)
    from aeropend_ros.cli.experiment_loop import run_until_decided

    def run_once(round_args):       # one run of the graph, recorded, not diagnosed: the loop diagnoses
        round_args.no_diagnose, json_target, round_args.json = True, round_args.json, None
        try:
            code = _run(round_args)
        finally:
            round_args.no_diagnose, round_args.json = False, json_target
        return code, getattr(round_args, 'recorded_bag', None)

    return run_until_decided(args, run_once)


def _run(args) -> int:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from aeropend_core.model.parameters import SAMPLE_TIME
    from aeropend_ros.cli.experiment_loop import excitation_overrides as experiment_overrides
    from aeropend_ros.cli.experiment_loop import LATE_START_LIMIT, ScheduleClock, experiment_metadata
    from aeropend_ros.excitation_node import ExcitationNode
    from aeropend_ros.identification_node import IdentificationNode

    def overrides(**values):
        return [Parameter(name, value=value) for name, value in values.items()]

    namespace = args.namespace              # every node of the graph lives in the rig's namespace

    use_sim = args.port is None
    hidden = DEFAULT_HIDDEN_EFFECTS if args.effect is None else ([] if args.effect == ['none'] else args.effect)
    from rclpy.signals import SignalHandlerOptions
    # This process handles Ctrl-C itself (KeyboardInterrupt in the main thread, SIGTERM mapped to it), so that the
    # shutdown is orderly: duty back to 0, bag finalised, then the diagnosis of what was recorded.
    rclpy.init(args=['--ros-args', '--log-level', 'warn'], signal_handler_options=SignalHandlerOptions.NO)
    previous_sigterm = signal.signal(signal.SIGTERM, _raise_keyboard_interrupt)
    # Ctrl-C (SIGINT) is how a run is stopped early, so it is handled even when this process was started with it
    # ignored (a background job of a non-interactive shell inherits SIG_IGN, and Python then keeps it), as the
    # nodes and `aeropend emulate` do; the diagnosis after the run stays interruptible too.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    closed = getattr(args, 'closed_loop', None)         # --controller: the law plays a reference schedule
    steps = None
    source = None
    nodes = []
    executors = []
    spinners = []
    memory = None
    recorder = None
    bag_folder = None
    try:
        probe = rclpy.create_node('aeropend_run_probe', namespace=namespace, start_parameter_services=False,
                                  enable_rosout=False)
        try:
            check_graph_is_free(probe, namespace)
        finally:
            probe.destroy_node()
        if use_sim:
            from aeropend_ros.sim_node import SimNode
            control = dict(control_mode='closed_loop', controller_file=str(closed['controller_path'])) \
                if closed else {}
            source = SimNode(parameter_overrides=overrides(
                effects=list(hidden) or [''], psnr_db=float(args.psnr), seed=int(args.seed),
                duty_limit=float(args.duty_cap), realtime_factor=float(args.realtime_factor),
                stop_after=float(args.duration) + (LATE_START_LIMIT if args.experiment else 0.0),
                wait_for_subscribers=2,     # the recorder and the identification: no start-up backlog
                **control), namespace=namespace, guard_duty_sources=True)
            if closed:
                source.play_schedule(closed['schedule'])        # from the first sample
        else:
            from aeropend_ros.serial_bridge_node import SerialBridgeNode
            calibrated = {}
            if args.calibration:        # the rig's calibration (zeros, scales, ...); --port wins over its port
                from aeropend_core.rig.calibration import read_calibration_file
                calibrated = read_calibration_file(args.calibration)
            control = {}
            if closed:      # the firmware runs the law: the controller's gains, the duty cap on the device
                control = {**closed['controller'].gains.as_dict(), 'control_mode': 'closed_loop',
                           'max_duty': min(float(args.duty_cap), float(calibrated.get('max_duty', 1.0)))}
            source = SerialBridgeNode(parameter_overrides=overrides(**{**calibrated, **control, 'port': args.port}),
                                      namespace=namespace)
        nodes.append(source)
        player = source                 # closed loop: what plays the schedule (the sim itself, or a player node)
        if closed and not use_sim:
            from aeropend_ros.cli.closed_loop_run import make_reference_player
            player = make_reference_player(closed['schedule'], closed['controller'], namespace, SAMPLE_TIME)
            nodes.append(player)
        start_delay = 1.0
        excitation = None           # closed loop: the law sets the duty, no excitation node
        if not closed:
            excitation = ExcitationNode(parameter_overrides=overrides(
                duration=max(float(args.duration) - start_delay - 2.0, 1.0), seed=int(args.seed),
                duty_cap=float(args.duty_cap), duty_max=min(0.7, float(args.duty_cap)), start_delay=start_delay,
                time_source='wall', time_scale=float(args.realtime_factor) if use_sim else 1.0,
                exit_when_done=False, **experiment_overrides(args)), namespace=namespace)
            if use_sim:     # the schedule plays in simulated time: the simulator's published samples x Ts
                excitation.follow(lambda: source.sequence * source.sample_time)
            nodes.append(excitation)
        identification = IdentificationNode(parameter_overrides=overrides(
            window_s=float(args.window), hop_s=float(args.hop), effects=list(args.model_effect) or ['']),
            namespace=namespace)
        nodes.append(identification)
        # the console prints every window and warning of this node once (_WindowPrinter); its log would repeat them
        from rclpy.logging import LoggingSeverity
        identification.get_logger().set_level(LoggingSeverity.ERROR)
        if not args.no_record:
            from aeropend_ros.recorder_node import RecorderNode
            rig = f'{args.rig}_' if args.rig else ''
            folder = Path(args.record) / f'aeropend_{rig}{time.strftime("%Y%m%d_%H%M%S")}'
            folder.parent.mkdir(parents=True, exist_ok=True)
            extra = {}
            if closed:      # the closed loop's reference and configuration topics are recorded too
                from aeropend_ros import topics as contract
                from aeropend_ros.recorder_node import DEFAULT_ALLOWED_TYPES
                extra['allowed_types'] = [*DEFAULT_ALLOWED_TYPES, contract.REFERENCE_TYPE,
                                          contract.CONTROLLER_CONFIG_TYPE]
            recorder = RecorderNode(parameter_overrides=overrides(output=str(folder), **extra), namespace=namespace)
            if closed:      # the controller file and the schedule, their content and sha256
                from aeropend_core.control.record import closed_loop_metadata
                recorder.writer.custom_data.update(closed_loop_metadata(
                    closed['controller_path'], closed['schedule'], closed['reference_path'], args.duty_cap,
                    closed['reference_text']))
            else:
                recorder.writer.custom_data.update(experiment_metadata(args))  # which schedule this bag played
            nodes.append(recorder)
            bag_folder = folder
        else:
            memory = _MemoryRecorder(namespace)
            nodes.append(memory.node)
        if args.foxglove is not None:
            from aeropend_ros.foxglove_node import FoxgloveNode
            foxglove = FoxgloveNode(parameter_overrides=overrides(port=int(args.foxglove)), namespace=namespace)
            nodes.append(foxglove)
            print(f'aeropend run: Foxglove: open a Foxglove WebSocket connection to {foxglove.url}', flush=True)
        # One single-threaded executor per node, each spinning in its own thread: cheaper per callback than a
        # MultiThreadedExecutor, and a busy node (the recorder) never delays the sim's timer.
        for node in nodes:
            executor = SingleThreadedExecutor()
            executor.add_node(node)
            executors.append(executor)

        what = 'simulator' if use_sim else f'rig on {args.port}'
        if args.rig:
            what += f' as rig {args.rig} (namespace {namespace}: topics {namespace}/aeropend/...)'
        if closed:          # said even with --quiet: which controller, and a schedule the user did not give
            gains = closed['controller'].gains
            print(f'aeropend run: closed loop: controller {closed["controller_path"]} (p {gains.p:g}, i {gains.i:g}, '
                  f'd {gains.d:g}, setpoint weight b {gains.setpoint_weight:g}; model '
                  f'{closed["controller"].model_source}), reference '
                  f'{closed["reference_text"]}' + ('' if closed['reference_path'] else ' (no --reference given)')
                  + f'; duty capped at {args.duty_cap:g} (--duty-cap)'
                  + (f', below the controller\'s u_clamp_max {gains.u_clamp_max:g}'
                     if gains.u_clamp_max > args.duty_cap else ''), file=sys.stderr, flush=True)
            if args.diagnosis_skipped:
                print(f'aeropend run: {args.diagnosis_skipped}', file=sys.stderr, flush=True)
        if not args.quiet:          # progress: standard error (standard output carries the results)
            print(f'aeropend run: {what}, {args.duration:g} s of '
                  + ('closed loop' if closed else 'excitation')
                  + (f' at {args.realtime_factor:g}x real time' if use_sim and args.realtime_factor != 1 else '')
                  + (f', recording to {bag_folder}' if bag_folder else ', not recording')
                  + f', identifying on {args.window:g} s windows every {args.hop:g} s'
                  + (f' (model effects: {", ".join(args.model_effect)})' if args.model_effect else ''),
                  file=sys.stderr, flush=True)
        for node, executor in zip(nodes, executors):
            spinner = threading.Thread(target=_spin, args=(executor,), name=node.get_name(), daemon=True)
            spinner.start()
            spinners.append(spinner)
        if closed:
            from aeropend_ros.cli.closed_loop_run import ClosedLoopClock, StepPrinter
            clock = ClosedLoopClock(source, player, float(args.duration), use_sim)
            steps = StepPrinter(player, closed['schedule'], closed['controller'].template)
        else:
            clock = ScheduleClock(excitation, source, use_sim, float(args.duration), whole=bool(args.experiment))
        interrupted = _wait_until_done(args, source, excitation, identification, use_sim, SAMPLE_TIME, recorder,
                                       lambda: foreign_publishers(nodes, namespace), watched_topics(namespace), clock,
                                       steps)
        if recorder is not None:        # where the schedule starts in the record, and whether it was played whole
            recorder.writer.custom_data.update(clock.metadata())
        if excitation is not None and excitation.started and not excitation.done:
            excitation.finish()          # duty back to 0 before the graph goes away
        if closed and not use_sim:
            _open_the_loop(source)       # the device: open loop, duty 0, before the graph goes away
            if clock.never_started:
                from aeropend_ros.cli.closed_loop_run import RIG_START_LIMIT
                print(f'aeropend run: the device never ran the law within {RIG_START_LIMIT:g} s (controller '
                      f'gains: {getattr(source, "gains_state", "?")}): closed loop needs firmware protocol 2 '
                      '(docs/rig-link.md)', file=sys.stderr, flush=True)
        if recorder is not None and closed and not use_sim:
            # the device keeps streaming (open loop, duty 0): its counts never go quiet; the samples in flight
            # in this process arrive within milliseconds
            _drain(recorder, None, timeout=CLOSED_LOOP_RIG_DRAIN_S)
        elif recorder is not None:
            _drain(recorder, getattr(source, 'sequence', None) if use_sim else None)
    except KeyboardInterrupt:
        interrupted = True
        print('aeropend run: interrupted; finalising', file=sys.stderr)
        if closed and not use_sim and source is not None:
            _open_the_loop(source)
    finally:
        if closed and steps is not None:
            _finish_steps(steps, args)
        # A second Ctrl-C must not cut the finalisation of the bag short (it takes a second or two).
        previous_sigint = signal.signal(signal.SIGINT, signal.SIG_IGN)
        for executor in executors:
            executor.shutdown(timeout_sec=10.0)     # returns as soon as its callback ends; a busy host is slow
        for spinner in spinners:
            spinner.join(timeout=10.0)
        if recorder is not None:
            recorder.finish()
        for node in reversed(nodes):
            node.destroy_node()
        rclpy.try_shutdown()
        signal.signal(signal.SIGTERM, previous_sigterm)
        signal.signal(signal.SIGINT, previous_sigint)
    if recorder is not None and recorder.failed:
        print(f'aeropend run: error: the recording failed, so the run stopped: {recorder.write_error}',
              file=sys.stderr)
        return 1
    args.recorded_bag = bag_folder
    if bag_folder is not None:
        print(f'recorded: {bag_folder}')
    if args.no_diagnose:
        return 130 if interrupted else 0
    if closed:
        # the closed loop's record is kept whatever becomes of the diagnosis (made for open-loop excitation)
        try:
            return _diagnose(bag_folder, memory, args, interrupted)
        except KeyboardInterrupt:
            return 130
        except Exception as error:  # noqa: BLE001 - the record is what matters; say what failed, keep it
            print(f'aeropend run: the diagnosis failed ({type(error).__name__}: {error}); the closed-loop record '
                  f'is kept{": " + str(bag_folder) if bag_folder else ""}', file=sys.stderr)
            return 1
    return _diagnose(bag_folder, memory, args, interrupted)


#: How long [s] a closed-loop run on the rig lets the recorder take the samples in flight at its end.
CLOSED_LOOP_RIG_DRAIN_S = 2.0


def _open_the_loop(bridge) -> None:
    """The rig's device back to open loop with duty 0 (the bridge's control_mode), said if it cannot be."""
    from rclpy.parameter import Parameter
    try:
        bridge.set_parameters([Parameter('control_mode', value='open_loop')])
    except Exception as error:  # noqa: BLE001 - the bridge's destroy sends duty 0 anyway
        print(f'aeropend run: cannot open the loop on the device ({error}); duty 0 is sent as the bridge stops',
              file=sys.stderr)


def _finish_steps(steps, args) -> None:
    """The closed loop's last console lines (steps not completed, the tally) even when the run was cut short."""
    try:
        steps.finish()
    except Exception as error:  # noqa: BLE001 - the console must not cost the record
        print(f'aeropend run: cannot judge the steps: {error}', file=sys.stderr)
    args.closed_loop_steps = steps.results


def _raise_keyboard_interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def _spin(executor) -> None:
    """Spin one node's executor until it is shut down."""
    from rclpy.executors import ExternalShutdownException
    try:
        executor.spin()
    except ExternalShutdownException:
        pass
    except Exception as error:  # noqa: BLE001 - filtered below, everything else re-raised
        # rclpy (Jazzy) can fail inside its own task handler when the executor is shut down from another thread
        # while a callback is being dispatched: its guard condition is already None (AttributeError) or already
        # destroyed (InvalidHandle, "destruction was requested"; seen beside a CPU hog): the end of the run, not an
        # error. Anything else, or these while the executor still runs, is raised.
        ending = isinstance(error, AttributeError) or type(error).__name__ == 'InvalidHandle'
        if not (ending and getattr(executor, '_is_shutdown', False)):
            raise


#: Longest wait [s] for the windows still being computed when the experiment ends (a loaded host computes a window
#: in tens of seconds; the wait ends as soon as every window that came due has its line).
LAST_WINDOW_DEADLINE_S = 120.0
#: Buffering progress before the first window when not a terminal: a line every this many seconds of samples
#: (at most a fifth of the window) [s].
BUFFERING_STEP_S = 5.0
#: Console words of each window state (:class:`aeropend_ros.identification_node.WindowEvent`).
STATE_WORDS = {'withheld': 'WITHHELD (not published)', 'refused': 'not analysed', 'skipped': 'SKIPPED (not computed)',
               'failed': 'FAILED'}
#: Prefixes of the node's status messages that the state words replace on the console.
_MESSAGE_PREFIXES = ('window not analysed: ', 'window not analysed, ', 'window not published: ', 'window failed: ')


def data_state(event) -> str:
    """The data state of a window in words: 'data clean', or 'data FLAGGED: 312 samples lost in 20 gap(s) (the
    fits were split there, nothing filled in); data quality: angle_wrap'."""
    if event.state == 'clean':
        return 'data clean'
    parts = []
    if event.lost_samples > 0:
        parts.append(f'{event.lost_samples} samples lost in {event.gaps} gap(s) (the fits were split there, nothing '
                     'filled in)')
    codes = [code for code in event.data.split(',') if code and code != 'lost_samples']
    if 'lost_samples' in event.data.split(',') and event.lost_samples <= 0:
        parts.append('samples rejected')
    if codes:
        parts.append('data quality: ' + ', '.join(codes))
    return 'data FLAGGED: ' + ('; '.join(parts) or event.data or 'see /diagnostics')


def window_line(event) -> str:
    """One console line per window: its span (acquisition time since the run's first sample [s]) and what became
    of it; a published window carries its held-out fit and its data state, a withheld one no numbers."""
    head = f'  window {event.start_s:5.1f}-{event.stop_s:5.1f} s: '
    if event.state in ('clean', 'flagged'):
        r = event.result
        return (head + f'held-out fit {r.fit_percent:6.2f} %, rms error {r.rms_error * 1e3:6.2f} mrad (noise '
                f'{r.noise_rms * 1e3:.2f} mrad), {r.compute_time:.2f} s to compute; {data_state(event)}')
    message = event.message
    if event.state == 'skipped' and ' skipped: ' in message:
        message = message.split(' skipped: ', 1)[1]
    for prefix in _MESSAGE_PREFIXES:
        message = message.removeprefix(prefix)
    lost = (f' [{event.lost_samples} samples lost in {event.gaps} gap(s)]'
            if event.lost_samples > 0 and 'lost' not in message else '')
    return head + f'{STATE_WORDS.get(event.state, event.state)}: {message}{lost}'


class _WindowPrinter:
    """The live part of the run's console: a buffering line until the first window (standard error, rewritten in
    place on a terminal), then one line per window (standard output) and the node's other warnings, each once."""

    def __init__(self, identification, window_s: float, quiet: bool = False) -> None:
        self.node = identification
        self.quiet = quiet             # --quiet: no progress (the buffering line); the window lines stay
        self.window_s = float(window_s)
        self.events = 0
        self.notices = 0
        self.buffered_step = -1
        self.computing = False
        self.tty = sys.stderr.isatty()
        self.open_line = False         # a buffering line without its newline on the terminal

    def _progress(self, text: str) -> None:
        if self.quiet:
            return
        if self.tty:
            sys.stderr.write('\r' + text + '\x1b[K')
            self.open_line = True
        else:
            sys.stderr.write(text + '\n')
        sys.stderr.flush()

    def _end_progress(self) -> None:
        if self.open_line:
            sys.stderr.write('\n')
            sys.stderr.flush()
            self.open_line = False

    def update(self) -> None:
        node = self.node
        while self.notices < len(node.notices):
            self._end_progress()
            print(f'  identification: {node.notices[self.notices]}', flush=True)
            self.notices += 1
        while self.events < len(node.window_events):
            self._end_progress()
            print(window_line(node.window_events[self.events]), flush=True)
            self.events += 1
        if self.events:
            return
        buffered = min(node.buffered_seconds(), self.window_s)
        step = int(buffered) if self.tty else int(buffered // min(BUFFERING_STEP_S, self.window_s / 5))
        if buffered < self.window_s and step > self.buffered_step:
            self.buffered_step = step
            self._progress(f'  buffering {buffered:.0f}/{self.window_s:g} s of samples for the first window')
        elif buffered >= self.window_s and not self.computing:
            self.computing = True
            self._progress(f'  buffering {self.window_s:g}/{self.window_s:g} s: computing the first window ...')

    def all_shown(self) -> bool:
        """Every window that came due has its line."""
        return len(self.node.window_events) >= self.node.windows_due and self.events >= self.node.windows_due


#: Longest wait [s] for the identification node to take the samples still queued at the end, before counting.
RECEIVED_DEADLINE_S = 10.0


def _say_samples_received(identification, published: int) -> None:
    """One line: the samples the identification node received of those the source published, and how the others
    went (lost in gaps between received samples, counted by sequence number; or never seen at the end). Waits
    (by condition, RECEIVED_DEADLINE_S at most) until the node has taken what is still queued for it."""
    deadline = time.monotonic() + RECEIVED_DEADLINE_S
    while (identification.samples_received + identification.samples_missed < published
           and time.monotonic() < deadline):
        time.sleep(0.05)
    received, missed = identification.samples_received, identification.samples_missed
    unseen = max(published - received - missed, 0)
    print(f'  identification node: received {received} of {published} samples published ({missed} lost in gaps'
          + (f', {unseen} not seen at the end' if unseen else '') + ')', flush=True)


def _wait_until_done(args, source, excitation, identification, use_sim: bool, sample_time: float,
                     recorder=None, foreign=None, watched=(), clock=None, steps=None) -> bool:
    """Print the live windows (one line each) until the experiment is over; True when interrupted (Ctrl-C).

    Stops early when the recorder cannot write the bag (disk full): the run then ends with that error. `foreign`
    (a callable giving the names of other graphs' publishers on the rig's topics) is asked every
    FOREIGN_CHECK_PERIOD_S: another graph found while the run lasts stops it with the start-up check's refusal."""
    started = time.monotonic()
    checked = started
    unnamed_since = None        # when a foreign endpoint was first seen without its node's name
    printer = _WindowPrinter(identification, args.window, quiet=getattr(args, 'quiet', False))
    try:
        while True:
            printer.update()
            if steps is not None:       # closed loop: one line per completed step
                steps.update()
            if foreign is not None and time.monotonic() - checked >= FOREIGN_CHECK_PERIOD_S:
                checked = time.monotonic()
                found = foreign()
                unnamed_since = (unnamed_since or checked) if UNNAMED_NODE in found else None
                if refusal_due(found, checked - (unnamed_since or checked)):
                    printer._end_progress()
                    raise graph_in_use(args.namespace, found, watched)
            if clock.over() if clock is not None else (
                    (use_sim and source.finished) or (not use_sim and time.monotonic() - started > args.duration)):
                break
            if recorder is not None and recorder.failed:
                printer._end_progress()
                print(f'aeropend run: recording stopped: {recorder.write_error}', file=sys.stderr, flush=True)
                return False
            time.sleep(0.1)
        # The window that came due with the last samples may still be computed: wait for its line (a condition:
        # every window that came due has its event), with a deadline a loaded host does not reach.
        deadline = time.monotonic() + LAST_WINDOW_DEADLINE_S
        while not printer.all_shown() and time.monotonic() < deadline:
            time.sleep(0.1)
            printer.update()
        printer.update()
        printer._end_progress()
        if not printer.all_shown():
            print(f'  the last window was still being computed after {LAST_WINDOW_DEADLINE_S:g} s: not shown',
                  file=sys.stderr, flush=True)
        published = getattr(source, 'sequence', None) if use_sim else getattr(source, 'stats', {}).get(
            'samples_published')
        if published:
            _say_samples_received(identification, int(published))
        return False
    except KeyboardInterrupt:
        printer._end_progress()
        print('aeropend run: interrupted; finalising', file=sys.stderr)
        return True


#: How often [s] a running graph looks for another graph's publishers on its rig's topics.
FOREIGN_CHECK_PERIOD_S = 1.0
#: Longest wait [s] for the recorder to take the samples still in flight at the end (a condition: it has every
#: sample the source published, counted or lost; or its counts stop growing for DRAIN_QUIET_S).
DRAIN_DEADLINE_S = 30.0
#: Time [s] the recorder's counts must stay unchanged before the drain ends when the published count is unknown.
DRAIN_QUIET_S = 1.0


def _drain(recorder, published: int | None = None, timeout: float = DRAIN_DEADLINE_S) -> None:
    """Let the recorder receive what is still in flight: until it has received (or counted as lost) the `published`
    samples, or, when that count is unknown, until its per-topic counts stop growing for DRAIN_QUIET_S."""
    deadline = time.monotonic() + timeout
    samples_topic = getattr(recorder, '_samples_topic', None)
    previous, quiet_since = None, time.monotonic()
    while time.monotonic() < deadline:
        counts = dict(getattr(recorder, '_received', {}))
        if published is not None and samples_topic is not None:
            lost = recorder.lost_counts().get(samples_topic, 0) if hasattr(recorder, 'lost_counts') else 0
            if counts.get(samples_topic, 0) + lost >= published:
                return
        elif counts != previous:
            previous, quiet_since = counts, time.monotonic()
        elif time.monotonic() - quiet_since >= DRAIN_QUIET_S:
            return
        time.sleep(0.05)


class _MemoryRecorder:
    """Keeps every sample in memory (used with --no-record, so the diagnosis still has data)."""

    def __init__(self, namespace: str = '/') -> None:
        import rclpy
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState

        from aeropend_ros import topics
        self.samples = []
        self.node = rclpy.create_node('memory_recorder', namespace=namespace)
        self.node.create_subscription(JointState, topics.SAMPLES,
                                      lambda msg: self.samples.append(topics.msg_to_sample(msg)),
                                      QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT))

    def recording(self):
        import numpy as np

        from aeropend_core.io.recording import from_columns
        samples = sorted(self.samples, key=lambda s: s.sequence)
        stamps = np.array([s.stamp_ns for s in samples], dtype=np.int64)
        columns = {'t': (stamps - stamps[0]) * 1e-9,
                   'duty': np.array([s.duty for s in samples]),
                   'armature_voltage': np.array([s.armature_voltage for s in samples]),
                   'armature_current': np.array([s.armature_current for s in samples]),
                   'angle': np.array([s.angle for s in samples])}
        return from_columns(columns, source='samples in memory')


def _diagnose(bag_folder, memory, args, interrupted: bool) -> int:
    from aeropend_core.errors import InsufficientDataError
    from aeropend_core.diagnosis.diagnose import diagnose
    if bag_folder is not None:
        from aeropend_core.io.recording import load_recording
        recording = load_recording(bag_folder)
    else:
        if not memory.samples:
            raise AeropendError('no samples were received; nothing to diagnose (is the source running?)')
        recording = memory.recording()
    print(f'\nDiagnosis of {len(recording)} samples ({recording.time[-1] - recording.time[0]:.1f} s) '
          f'from {recording.source or "the run"}:', flush=True)
    try:
        from aeropend_core.cli._checks import calibration_fixed, fixed_effects
        fixed, fixed_from, calibration_message = calibration_fixed(args.calibration,
                                                                   fixed_effects(args.fix, args.model_effect))

        def progress(message: str) -> None:          # standard error, as `aeropend diagnose`
            if not args.quiet:
                print(f'  ... {message}', file=sys.stderr, flush=True)

        if calibration_message:
            progress(calibration_message)
        diagnosis = diagnose(recording, effects=tuple(args.model_effect), fixed=fixed, fixed_from=fixed_from,
                             progress=progress)
    except InsufficientDataError as error:
        print(f'aeropend run: cannot diagnose: {error}', file=sys.stderr)
        return 130 if interrupted else 1
    from aeropend_core.present.summary import format_summary
    print(format_summary(diagnosis))
    if bag_folder is not None:                   # kept with the record: what was printed, and its report
        from aeropend_core.cli._checks import save_beside_bag
        print('saved beside the bag: ' + ', '.join(save_beside_bag(diagnosis, bag_folder)))
    if args.report:
        from aeropend_core.present.report import write_report
        print(f'report: {write_report(diagnosis, args.report, source=str(bag_folder or "samples in memory"))}')
    if args.json:
        write_run_json(args.json, {'schema': 'aeropend.run/1',
                                   'recording': str(bag_folder) if bag_folder is not None else None,
                                   'samples': len(recording), 'interrupted': interrupted,
                                   'diagnosis': diagnosis.numbers_dict(),
                                   **({'closed_loop_steps': args.closed_loop_steps}
                                      if getattr(args, 'closed_loop_steps', None) is not None else {})})
    print(_next_step(diagnosis, bag_folder, args))
    return 130 if interrupted else 0


def _next_step(diagnosis, bag_folder, args) -> str:
    """What to do next, as a command the user can paste."""
    data = str(bag_folder) if bag_folder is not None else '<your recording>'
    if getattr(args, 'calibration', None):
        data += f' --calibration {args.calibration}'
    data += ''.join(f' --fix {value}' for value in getattr(args, 'fix', []))
    named = list(getattr(diagnosis, 'missing_effects', None) or
                 ([diagnosis.missing_effect] if getattr(diagnosis, 'missing_effect', None) else []))
    if named:
        adds = ' '.join(f'--add {name}' for name in [*args.model_effect, *named])
        return (f'Next: add it and watch the error fall: aeropend diagnose {data} {adds} --report report.html '
                f'(or run again with {" ".join(f"--add {n}" for n in named)})')
    return f'Next: the full report of this recording: aeropend diagnose {data} --report report.html'


if __name__ == '__main__':  # pragma: no cover - use `aeropend run`
    sys.exit(os.EX_USAGE)
