"""Analysis of one sliding window of samples for the online identification (ROS-free; used by the node).

Per window (time-first arrays of shape ``(n,)``, SI units):

0. **Data quality** — :func:`aeropend_core.signals.quality.check_recording` on the window (refusals raise
   :class:`~aeropend_core.signals.quality.DataQualityError`; repairs are used and listed in ``findings``).
1. **Excitation check** — the first ``1 - holdout_fraction`` of the window (training part) must hold at least
   ``min_steps`` steps of the armature voltage and a voltage range of ``min_voltage_range`` V, and the held-out
   part must move the rod by more than a few noise levels; otherwise :class:`InsufficientDataError` says why.
2. **Weak SINDy** on the training part (:func:`aeropend_core.identify.pendulum.identify_pendulum`): the coefficients of
   ``d²angle/dt² = Σ w_j θ_j`` with standard errors and the derived parameters. Effects whose catalog record has
   a weak form enter its library.
3. **Output-error refinement** on the training part, started from the weak-SINDy values, with *every* requested
   effect (friction, drag, lag, dead zone included): the physical parameters ± 1σ.
4. **Held-out fit**: free-run simulation of the refined model over the held-out part, driven by the measured
   Va and Ia from the measured initial angle: fit % = 100·(1 − ‖y − ŷ‖/‖y − mean(y)‖) (MATLAB ``compare``
   convention, simulation, not one-step prediction), RMS error [rad] and the angle's noise RMS [rad] (the floor).

**Lost samples** (gaps in the sequence counter or in the stamps) are not filled: as in the offline diagnosis
(:func:`aeropend_core.diagnosis.compare.split_at_gaps`) the window is split at each gap into pieces; the weak form
is fitted on the training pieces together, the output-error segments and the held-out simulation restart after
each gap (from the measured state), and no residual is taken where a sample is missing. The result states the gaps
(count, lost samples, longest); a window is refused only when too little remains (more than
``MAX_LOST_FRACTION`` lost, or too little training or held-out data between the gaps).

Steps 3 and 4 are :func:`aeropend_core.diagnosis.compare.compare` — the diagnosis's own definitions, with its motor
observer — when the window is at least its minimum length (20 s); shorter windows use a plain output-error fit
(:mod:`aeropend_core.diagnosis.output_error`, multiple shooting over ~10 s segments) and the same fit % definition.

The analysis is a plain function so that it can be swapped (e.g. for the diagnosis loop's ``compare``) in one place.
"""
from __future__ import annotations

import math
import time as _time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

# the output-error segment length [s] and the fit % are the diagnosis's own (one definition of each)
from aeropend_core.diagnosis.compare import SEGMENT_SECONDS
from aeropend_core.diagnosis.compare import fit_percent as _fit_percent
from aeropend_core.model.effects import check_effect_names, get_effect
from aeropend_core.errors import AeropendError, InsufficientDataError
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, SAMPLE_TIME, RigParameters



@dataclass
class WindowResult:
    """What one window produced. Dicts map a name to ``(value, standard_error)``, SI units.

    Attributes
    ----------
    start, stop : float
        Window bounds, acquisition time [s] (same epoch as the sample stamps).
    effects : tuple of str
        Effects in the model for this window.
    coefficients : dict
        Weak-SINDy coefficients of d²angle/dt² [rad/s² per unit term] by term name.
    parameters : dict
        Physical parameters of the refined model (``gravity_stiffness`` 1/s², ``damping`` 1/s, ``thrust_gain``
        rad/s²/V², ``armature_resistance`` Ω, ``thrust_coefficient`` Kq N·s², plus each effect's parameters), in
        the one vocabulary of :mod:`aeropend_core.model.names`.
    estimators : dict
        Which estimator gave each of ``parameters`` (``'output_error'``, ``'motor_observer'``); the weak-SINDy
        values of the same quantities are in ``weak_parameters``.
    weak_parameters : dict
        The same quantities as estimated by weak SINDy on the training part (estimator ``'weak_sindy'``).
    fit_percent : float
        Held-out free-run fit [%] (100 is perfect; can be negative).
    rms_error, noise_rms : float
        Held-out RMS angle error and the angle's measurement-noise RMS [rad].
    held_out_seconds : float
        Length of the held-out part [s].
    compute_time : float
        Wall time of the analysis [s].
    method : str
        ``'compare'`` (:func:`aeropend_core.diagnosis.compare.compare`, windows of at least its 20 s)
        or ``'window'`` (this module's own output-error fit, for shorter windows).
    findings : tuple of aeropend_core.signals.quality.Finding
        What the data-quality gate repaired or warned about in this window (empty: clean).
    gap_count : int
        Gaps of lost samples in the window (each splits the fits; nothing is filled in).
    lost_samples : int
        Samples missing inside the window.
    longest_gap_seconds : float
        The longest gap [s].
    """

    start: float
    stop: float
    effects: tuple[str, ...]
    coefficients: dict[str, tuple[float, float]] = field(default_factory=dict)
    parameters: dict[str, tuple[float, float]] = field(default_factory=dict)
    fit_percent: float = float('nan')
    rms_error: float = float('nan')
    noise_rms: float = float('nan')
    held_out_seconds: float = 0.0
    compute_time: float = 0.0
    method: str = ''
    findings: tuple = ()
    estimators: dict[str, str] = field(default_factory=dict)
    weak_parameters: dict[str, tuple[float, float]] = field(default_factory=dict)
    gap_count: int = 0
    lost_samples: int = 0
    longest_gap_seconds: float = 0.0


def check_excitation(armature_voltage: np.ndarray, angle: np.ndarray, n_train: int, sample_time: float,
                     min_steps: int = 2, min_voltage_range: float = 0.05) -> None:
    """Raise :class:`InsufficientDataError` naming the problem when the window cannot identify the model."""
    from aeropend_core.signals.preprocess import detect_steps, noise_rms
    train = armature_voltage[:n_train]
    voltage_range = float(np.ptp(train)) if train.size else 0.0
    if voltage_range < min_voltage_range:
        raise InsufficientDataError(f'excitation insufficient: Va varies by {voltage_range:.3f} V '
                                    f'(< {min_voltage_range} V) in the training part; apply duty steps')
    steps = len(detect_steps(train, sample_time))
    if steps < min_steps:
        raise InsufficientDataError(f'excitation insufficient: {steps} duty step(s) in the training part '
                                    f'(need {min_steps}); use a longer window or shorter dwells')
    held = angle[n_train:]
    noise = noise_rms(held)
    if held.size < 50 or not np.std(held) > 3.0 * max(noise, 1e-6):
        raise InsufficientDataError('excitation insufficient: the rod barely moves in the held-out part, so the '
                                    'held-out fit means nothing; use a longer window or more steps')


def check_window_data(time: np.ndarray, columns: dict[str, np.ndarray], sample_time: float) -> None:
    """Refuse data the analysis would turn into wrong numbers: unequal lengths, NaN/inf or absurd values (the
    data-quality gate's rule, :func:`aeropend_core.signals.quality.require_finite`), a time axis that does not
    advance by whole numbers of `sample_time` [s] (within 1 %; a step of several samples is a gap of lost ones).
    The node passes each window through the whole gate first.

    Raises
    ------
    AeropendError
        Naming the column and how many values are bad (the node rejects such samples before they get here).
    """
    from aeropend_core.signals.quality import require_finite
    for name, values in columns.items():
        if values.shape != time.shape:
            raise AeropendError(f'{name} has {values.size} values for {time.size} times')
    require_finite(['time', *columns], [time, *columns.values()])
    steps = np.diff(time)
    whole = np.maximum(np.rint(steps / sample_time), 1.0) * sample_time
    if steps.size and (np.any(steps <= 0) or np.max(np.abs(steps - whole)) > 0.01 * sample_time):
        raise AeropendError(f'time is not uniform: steps from {steps.min():.6g} to {steps.max():.6g} s, expected '
                            f'whole multiples of {sample_time:.6g} s (a multiple is a gap of lost samples); stamp '
                            f'the samples with their sequence number x the sample time')


def analyze_window(time: np.ndarray, armature_voltage: np.ndarray, armature_current: np.ndarray,
                   angle: np.ndarray, effects: Sequence[str] = (), holdout_fraction: float = 0.25,
                   sample_time: float = SAMPLE_TIME, parameters: RigParameters = DEFAULT_PARAMETERS,
                   max_iterations: int = 30, sequence: np.ndarray | None = None) -> WindowResult:
    """Identify the pendulum on one window and score it on its held-out end (module docstring).

    Parameters
    ----------
    time : ndarray, shape (n,)
        Acquisition times [s], spaced by `sample_time` or whole multiples of it where samples were lost (gaps:
        the window is split there, nothing is filled).
    armature_voltage, armature_current, angle : ndarray, shape (n,)
        Va [V], Ia [A], angle [rad].
    effects : sequence of str
        Catalog effects in the model.
    holdout_fraction : float
        Fraction of the window (its end) kept out of the fit and used for the held-out score.
    sample_time : float
        The acquisition period [s].
    parameters : RigParameters
        Rig constants (SI) for the derived parameters.
    max_iterations : int
        Output-error iterations of the short-window fit [-].
    sequence : ndarray of int, shape (n,), optional
        The samples' sequence numbers [-]: gaps are taken from them when given (else from `time`).

    Raises
    ------
    InsufficientDataError
        Excitation too poor, or too few samples.
    """
    from aeropend_core.identify.pendulum import identify_pendulum, weak_form_effects

    started = _time.perf_counter()
    effects = check_effect_names(effects)
    time = np.asarray(time, dtype=float)
    voltage = np.asarray(armature_voltage, dtype=float)
    current = np.asarray(armature_current, dtype=float)
    angle = np.asarray(angle, dtype=float)
    check_window_data(time, {'armature_voltage': voltage, 'armature_current': current, 'angle': angle}, sample_time)
    if not 0.0 < holdout_fraction < 1.0:
        raise AeropendError(f'holdout_fraction must be in (0, 1), got {holdout_fraction}')
    # The data-quality gate (the same as for files): refusals raise, repairs are used and kept with the result.
    from aeropend_core.diagnosis.compare import split_at_gaps
    from aeropend_core.io.recording import Recording
    from aeropend_core.signals.quality import check_recording
    signals = {'armature_voltage': voltage, 'armature_current': current, 'angle': angle}
    if sequence is not None:
        sequence = np.asarray(sequence, dtype=float)
        if sequence.shape != time.shape:
            raise AeropendError(f'sequence has {sequence.size} values for {time.size} times')
        signals['sequence'] = sequence
    checked = check_recording(Recording(time, signals, source='window'), sample_time=sample_time,
                              context='window').recording
    measured_time = np.asarray(checked.time, dtype=float)
    voltage, current, angle = (checked.signals[k] for k in ('armature_voltage', 'armature_current', 'angle'))
    # Lost samples: on the sample grid, marked (never used as data); refused beyond MAX_LOST_FRACTION.
    grid_time, filled, gaps = split_at_gaps(measured_time, {'armature_voltage': voltage, 'armature_current': current,
                                                            'angle': angle}, sample_time, 'the window',
                                            checked.signals.get('sequence'))
    time = grid_time
    voltage, current, angle = filled['armature_voltage'], filled['armature_current'], filled['angle']
    n = time.size
    n_train = int(round(n * (1.0 - holdout_fraction)))
    train_pieces = gaps.pieces(0, n_train)
    held_pieces = gaps.pieces(n_train, n)
    train_seconds = sum(b - a for a, b in train_pieces) * sample_time
    held_seconds = sum(b - a for a, b in held_pieces) * sample_time
    if train_seconds < 2.0 or held_seconds < 0.5:
        lost = (f' between {gaps.count} gap(s) of lost samples ({gaps.lost} samples, the longest '
                f'{gaps.longest_seconds:.3f} s)' if gaps.count else '')
        raise InsufficientDataError(f'window of {n * sample_time:.1f} s too short: {train_seconds:.1f} s of training '
                                    f'and {held_seconds:.1f} s held out remain{lost}; need >= 2 s of training and '
                                    '0.5 s held out')
    check_excitation(voltage, angle, n_train, sample_time)

    weak_effects = [name for name in effects if name in weak_form_effects()]
    if gaps.count:      # the weak form on the training pieces between the gaps, together
        weak = identify_pendulum(*([c[a:b] for a, b in train_pieces] for c in (time, voltage, current, angle)),
                                 effects=weak_effects, parameters=parameters)
    else:
        weak = identify_pendulum(time[:n_train], voltage[:n_train], current[:n_train], angle[:n_train],
                                 effects=weak_effects, parameters=parameters)
    equation = weak.equation
    coefficients = {name: (float(value), float(equation.standard_errors.get(name, float('nan'))))
                    for name, value in equation.coefficients.items()}

    # Output-error refinement with every requested effect, started from the weak-form values (same names).
    p = weak.parameters
    start = {'gravity_stiffness': max(p.get('gravity_stiffness', 0.0), 1.0), 'damping': max(p.get('damping', 0.0), 0.1),
             'thrust_gain': max(p.get('thrust_gain', 0.0), 1.0),
             'armature_resistance': min(max(p.get('armature_resistance', 1.0), 0.1), 5.0)}
    for name in weak_effects:
        for parameter in get_effect(name).parameters:
            value = p.get(parameter.name, float('nan'))
            if math.isfinite(value):   # the fit moves starts off the bounds itself
                start[parameter.name] = float(np.clip(value, parameter.lower, parameter.upper))
    scale = (parameters.gear_ratio * parameters.back_emf_constant) ** 2 / parameters.lever_per_inertia
    if gaps.measured_seconds >= _compare_min_duration():
        values, errors, fit_percent, rms_error, noise = _held_out_by_compare(
            measured_time, voltage[gaps.valid], current[gaps.valid], angle[gaps.valid], effects, holdout_fraction,
            start, checked.signals.get('sequence'))
        method = 'compare'
    else:
        typical = {parameter.name: parameter.typical for name in effects for parameter in get_effect(name).parameters}
        values, errors, fit_percent, rms_error, noise = _held_out_by_window(
            voltage, current, angle, effects, n_train, sample_time, typical | start, max_iterations, gaps)
        method = 'window'
    values['thrust_coefficient'] = values['thrust_gain'] * scale
    errors['thrust_coefficient'] = errors.get('thrust_gain', float('nan')) * scale
    estimators = {name: 'output_error' for name in values}
    if errors.pop('armature_resistance_from_observer', False):
        estimators['armature_resistance'] = 'motor_observer'
    weak_parameters = {name: (float(p[name]), float(weak.standard_errors.get(name, float('nan'))))
                       for name in values if name in p}
    return WindowResult(
        start=float(time[0]), stop=float(time[-1] + sample_time), effects=effects, coefficients=coefficients,
        parameters={name: (float(values[name]), float(errors.get(name, float('nan')))) for name in values},
        fit_percent=float(fit_percent), rms_error=float(rms_error), noise_rms=float(noise),
        held_out_seconds=held_seconds, compute_time=_time.perf_counter() - started, method=method,
        estimators=estimators, weak_parameters=weak_parameters, findings=tuple(checked.findings),
        gap_count=gaps.count, lost_samples=gaps.lost, longest_gap_seconds=gaps.longest_seconds)


def _compare_min_duration() -> float:
    try:
        from aeropend_core.diagnosis.compare import MIN_DURATION
    except ImportError:  # pragma: no cover - the diagnosis loop is part of aeropend_core
        return float('inf')
    return float(MIN_DURATION)


def _held_out_by_compare(time, voltage, current, angle, effects, holdout_fraction, start, sequence=None):
    """Refinement and held-out score by :func:`aeropend_core.diagnosis.compare.compare` (diagnosis definitions);
    the measured samples only: gaps are split by :func:`aeropend_core.diagnosis.compare.prepare` itself."""
    from aeropend_core.diagnosis.compare import compare, prepare
    from aeropend_core.io.recording import Recording
    signals = {'armature_voltage': voltage, 'armature_current': current, 'angle': angle}
    if sequence is not None:
        signals['sequence'] = np.asarray(sequence, dtype=float)
    record = Recording(time - time[0], signals, source='the identification window')
    prepared = prepare(record, train_fraction=1.0 - holdout_fraction)
    comparison = compare(prepared, effects, start=start)
    values = dict(comparison.parameters)
    errors = dict(comparison.fit.standard_errors)
    if prepared.motor is not None:
        # With the motor observer the thrust voltage is its back-EMF (R = 0 in the pendulum model); the armature
        # resistance then comes from the observer fitted to Ia.
        values['armature_resistance'] = float(prepared.motor.parameters['motor_resistance'])
        errors['armature_resistance'] = float(prepared.motor.standard_errors.get('motor_resistance', math.nan))
        errors['armature_resistance_from_observer'] = True     # a marker for the caller's estimator table
    return values, errors, comparison.fit_percent, comparison.rms_error, comparison.noise_rms


def _held_out_by_window(voltage, current, angle, effects, n_train, sample_time, start, max_iterations, gaps):
    """Output-error refinement on the training part and free-run score on the rest (windows shorter than
    what :mod:`aeropend_core.diagnosis.compare` accepts); segments restart after every gap (`gaps`, a
    :class:`aeropend_core.diagnosis.compare.Gaps`), whose filled samples give no residual."""
    from aeropend_core.diagnosis import output_error as oe
    from aeropend_core.signals.preprocess import condition_inputs, noise_rms
    n = angle.size
    conditioned = condition_inputs(voltage, current, sample_time)
    cv, ci = conditioned.armature_voltage, conditioned.armature_current
    structure = oe.Structure(effects)
    step = int(round(SEGMENT_SECONDS / sample_time))
    segments = []
    for first, last in gaps.pieces(0, n_train):       # ~SEGMENT_SECONDS segments within each piece between gaps
        piece = [(s, min(s + step, last)) for s in range(first, last, step)]
        if len(piece) > 1 and piece[-1][1] - piece[-1][0] < step // 2:   # fold a short tail into its neighbour
            piece[-2:] = [(piece[-2][0], piece[-1][1])]
        segments += piece
    valid = gaps.valid if gaps.count else None
    train = oe.SegmentedData(cv[:n_train], ci[:n_train], angle[:n_train], segments, sample_time,
                             valid=None if valid is None else valid[:n_train])
    refined = oe.fit_output_error(train, structure, start, max_iterations=max_iterations)
    values = dict(refined.parameters)
    errors = dict(refined.standard_errors)
    held_segments = [(a - n_train, b - n_train) for a, b in gaps.pieces(n_train, n)]
    held = oe.SegmentedData(cv[n_train:], ci[n_train:], angle[n_train:], held_segments, sample_time)
    offset = structure.offset_parameter
    initial = oe.initial_states_from_data(held, values.get(offset, 0.0) if offset else 0.0)
    predicted = oe.simulate_angle(held, refined.parameters, structure, initial)
    landed = np.isfinite(predicted)
    if valid is not None:
        landed &= valid[n_train:]
    measured = angle[n_train:][landed]
    error = predicted[landed] - measured
    fit_percent = _fit_percent(measured, predicted[landed])
    held_measured = angle[n_train:] if valid is None else angle[n_train:][valid[n_train:]]
    return values, errors, fit_percent, float(np.sqrt(np.mean(error ** 2))), noise_rms(held_measured)


class ParameterTrends:
    """The diagnosis's drift test (:func:`aeropend_core.diagnosis.drift.trend_test`) over the online windows.

    Consecutive windows overlap (a 25 s window every 5 s), so their estimates are not independent: the trend is
    tested on windows that do not overlap (the latest one and every earlier one ending before the next kept one
    starts). The history restarts when the set of parameter names changes (the model's effects changed).

    Parameters
    ----------
    window_seconds : float
        Length of the windows [s] (the node's ``window_s``).
    """

    def __init__(self, window_seconds: float = 25.0) -> None:
        self.window_seconds = float(window_seconds)
        self.history: list[tuple[float, dict[str, float]]] = []

    def reset(self, window_seconds: float | None = None) -> None:
        """Forget the history (the source restarted, the model changed), optionally with a new window length [s]."""
        self.history = []
        if window_seconds is not None:
            self.window_seconds = float(window_seconds)

    def add(self, stop: float, values: dict[str, tuple[float, float] | float]) -> dict[str, dict]:
        """Add the window ending at `stop` [s]; returns ``{name: trend row}`` (``drifting`` flags a drift)."""
        from aeropend_core.diagnosis.drift import trend_test
        plain = {name: float(v[0] if isinstance(v, tuple) else v) for name, v in values.items()}
        if self.history and set(self.history[-1][1]) != set(plain):
            self.history = []
        self.history.append((float(stop), plain))
        kept = self._kept()
        times = np.array([t - 0.5 * self.window_seconds for t, _ in kept])
        return {name: trend_test(times, np.array([row[name] for _, row in kept]), name) for name in plain}

    def _kept(self) -> list[tuple[float, dict[str, float]]]:
        kept = [self.history[-1]]
        for stop_time, row in reversed(self.history[:-1]):
            if stop_time <= kept[-1][0] - self.window_seconds:
                kept.append((stop_time, row))
        kept.reverse()
        return kept

    def tested_stops(self) -> list[float]:
        """Ends [s] of the windows the last trend was tested on (the latest and the earlier ones that do not
        overlap), oldest first; empty before the first window."""
        return [stop for stop, _ in self._kept()] if self.history else []


#: Parameters whose trend the online identification tests (the nominal ones; the derived thrust_coefficient moves
#: with thrust_gain and would count the same drift twice).
TREND_PARAMETERS = ('gravity_stiffness', 'damping', 'thrust_gain', 'armature_resistance')


def trend_message(rows: dict[str, dict], units: dict[str, str] | None = None) -> str:
    """The drift sentence of the online windows, e.g. "parameter drift: thrust gain -15 % over 120 s (...)" with the
    likely causes; '' when no row drifts.

    Parameters
    ----------
    rows : dict
        ``{name: trend row}`` from :meth:`ParameterTrends.add` [-].
    units : dict, optional
        ``{name: SI unit}`` for the start and end values [-].
    """
    from aeropend_core.diagnosis.drift import CAUSES
    drifting = [row for row in rows.values() if row.get('drifting')]
    if not drifting:
        return ''
    units = units or {}
    parts, causes = [], []
    for row in drifting:
        label = row['parameter'].replace('_', ' ')
        unit = units.get(row['parameter'], '')
        parts.append(f'{label} {row["change"] * 100:+.0f} % over {row["span"]:.0f} s ({row["start"]:.4g} -> '
                     f'{row["end"]:.4g}{" " + unit if unit else ""}, trend t = {row["t_statistic"]:+.1f}, p = '
                     f'{row["p_value"]:.1g}, over {row["stretches"]} windows that do not overlap)')
        causes.append(f'{label}: {CAUSES.get(row["parameter"], "unknown")}')
    return 'parameter drift: ' + '; '.join(parts) + '. Likely causes: ' + '; '.join(causes) + '.'


def trend_text(row: dict) -> str:
    """One trend row in a few words: '-15.2 % over 120 s, t = -9.1, p = 1e-05, 6 windows' ('' before 4 windows)."""
    if row.get('stretches', 0) < 4 or not math.isfinite(row.get('change', float('nan'))):
        return ''
    return (f'{row["change"] * 100:+.1f} % over {row["span"]:.0f} s, t = {row["t_statistic"]:+.1f}, p = '
            f'{row["p_value"]:.1g}, {row["stretches"]} windows' + (', DRIFT' if row['drifting'] else ''))
