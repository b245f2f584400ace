"""The experiment loop: diagnose -> design -> play -> diagnose every record together, until decided.

One function, :func:`until_decided`, drives the loop for any source of records: ``aeropend run --until-decided``
plays each round through the ROS graph (simulator or rig) and hands back the bag's recording; the benchmark and the
tests play it on the in-process simulator. The loop itself is the same:

1. play the first excitation (the caller's: a Latin hypercube, or a given schedule) and diagnose it;
2. while the verdict is ``confounded``: design the experiment that separates the two confounded models
   (:func:`aeropend_core.diagnosis.experiment_design.design_experiment`, within the duty and angle limits), play
   it, and diagnose *all* records so far together (:func:`aeropend_core.diagnosis.joint.diagnose_joint`);
3. the design says how long its schedule, repeated, must run to decide at the record's noise
   (:attr:`~aeropend_core.diagnosis.experiment_design.ExperimentDesign.seconds_to_decide`): the next round plays it
   as many times as that needs, in one record, when that fits what is left of the budget; when it does not, the
   loop ends at once with the verdict ``cannot_decide_within_budget`` and the stated need (how many seconds, or how
   much less noise), instead of playing rounds that cannot decide;
4. stop when the verdict is no longer ``confounded`` (decided), when the budget (runs, seconds of excitation) is
   spent, when no design is possible within the limits (refused, with the reason), or when a round could not be
   played.

Every round keeps its diagnosis, what it played and the design made after it, so the caller can list them.
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from aeropend_core.errors import AeropendError, InsufficientDataError

if TYPE_CHECKING:       # annotations only (imported where the loop uses them, so importing it stays cheap)
    from aeropend_core.diagnosis.diagnose import Diagnosis
    from aeropend_core.diagnosis.experiment_design import ExperimentDesign
    from aeropend_core.io.recording import Recording

#: Verdict that keeps the loop going.
CONFOUNDED = 'confounded'


class RoundFailed(AeropendError):
    """A round could not be played or recorded (the message says why); the loop stops after the rounds so far."""


@dataclass(frozen=True)
class LoopBudget:
    """Limits of the loop.

    Attributes
    ----------
    max_runs : int [-]
        Runs at most, the first included.
    max_seconds : float [s]
        Excitation over all runs at most (each designed run counts its schedule plus `overhead_seconds`).
    design_seconds : float [s]
        Length of each designed schedule (at least the design's minimum, 20 s); a round plays it as many times in
        a row as the design says deciding needs.
    duty_limit : float, dimensionless
        Highest duty fraction a designed step may ask for.
    angle_limit : float [rad]
        Every competing model's predicted angle stays below it.
    overhead_seconds : float [s]
        Time a played schedule adds to its run (a rest before the first step, a margin for the recorder).
    """

    max_runs: int = 3
    max_seconds: float = 300.0
    design_seconds: float = 30.0
    duty_limit: float = 0.7
    angle_limit: float = math.radians(80.0)
    overhead_seconds: float = 0.0


@dataclass
class Played:
    """What one round played and recorded.

    Attributes
    ----------
    recording : Recording
        The recorded samples (Va [V], Ia [A], angle [rad]).
    source : str
        Where it is kept (bag folder, file or a label).
    played : str
        What was played (the schedule file, or the Latin hypercube and its seed).
    seconds : float [s]
        Excitation time the round used (counted against the budget).
    """

    recording: Recording
    source: str
    played: str
    seconds: float


@dataclass
class LoopRound:
    """One round: what it played, the diagnosis of every record so far, and the design made after it.

    Attributes
    ----------
    number : int [-]
        1 for the first run.
    played : Played
        The round's record.
    diagnosis : Diagnosis
        Of all records up to this one, together.
    design : ExperimentDesign or None
        The experiment designed after this round (None when the loop stopped here).
    next_schedule : str
        Where the design was written for the next round ('' if not written).
    diagnosis_seconds, design_seconds : float [s]
        Wall-clock time of this round's diagnosis and design.
    """

    number: int
    played: Played
    diagnosis: Diagnosis
    design: ExperimentDesign | None = None
    next_schedule: str = ''
    diagnosis_seconds: float = 0.0
    design_seconds: float = 0.0


@dataclass
class LoopOutcome:
    """The rounds in order and why the loop ended.

    Attributes
    ----------
    rounds : list of LoopRound
        Every round, the last one holding the decision.
    ending : str
        Why the loop stopped, in words.
    refused : str
        The design's refusal ('' unless the loop ended because no experiment could be designed).
    excitation_seconds : float [s]
        Excitation played over all rounds.
    needed_seconds : float [s]
        With the verdict ``cannot_decide_within_budget``: how long the last design's schedule must run to decide
        (inf when no duration decides at this noise); NaN otherwise.
    needed_noise_rms : float [rad]
        With that verdict: the angle-noise RMS at which the design would decide within the budget left.
    angle_quantisation_rms : float [rad]
        With that verdict: the RMS error of the records' angle counts alone (step / sqrt(12)); when it exceeds
        `needed_noise_rms`, no noise level of this angle sensor decides (NaN when the angle has no counts).
    verdict : str
        ``decided``, ``cannot_decide_within_budget``, ``budget_spent``, ``refused`` or ``not_completed``.
    """

    rounds: list[LoopRound] = field(default_factory=list)
    ending: str = ''
    refused: str = ''
    excitation_seconds: float = 0.0
    needed_seconds: float = math.nan
    needed_noise_rms: float = math.nan
    angle_quantisation_rms: float = math.nan
    verdict: str = 'not_completed'

    @property
    def decision(self):
        """The last round's diagnosis (None if no round completed)."""
        return self.rounds[-1].diagnosis if self.rounds else None

    @property
    def decided(self) -> bool:
        """True when the last diagnosis is no longer confounded."""
        return self.decision is not None and self.decision.verdict != CONFOUNDED


def diagnose_records(recordings: Sequence, options: Mapping | None = None):
    """Diagnose one record alone, or several together (shared parameters, per-record initial states).

    Parameters
    ----------
    recordings : sequence of Recording [-]
        The records so far, in the order played.
    options : mapping, optional [-]
        Passed to the diagnosis (``effects``, ``fixed``, ``progress``, ``drift``, ...).

    Returns
    -------
    Diagnosis
        Of the records together.
    """
    options = dict(options or {})
    if len(recordings) == 1:
        from aeropend_core.diagnosis.diagnose import diagnose
        return diagnose(recordings[0], **options)
    from aeropend_core.diagnosis.joint import diagnose_joint
    return diagnose_joint(list(recordings), **options)


def until_decided(play: Callable, budget: LoopBudget = LoopBudget(), diagnose_options: Mapping | None = None,
                  seed: int = 0, write_schedule: Callable | None = None, on_round: Callable | None = None,
                  say: Callable | None = None, design_options: Mapping | None = None) -> LoopOutcome:
    """Run the loop (module docstring) until the verdict is decided or the budget is spent.

    Parameters
    ----------
    play : callable [-]
        ``play(design, schedule) -> Played``: plays the first excitation when `design` is None, otherwise the
        designed experiment (`schedule` is the file `write_schedule` returned, or None); raises
        :class:`RoundFailed` when the round could not be played.
    budget : LoopBudget [-]
        Runs, seconds and the design's limits.
    diagnose_options : mapping, optional [-]
        Options of every diagnosis (:func:`diagnose_records`).
    seed : int [-]
        Seed of the designs (round k uses ``seed + k``: reproducible).
    write_schedule : callable, optional [-]
        ``write_schedule(round_number, design) -> str``: where the design of the next round is kept (the file the
        excitation node plays); default: not written.
    on_round : callable, optional [-]
        Called with each :class:`LoopRound` when its diagnosis is done, and again (``design`` set) after the design.
    say : callable, optional [-]
        Progress messages (one line each).
    design_options : mapping, optional [-]
        Extra options of :func:`~aeropend_core.diagnosis.experiment_design.design_experiment` (``candidates``,
        ``refinements``, ``draws``, ``original_duty_limit``).

    Returns
    -------
    LoopOutcome
        Every round and why the loop stopped.
    """
    from aeropend_core.diagnosis.experiment_design import DesignRefused, confounded_models, design_experiment
    from aeropend_core.model.effects import catalog_scope
    say = say or (lambda message: None)
    outcome = LoopOutcome()
    records: list = []
    design = None
    schedule = None
    while True:
        try:
            played = play(design, schedule)
        except RoundFailed as error:
            outcome.ending = f'round {len(records) + 1} did not complete ({error}); the loop stops'
            break
        records.append(played.recording)
        outcome.excitation_seconds += played.seconds
        say(f'round {len(records)}: diagnosing {len(records)} record(s) together')
        started = time.perf_counter()
        try:
            diagnosis = diagnose_records(records, diagnose_options)
        except InsufficientDataError as error:
            outcome.ending = f'cannot diagnose: {error}'
            break
        current = LoopRound(len(records), played, diagnosis, diagnosis_seconds=time.perf_counter() - started)
        outcome.rounds.append(current)
        if on_round:
            on_round(current)
        if diagnosis.verdict != CONFOUNDED:
            outcome.verdict = 'decided'
            outcome.ending = (f'decided after {len(records)} run(s) ({outcome.excitation_seconds:.0f} s of '
                              f'excitation)' + _unconfirmed(outcome.rounds))
            break
        left = budget.max_seconds - outcome.excitation_seconds - budget.overhead_seconds
        if len(records) >= budget.max_runs or left < budget.design_seconds:
            outcome.verdict = 'budget_spent'
            outcome.ending = (f'budget spent ({len(records)} of {budget.max_runs} runs, '
                              f'{outcome.excitation_seconds:.0f} s of {budget.max_seconds:g} s): still confounded')
            break
        say('designing the experiment that separates the confounded effects')
        started = time.perf_counter()
        try:
            with catalog_scope():       # a lookalike term registered for the design is gone with it (issue #44)
                models = confounded_models(diagnosis)
                design = design_experiment(models, diagnosis.noise_rms, duration=budget.design_seconds,
                                           duty_limit=budget.duty_limit, angle_limit=budget.angle_limit,
                                           seed=seed + len(records), **dict(design_options or {}))
        except DesignRefused as error:
            outcome.verdict = 'refused'
            outcome.refused = outcome.ending = f'no experiment designed: {error}'
            break
        current.design = design
        current.design_seconds = time.perf_counter() - started
        needed = design.seconds_to_decide
        repeats = max(1, math.ceil(needed / design.schedule.duration - 1e-9)) if math.isfinite(needed) else 0
        if not repeats or repeats * design.schedule.duration > left:
            outcome.verdict = 'cannot_decide_within_budget'
            outcome.needed_seconds = needed
            outcome.needed_noise_rms = design.noise_to_decide(_whole_schedules(left, design))
            step = float(getattr(getattr(diagnosis, 'prepared', None), 'angle_step', 0.0) or 0.0)
            outcome.angle_quantisation_rms = step / math.sqrt(12.0) if step > 0 else math.nan
            outcome.ending = cannot_decide_text(design, left, budget, step)
            if on_round:
                on_round(current)
            break
        if repeats > 1:
            design = current.design = design.repeated(repeats)
            say(f'the design needs about {needed:.0f} s to decide: playing its {budget.design_seconds:g} s schedule '
                f'{repeats} times ({design.schedule.duration:.0f} s)')
        schedule = write_schedule(len(records) + 1, design) if write_schedule else None
        current.next_schedule = str(schedule or '')
        if on_round:
            on_round(current)
    return outcome


def cannot_decide_text(design, left_seconds: float, budget: LoopBudget, angle_step: float = 0.0) -> str:
    """The loop's early end when the design needs more than the budget left, in words.

    Parameters
    ----------
    design : ExperimentDesign [-]
        The last design (its need, noise and separation).
    left_seconds : float [s]
        Excitation left in the budget for the next round (its overhead taken off).
    budget : LoopBudget [-]
        The loop's budget (the --max-seconds it names).
    angle_step : float [rad]
        The angle sensor's count (0: no counts); when its quantisation alone exceeds the noise that would decide,
        the text says that no noise level of this sensor decides and how much finer a sensor must be.

    Returns
    -------
    str
        'cannot decide within the budget: ...' with the need and what to change.
    """
    from aeropend_core.diagnosis.experiment_design import MATERIAL, _decibels
    needed = design.seconds_to_decide
    noise = design.noise_rms
    quieter = design.noise_to_decide(_whole_schedules(left_seconds, design))
    lower = (f'lower the angle noise to about {quieter * 1e3:.2f} mrad RMS ({_decibels(noise, quieter):.1f} dB less)'
             if quieter > 0 else 'lower the angle noise')
    counts = angle_step / math.sqrt(12.0) if angle_step > 0 else 0.0
    if quieter > 0 and counts > quieter:
        # the counts' own error (step / sqrt(12)) already exceeds it: this sensor cannot get there at any noise
        finer = angle_step / (quieter * math.sqrt(12.0))
        bits = math.ceil(math.log2(finer))
        lower = (f'no noise level of this angle sensor gets there (its counts alone, {angle_step * 1e3:.2f} mrad '
                 f'each, leave {counts * 1e3:.2f} mrad RMS, more than the {quieter * 1e3:.2f} mrad RMS that would '
                 f'decide): it takes an angle sensor at least {finer:.1f} times finer ({bits} more bit'
                 f'{"s" if bits > 1 else ""}), with noise to match,')
    reason = design.physical_reason()
    reason = f' ({reason})' if reason else ''
    where = (f'{", ".join(m.label for m in design.models)}: the best schedule found separates them by '
             f'{design.separation:.2g} x the noise RMS')
    if not math.isfinite(needed):
        return (f'cannot decide within the budget: at this noise ({noise * 1e3:.2f} mrad RMS, {_psnr(noise):.0f} dB '
                f'of the pi/2 full scale) no duration decides ({where}, below the {MATERIAL:g} x the diagnosis needs '
                f'to count a difference){reason}; {lower} to decide within the {left_seconds:.0f} s left, or fix one '
                'of the two at its hardware value (--fix)')
    total = budget.max_seconds - left_seconds + math.ceil(needed / design.schedule.duration - 1e-9) * \
        design.schedule.duration
    return (f'cannot decide within the budget: the design needs about {needed:.0f} s of this schedule at this noise '
            f'({noise * 1e3:.2f} mrad RMS, {_psnr(noise):.0f} dB of the pi/2 full scale; {where}), '
            f'{left_seconds:.0f} s are left; raise --max-seconds to {math.ceil(total / 10) * 10:.0f} s, or {lower}'
            f'{reason}')


def _whole_schedules(seconds: float, design) -> float:
    """The part of `seconds` [s] that whole repetitions of the design's schedule fill [s]."""
    return math.floor(seconds / design.schedule.duration + 1e-9) * design.schedule.duration


def _psnr(noise_rms: float) -> float:
    """The angle noise as a PSNR [dB] of the pi/2 full scale (the simulator's and the stream's convention)."""
    return 20.0 * math.log10((math.pi / 2) / noise_rms) if noise_rms > 0 else math.inf


def _unconfirmed(rounds: list[LoopRound]) -> str:
    """A warning when the records together find nothing that an earlier round found (confounded) missing."""
    if len(rounds) < 2 or rounds[-1].diagnosis.verdict != 'nothing_missing':
        return ''
    earlier = next(((r, f) for r in rounds[:-1] for f in r.diagnosis.found if f.confounded_with), None)
    if earlier is None:
        return ''
    number, names = earlier[0].number, ', '.join([earlier[1].effect, *earlier[1].confounded_with])
    return (f'; but round {number} found one of {names} missing and the records together find nothing significant: '
            'the earlier evidence is not confirmed (a weak effect, or chance in that record); a longer experiment '
            'would tell')


__all__ = ['cannot_decide_text', 'LoopBudget',
           'LoopOutcome', 'LoopRound', 'Played', 'RoundFailed', 'diagnose_records', 'until_decided']
