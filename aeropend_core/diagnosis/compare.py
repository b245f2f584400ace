"""Compare a model with measurements: fit on a training part, judge on a held-out part, localise the error.

Conventions (stated so nobody has to guess; ``docs/method.md`` section 2.4):

* **fit %** is MATLAB ``compare``'s NRMSE fit of the *free-run simulation* of the angle on the held-out part:
  ``100 (1 - ||y - y_sim|| / ||y - mean(y)||)`` (can be negative). The simulation is driven by the measured Va
  and Ia only; its initial angle and rate are estimated on the first second of the held-out part (like
  ``compare``'s estimated initial conditions) and it runs free from there.
* **k-step prediction**: the model restarted every k samples from the state estimated from the measured angle,
  error taken exactly k samples later (k Ts seconds ahead).
* **rms_error** [rad]: RMS of measured minus simulated angle on the held-out part; **noise_rms** [rad]: the angle's
  measurement-noise RMS estimated from the data itself (third differences); the model error beyond the noise is
  ``sqrt(max(rms_error^2 - noise_rms^2, 0))``.
* Residual tests as MATLAB ``resid``: autocorrelation (whiteness) and cross-correlation with the thrust input for
  lags up to 25 integration steps, against the 99 % band 2.58/sqrt(N).

Only the armature voltage, armature current and angle columns are used; truth columns are ignored.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property, partial

import numpy as np

from aeropend_core.signals.filters import savgol_filter
from aeropend_core.errors import AeropendError, InsufficientDataError
from aeropend_core.diagnosis import MIN_DURATION  # noqa: F401 - the shortest record [s], also read from here
from aeropend_core.diagnosis.basins import PROFILED, search_lag_basins
from aeropend_core.diagnosis.map_profile import profile_motor_map
from aeropend_core.diagnosis.threshold_profile import REFIT_ITERATIONS, once_per_gate_pattern, threshold_profile
from aeropend_core.diagnosis.gaps import MAX_LOST_FRACTION, SHORTEST_PIECE, Gaps, split_at_gaps  # noqa: F401
from aeropend_core.model.effects import kernel_parameter
from aeropend_core.diagnosis.output_error import (STRIDE, OutputErrorFit, SegmentedData, Structure, fit_output_error,
                                        initial_states_from_data)
from aeropend_core.signals.motor import MotorFit, back_emf_ensemble, fit_motor
from aeropend_core.signals.preprocess import (condition_inputs, noise_rms, piecewise_constant, quantisation_bias_rms,
                                             quantisation_step, sharp_steps, smooth_between_steps, step_switches,
                                             bootstrap_blocks)
from aeropend_core.diagnosis.motor_terms import AddedMotorTerm
from aeropend_core.io.recording import Recording

#: Fraction of the record used for training; the rest is held out.
TRAIN_FRACTION = 0.75
#: Target length of the multiple-shooting segments [s] (shorter ones let Ia^2 terms mimic damping).
SEGMENT_SECONDS = 10.0
#: Held-out initial state is estimated on this many seconds [s].
HELDOUT_INITIAL_SECONDS = 1.0
#: Horizon of the k-step prediction [s].
PREDICTION_HORIZON = 0.1
#: A simulation further than this from the measured angle [rad, many turns of the rod] has run away (diverged).
DIVERGED_RAD = 1e3
#: Lags of the residual tests, in integration steps (STRIDE samples).
RESIDUAL_LAGS = 25
#: Dead-zone thresholds refitted after the ranking by one simulation each.
PROFILE_REFITS = 3
#: Starting values of effect parameters, as a fraction of the catalog's typical value.
EFFECT_START_FRACTION = 0.3


@np.errstate(over='ignore', invalid='ignore')
def ran_away(measured: np.ndarray, simulated: np.ndarray) -> bool:
    """True when a free-run simulation [rad] has diverged: non-finite, or more than DIVERGED_RAD from `measured`."""
    deviation = np.abs(np.asarray(measured, dtype=float) - np.asarray(simulated, dtype=float))
    return bool(not np.all(np.isfinite(deviation)) or deviation.max(initial=0.0) > DIVERGED_RAD)


def fit_percent(measured: np.ndarray, simulated: np.ndarray) -> float:
    """MATLAB ``compare`` NRMSE fit [%]: 100 (1 - ||y - y_sim|| / ||y - mean(y)||)."""
    measured, simulated = np.asarray(measured), np.asarray(simulated)
    denominator = np.linalg.norm(measured - measured.mean())
    if denominator == 0:
        return float('nan')
    return float(100.0 * (1.0 - np.linalg.norm(measured - simulated) / denominator))


def excess_error(rms_error: float, noise: float) -> float:
    """Model error beyond the measurement noise [rad]: sqrt(max(rms^2 - noise^2, 0))."""
    return float(math.sqrt(max(rms_error ** 2 - noise ** 2, 0.0)))


@dataclass
class PreparedRecord:
    """A validated recording with conditioned inputs and its training / held-out split.

    Arrays have shape (n,): ``time`` [s], ``armature_voltage`` [V], ``armature_current`` [A], ``angle`` [rad];
    ``voltage``/``current`` are the conditioned inputs used in the thrust term.
    """

    time: np.ndarray
    armature_voltage: np.ndarray
    armature_current: np.ndarray
    angle: np.ndarray
    sample_time: float
    voltage: np.ndarray
    current: np.ndarray
    step_indices: np.ndarray
    noise_rms: float
    split: int
    motor: MotorFit | None = None
    gate_voltage: np.ndarray | None = None
    findings: tuple = ()
    gaps: Gaps | None = None
    #: The angle's ADC step [rad] (0 when the angle is not quantised); a slow signal quantised without dither
    #: carries an error up to step/sqrt(12) that the noise estimate (third differences) does not see.
    angle_step: float = 0.0
    #: Back-EMF changes [V] the motor observer's estimation error allows, shape (members, n)
    #: (:func:`aeropend_core.signals.motor.back_emf_ensemble`); the training fits add their effect to the standard
    #: errors. None without the observer.
    voltage_ensemble: np.ndarray | None = None
    #: No period-average armature current: the reduced model (thrust from Va through the motor map,
    #: :mod:`aeropend_core.signals.reduced`); ``motor_map`` then holds its profiled parameters (SI) and doubts.
    reduced: bool = False
    motor_map: dict | None = None
    #: A motor term given with ``--motor-term``, already in the observer whose back-EMF is `voltage`
    #: (:class:`aeropend_core.diagnosis.motor_discovery.AddedMotorTerm`; None: none).
    motor_term: AddedMotorTerm | None = None
    train: SegmentedData = field(init=False)
    heldout: SegmentedData = field(init=False)

    def __post_init__(self) -> None:
        n = len(self.time)
        if self.gaps is None:
            self.gaps = Gaps(np.ones(n, dtype=bool), self.sample_time)
        first = min(STEP_GUARD, n // 10)   # skip a possible step transient at the very start
        train_segments = [piece for a, b in self.gaps.pieces(first, self.split)
                          for piece in segment_at_steps(a, b, self.step_indices, self.sample_time)]
        self.train = SegmentedData(self.voltage, self.current, self.angle, train_segments, self.sample_time,
                                   self.gate_voltage, self.valid, self.voltage_ensemble, self.step_indices,
                                   quantisation_bias_rms(self.angle_step, self.noise_rms))
        self.heldout = SegmentedData(self.voltage, self.current, self.angle, self.gaps.pieces(self.split, n),
                                     self.sample_time, self.gate_voltage, self.valid)

    @property
    def valid(self) -> np.ndarray | None:
        """Measured samples (False where a gap of lost samples or a join between records was filled), or None when
        every sample was measured."""
        return self.gaps.valid if self.gaps is not None and not self.gaps.complete else None

    @property
    def smoothing_window(self) -> int:
        """Samples of the Savitzky-Golay window (odd, ~0.1 s) used to estimate the angle's rate from data."""
        return max(7, int(round(0.1 / self.sample_time)) | 1)

    @cached_property
    def smoothed_angle(self) -> np.ndarray:
        """The measured angle smoothed over ~0.1 s [rad], shape (n,)."""
        return savgol_filter(self.angle, self.smoothing_window, 3)

    @cached_property
    def smoothed_rate(self) -> np.ndarray:
        """The angle's rate estimated from the measured angle over ~0.1 s [rad/s], shape (n,)."""
        return savgol_filter(self.angle, self.smoothing_window, 3, deriv=1, delta=self.sample_time)

    @property
    def duration(self) -> float:
        return float(self.time[-1] - self.time[0] + self.sample_time)


#: Samples skipped at the start of the record (a step may land on sample 0 with no sample before it).
STEP_GUARD = 8


def segment_at_steps(start: int, stop: int, steps: np.ndarray, sample_time: float,
                     target_seconds: float = SEGMENT_SECONDS) -> list[tuple[int, int]]:
    """Split [start, stop) into segments of about `target_seconds`, cut just before input steps.

    Cutting a few samples before a step starts each segment from a quasi-steady input, so unknown internal states
    (a lagging thrust) start near their equilibrium.
    """
    target = int(round(target_seconds / sample_time))
    cuts = [start]
    candidates = np.asarray(steps, dtype=int) - 3
    candidates = candidates[(candidates > start) & (candidates < stop)]
    while stop - cuts[-1] > 1.5 * target:
        goal = cuts[-1] + target
        if candidates.size:
            best = candidates[np.argmin(np.abs(candidates - goal))]
            cut = int(best) if abs(int(best) - goal) < 0.5 * target and best > cuts[-1] + target // 2 else goal
        else:
            cut = goal
        cuts.append(cut)
    cuts.append(stop)
    return [(a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b - a > 4 * STRIDE]


def prepare(recording: Recording, train_fraction: float = TRAIN_FRACTION,
            use_motor_observer: bool = True) -> PreparedRecord:
    """Validate a recording (only Va, Ia and angle are used) and condition it for fitting.

    Raises :class:`InsufficientDataError` / :class:`AeropendError` naming the problem and what to do.
    """
    source = recording.source or 'the recording'
    for name in ('armature_voltage', 'angle'):
        if name not in recording.signals:
            raise AeropendError(f'{source} has no {name!r} column; the diagnosis needs armature_voltage [V] (or the '
                                f'duty) and angle [rad], and uses armature_current [A] when it is recorded')
    # The data-quality gate (aeropend_core.signals.quality): repairs what is unambiguous and says so, refuses the
    # rest; a recording loaded by load_recording has passed it already (its findings are kept, not repeated).
    from aeropend_core.signals.quality import check_recording
    checked = check_recording(recording).recording
    time = np.asarray(checked.time, dtype=float)
    voltage = np.asarray(checked.signals['armature_voltage'], dtype=float)
    reduced = 'armature_current' not in checked.signals     # the reduced model (aeropend_core.signals.reduced)
    current = np.zeros_like(voltage) if reduced else np.asarray(checked.signals['armature_current'], dtype=float)
    angle = np.asarray(checked.signals['angle'], dtype=float)
    if time.size < 10:
        raise InsufficientDataError(f'{source} has only {time.size} samples; record at least {MIN_DURATION:g} s')
    steps = np.diff(time)
    sample_time = float(np.median(steps))
    if sample_time > 0 and np.all(steps > 0):
        # The clock's step over the whole record: each step counted in samples (robust: an error far below half a
        # sample), then the span divided by the count. The median step alone carries the stamps' rounding (a CSV's
        # 12 significant digits leave 1e-8 s above 1000 s: 2e-6 relative), which over a 1-hour record (1.8 M
        # samples) puts the last samples 3 samples off the grid.
        sample_time = float((time[-1] - time[0]) / np.sum(np.maximum(np.rint(steps / sample_time), 1.0)))
    if sample_time > 1.0 / 19.5:
        raise AeropendError(f'{source}: samples are {sample_time:g} time units apart; the t column must be in '
                            f'seconds (the rig samples every 1/490 s = 0.00204 s)')
    sequence = recording.signals.get('sequence')
    time, filled, gaps = split_at_gaps(time, {'armature_voltage': voltage, 'armature_current': current,
                                               'angle': angle}, sample_time, source, sequence)
    voltage, current, angle = filled['armature_voltage'], filled['armature_current'], filled['angle']
    duration = gaps.measured_seconds
    if duration < MIN_DURATION:
        raise InsufficientDataError(f'{source} lasts {duration:.1f} s{gaps.lost_text}; the comparison needs at '
                                    f'least {MIN_DURATION:g} s (training and held-out parts of ~10 s segments)')
    if np.ptp(voltage) < 0.05 * max(np.max(np.abs(voltage)), 1e-9) or np.ptp(voltage) < 1e-3:
        raise InsufficientDataError(f'{source}: the armature voltage barely changes ({np.ptp(voltage):.3g} V '
                                    f'peak to peak); excite the rig with duty steps (aeropend simulate / the '
                                    f'excitation node) to identify it')
    if np.ptp(angle) < 10 * max(noise_rms(angle), 1e-6):
        raise InsufficientDataError(f'{source}: the angle barely moves ({np.ptp(angle):.3g} rad peak to peak); '
                                    f'use larger duty steps')
    conditioned = condition_inputs(voltage, current, sample_time)
    split = int(round(train_fraction * time.size))
    # Start the held-out part just before an input step near the nominal split (quasi-steady internal states).
    near = conditioned.step_indices[np.abs(conditioned.step_indices - split) < int(3.0 / sample_time)]
    if near.size:
        split = int(near[np.argmin(np.abs(near - split))]) - 3
    thrust_voltage, thrust_current, motor, ensemble = (conditioned.armature_voltage, conditioned.armature_current,
                                                       None, None)
    stepped = piecewise_constant(voltage, conditioned.step_indices)
    if reduced:     # Va's steps drive the motor map (profiled below): no current, R = 0 in the pendulum model
        thrust_voltage = stepped if stepped is not None else conditioned.armature_voltage
        thrust_current = np.zeros_like(current)
    elif use_motor_observer:
        # A step input: Va's per-step medians. A continuously varying one (a chirp): Va as sampled, held over each
        # sample like the duty, with only its one-sample jumps as steps. There the measured Va - R Ia is no thrust
        # voltage: Ia lags Va by La/Ra ~ one sample, and a 0.1-2.5 Hz chirp left 11 % of the true back-EMF's swing
        # in it (thrust gain +12 %, Ra +3 %, z up to +19, bench/chirp_on_own_rig.py); the observer models La.
        observer_steps = conditioned.step_indices if stepped is not None else sharp_steps(
            voltage, conditioned.step_indices)
        observed = stepped if stepped is not None else smooth_between_steps(voltage, observer_steps, sample_time)
        switch = step_switches(observer_steps, observed.size, sample_time)
        try:
            motor = fit_motor(observed, current, observer_steps, sample_time, switch)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError):
            motor = None      # the observer is an improvement, not a requirement: use the measured Va - R Ia
        if motor is not None and motor.adequate and np.all(np.isfinite(motor.back_emf)):
            # the observer's back-EMF is the thrust voltage; R is then 0 in the pendulum model
            thrust_voltage, thrust_current = motor.back_emf, np.zeros_like(current)
            ensemble, motor_errors = back_emf_ensemble(motor, observed, voltage, current, observer_steps,
                                                       sample_time, with_errors=True,
                                                       blocks=None if stepped is not None else
                                                       bootstrap_blocks(observer_steps, voltage.size, sample_time))
            motor = replace(motor, standard_errors=motor_errors)
        else:
            motor = None
    valid = gaps.valid
    # the Va the observer ran on (a continuous input's as sampled), else the steps' medians, else the conditioned Va
    observed_voltage = (observed if motor is not None and stepped is None else
                        stepped if stepped is not None else conditioned.armature_voltage)
    prep = PreparedRecord(time=time, armature_voltage=voltage, armature_current=current, angle=angle,
                          sample_time=sample_time, voltage=thrust_voltage, current=thrust_current,
                          step_indices=conditioned.step_indices, noise_rms=noise_rms(angle[valid]), split=split,
                          motor=motor, gate_voltage=observed_voltage,
                          gaps=gaps, angle_step=quantisation_step(angle[valid]), voltage_ensemble=ensemble,
                          findings=tuple(checked.findings), reduced=reduced)
    return profile_motor_map(prep, fit_model) if reduced else prep


def initial_guess(prep: PreparedRecord, threshold_voltage: float | None = None) -> dict[str, float]:
    """Starting values of the nominal parameters by an equation-error fit on smoothed derivatives.

    Regresses the angle's second derivative on [sin y, dy/dt, Va^2, Va Ia, Ia^2] over the training part; R
    follows from eq (5)'s structure (the Va Ia coefficient is -2 R times the Va^2 one). With the motor observer
    the thrust regressor is e|e| of its back-EMF and R is 0. With `threshold_voltage` [V] the thrust regressors
    are gated by a dead zone at that armature voltage. Only starting values.
    """
    window = prep.smoothing_window
    stop = prep.split
    y = prep.smoothed_angle[:stop]
    dy = prep.smoothed_rate[:stop]
    ddy = savgol_filter(prep.angle[:stop], window, 3, deriv=2, delta=prep.sample_time)
    va, ia = prep.voltage[:stop], prep.current[:stop]
    if threshold_voltage is not None:
        gate = (prep.gate_voltage[:stop] >= threshold_voltage).astype(float)
        va, ia = va * gate, ia * gate       # thrust terms are products of two of them: gated once
    keep = slice(window, stop - window)
    if prep.motor is not None or prep.reduced:
        regressors = np.column_stack([-np.sin(y), -dy, va * np.abs(va)])
        (gravity, damping, gain), *_ = np.linalg.lstsq(regressors[keep], ddy[keep], rcond=None)
        resistance = 0.0
    else:
        regressors = np.column_stack([-np.sin(y), -dy, va * va, va * ia, ia * ia])
        (gravity, damping, gain, k_vi, _), *_ = np.linalg.lstsq(regressors[keep], ddy[keep], rcond=None)
        resistance = -k_vi / (2 * gain) if gain > 0 else float('nan')
        if not 0.05 < resistance < 20:
            resistance = 1.0
    if not (gain > 0 and gravity > 0):
        # The regression is only a start; fall back to a gravity/thrust balance if it is implausible.
        e = va - resistance * ia
        thrust = e * np.abs(e)
        gravity = gravity if gravity > 0 else 100.0
        gain = float(np.dot(np.sin(y), thrust) / max(np.dot(thrust, thrust), 1e-12) * gravity)
    damping = damping if damping > 0 else 0.1 * math.sqrt(gravity)
    return {'gravity_stiffness': float(gravity), 'damping': float(damping), 'thrust_gain': float(max(gain, 1e-6)),
            'armature_resistance': float(resistance)}


def effect_start_values(effects: Sequence[str]) -> dict[str, float]:
    """Starting values of effect parameters (from each catalog record: by default a fraction of the typical
    value)."""
    from aeropend_core.model.effects import get_effect
    start = {}
    for name in effects:
        start.update(get_effect(name).start_parameters())
    return start


def input_levels(prep: PreparedRecord, stop: int | None = None) -> np.ndarray:
    """The distinct held armature-voltage levels [V] in samples [0, stop) (median of each step interval), sorted."""
    stop = len(prep.armature_voltage) if stop is None else stop
    steps = prep.step_indices[prep.step_indices < stop]
    bounds = np.concatenate(([0], steps, [stop]))
    levels = np.array([np.median(prep.armature_voltage[a:b]) for a, b in zip(bounds[:-1], bounds[1:]) if b > a])
    return np.unique(np.round(levels[levels > 0.05], 4))


def gate_thresholds(prep: PreparedRecord) -> np.ndarray:
    """Candidate dead-zone thresholds [V]: midpoints between the training part's input levels (below 75 % of the
    largest).

    The fit cannot place a threshold more finely than the levels the training data holds: between two adjacent
    levels the residual does not change, so the midpoint is the estimate and the levels bound it.
    """
    levels = input_levels(prep, prep.split)
    if levels.size < 2:
        return np.zeros(0)
    mids = np.concatenate(([levels[0] * 0.5], 0.5 * (levels[1:] + levels[:-1])))
    return mids[mids < 0.75 * levels.max()]


def fit_model(prep: PreparedRecord, effects: Sequence[str] = (), start: dict[str, float] | None = None,
              data: SegmentedData | None = None, fixed: dict[str, float] | None = None,
              initial_states: np.ndarray | None = None, search_basins: bool = True) -> OutputErrorFit:
    """Output-error fit of nominal + `effects` on the training segments (or `data`).

    A thrust gate's threshold is profiled over the input levels present (the residual is flat between them).
    A lag's time constant or an offset is searched over its other basins unless `search_basins` is false (a fit
    warm-started from a neighbouring fit's values, whose basin is already chosen).
    `fixed` holds parameters at known values (SI; e.g. a hardware filter's delay). `initial_states` [rad, rad/s]
    start the segments' states on long records (see :func:`fit_output_error`).
    """
    structure = Structure(tuple(effects))
    data = data if data is not None else prep.train
    values = dict(initial_guess(prep))
    fixed_base = {'armature_resistance': 0.0} if prep.motor is not None or prep.reduced else {}
    values.update(effect_start_values(effects))
    if start:
        values.update({k: v for k, v in start.items() if k in structure.parameter_names})
    fixed_base.update({k: float(v) for k, v in (fixed or {}).items() if k in structure.parameter_names})
    values.update(fixed_base)
    gate = structure.gate_parameter
    if gate is None:
        fit_from = partial(fit_output_error, data, structure, fixed=fixed_base, initial_states=initial_states)
        fit = fit_from(values)
        for kind in PROFILED if search_basins else ():   # a nonlinear time constant or offset: its whole range
            name = kernel_parameter(structure.effects, kind)
            if name is not None and name not in fixed_base:
                return search_lag_basins(prep, fit_from, values, name, fit, kind)
        return fit
    thresholds = gate_thresholds(prep)
    if thresholds.size == 0:
        raise InsufficientDataError('a thrust threshold (dead zone) needs steps at several small duty levels; '
                                    'none are in the data')
    # Profile: rank thresholds by one simulation each, then refit the best few. Each threshold is simulated from
    # the given start values and from nominal values fitted by equation error with that threshold's gate: a large
    # dead zone leaves the nominal fit (the given start) far off, and ranking only from it picks a wrong level.
    initial = initial_states_from_data(data, values.get(structure.offset_parameter, 0.0))
    ranked = _rank_thresholds(prep, data, structure, thresholds, values, fixed_base, gate, initial)
    chosen: list[tuple[float, dict]] = []
    for _score, threshold, start_values in ranked:
        if len(chosen) == PROFILE_REFITS:
            break
        if not any(threshold == t for t, _ in chosen):
            chosen.append((threshold, start_values))
    best = None
    for threshold, start_values in chosen:
        fit = fit_output_error(data, structure, start_values, fixed={**fixed_base, gate: threshold},
                               initial_states=initial_states)
        if best is None or fit.residual_rms < best.residual_rms:
            best = fit
    levels = input_levels(prep, prep.split)
    threshold = best.parameters[gate]
    low = float(levels[levels < threshold].max()) if np.any(levels < threshold) else 0.0
    high = float(levels[levels > threshold].min()) if np.any(levels > threshold) else threshold
    best.extra['threshold_interval'] = (low, high)
    best.extra['threshold_ranking'] = [(threshold, score) for score, threshold, _ in ranked]   # [V], [rad]
    # Anywhere between the two levels fits equally: a uniform uncertainty over that interval.
    best.standard_errors[gate] = (high - low) / math.sqrt(12.0)
    return best


#: Dead-zone thresholds ranked per pass: a record with more input levels than this (a long record) is ranked coarse
#: to fine, so the ranking's cost grows with the logarithm of the number of levels instead of with it.
PROFILE_GRID = 24
#: Parameter rows simulated at once while ranking thresholds (bounds the memory: rows x record length floats).
PROFILE_CHUNK = 8


def _rank_thresholds(prep: PreparedRecord, data: SegmentedData, structure: Structure, thresholds: np.ndarray,
                     values: dict[str, float], fixed_base: dict[str, float], gate: str,
                     initial: np.ndarray) -> list[tuple[float, float, dict]]:
    """(rms [rad], threshold [V], start values) of the thresholds ranked by one simulation each, best first.

    Each threshold is simulated from the given start values and from nominal values fitted by equation error with
    that threshold's gate. Up to ``PROFILE_GRID`` thresholds every one is ranked; with more, every k-th first, then
    the thresholds between the best ones' ranked neighbours, until no unranked threshold lies next to one of the
    ``PROFILE_REFITS`` best.
    """
    index = data.residual_index
    measured = data.angle[index]
    scored: dict[int, list[tuple[float, float, dict]]] = {}

    def score(indices) -> None:
        todo = [int(i) for i in sorted(set(indices)) if int(i) not in scored]
        trials = [(i, values) for i in todo]
        trials += [(i, {**values, **initial_guess(prep, float(thresholds[i])), **fixed_base}) for i in todo]
        for first in range(0, len(trials), PROFILE_CHUNK):
            chunk = trials[first:first + PROFILE_CHUNK]
            rows = np.array([structure.row({**start_values, **fixed_base, gate: float(thresholds[i])})
                             for i, start_values in chunk])
            simulated = data.simulate(structure, rows, np.repeat(initial[None], len(rows), axis=0))[:, index]
            with np.errstate(over='ignore', invalid='ignore'):  # a diverged trial scores inf below, quietly
                rms = np.sqrt(np.mean((simulated - measured) ** 2, axis=1))
            for (i, start_values), value in zip(chunk, rms):
                scored.setdefault(i, []).append((float(value) if np.isfinite(value) else np.inf,
                                                 float(thresholds[i]), start_values))

    ranges = [(0, len(thresholds) - 1)]
    while ranges:
        score(np.concatenate([np.round(np.linspace(a, b, min(PROFILE_GRID, b - a + 1))) for a, b in ranges]))
        done = sorted(scored)
        best = sorted(done, key=lambda i: min(s for s, _, _ in scored[i]))[:PROFILE_REFITS]
        ranges = []
        for i in best:
            position = done.index(i)
            left = done[position - 1] if position > 0 else i
            right = done[position + 1] if position + 1 < len(done) else i
            if any(k not in scored for k in range(left, right + 1)):
                ranges.append((left, right))
    return sorted((trial for trials in scored.values() for trial in trials), key=lambda trial: trial[0])


@dataclass
class Evaluation:
    """How well a fitted model reproduces the held-out data, and where it fails (all angles in rad)."""

    fit_percent: float
    rms_error: float
    noise_rms: float
    prediction_rms: float
    prediction_horizon: float
    simulated: np.ndarray                      # (n,) simulated angle over the whole record (train segments + held-out)
    residual_autocorrelation: np.ndarray       # (lags+1,)
    residual_input_correlation: np.ndarray     # (2 lags+1,), lags -L..L in integration steps
    correlation_band: float
    lag_seconds: np.ndarray
    regimes: dict[str, dict[str, float]]
    worst_windows: list[dict[str, float | str]]
    #: The fitted model's simulation of the record grows without bound (non-finite, or more than DIVERGED_RAD from
    #: the measured angle): its parameters make it unstable on this input, so they are not estimates.
    diverged: bool = False

    @property
    def excess_error(self) -> float:
        """Model error beyond the noise [rad]."""
        return excess_error(self.rms_error, self.noise_rms)

    @property
    def whiteness_violations(self) -> int:
        """Lags (excluding 0) where the residual autocorrelation leaves the 99 % band."""
        return int(np.sum(np.abs(self.residual_autocorrelation[1:]) > self.correlation_band))


def _heldout_simulation(prep: PreparedRecord, fit: OutputErrorFit) -> np.ndarray:
    """Free-run simulation over the held-out part, initial state estimated on its first second."""
    structure = fit.structure
    head = int(round(HELDOUT_INITIAL_SECONDS / prep.sample_time))
    fixed = dict(fit.parameters)
    # one head per held-out piece (the held-out part restarts after each gap of lost samples)
    head_data = SegmentedData(prep.voltage, prep.current, prep.angle,
                              [(a, min(b, a + head)) for a, b in prep.heldout.segments], prep.sample_time,
                              prep.gate_voltage, prep.valid)
    ic_fit = fit_output_error(head_data, structure, fixed, fixed=fixed, max_iterations=30, covariance=False)  # states
    return prep.heldout.simulate(structure, structure.row(fit.parameters)[None],
                                 ic_fit.initial_states[None])[0]


def _k_step_prediction(prep: PreparedRecord, fit: OutputErrorFit, horizon: float) -> tuple[np.ndarray, np.ndarray]:
    """Predictions exactly k samples ahead on the held-out part: (indices, predicted angle)."""
    k = max(STRIDE, int(round(horizon / prep.sample_time / STRIDE)) * STRIDE)
    starts = np.arange(prep.split, len(prep.time) - k - STRIDE, k + STRIDE)
    if prep.valid is not None:   # no prediction across a gap of lost samples
        starts = np.array([s for s in starts if prep.valid[s:s + k + STRIDE].all()], dtype=int)
    if starts.size == 0:
        return np.zeros(0, dtype=int), np.zeros(0)
    segments = [(int(s), int(s) + k + STRIDE) for s in starts]
    data = SegmentedData(prep.voltage, prep.current, prep.angle, segments, prep.sample_time,
                         prep.gate_voltage, min_samples=2 * STRIDE)
    offset = fit.parameters.get(fit.structure.offset_parameter, 0.0)
    initial = np.column_stack([prep.smoothed_angle[starts] - offset, prep.smoothed_rate[starts]])
    predicted = data.simulate(fit.structure, fit.structure.row(fit.parameters)[None], initial[None])[0]
    return starts + k, predicted[starts + k]


def _correlation(a: np.ndarray, b: np.ndarray, lags: int) -> np.ndarray:
    """Normalised cross-correlation of a(t) with b(t - lag) for lag in [-lags, lags]."""
    a = a - a.mean()
    b = b - b.mean()
    scale = math.sqrt(float(np.dot(a, a) * np.dot(b, b))) or 1.0
    n = len(a)
    out = np.empty(2 * lags + 1)
    for i, lag in enumerate(range(-lags, lags + 1)):
        if lag >= 0:
            out[i] = np.dot(a[lag:], b[:n - lag]) / scale
        else:
            out[i] = np.dot(a[:n + lag], b[-lag:]) / scale
    return out


def regime_masks(prep: PreparedRecord) -> dict[str, np.ndarray]:
    """Boolean masks (n,) of the operating regimes in which errors are localised."""
    angle, rate = prep.smoothed_angle, prep.smoothed_rate
    n = len(angle)
    # time since the latest step at or before each sample (inf before the first): one search, linear in the record
    steps = np.sort(np.asarray(prep.step_indices, dtype=np.int64))
    latest = np.searchsorted(steps, np.arange(n), side='right') - 1
    since_step = np.where(latest >= 0, (np.arange(n) - steps[np.maximum(latest, 0)]) * prep.sample_time, np.inf) \
        if steps.size else np.full(n, np.inf)
    speed_scale = np.percentile(np.abs(rate), 95)
    angle_span = np.percentile(angle, 95) - np.percentile(angle, 5)
    low_angle, high_angle = np.percentile(angle, [5, 95])
    voltage_scale = np.percentile(prep.armature_voltage, 95)
    return {
        'near direction reversals of the rod (|rate| < 5 % of its range)': np.abs(rate) < 0.05 * speed_scale,
        'large angle (top 25 % of the range)': angle > high_angle - 0.25 * angle_span,
        'small angle (bottom 25 % of the range)': angle < low_angle + 0.25 * angle_span,
        'within 0.5 s after an input step': since_step < 0.5,
        'steady input (> 0.5 s after a step)': since_step >= 0.5,
        'low thrust (Va < 30 % of its range)': prep.armature_voltage < 0.3 * voltage_scale,
        'rising (rate > 0)': rate > 0.05 * speed_scale,
        'falling (rate < 0)': rate < -0.05 * speed_scale,
    }


@np.errstate(over='ignore', invalid='ignore')      # a run-away simulation is flagged (``diverged``), not warned
def evaluate(prep: PreparedRecord, fit: OutputErrorFit) -> Evaluation:
    """Held-out simulation fit, k-step prediction, residual tests and error localisation for a fitted model."""
    stop = len(prep.time)
    heldout = _heldout_simulation(prep, fit)
    index = prep.heldout.residual_index
    measured, simulated = prep.angle[index], heldout[index]
    residual = measured - simulated
    rms = float(np.sqrt(np.mean(residual ** 2)))
    # Whole-record simulation for plots and regimes: training segments with their fitted initial states.
    full = np.full(stop, np.nan)
    train_sim = prep.train.simulate(fit.structure, fit.structure.row(fit.parameters)[None],
                                    fit.initial_states[None])[0]
    full[prep.train.residual_index] = train_sim[prep.train.residual_index]
    full[index] = simulated
    predicted_index, predicted = _k_step_prediction(prep, fit, PREDICTION_HORIZON)
    prediction_rms = float(np.sqrt(np.mean((prep.angle[predicted_index] - predicted) ** 2))) \
        if predicted.size else float('nan')
    e = prep.voltage - fit.parameters['armature_resistance'] * prep.current
    thrust_input = (e * np.abs(e))[index]
    autocorrelation = _correlation(residual, residual, RESIDUAL_LAGS)[RESIDUAL_LAGS:]
    cross = _correlation(residual, thrust_input, RESIDUAL_LAGS)
    band = 2.58 / math.sqrt(len(residual))
    lags = np.arange(-RESIDUAL_LAGS, RESIDUAL_LAGS + 1) * STRIDE * prep.sample_time
    # Error localisation over the whole record (both parts) where a simulation exists.
    # an unstable fitted model (e.g. a discovered term's refit) runs away: say so rather than square an overflow
    simulated_index = np.concatenate([prep.train.residual_index, index])
    diverged = ran_away(prep.angle[simulated_index], full[simulated_index])
    available = np.abs(prep.angle - full) <= DIVERGED_RAD       # False where nothing is simulated (NaN) or run away
    error = np.where(available, prep.angle - full, np.nan)
    overall = float(np.sqrt(np.nanmean(error ** 2))) if available.any() else float('nan')
    regimes = {}
    for name, mask in regime_masks(prep).items():
        selected = mask & available
        if selected.sum() < 20:
            continue
        value = float(np.sqrt(np.mean(error[selected] ** 2)))
        regimes[name] = {'rms_error': value, 'ratio_to_overall': value / overall if overall else float('nan'),
                         'fraction_of_samples': float(selected.sum() / available.sum())}
    worst = _worst_windows(prep, error)
    return Evaluation(fit_percent=fit_percent(measured, simulated), rms_error=rms, noise_rms=prep.noise_rms,
                      prediction_rms=prediction_rms, prediction_horizon=PREDICTION_HORIZON, simulated=full,
                      residual_autocorrelation=autocorrelation, residual_input_correlation=cross,
                      correlation_band=band, lag_seconds=lags, regimes=regimes, worst_windows=worst,
                      diverged=diverged)


def _worst_windows(prep: PreparedRecord, error: np.ndarray, width: float = 1.0, count: int = 5) -> list[dict]:
    """The `count` one-second windows with the largest RMS error, with what the input was doing."""
    n = int(round(width / prep.sample_time))
    windows = []
    for start in range(0, len(error) - n + 1, n):
        piece = error[start:start + n]
        finite = np.isfinite(piece)
        if finite.sum() < n // 4:
            continue
        steps_inside = prep.step_indices[(prep.step_indices >= start) & (prep.step_indices < start + n)]
        va = prep.armature_voltage[start:start + n]
        if steps_inside.size:
            k = int(steps_inside[0])
            before = float(np.median(prep.armature_voltage[max(k - 20, 0):k])) if k > 0 else 0.0
            after = float(np.median(prep.armature_voltage[k:k + 20]))
            doing = f'step {"up" if after > before else "down"} {before:.2f} V -> {after:.2f} V'
        else:
            doing = f'steady at {np.median(va):.2f} V'
        windows.append({'start': float(prep.time[start]), 'stop': float(prep.time[min(start + n, len(error) - 1)]),
                        'rms_error': float(np.sqrt(np.nanmean(piece ** 2))), 'input': doing,
                        'part': 'held-out' if start >= prep.split else 'training'})
    windows.sort(key=lambda w: -w['rms_error'])
    return windows[:count]


@dataclass
class Comparison:
    """A fitted model (nominal + effects) and its evaluation on the held-out data; made by :func:`compare`.

    Parameters
    ----------
    effects : tuple of str [-]
        Effects in the model besides the nominal equation.
    fit : OutputErrorFit [-]
        The output-error fit on the training part: ``parameters`` and ``standard_errors`` (SI).
    evaluation : Evaluation [-]
        The free-run simulation of the held-out part: ``fit_percent`` [%], ``rms_error`` and ``noise_rms`` [rad].
    """

    effects: tuple[str, ...]
    fit: OutputErrorFit
    evaluation: Evaluation

    @property
    def parameters(self) -> dict[str, float]:
        return self.fit.parameters

    @property
    def fit_percent(self) -> float:
        return self.evaluation.fit_percent

    @property
    def rms_error(self) -> float:
        return self.evaluation.rms_error

    @property
    def noise_rms(self) -> float:
        return self.evaluation.noise_rms

    # the result presents itself (words in present/results_text.py, imported when called; the package example runs
    # these)
    def summary(self) -> dict:
        """Model, fit [%], RMS error, noise and error beyond it [rad], doubts (:func:`~aeropend_core.present.
        results_text.comparison_summary`)."""
        from aeropend_core.present.results_text import comparison_summary
        return comparison_summary(self)

    def as_text(self) -> str:
        """The model, its held-out fit, parameters (SI, +- 1 sigma), error by regime [mrad] and doubts, as text."""
        from aeropend_core.present.results_text import comparison_text
        return comparison_text(self)

    def as_html(self) -> str:
        """A self-contained HTML fragment (``<section>``): summary line, doubts, parameter table (SI)."""
        from aeropend_core.present.results_text import comparison_html
        return comparison_html(self)

    def to_dict(self) -> dict:
        """The numbers (errors [rad], parameters SI with 1-sigma and units, regimes, doubts; NaN where unknown)."""
        from aeropend_core.present.results_text import comparison_dict
        return comparison_dict(self)


def compare(recording: Recording | PreparedRecord, effects: Sequence[str] = (),
            start: dict[str, float] | None = None, fixed: dict[str, float] | None = None,
            initial_states: np.ndarray | None = None) -> Comparison:
    """Fit nominal + `effects` on the training part and evaluate on the held-out part (see module docstring).

    Parameters
    ----------
    recording : Recording or PreparedRecord [-]
        At least 20 s with ``armature_voltage`` [V], ``armature_current`` [A] and ``angle`` [rad] (other columns
        are ignored); a :class:`PreparedRecord` is used as it is.
    effects : sequence of str [-]
        Catalog effects in the model besides the nominal terms.
    start : dict of str -> float, optional [SI unit of each parameter]
        Starting values of parameters (e.g. the current model's), by name.
    fixed : dict of str -> float, optional [SI unit of each parameter]
        Parameters held at given values (known hardware values), by name.
    initial_states : ndarray, shape (segments, 2), optional [rad, rad/s]
        Starting (angle, rate) of the training segments, e.g. the current model's fit's; used on long records only
        (:func:`aeropend_core.diagnosis.output_error.fit_output_error`).

    Returns
    -------
    Comparison
        The output-error fit (parameters SI, ± 1σ) and its held-out evaluation: ``fit_percent`` [%],
        ``rms_error`` and ``noise_rms`` [rad], residual tests, error by regime and the worst windows.
    """
    prep = recording if isinstance(recording, PreparedRecord) else prepare(recording)
    fit = fit_model(prep, effects, start, fixed=fixed, initial_states=initial_states)
    if 'threshold_interval' in fit.extra:
        fit = _profile_threshold(prep, _place_threshold_among_heldout_levels(prep, fit), initial_states)
    return Comparison(tuple(effects), fit, evaluate(prep, fit))


def _place_threshold_among_heldout_levels(prep: PreparedRecord, fit: OutputErrorFit) -> OutputErrorFit:
    """A dead zone's threshold on the side of each held-out input level that the training part cannot decide.

    The training part pins the threshold only to the interval between two of its input levels (any value inside
    fits it equally). A held-out level inside that interval is gated or not depending on an arbitrary choice (the
    midpoint), which the held-out error would then judge as if it were a wrong model. The held-out levels split
    the interval; the sub-interval whose midpoint simulates the held-out part best is taken, and the reported
    interval narrows to it. One discrete choice among models that fit the training part equally, not a refit.
    """
    low, high = fit.extra['threshold_interval']
    gate = fit.structure.gate_parameter
    held = np.unique(np.round(prep.gate_voltage[prep.split:], 6))
    inside = held[(held > low) & (held < high)]
    if inside.size == 0:
        return fit
    edges = np.concatenate(([low], inside, [high]))
    index = prep.heldout.residual_index
    best = None
    for a, b in zip(edges[:-1], edges[1:]):
        trial = replace(fit, parameters={**fit.parameters, gate: float(0.5 * (a + b))})
        simulated = _heldout_simulation(prep, trial)
        rms = float(np.sqrt(np.mean((prep.angle[index] - simulated[index]) ** 2)))
        if np.isfinite(rms) and (best is None or rms < best[0]):
            best = (rms, trial, float(a), float(b))
    if best is None:
        return fit
    _, chosen, a, b = best
    chosen.extra = {**fit.extra, 'threshold_interval': (a, b), 'threshold_interval_training': (low, high)}
    chosen.standard_errors = {**fit.standard_errors, gate: (b - a) / math.sqrt(12.0)}
    return chosen


def _profile_threshold(prep: PreparedRecord, fit: OutputErrorFit, initial_states: np.ndarray | None) -> OutputErrorFit:
    """`fit` with its threshold's 1σ from a profile of the training cost (:mod:`threshold_profile`: the level
    spacing is no bound on a continuous input) and the threshold's doubt carried into the other parameters."""
    gate = fit.structure.gate_parameter
    held = {name: value for name, value in fit.parameters.items() if name not in fit.free_names and name != gate}

    def refit(threshold: float) -> OutputErrorFit:
        return fit_output_error(prep.train, fit.structure, fit.parameters, fixed={**held, gate: threshold},
                                max_iterations=REFIT_ITERATIONS, initial_states=initial_states,
                                covariance=False)      # the profile reads the cost and the parameters, no sigma
    refit = once_per_gate_pattern(refit, prep.train.gate_signal, gate)
    profile = threshold_profile(refit, fit, gate, 0.0, float(np.max(prep.gate_voltage[:prep.split])),
                                ranking=fit.extra.get('threshold_ranking', ()))
    errors = dict(fit.standard_errors)
    level_rule = errors.get(gate, math.nan)
    errors[gate] = max(level_rule, profile['sigma']) if math.isfinite(level_rule) else profile['sigma']
    for name, spread in profile['spread'].items():
        if name in errors and math.isfinite(errors[name]):
            errors[name] = math.hypot(errors[name], spread)
    profile['conditional_errors'] = dict(fit.standard_errors)     # the level-spacing rule, the threshold held
    return replace(fit, standard_errors=errors, extra={**fit.extra, 'threshold_profile': profile})


__all__ = ['PreparedRecord', 'Comparison', 'Evaluation', 'prepare', 'compare', 'fit_model', 'evaluate',
           'fit_percent', 'excess_error', 'ran_away', 'DIVERGED_RAD']
