"""The check of a closed-loop record: for every step, measured vs predicted metrics and each template item.

The prediction is the closed-loop simulation of the model the controller was designed on (the controller file's
model), with the same law, gains, schedule and duty cap, at the noise measured in the record. A measured step that
misses an item the prediction met is the model's miss (``aeropend diagnose`` says which effect); one the prediction
missed too was never designed to pass.

Settling is a noisy number: where the tail of a transient grazes the band, the angle noise fed back through the
loop moves the last exit from the band by up to a second between two runs of the same rig (s22: a point prediction
within +-20 % of the measured in 62 of 93 steps; on the model itself, one noise draw against another, 84 %). So the
prediction also gives the **range** of the settling time over ``SETTLING_DRAWS`` more noise draws of the model (the
same judgement of each: band, smoothing, final window): when the model is right, a run falls inside the range of
n draws with probability (n - 1)/(n + 1), 19 in 21 for n = 20. The range's **median** is the point to compare a run
with: on the true model, one draw predicts another within +-20 % in 37 of 45 steps, the median of 20 draws in 39 of
45 (s26, fresh seeds; a settling spread over two modes, the tail grazing the band or not, has no point estimate).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from aeropend_core.control.controller_file import Controller
from aeropend_core.control.law import PidGains
from aeropend_core.control.loop import FeedforwardMap, feedforward_per_sample, noise_draws
from aeropend_core.control.metrics import StepMetrics, Template, noise_sigma, schedule_metrics
from aeropend_core.control.reference import ReferenceSchedule
from aeropend_core.errors import AeropendError
from aeropend_core.model.parameters import SAMPLE_TIME
from aeropend_core.sim.noise import FULL_SCALE, MeasurementNoise

#: noise draws of the model besides the prediction's own, read for the predicted settling's range
SETTLING_DRAWS = 19

ITEM_NAMES = {'settling': 'settling time', 'overshoot': 'overshoot', 'error': 'steady-state error',
              'duty': 'peak duty'}


@dataclass
class StepCheck:
    """One step: measured and predicted metrics, and the template's items missed by each."""

    index: int
    measured: StepMetrics
    predicted: StepMetrics | None
    measured_misses: dict[str, float]
    predicted_misses: dict[str, float]
    #: the predicted settling [s] over the model's noise draws: (shortest, longest, draws, draws not settled)
    settling_range: tuple[float, float, int, int] | None = None
    #: the median of those draws' settling [s] (a draw not settled counts as its hold): the point prediction
    settling_median: float | None = None

    @property
    def settling_in_range(self) -> bool | None:
        """Whether the measured settling time lies in the predicted range (None: no range)."""
        if self.settling_range is None:
            return None
        low, high = self.settling_range[:2]
        return low - 1e-9 <= self.measured.settling_time <= high + 1e-9

    def to_dict(self) -> dict:
        ranged = None
        if self.settling_range is not None:
            low, high, draws, unsettled = self.settling_range
            ranged = {'shortest_s': low, 'longest_s': high, 'median_s': self.settling_median, 'draws': draws,
                      'not_settled': unsettled, 'measured_inside': self.settling_in_range}
        return {'step': self.index, 'from_rad': self.measured.initial, 'to_rad': self.measured.target,
                'measured': _finite(self.measured.as_dict()),
                'predicted': _finite(self.predicted.as_dict()) if self.predicted else None,
                'predicted_settling_range': ranged,
                'measured_misses': _finite(self.measured_misses), 'predicted_misses': _finite(self.predicted_misses)}


@dataclass
class CheckResult:
    """The check of a closed-loop record (:func:`check_record`): each step measured and predicted against the
    template; it presents itself (``summary()``, ``as_text()``, ``as_html()``, ``to_dict()``), tested in
    tests/test_control.py."""

    template: Template
    steps: list[StepCheck]
    predicted_time: np.ndarray
    predicted_angle: np.ndarray
    predicted_duty: np.ndarray
    notes: list[str] = field(default_factory=list)
    gains: PidGains | None = None      #: the controller's, as checked (and predicted with)

    @property
    def met(self) -> bool:
        return all(not step.measured_misses for step in self.steps)

    @property
    def verdict(self) -> str:
        if not self.steps:
            return 'no complete step'
        if self.met:
            return 'meets the template'
        if any(set(step.measured_misses) - set(step.predicted_misses) for step in self.steps):
            return 'misses the template where the model predicted it would meet it'
        return 'misses the template, as the model predicted'

    def summary(self) -> dict:
        """The check on one screen: ``verdict`` and ``met`` [-], ``steps`` [-], per step the template's items the
        record ``missed`` and those the model predicted missed (``predicted_missed``), and the ``notes`` (a run cut
        short, ...)."""
        return {'verdict': self.verdict, 'met': self.met, 'steps': len(self.steps),
                'missed': {step.index: sorted(step.measured_misses) for step in self.steps if step.measured_misses},
                'predicted_missed': {step.index: sorted(step.predicted_misses) for step in self.steps
                                     if step.predicted_misses}, 'notes': list(self.notes)}

    def as_html(self) -> str:
        """:meth:`as_text` as a self-contained HTML fragment (``<section>``, escaped); the page with the plots is
        :func:`aeropend_core.control.report.check_report`."""
        from aeropend_core.present.results_text import text_html
        return text_html(self.as_text(), 'aeropend control check', 'aeropend-control-check')

    def to_dict(self) -> dict:
        """The ``aeropend control check --json`` object less the record's name and the controller's SHA-256 (the
        verb adds those); angles [rad], times [s], overshoot and error [% of the step]."""
        return {'schema': 'aeropend.control_check/1', 'template': self.template.as_dict(), 'verdict': self.verdict,
                'gains': self.gains.as_dict() if self.gains is not None else None,
                'met': self.met, 'steps': [step.to_dict() for step in self.steps], 'notes': list(self.notes),
                'units': {'angles': 'rad', 'times': 's', 'overshoot_and_error': '% of the step', 'duty': '1'}}

    def as_text(self) -> str:
        """What ``aeropend control check`` prints: per step the measured and predicted metrics against the template
        (deg, s, %), the verdict, the next step and the notes."""
        lines = [f'Template: {self.template.text()}']
        if self.gains is not None:
            lines.append(f'Controller: {self.gains.text()}')
        for step in self.steps:
            m, p = step.measured, step.predicted
            lines.append(f'step {step.index}: {math.degrees(m.initial):.1f} -> {math.degrees(m.target):.1f} deg '
                         f'(band +-{math.degrees(m.band):.2f} deg)')
            for item in ('overshoot', 'settling', 'error', 'duty'):
                limit = getattr(self.template, item)
                measured = _show(item, m)
                predicted = _show(item, p) if p else 'n/a'
                if limit is None:
                    judged = 'not judged'
                else:
                    judged = 'MISSED' if item in step.measured_misses else 'met'
                    if item in step.measured_misses and item not in step.predicted_misses:
                        judged += ' (predicted met)'
                lines.append(f'  {ITEM_NAMES[item]:<19} measured {measured:>10}  predicted {predicted:>10}  '
                             f'limit {_limit(item, limit):>8}  {judged}')
            lines.append(f'  {"rise time":<19} measured {_rise(m):>10}  predicted {_rise(p) if p else "n/a":>10}')
            if step.settling_range is not None:
                lines.append(f'  {_range_text(step)}')
        lines.append(f'Verdict: {self.verdict}.')
        if not self.met and any(set(s.measured_misses) - set(s.predicted_misses) for s in self.steps):
            lines.append('Next: the model misses what the rig does; `aeropend diagnose` on this record names the '
                         'effect, then `aeropend control design --model DIAGNOSIS.json` designs on it.')
        lines.extend(f'Note: {note}' for note in self.notes)
        return '\n'.join(lines)


def _show(item: str, metrics: StepMetrics) -> str:
    if item == 'settling':
        return f'{metrics.settling_time:.2f} s' if metrics.settled else 'not settled'
    if item == 'overshoot':
        return f'{metrics.overshoot:.1f} %'
    if item == 'error':
        return f'{metrics.steady_state_error:+.1f} %'
    return f'{metrics.peak_duty:.2f}'


def _range_text(step: StepCheck) -> str:
    low, high, draws, unsettled = step.settling_range
    where = 'inside' if step.settling_in_range else 'outside'
    median = f'median {step.settling_median:.2f} s, ' if step.settling_median is not None else ''
    text = f'settling over {draws} noise draws of the model: {median}{low:.2f}-{high:.2f} s (the measured is {where} it'
    if unsettled:
        text += f'; {unsettled} draw(s) not settled within the hold'
    return text + ')'


def _rise(metrics: StepMetrics) -> str:
    return f'{metrics.rise_time:.2f} s' if math.isfinite(metrics.rise_time) else 'none'


def _limit(item: str, limit) -> str:
    if limit is None:
        return '-'
    return {'settling': f'{limit:g} s', 'overshoot': f'{limit:g} %', 'error': f'{limit:g} %',
            'duty': f'{limit:g}'}[item]


def _finite(values: dict) -> dict:
    return {key: (None if isinstance(value, float) and not math.isfinite(value) else value)
            for key, value in values.items()}


def settling_ranges(gains: PidGains, reference: np.ndarray, feedforward: np.ndarray, parameters, effects,
                    noise: MeasurementNoise, schedule: ReferenceSchedule, seeds, first: list[StepMetrics] | None = None,
                    sample_time: float = SAMPLE_TIME, duty_limit: float = 1.0) -> dict:
    """Step start [s] -> (shortest, longest settling [s], draws, draws not settled, median settling [s]) over
    closed-loop runs of the model, one per seed of `seeds` (plus the metrics `first` of one run already made): each
    judged by the same :func:`~aeropend_core.control.metrics.schedule_metrics`. `reference` [rad] and `feedforward`
    [duty] per sample. A draw that does not settle counts as its hold."""
    drawn = [metrics for _run, metrics in noise_draws(gains, reference, feedforward, parameters, effects, noise, seeds,
                                                      schedule, sample_time, duty_limit)]
    return _ranges([first or []] + drawn)


def _ranges(drawn: list[list[StepMetrics]]) -> dict:
    """:func:`settling_ranges`' answer from the per-step metrics of each draw."""
    per_step: dict[float, list[StepMetrics]] = {}
    for metrics in drawn:
        for m in metrics:
            per_step.setdefault(round(m.start, 6), []).append(m)
    return {start: (min(m.settling_time for m in ms), max(m.settling_time for m in ms), len(ms),
                    sum(not m.settled for m in ms), float(np.median([m.settling_time for m in ms])))
            for start, ms in per_step.items()}


def check_record(time: np.ndarray, angle: np.ndarray, duty: np.ndarray, controller: Controller,
                 schedule: ReferenceSchedule, template: Template | None = None, seed: int = 0,
                 sample_time: float = SAMPLE_TIME, duty_limit: float | None = None,
                 draws: int = SETTLING_DRAWS) -> CheckResult:
    """Measured vs predicted metrics of every complete step of a closed-loop record (time [s] from the schedule's
    start, angle [rad], duty [fraction]); the predicted settling's range over `draws` more noise draws of the model
    (seeds seed + 1 .. seed + draws; 0: no range)."""
    template = template or controller.template or Template()
    time = np.asarray(time, dtype=float)
    angle = np.asarray(angle, dtype=float)
    duty = np.asarray(duty, dtype=float)
    measured = schedule_metrics(time, angle, duty, schedule)
    notes = []
    if len(measured) < len([1 for _s, _e, b, a in schedule.step_times() if a != b]):
        notes.append(f'{len(measured)} of {len(schedule.steps)} steps are complete in this record (a cut-short run '
                     'is judged on the steps it played)')
    # The prediction at the noise measured on the record's holds (PSNR against the stream's full-scale angle).
    sigma = float(np.median([noise_sigma(angle[(time >= m.start + 0.8 * m.hold) & (time < m.start + m.hold)])
                             for m in measured])) if measured else 0.0
    psnr = 20 * math.log10(FULL_SCALE['angle'] / sigma) if sigma > 0 else None
    noise = MeasurementNoise(psnr_db=psnr, quantise=True, signals=('angle',))
    n = int(round(schedule.duration / sample_time))
    cap = duty_limit if duty_limit is not None else controller.gains.u_clamp_max
    from aeropend_core.model.effects import get_effect, resolve_effects
    if draws > 0 and not all(get_effect(name).compiled for name in resolve_effects(controller.effects)):
        notes.append('the predicted settling\'s range over noise draws is not given: the model has an effect outside '
                     'the compiled closed loop (each draw would take ~30 us a sample)')
        draws = 0
    # the prediction (seed) and the range's draws (seed + 1 .. seed + draws) side by side on two threads
    reference = schedule.reference(n, sample_time)
    feedforward = FeedforwardMap(controller.parameters, controller.effects)
    if draws > 0:
        feedforward = feedforward_per_sample(feedforward, reference)
    runs = noise_draws(controller.gains, reference, feedforward, controller.parameters, controller.effects, noise,
                       range(seed, seed + 1 + draws), schedule, sample_time, cap)
    predicted, predicted_metrics = runs[0]
    by_start = {round(m.start, 6): m for m in predicted_metrics}
    ranges = _ranges([metrics for _run, metrics in runs]) if draws > 0 else {}
    steps = []
    for index, m in enumerate(measured, start=1):
        p = by_start.get(round(m.start, 6))
        ranged = ranges.get(round(m.start, 6))
        steps.append(StepCheck(index, m, p, m.misses(template), p.misses(template) if p else {},
                               ranged[:4] if ranged else None, ranged[4] if ranged else None))
    if schedule.dither_amplitude > 0:
        notes.append(f'a reference dither of {math.degrees(schedule.dither_amplitude):.2f} deg was played: the '
                     'metrics read the stepped reference')
    if not steps:
        raise AeropendError('no complete step in this record: nothing to check (the run ended before its first '
                            'step was held to the end)')
    return CheckResult(template, steps, predicted.time, predicted.angle, predicted.duty, notes, controller.gains)
