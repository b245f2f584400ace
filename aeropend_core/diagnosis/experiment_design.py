"""Design the experiment that separates two competing models (model discrimination), within the rig's limits.

When a diagnosis reports two effects as confounded (interchangeable on the data it had), each explanation is a
fitted model: nominal + its effects, parameters ± 1σ from the output-error fit
(:mod:`aeropend_core.diagnosis.output_error`). This module searches duty schedules -- duty steps, rests at duty 0
(free decays), sine sweeps and square waves, starting from full-range square waves and steps with rests -- for
the one whose predicted angle differs most between the two models, relative to the angle's measurement noise, and
writes it as a step file the excitation node plays (``aeropend run --experiment FILE``).

The score is conservative in two ways (Box--Hill / Buzzi-Ferraris model discrimination, linearised):

* **refitting**: when the new record is diagnosed, each model refits its parameters and its segments' initial
  states. So the difference between the two predictions counts only as far as neither model can absorb it: the
  difference is projected out of the span of the other model's sensitivities (its free parameters, and the angle
  and rate at the start of every ~10 s segment) and the smaller of the two one-sided remainders is kept;
* **parameter uncertainty**: the two models are also run with a few parameter draws from their fitted covariance
  (paired draws), and the smallest separation over the draws is the score.

The search maximises the smaller of the separations over the first 75 % of the schedule and over its last 25 %:
the diagnosis fits on the first 75 % of every record and judges the models on the held-out rest (Diebold--Mariano
on the held-out errors), so a schedule whose separating parts (rests at duty 0, large steps) all fall in the
training part decides nothing (bench/results/2026-11-27-s9-loop3).

The separation is reported as the RMS of that remainder over the schedule, in units of the noise RMS ("after 30 s
of this schedule the two models differ by 2.1 x the noise RMS"), next to the same number for the original
excitation (a Latin hypercube of the same length). Both models are driven by the armature voltage, current and
back-EMF that the nominal motor model (:class:`aeropend_core.model.parameters.RigParameters`) predicts for the
duty: on the simulator that is exact, on a rig whose motor differs from the nominal one the prediction scales with
the difference (stated in the result's doubts).

Safety: every duty of a design is at most ``duty_limit``, and every model (fitted and drawn parameters) keeps its
predicted angle below ``angle_limit`` [rad]; a design that cannot be made within the limits and the duration budget
is refused with the reason (:class:`DesignRefused`).
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from statistics import NormalDist

import numpy as np

from aeropend_core.diagnosis.design_blocks import (_mutate, _random_blocks,
                                                   _structured_blocks)
from aeropend_core.errors import AeropendError
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, SAMPLE_TIME, RigParameters
from aeropend_core.sim.schedule_file import (Block, DutySchedule, read_schedule, steps_to_duty,
                                             write_schedule)

#: Default duration budget of a designed experiment [s] (the diagnosis needs at least 20 s of a record).
DEFAULT_DURATION = 30.0
#: Shortest duration budget [s]: a record shorter than the diagnosis's minimum could not be judged alone.
MIN_DURATION = 20.0
#: Default duty limit (fraction), the run's safety cap.
DEFAULT_DUTY_LIMIT = 0.7
#: Default limit on every model's predicted angle [rad] (80 deg: below the horizontal with margin).
DEFAULT_ANGLE_LIMIT = math.radians(80.0)
#: Parameter draws per model for the uncertainty (the score is the minimum over the paired draws).
DEFAULT_DRAWS = 4
#: Random schedules tried, then local changes of the best.
DEFAULT_CANDIDATES = 60
DEFAULT_REFINEMENTS = 30
#: The diagnosis's threshold on the held-out Diebold--Mariano statistic (aeropend_core.diagnosis.candidates.DM_MIN,
#: kept equal by a test; not imported, see MATERIAL).
DM_THRESHOLD = 2.33
#: Probability that a schedule played for its ``seconds_to_decide`` decides (white noise): the need is a power
#: calculation, not the time at which the expected statistic just reaches the threshold (that decides about half
#: the time, and the loop then spends a second run).
DECISION_POWER = 0.9
#: Accumulated evidence, sum of (separation / noise)^2 over the samples of the played record's held-out last 25 %
#: (where the diagnosis judges the models), taken as decisive. For white noise the Diebold--Mariano statistic of that
#: part is about N(sqrt(evidence) / 2, 1), so it clears DM_THRESHOLD with probability DECISION_POWER when
#: sqrt(evidence) / 2 = 2.33 + 1.28: evidence 52.2. Correlated noise needs more. How long a schedule, repeated, must
#: run.
DECISIVE_EVIDENCE = (2.0 * (DM_THRESHOLD + NormalDist().inv_cdf(DECISION_POWER))) ** 2
#: The diagnosis counts a difference between two models only when it lowers the held-out mean-square error by at
#: least (MATERIAL x the noise RMS)^2 (aeropend_core.diagnosis.candidates.MATERIAL, kept equal by a test; not
#: imported: the diagnosis modules take seconds to import): a schedule that separates less decides at no length.
MATERIAL = 0.05
#: Share of every record the diagnosis fits on (aeropend_core.diagnosis.compare.TRAIN_FRACTION); the rest judges.
TRAIN_FRACTION = 0.75
#: Relative step of the finite-difference sensitivities.
SENSITIVITY_STEP = 1e-3
#: Longest experiment [s] counted as practical (the longest --design-seconds): a pair that needs more cannot be
#: decided within the limits at this noise.
PRACTICAL_SECONDS = 600.0


class DesignRefused(AeropendError):
    """No schedule within the limits: the message says which limit and what to change."""


@dataclass(frozen=True)
class CompetingModel:
    """One explanation of the data: nominal + `effects` with the fitted parameters and their covariance.

    Attributes
    ----------
    effects : tuple of str
        Catalog effects of the model.
    parameters : dict of str -> float [SI unit of each parameter]
        Every parameter of the model's structure (fitted or held).
    free_names : tuple of str
        The fitted parameters, in the order of `covariance`.
    covariance : ndarray, shape (n_free, n_free) [products of the parameters' SI units]
        Their covariance (from the fit's standard errors and correlation).
    thrust_from_back_emf : bool
        True when the fit's thrust voltage was the motor observer's back-EMF (then the current is not used).
    label : str
        How the model is named in reports.
    """

    effects: tuple[str, ...]
    parameters: dict[str, float]
    free_names: tuple[str, ...]
    covariance: np.ndarray
    thrust_from_back_emf: bool = True
    label: str = ''

    @classmethod
    def from_comparison(cls, comparison, thrust_from_back_emf: bool, label: str = '') -> CompetingModel:
        """The model of a fitted :class:`aeropend_core.diagnosis.compare.Comparison`.

        Parameters
        ----------
        comparison : Comparison [-]
            The fitted model (parameters SI, standard errors, correlation).
        thrust_from_back_emf : bool [-]
            Whether the record it was fitted on used the motor observer's back-EMF as thrust voltage.
        label : str [-]
            Its name in reports (default: the effects joined by ' + ').

        Returns
        -------
        CompetingModel
            The model with a covariance built from the fit's 1σ and correlation (NaN entries as 0).
        """
        fit = comparison.fit
        names = tuple(fit.free_names)
        errors = np.array([fit.standard_errors.get(n, math.nan) for n in names], dtype=float)
        errors = np.where(np.isfinite(errors), errors, 0.0)
        correlation = np.asarray(fit.correlation, dtype=float)
        if correlation.shape != (len(names), len(names)):
            correlation = np.eye(len(names))
        correlation = np.where(np.isfinite(correlation), correlation, 0.0)
        covariance = correlation * np.outer(errors, errors)
        effects = tuple(comparison.effects)
        return cls(effects, dict(fit.parameters), names, covariance, thrust_from_back_emf,
                   label or ' + '.join(('nominal',) + effects))


@dataclass
class ExperimentDesign:
    """The chosen schedule and what it is predicted to show. Angles in rad, times in s.

    Attributes
    ----------
    schedule : DutySchedule
        The designed schedule.
    models : tuple of CompetingModel
        The two models it separates.
    separation : float [-]
        Predicted RMS of the difference neither model can absorb by refitting, over the schedule, in units of the
        noise RMS (the smallest over the parameter draws).
    separation_fitted : float [-]
        The same at the fitted parameters only.
    peak_separation : float [-]
        Largest absolute predicted difference (fitted parameters, before refitting) / noise RMS.
    baseline_separation : float [-]
        The same score for the original excitation (a Latin hypercube of the same length and duty range).
    noise_rms : float [rad]
        The measurement noise the separation is measured in.
    max_angle : float [rad]
        Largest predicted angle of any model and draw.
    duty_limit, angle_limit : float [-], [rad]
        The limits the design respects.
    tried : int [-]
        Schedules evaluated.
    doubts : list of str
        What the prediction assumes.
    """

    schedule: DutySchedule
    models: tuple[CompetingModel, CompetingModel]
    separation: float
    separation_fitted: float
    peak_separation: float
    baseline_separation: float
    noise_rms: float
    max_angle: float
    duty_limit: float
    angle_limit: float
    tried: int
    doubts: list[str] = field(default_factory=list)
    #: Samples compared over the schedule (every integration step) [-].
    samples: int = 0
    #: The separation over the first 75 % of the schedule (where the diagnosis fits) and over the last 25 % (where
    #: it judges the models on held-out data) [-]; the search maximises the smaller of the two.
    separation_train: float = math.nan
    separation_heldout: float = math.nan
    #: Times the designed schedule is played in a row (:meth:`repeated`) [-].
    repeats: int = 1

    @property
    def seconds_to_decide(self) -> float:
        """How long [s] this schedule, repeated, must run to decide DECISION_POWER (90 %) of the time: its held-out
        quarter's evidence reaches DECISIVE_EVIDENCE (inf when the separation is below the diagnosis's materiality
        floor, MATERIAL x the noise: then no duration decides)."""
        if not self.separation >= MATERIAL:
            return math.inf
        return self._seconds_at(self.separation)

    def _seconds_at(self, separation: float) -> float:
        evidence = separation ** 2 * self.samples * (1.0 - TRAIN_FRACTION) / max(self.repeats, 1)
        return self.schedule.duration / max(self.repeats, 1) * DECISIVE_EVIDENCE / evidence if evidence > 0 \
            else math.inf

    def noise_to_decide(self, seconds: float) -> float:
        """The largest angle-noise RMS [rad] at which this schedule, repeated, decides within `seconds` [s]: the
        separation scales with 1 / noise, so it must clear MATERIAL and fill DECISIVE_EVIDENCE in that time."""
        if not self.separation > 0 or not seconds > 0:
            return 0.0
        return self.noise_rms * min(self.separation / MATERIAL,
                                    math.sqrt(seconds / self._seconds_at(self.separation)))

    def repeated(self, times: int) -> ExperimentDesign:
        """The same schedule played `times` times in a row (one longer record; the separation per sample is taken
        as the designed schedule's, each repetition starting with its rest at duty 0)."""
        from dataclasses import replace
        times = max(int(times), 1)
        unit = self.schedule.blocks if self.repeats == 1 else self.schedule.blocks[:len(self.schedule.blocks)
                                                                                  // self.repeats]
        return replace(self, schedule=DutySchedule(tuple(unit) * times), samples=self.samples // self.repeats * times,
                       repeats=times)

    @property
    def gain(self) -> float:
        """Predicted separation relative to the original excitation's (inf when that one shows none)."""
        return self.separation / self.baseline_separation if self.baseline_separation > 0 else math.inf

    def describe(self) -> str:
        """The prediction in words, with its assumptions."""
        a, b = (m.label for m in self.models)
        highest_duty = float(self.schedule.steps[:, 0].max())
        return (f'after {self.schedule.duration:.0f} s of this schedule the two models ({a} vs {b}) differ by '
                f'{self.separation:.2g} x the noise RMS ({self.noise_rms * 1e3:.2f} mrad): the RMS of the difference '
                f'that neither model can absorb by refitting its parameters and initial states, the smallest over '
                f'{DEFAULT_DRAWS} parameter draws ({self.separation_fitted:.2g} x at the fitted values, peak '
                f'difference {self.peak_separation:.2g} x; {self.separation_train:.2g} x over the first 75 % '
                f'that the diagnosis fits on, {self.separation_heldout:.2g} x over the held-out last 25 %). '
                f'The original excitation of the same length: '
                f'{self.baseline_separation:.2g} x ({self.gain:.1f} times less). Largest predicted angle '
                f'{math.degrees(self.max_angle):.0f} deg (limit {math.degrees(self.angle_limit):.0f}), duty at most '
                f'{highest_duty:.3f} (limit {self.duty_limit:.3f}). '
                + self.decidability())

    def physical_reason(self) -> str:
        """Why the two models are hard to separate, one sentence ('' for a pair without a known reason)."""
        from aeropend_core.model.effects import why_alike
        a, b = (set(m.effects) for m in self.models)
        differ = sorted(a ^ b)
        return why_alike(*differ) if len(differ) == 2 else ''

    def decidability(self) -> str:
        """Whether this schedule decides, how long it (repeated) would take, and why not when it cannot."""
        seconds = self.seconds_to_decide
        rule = (f'for the difference in the held-out last 25 % of the record to add up to {DECISIVE_EVIDENCE:.0f} '
                f'(noise RMS)^2, enough to decide {DECISION_POWER:.0%} of the time (white noise; more if not)')
        if seconds <= self.schedule.duration:
            return f'Enough to decide: {seconds:.0f} s are needed {rule}.'
        reason = self.physical_reason()
        reason = f' Why: {reason}.' if reason else ''
        if not math.isfinite(seconds):
            quieter = self.noise_to_decide(PRACTICAL_SECONDS)
            return (f'Cannot be decided at this noise, however long: the most separating schedule found (duty at '
                    f'most {self.duty_limit:.3g}, angles below {math.degrees(self.angle_limit):.0f} deg) separates '
                    f'the two models by {self.separation:.2g} x the noise RMS, below the {MATERIAL:g} x the '
                    f'diagnosis needs to count a difference at all.{reason} About '
                    f'{_decibels(self.noise_rms, quieter):.1f} dB less noise ({quieter * 1e3:.2f} mrad RMS) would '
                    f'decide it in {PRACTICAL_SECONDS:.0f} s; or a hardware value (--fix) decides it.')
        if seconds <= PRACTICAL_SECONDS:
            return (f'Not enough in {self.schedule.duration:.0f} s: this schedule, repeated, needs about {seconds:.0f} '
                    f's {rule}: give a longer budget (--max-seconds).{reason}')
        return (f'Cannot be decided within the limits at this noise: the most separating schedule found (duty at '
                f'most {self.duty_limit:.3g}, angles below {math.degrees(self.angle_limit):.0f} deg) would have to '
                f'run about {seconds:.3g} s {rule}.{reason} Lower noise (the time falls with the noise variance: '
                f'10 dB less noise, 10 times shorter) or a hardware value (--fix) decides it.')

    def to_dict(self) -> dict:
        """Machine-readable form (SI units), as written into the schedule file's ``experiment`` section."""
        return {'models': [{'label': m.label, 'effects': list(m.effects),
                            'parameters': {k: float(v) for k, v in m.parameters.items()}} for m in self.models],
                'duration_s': self.schedule.duration,
                'predicted_separation_noise_rms': float(self.separation),
                'predicted_separation_at_fitted_noise_rms': float(self.separation_fitted),
                'predicted_peak_difference_noise_rms': float(self.peak_separation),
                'predicted_separation_training_part_noise_rms': float(self.separation_train),
                'predicted_separation_heldout_part_noise_rms': float(self.separation_heldout),
                'original_excitation_separation_noise_rms': float(self.baseline_separation),
                'noise_rms_rad': float(self.noise_rms), 'max_predicted_angle_rad': float(self.max_angle),
                'duty_limit': float(self.duty_limit), 'angle_limit_rad': float(self.angle_limit),
                'schedules_tried': int(self.tried), 'seconds_to_decide': float(self.seconds_to_decide),
                'decision_power': DECISION_POWER,
                'blocks': [b.text() for b in self.schedule.blocks],
                'decidable_within_limits': bool(self.seconds_to_decide <= PRACTICAL_SECONDS),
                'material_separation_noise_rms': MATERIAL, 'repeats': int(self.repeats),
                'description': self.describe(), 'doubts': list(self.doubts)}

    def write(self, path: str | Path) -> Path:
        """Write the schedule file (YAML, SI units; see :func:`write_schedule`)."""
        return write_schedule(path, self.schedule.steps, self.to_dict())


def _decibels(noise_rms: float, lower_rms: float) -> float:
    """How many dB `lower_rms` [rad] is below `noise_rms` [rad] (inf when it is 0)."""
    return 20.0 * math.log10(noise_rms / lower_rms) if lower_rms > 0 else math.inf


# ------------------------------------------------------------------------------------------------ predictions
def motor_inputs(duty: np.ndarray, parameters: RigParameters = DEFAULT_PARAMETERS,
                 sample_time: float = SAMPLE_TIME) -> dict[str, np.ndarray]:
    """Armature voltage [V], current [A] and back-EMF [V] the nominal motor model gives for `duty` (shape (n,))."""
    from aeropend_core.sim.simulate import RigSimulator
    trajectory = RigSimulator(parameters, None, sample_time).run(np.asarray(duty, dtype=float))
    return {'armature_voltage': trajectory.armature_voltage, 'armature_current': trajectory.armature_current,
            'back_emf': parameters.back_emf_constant * trajectory.truth['motor_speed']}


class _Predictor:
    """Predicted measured angle of one model on one schedule, with sensitivities (rows batched in one run)."""

    def __init__(self, model: CompetingModel, inputs: Mapping[str, np.ndarray], sample_time: float,
                 segments: list[tuple[int, int]]) -> None:
        from aeropend_core.diagnosis.output_error import SegmentedData, Structure
        self.model = model
        self.structure = Structure(tuple(model.effects))
        voltage = inputs['back_emf'] if model.thrust_from_back_emf else inputs['armature_voltage']
        current = np.zeros_like(voltage) if model.thrust_from_back_emf else inputs['armature_current']
        n = len(voltage)
        self.whole = SegmentedData(voltage, current, np.zeros(n), [(0, n)], sample_time,
                                   gate_signal=inputs['armature_voltage'])
        self.pieces = SegmentedData(voltage, current, np.zeros(n), segments, sample_time,
                                    gate_signal=inputs['armature_voltage'])
        self.index = self.whole.residual_index

    def run(self, values: Sequence[Mapping[str, float]]) -> np.ndarray:
        """Angle [rad] at the residual samples for each parameter dict, shape (len(values), m)."""
        rows = np.array([self.structure.row(dict(v)) for v in values])
        initial = np.zeros((len(rows), 1, 2))
        return self.whole.simulate(self.structure, rows, initial)[:, self.index]

    def sensitivities(self, fitted: np.ndarray) -> np.ndarray:
        """Columns d angle / d (free parameter, segment initial angle and rate), shape (m, n_columns)."""
        from aeropend_core.diagnosis.output_error import _bounds
        model = self.model
        names = [n for n in model.free_names if n in model.parameters]
        lower, upper = _bounds(tuple(names))
        variants = [dict(model.parameters)]
        for name, lo, hi in zip(names, lower, upper):
            value = model.parameters[name]
            step = SENSITIVITY_STEP * max(abs(value), 1e-3)
            step = -step if value + step > hi else step
            variants.append({**model.parameters, name: value + step})
        runs = self.run(variants)
        columns = [(runs[i + 1] - runs[0]) for i in range(len(names))]
        # initial states of the ~10 s segments: each segment's response to its own start angle and rate
        row = self.structure.row(dict(model.parameters))[None, :]
        pieces = self.pieces
        starts = pieces.seg_start
        full = np.full(len(self.whole.angle), np.nan)
        full[self.index] = fitted
        rate = np.gradient(np.nan_to_num(full[self.index]), self.index * pieces.sample_time)
        offset = model.parameters.get(self.structure.offset_parameter or '', 0.0)
        base = np.zeros((len(starts), 2))
        positions = np.searchsorted(self.index, starts)
        base[:, 0] = np.nan_to_num(full[starts]) - offset
        base[:, 1] = rate[np.minimum(positions, len(rate) - 1)]
        reference = pieces.simulate(self.structure, row, base[None])[0]
        for component, delta in ((0, 1e-3), (1, 1e-2)):
            moved = base.copy()
            moved[:, component] += delta
            shifted = pieces.simulate(self.structure, row, moved[None])[0]
            change = np.nan_to_num(shifted - reference)[self.index]
            for a, b in zip(pieces.seg_start, pieces.seg_stop):
                column = np.where((self.index >= a) & (self.index < b), change, 0.0)
                if np.any(column):
                    columns.append(column)
        return np.column_stack(columns) if columns else np.zeros((len(self.index), 0))


def predicted_angle(model: CompetingModel, duty: np.ndarray, parameters: RigParameters = DEFAULT_PARAMETERS,
                    sample_time: float = SAMPLE_TIME) -> tuple[np.ndarray, np.ndarray]:
    """A model's predicted measured angle for a duty sequence, from rest (what the design compares).

    Parameters
    ----------
    model : CompetingModel [-]
        The model (fitted parameters).
    duty : ndarray, shape (n,), dimensionless
        Duty fraction per sample.
    parameters : RigParameters [SI]
        The motor model that turns duty into the model's inputs.
    sample_time : float [s]
        Ts.

    Returns
    -------
    index : ndarray of int
        The samples predicted (every integration step).
    angle : ndarray [rad]
        The predicted measured angle there.
    """
    duty = np.asarray(duty, dtype=float)
    predictor = _Predictor(model, motor_inputs(duty, parameters, sample_time), sample_time, [(0, len(duty))])
    return predictor.index, predictor.run([model.parameters])[0]


def _draws(model: CompetingModel, count: int, rng: np.random.Generator) -> list[dict[str, float]]:
    """The fitted parameters, then `count` draws from their covariance (clipped to each parameter's bounds)."""
    from aeropend_core.diagnosis.output_error import _bounds
    values = [dict(model.parameters)]
    names = list(model.free_names)
    if not names or count <= 0:
        return values + [dict(model.parameters)] * max(count, 0)
    lower, upper = _bounds(tuple(names))
    covariance = 0.5 * (model.covariance + model.covariance.T)
    eigenvalues, vectors = np.linalg.eigh(covariance)
    root = vectors * np.sqrt(np.clip(eigenvalues, 0.0, None))
    centre = np.array([model.parameters[n] for n in names])
    for _ in range(count):
        drawn = np.clip(centre + root @ rng.standard_normal(len(names)), lower, upper)
        values.append({**model.parameters, **dict(zip(names, drawn.tolist()))})
    return values


def _basis(columns: np.ndarray) -> np.ndarray:
    """An orthonormal basis (shape (m, rank)) of the span of `columns` (columns scaled to unit norm first)."""
    if columns.shape[1] == 0:
        return columns
    norms = np.linalg.norm(columns, axis=0)
    scaled = columns[:, norms > 0] / norms[norms > 0]
    q, r = np.linalg.qr(scaled)
    diagonal = np.abs(np.diag(r))
    return q[:, diagonal > 1e-9 * max(float(diagonal.max(initial=0.0)), 1e-300)]


def _remainder(basis: np.ndarray, difference: np.ndarray) -> np.ndarray:
    """`difference` less its least-squares projection on the span of `basis` (orthonormal columns)."""
    return difference - basis @ (basis.T @ difference) if basis.shape[1] else difference


@dataclass
class _Score:
    separation: float
    separation_fitted: float
    peak: float
    max_angle: float
    samples: int = 0
    #: The separation over the training part and over the held-out part of the played record [-] (each the
    #: smallest over the draws); the search maximises the smaller of the two (``objective``).
    train: float = -math.inf
    heldout: float = -math.inf

    @property
    def objective(self) -> float:
        return min(self.train, self.heldout)


def predict_separation(models: Sequence[CompetingModel], duty: np.ndarray, noise_rms: float,
                       parameters: RigParameters = DEFAULT_PARAMETERS, sample_time: float = SAMPLE_TIME,
                       draws: int = DEFAULT_DRAWS, seed: int = 0) -> dict[str, float]:
    """The predicted separation of two models on a duty sequence (module docstring), in units of the noise RMS.

    Parameters
    ----------
    models : sequence of two CompetingModel [-]
        The competing explanations.
    duty : ndarray, shape (n,), dimensionless
        Duty fraction per sample.
    noise_rms : float [rad]
        The angle's measurement-noise RMS.
    parameters : RigParameters [SI]
        The motor model that turns duty into armature voltage, current and back-EMF.
    sample_time : float [s]
        Ts.
    draws : int [-]
        Parameter draws per model.
    seed : int [-]
        Seed of the draws.

    Returns
    -------
    dict
        ``separation`` (min over draws), ``separation_fitted``, ``peak`` (noise RMS units), ``max_angle`` [rad],
        ``separation_train`` and ``separation_heldout`` (over the first 75 % and the last 25 % of `duty`).
    """
    score = _score(models, np.asarray(duty, dtype=float), noise_rms, parameters, sample_time, draws,
                   np.random.default_rng(seed), math.inf)
    return {'separation': score.separation, 'separation_fitted': score.separation_fitted, 'peak': score.peak,
            'max_angle': score.max_angle, 'separation_train': score.train, 'separation_heldout': score.heldout}


def _score(models, duty, noise_rms, parameters, sample_time, draws, rng, angle_limit) -> _Score:
    from aeropend_core.diagnosis.compare import segment_at_steps
    inputs = motor_inputs(duty, parameters, sample_time)
    steps = np.flatnonzero(np.diff(duty)) + 1
    segments = segment_at_steps(0, len(duty), steps, sample_time)
    predictors = [_Predictor(m, inputs, sample_time, segments) for m in models]
    draw_values = [_draws(m, draws, np.random.default_rng(rng.integers(2 ** 32))) for m in models]
    runs = [p.run(v) for p, v in zip(predictors, draw_values)]
    max_angle = float(max(np.nanmax(np.abs(r)) if np.any(np.isfinite(r)) else math.inf for r in runs))
    if not np.all([np.all(np.isfinite(r)) for r in runs]):
        max_angle = math.inf
    if max_angle > angle_limit:
        return _Score(-math.inf, -math.inf, 0.0, max_angle)
    columns = [_basis(p.sensitivities(r[0])) for p, r in zip(predictors, runs)]
    heldout = predictors[0].index >= int(round(TRAIN_FRACTION * len(duty)))
    parts = {'whole': slice(None), 'train': ~heldout, 'heldout': heldout}
    separations = {part: [] for part in parts}
    for k in range(len(draw_values[0])):
        difference = runs[0][k] - runs[1][k]
        # model 0 true -> model 1 refits (remove what model 1's sensitivities absorb), and the other way round
        left = _remainder(columns[1], difference)
        right = _remainder(columns[0], -difference)
        for part, where in parts.items():
            rms = [float(np.sqrt(np.mean(r[where] ** 2))) if r[where].size else 0.0 for r in (left, right)]
            separations[part].append(min(rms) / noise_rms)
    peak = float(np.max(np.abs(runs[0][0] - runs[1][0]))) / noise_rms
    return _Score(float(min(separations['whole'])), float(separations['whole'][0]), peak, max_angle,
                  int(len(runs[0][0])), float(min(separations['train'])), float(min(separations['heldout'])))


def baseline_duty(duration: float, duty_limit: float, seed: int = 1,
                  sample_time: float = SAMPLE_TIME) -> np.ndarray:
    """The original excitation of `duration` [s]: the run's Latin hypercube over duty 0..min(0.7, limit)."""
    from aeropend_core.sim.excitation import lhc_schedule
    cap = min(0.7, duty_limit)
    return lhc_schedule(duration, duty_range=(0.0, cap), duty_cap=cap, seed=seed).duty(sample_time, duration)


def design_experiment(models: Sequence[CompetingModel], noise_rms: float, duration: float = DEFAULT_DURATION,
                      duty_limit: float = DEFAULT_DUTY_LIMIT, angle_limit: float = DEFAULT_ANGLE_LIMIT,
                      parameters: RigParameters = DEFAULT_PARAMETERS, sample_time: float = SAMPLE_TIME,
                      candidates: int = DEFAULT_CANDIDATES, refinements: int = DEFAULT_REFINEMENTS,
                      draws: int = DEFAULT_DRAWS, seed: int = 0,
                      original_duty_limit: float | None = None) -> ExperimentDesign:
    """Search the schedule that separates two models most, within the duty and angle limits and the budget.

    Parameters
    ----------
    models : sequence of two CompetingModel [-]
        The competing explanations (e.g. :func:`competing_models`).
    noise_rms : float [rad]
        The angle's measurement-noise RMS (the unit of the separation).
    duration : float [s]
        Duration budget of the experiment (at least MIN_DURATION).
    duty_limit : float, dimensionless
        Highest duty fraction any step may ask for.
    angle_limit : float [rad]
        Every model's predicted angle (fitted and drawn parameters) must stay below it.
    parameters : RigParameters [SI]
        The motor model that turns duty into the models' inputs.
    sample_time : float [s]
        Ts.
    candidates, refinements : int [-]
        Random schedules tried, then local changes of the best.
    draws : int [-]
        Parameter draws per model (the score is the minimum over paired draws).
    seed : int [-]
        Seed of the search and the draws (the design is reproducible).
    original_duty_limit : float, optional, dimensionless
        Highest duty of the original excitation the design is compared with (default: `duty_limit`, at most 0.7).

    Returns
    -------
    ExperimentDesign
        The schedule, its predicted separation (noise RMS units) and the original excitation's.

    Raises
    ------
    DesignRefused
        Fewer than two models, a budget below MIN_DURATION, limits outside their range, or no schedule tried keeps
        every model below the angle limit.
    """
    if len(models) != 2:
        raise DesignRefused(f'an experiment is designed between two models, got {len(models)}')
    if not math.isfinite(duration) or duration < MIN_DURATION:
        raise DesignRefused(f'the duration budget {duration:g} s is below the {MIN_DURATION:g} s a record needs to be '
                            f'diagnosed; give at least {MIN_DURATION:g} s')
    if not 0.05 <= duty_limit <= 1.0:
        raise DesignRefused(f'the duty limit must be a fraction in [0.05, 1], got {duty_limit:g}')
    if not 0 < angle_limit <= math.pi:
        raise DesignRefused(f'the angle limit must be in (0, pi] rad, got {angle_limit:g}')
    if not noise_rms > 0:
        raise DesignRefused(f'the noise RMS must be positive to measure a separation in it, got {noise_rms!r} rad')
    rng = np.random.default_rng(seed)
    best = None
    lowest_angle = math.inf
    tried = 0

    def evaluate(blocks):
        nonlocal best, lowest_angle, tried
        tried += 1
        schedule = DutySchedule(blocks)
        score = _score(models, schedule.duty(sample_time), noise_rms, parameters, sample_time, draws,
                       np.random.default_rng(seed + 1), angle_limit)
        lowest_angle = min(lowest_angle, score.max_angle)
        # both parts of the played record must see the separation: the diagnosis fits on the first 75 % and judges
        # on the held-out rest (a schedule whose rests all fall in the training part gave no held-out evidence)
        if best is None or score.objective > best[1].objective:
            best = (blocks, score)
        return score

    for blocks in _structured_blocks(duration, duty_limit):
        evaluate(blocks)
    for _ in range(candidates):
        evaluate(_random_blocks(rng, duration, duty_limit))
    if best is None or not math.isfinite(best[1].separation):
        raise DesignRefused(f'no schedule of {tried} tried keeps every model below the angle limit '
                            f'{math.degrees(angle_limit):.0f} deg (the lowest reached '
                            f'{math.degrees(lowest_angle):.0f} deg); lower the duty limit or raise the angle limit')
    for _ in range(refinements):
        evaluate(_mutate(best[0], rng, duration, duty_limit))
    blocks, score = best
    if not score.separation > 0:
        raise DesignRefused(f'no schedule of {tried} tried within duty {duty_limit:g} and angle '
                            f'{math.degrees(angle_limit):.0f} deg separates the two models at all; widen the limits')
    schedule = DutySchedule(blocks)
    if float(schedule.steps[:, 0].max()) > duty_limit + 1e-12:       # never: blocks are built within the limit
        raise DesignRefused(f'internal check: a designed step exceeds the duty limit {duty_limit:g}')
    original = duty_limit if original_duty_limit is None else original_duty_limit
    baseline = _score(models, baseline_duty(duration, original, sample_time=sample_time), noise_rms, parameters,
                      sample_time, draws, np.random.default_rng(seed + 1), math.inf)
    doubts = ['predicted with the nominal motor model turning duty into armature voltage, current and back-EMF; on a '
              'rig whose motor differs, the predicted angles scale with the difference',
              'the refit is linearised around the fitted parameters (first-order projection): a large separation is '
              'an estimate, checked by the diagnosis of the played record']
    return ExperimentDesign(schedule, (models[0], models[1]), score.separation, score.separation_fitted, score.peak,
                            max(baseline.separation, 0.0), noise_rms, score.max_angle, duty_limit, angle_limit,
                            tried, doubts, score.samples, score.train, score.heldout)


def measured_separation(recording, effect_sets: Sequence[Sequence[str]], noise_rms: float,
                        fixed: Mapping[str, float] | None = None) -> dict[str, float]:
    """The separation of two models measured on a played record: each fitted on the whole record (all segments,
    its own initial states), ``sqrt(|rms_a^2 - rms_b^2|) / noise_rms``.

    Parameters
    ----------
    recording : Recording or PreparedRecord [-]
        The played record (at least 20 s).
    effect_sets : sequence of two sequences of str [-]
        The effects of the two models.
    noise_rms : float [rad]
        The unit of the separation (the design's noise RMS).
    fixed : mapping of str -> float, optional [SI]
        Parameters held at known values.

    Returns
    -------
    dict
        ``separation`` [-], the residual RMS of each model ``rms`` [rad] (list, in the order given) and
        ``better`` (the index of the model with the smaller residual).
    """
    from aeropend_core.diagnosis.compare import PreparedRecord, fit_model, prepare, segment_at_steps
    from aeropend_core.diagnosis.output_error import SegmentedData
    prep = recording if isinstance(recording, PreparedRecord) else prepare(recording)
    pieces = [piece for a, b in prep.gaps.pieces(0, len(prep.time))
              for piece in segment_at_steps(a, b, prep.step_indices, prep.sample_time)]
    data = SegmentedData(prep.voltage, prep.current, prep.angle, pieces, prep.sample_time, prep.gate_voltage,
                         prep.valid, None, prep.step_indices)
    rms = [float(fit_model(prep, tuple(effects), data=data, fixed=dict(fixed or {})).residual_rms)
           for effects in effect_sets]
    return {'separation': math.sqrt(abs(rms[0] ** 2 - rms[1] ** 2)) / noise_rms, 'rms': rms,
            'better': int(np.argmin(rms))}


# ------------------------------------------------------------------------------------------------ from a diagnosis
def competing_models(prepared, effect_sets: Sequence[Sequence[str]], fixed: Mapping[str, float] | None = None,
                     start: Mapping[str, float] | None = None) -> list[CompetingModel]:
    """Fit nominal + each effect set on a prepared record and return them as competing models.

    Parameters
    ----------
    prepared : PreparedRecord [-]
        The record (:func:`aeropend_core.diagnosis.compare.prepare`).
    effect_sets : sequence of sequences of str [-]
        The effects of each model (catalog names), one tuple per competing model, e.g. a lag in either of two places.
    fixed : mapping of str -> float, optional [SI]
        Parameters held at known values.
    start : mapping of str -> float, optional [SI]
        Starting values.

    Returns
    -------
    list of CompetingModel
        One per effect set, fitted on the record's training part.
    """
    from aeropend_core.diagnosis.compare import compare
    observer = prepared.motor is not None
    return [CompetingModel.from_comparison(compare(prepared, tuple(effects), start=dict(start or {}) or None,
                                                   fixed=dict(fixed or {})), observer)
            for effects in effect_sets]


def confounded_models(diagnosis) -> list[CompetingModel]:
    """The two competing models of a diagnosis with the verdict 'confounded': its first confounded pair of catalog
    effects, or else the catalog set and the term outside the catalog that explains the data as well (a discovered
    lookalike, :mod:`aeropend_core.diagnosis.discovery`).

    Parameters
    ----------
    diagnosis : Diagnosis [-]
        The result of :func:`aeropend_core.diagnosis.diagnose.diagnose` (with its prepared record).

    Returns
    -------
    list of CompetingModel
        The selected model (with the chosen effect, or the catalog set) and the same model with the rival (or the
        discovered term) in its place.

    Raises
    ------
    DesignRefused
        The diagnosis reports no confounded pair of effects nor a lookalike term, or carries no prepared record.

    Notes
    -----
    A lookalike term is registered in the catalog as a ``term_*`` effect, which the design's simulations of the
    returned models need: call this and :func:`design_experiment` inside one
    :func:`~aeropend_core.model.effects.catalog_scope` (``experiment_loop.run_loop`` does), so the term is gone
    afterwards and the next analysis in the process sees the catalog it would have seen without it.
    """
    pair = next(((f.effect, f.confounded_with[0]) for f in diagnosis.found if f.confounded_with), None)
    lookalike = None if pair is not None else next(
        (t for t in getattr(getattr(diagnosis, 'discovery', None), 'terms', ()) if t.status == 'confounded'), None)
    if (pair is None and lookalike is None) or diagnosis.prepared is None:
        raise DesignRefused(f'the diagnosis ({diagnosis.verdict}) reports no two effects it cannot tell apart; there '
                            'is nothing to design an experiment for')
    if diagnosis.prepared.reduced:
        raise DesignRefused('the record has no armature current (reduced model): designing an experiment needs the '
                            'full model; record the armature current')
    final = diagnosis.final
    observer = diagnosis.prepared.motor is not None
    first = CompetingModel.from_comparison(final, observer)
    start = dict(final.parameters)
    if pair is not None:
        chosen, rival = pair
        swapped = tuple(rival if e == chosen else e for e in final.effects)
    else:       # the discovered term in place of the catalog set it looks like
        from aeropend_core.diagnosis.discovery import term_effect
        name = term_effect(lookalike.term)
        swapped = tuple(e for e in final.effects if e not in lookalike.confounded_with) + (name,)
        value = lookalike.coefficient()[0]
        start[f'{name}_coefficient'] = float(value) if math.isfinite(value) else 0.0
    known = next((c.comparison for c in diagnosis.candidates
                  if c.comparison is not None and set(c.comparison.effects) == set(swapped)), None)
    if known is None:
        from aeropend_core.diagnosis.compare import compare
        known = compare(diagnosis.prepared, swapped, start=start, fixed=dict(diagnosis.fixed))
    return [first, CompetingModel.from_comparison(known, observer)]


__all__ = ['CompetingModel', 'Block', 'DutySchedule', 'ExperimentDesign', 'DesignRefused', 'design_experiment',
           'predict_separation', 'measured_separation', 'competing_models', 'confounded_models', 'write_schedule',
           'read_schedule', 'steps_to_duty', 'motor_inputs', 'baseline_duty', 'predicted_angle']
