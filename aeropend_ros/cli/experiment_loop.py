"""``aeropend run --experiment FILE`` and ``aeropend run --until-decided``: play a designed schedule, close the loop.

``--experiment FILE`` plays a schedule file (``steps: [[duty, dwell_s], ...]``, as written by the design,
:mod:`aeropend_core.diagnosis.experiment_design`) through the excitation node instead of the Latin hypercube; the
bag's ``metadata.yaml`` names the file and its SHA-256 (``custom_data``: ``aeropend.experiment``,
``aeropend.experiment_sha256``). ``--until-decided`` loops (:mod:`aeropend_core.diagnosis.experiment_loop`): run
(the Latin hypercube first, or ``--experiment FILE``) -> diagnose every record so far together -> if two effects
are confounded, design the experiment that separates them -> run it -> diagnose again, until the verdict is no
longer "confounded" or the budget (``--max-runs``, ``--max-seconds``) is spent. Each designed schedule is played
as many times in a row as the design says deciding needs at the record's noise; when that does not fit the budget
left, the loop ends at once with the verdict ``cannot_decide_within_budget`` and the need (seconds, or how much less
noise). Every round's verdict, schedule and
bag are listed at the end; ``--json`` holds every round's diagnosis in order, the last one being the decision. A
design that cannot be made within the limits ends the loop with its reason as the one-line error (exit 2), after
the rounds so far are listed.
"""
from __future__ import annotations

import argparse
import hashlib
import math
import sys
import time
from pathlib import Path

from aeropend_core.errors import AeropendError

#: Rest before the first step [s] and margin after the last [s] of a played schedule (the run's start delay, and
#: time for the recorder to see the last samples).
START_DELAY = 1.0
END_MARGIN = 2.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The experiment options of ``aeropend run``."""
    parser.add_argument('--experiment', metavar='FILE.yaml', default=None,
                        help='play this schedule file (steps: [[duty, dwell_s], ...], e.g. written by --until-decided) '
                             'instead of the Latin hypercube; the run lasts the schedule (+3 s) and the bag\'s '
                             'metadata names the file; with --until-decided it is the first round (default: none)')
    parser.add_argument('--until-decided', action='store_true',
                        help='loop: run, diagnose all records so far together, and while two effects are confounded '
                             'design the experiment that separates them and run it (needs recording)')
    parser.add_argument('--max-runs', type=int, default=3, metavar='N',
                        help='with --until-decided: at most N runs, the first included (default 3)')
    parser.add_argument('--max-seconds', type=float, default=300.0, metavar='S',
                        help='with --until-decided: at most S seconds of excitation over all runs; when the design '
                             'says deciding needs more than is left, the loop ends at once with the verdict '
                             '"cannot decide within the budget" and the seconds (or the lower noise) it would '
                             'need (default 300)')
    parser.add_argument('--design-seconds', type=float, default=30.0, metavar='S',
                        help='with --until-decided: length of each designed schedule [s]; a round plays it as many '
                             'times in a row as the design says deciding needs (default 30, at least 20)')
    parser.add_argument('--design-candidates', type=int, default=60, metavar='N',
                        help='with --until-decided: random schedules each design tries before refining the best '
                             '(half as many refinements); fewer is faster and may separate less (default 60)')
    parser.add_argument('--max-angle', type=float, default=80.0, metavar='DEG',
                        help='with --until-decided: every competing model\'s predicted angle stays below this '
                             '[deg] (default 80)')


def check_arguments(args) -> None:
    """Refuse inconsistent experiment options before any node starts (AeropendError: one line, exit 2)."""
    if args.experiment:
        from aeropend_core.diagnosis.experiment_design import read_schedule
        steps, _ = read_schedule(args.experiment, duty_limit=args.duty_cap)
        args.duration = float(steps[:, 1].sum()) + START_DELAY + END_MARGIN
    if not args.until_decided:
        return
    if args.no_record:
        raise AeropendError('--until-decided keeps every round\'s bag and diagnoses them together; drop --no-record')
    if args.no_diagnose:
        raise AeropendError('--until-decided decides by the diagnosis; drop --no-diagnose')
    if not 1 <= args.max_runs <= 20:
        raise AeropendError(f'--max-runs must be a whole number in [1, 20], got {args.max_runs}')
    if not 0 < args.max_seconds < math.inf:
        raise AeropendError(f'--max-seconds must be a positive number of seconds, got {args.max_seconds}')
    from aeropend_core.diagnosis.experiment_design import MIN_DURATION
    if not MIN_DURATION <= args.design_seconds <= 600:
        raise AeropendError(f'--design-seconds must be in [{MIN_DURATION:g}, 600] s (a record shorter than '
                            f'{MIN_DURATION:g} s cannot be diagnosed), got {args.design_seconds}')
    if not 5 <= args.design_candidates <= 1000:
        raise AeropendError(f'--design-candidates must be a whole number in [5, 1000], got {args.design_candidates}')
    if not 5 <= args.max_angle <= 90:
        raise AeropendError(f'--max-angle must be in [5, 90] deg, got {args.max_angle}')
    if args.duration > args.max_seconds:
        raise AeropendError(f'--duration {args.duration:g} s already exceeds --max-seconds {args.max_seconds:g} s; '
                            'raise --max-seconds or shorten the first run')


def experiment_metadata(args) -> dict[str, str]:
    """What the run plays, for the bag's metadata.yaml ``custom_data`` (string -> string)."""
    if not getattr(args, 'experiment', None):
        return {'aeropend.experiment': f'latin hypercube, seed {args.seed}, duty up to {min(0.7, args.duty_cap):g}'}
    path = Path(args.experiment)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    return {'aeropend.experiment': str(path.resolve()), 'aeropend.experiment_sha256': digest}


#: Longest a schedule may start late [s of the source's time] before a run ends without it (no duty subscriber).
LATE_START_LIMIT = 60.0


class ScheduleClock:
    """Ends a run once the excitation's whole schedule and the rest after it are recorded, however late it starts.

    The excitation node starts its schedule when it has found the duty subscriber (discovery: seconds on a loaded
    host), while the simulator counted a fixed length from its own start, so a run lost the schedule's end. Now the
    run ends when the node reports its schedule done, plus END_MARGIN: on the simulator END_MARGIN seconds of
    *simulated* time after the samples published by then (the simulator is told where to stop; the excitation
    plays on the simulator's sample clock, :meth:`ExcitationNode.follow`), on the rig END_MARGIN wall seconds.
    Either way the run gives up LATE_START_LIMIT seconds after its planned length if the schedule never ends. Where
    the schedule starts goes into the bag's metadata (:meth:`metadata`).

    Parameters
    ----------
    excitation : ExcitationNode [-]
        The graph's excitation node (``started``, ``done``, ``total_time`` [s], ``_start_ns`` [ns]).
    source : SimNode or SerialBridgeNode [-]
        The samples' source (the simulator: ``start_ns`` [ns], ``stop_after`` [s], ``finished``).
    use_sim : bool [-]
        Whether the source is the simulator.
    duration : float [s]
        The run's planned length (schedule + START_DELAY + END_MARGIN).
    whole : bool [-]
        True for a schedule file (``--experiment``): the run lasts until it is played whole. False for the Latin
        hypercube, which is cut at `duration` as before (the simulator stops there; the rig after `duration` s).
    """

    def __init__(self, excitation, source, use_sim: bool, duration: float, whole: bool = True) -> None:
        self.excitation, self.source, self.use_sim, self.duration = excitation, source, use_sim, duration
        self.whole = whole
        self.started = time.monotonic()
        self._done_at = None
        self._stop_set = False

    def offset(self) -> float:
        """Simulated seconds [s] from the simulator's first sample to the excitation's start (its start delay
        follows); NaN before the start or on the rig."""
        if not self.use_sim or not self.excitation.started:
            return math.nan
        return self.excitation._start_ns * 1e-9        # the excitation follows the simulator's sample clock

    def over(self) -> bool:
        """True when the run can end: the schedule and END_MARGIN after it recorded, or it never started."""
        if self.use_sim:
            # once the simulator holds the final duty 0: the whole rest after the schedule is recorded
            if self.whole and self.excitation.done and not self._stop_set and self.source.commanded_duty == 0.0:
                self._stop_set = True
                self.source.stop_after = self.source.sequence * self.source.sample_time + END_MARGIN
            if self.source.finished:
                return True
        elif not self.whole:
            return time.monotonic() - self.started > self.duration
        elif self.excitation.done:
            self._done_at = self._done_at if self._done_at is not None else time.monotonic()
            return time.monotonic() - self._done_at >= END_MARGIN
        # never started or never done (no duty subscriber, no samples): give up, at least real time assumed
        return self.whole and not self.excitation.done and \
            time.monotonic() - self.started > self.duration + LATE_START_LIMIT

    def metadata(self) -> dict[str, str]:
        """For the bag's metadata.yaml ``custom_data``: where the schedule starts and whether it was played whole."""
        excitation = self.excitation
        whole = bool(excitation.done) and (not self.whole or self._stop_set or self._done_at is not None)
        data = {'aeropend.schedule_seconds': f'{excitation.total_time:.6f}',
                'aeropend.schedule_complete': 'true' if whole else 'false'}
        if excitation.started:
            # the excitation's start in the clock of the samples' header stamps (ns since the epoch); its first
            # step follows after its start delay
            start = self.source.start_ns + round(self.offset() * 1e9) if self.use_sim else excitation._start_ns
            data['aeropend.schedule_start_stamp_ns'] = str(int(start))
            if self.use_sim:    # from the simulator's sample 0 (counter position[4]; a bag may start later)
                data['aeropend.schedule_offset_s'] = f'{self.offset():.6f}'
                data['aeropend.schedule_start_sample'] = str(round(self.offset() / self.source.sample_time))
        return data


def excitation_overrides(args) -> dict:
    """Excitation-node parameters that play ``--experiment`` (its steps file; empty without the option)."""
    if not getattr(args, 'experiment', None):
        return {}
    return {'schedule': 'steps', 'steps_file': str(args.experiment)}


def _diagnose_options(args, say) -> dict:
    from aeropend_core.cli._checks import calibration_fixed, fixed_effects
    fixed, fixed_from, _ = calibration_fixed(args.calibration, fixed_effects(args.fix, args.model_effect))
    return dict(effects=tuple(args.model_effect), fixed=fixed, fixed_from=fixed_from, progress=say, drift=False)


def run_until_decided(args, run_once) -> int:
    """The loop of ``--until-decided`` (module docstring) through the core's
    :func:`aeropend_core.diagnosis.experiment_loop.until_decided`; `run_once(args)` runs the graph once and returns
    ``(exit code, bag folder)``. With ``--experiment FILE`` the first round plays FILE instead of the hypercube."""
    from aeropend_core.diagnosis.experiment_loop import LoopBudget, Played, RoundFailed, until_decided
    from aeropend_core.io.recording import load_recording
    from aeropend_core.present.verdict_text import diagnosis_dict, verdict_of

    def say(message: str) -> None:
        if not args.quiet:
            print(f'  ... {message}', file=sys.stderr, flush=True)

    first, seed = args.experiment, args.seed
    bags: list[Path] = []

    def play(design, schedule) -> Played:
        args.experiment = str(schedule) if schedule else first
        # each round's simulated noise its own: with one seed every record carried the same noise sequence
        args.seed = seed + len(bags)
        if design is not None:
            args.duration = design.schedule.duration + START_DELAY + END_MARGIN
        code, bag = run_once(args)
        if code != 0 or bag is None:
            raise RoundFailed(f'exit {code}')
        bags.append(Path(bag))
        print(f'\nRound {len(bags)}: diagnosing {" + ".join(str(b) for b in bags)}', file=sys.stderr, flush=True)
        played = args.experiment or experiment_metadata(args)['aeropend.experiment']
        return Played(load_recording(bag), str(bag), played, float(args.duration))

    def write(number: int, design) -> str:
        return str(design.write(Path(args.record) / f'experiment_round{number}_{time.strftime("%Y%m%d_%H%M%S")}.yaml'))

    def report(entry) -> None:
        if entry.design is None:
            print(f'round {entry.number}: {entry.diagnosis.verdict}: {verdict_of(entry.diagnosis)}', flush=True)
        elif entry.next_schedule:
            print(f'designed {entry.next_schedule}: {entry.design.describe()}', flush=True)
        else:
            print(f'designed (not played): {entry.design.describe()}', flush=True)

    budget = LoopBudget(max_runs=args.max_runs, max_seconds=args.max_seconds, design_seconds=args.design_seconds,
                        duty_limit=min(0.7, args.duty_cap), angle_limit=math.radians(args.max_angle),
                        overhead_seconds=START_DELAY + END_MARGIN)
    search = {'candidates': args.design_candidates, 'refinements': max(1, args.design_candidates // 2)}
    outcome = until_decided(play, budget, _diagnose_options(args, say), seed=seed, write_schedule=write,
                            on_round=report, say=say, design_options=search)
    args.seed = seed
    rounds = [{'round': r.number, 'bag': r.played.source, 'schedule': r.played.played,
               'verdict': r.diagnosis.verdict, 'message': verdict_of(r.diagnosis),
               'diagnosis': diagnosis_dict(r.diagnosis),
               **({'design': r.design.to_dict(), 'next_schedule': r.next_schedule} if r.design is not None else {})}
              for r in outcome.rounds]
    ending = outcome.ending
    print(f'\n--until-decided: {outcome.verdict}: {ending}', flush=True)
    for entry in rounds:
        print(f'  round {entry["round"]}: {entry["verdict"]:<16} schedule {entry["schedule"]}  bag {entry["bag"]}',
              flush=True)
    diagnosis = outcome.decision
    if args.report and diagnosis is not None:
        from aeropend_core.present.report import write_report
        print(f'report: {write_report(diagnosis, args.report, source=" + ".join(map(str, bags)))}')
    if args.json:
        from aeropend_ros.cli.run_json import write_run_json
        write_run_json(args.json, {'rounds': rounds, 'ending': ending, 'bags': [str(b) for b in bags],
                                'loop_verdict': outcome.verdict, 'excitation_seconds': outcome.excitation_seconds,
                                'needed_seconds': outcome.needed_seconds,
                                'needed_noise_rms_rad': outcome.needed_noise_rms,
                                'angle_quantisation_rms_rad': outcome.angle_quantisation_rms,
                                'decision': rounds[-1]['diagnosis'] if rounds else None})
    if outcome.refused:     # the rounds so far are listed (and in --json); the refusal is the one-line error, exit 2
        raise AeropendError(outcome.refused)
    if not rounds:
        print(f'aeropend run: {ending}', file=sys.stderr)
        return 1
    return 0


__all__ = ['ScheduleClock', 'add_arguments', 'check_arguments', 'experiment_metadata', 'excitation_overrides',
           'run_until_decided']
