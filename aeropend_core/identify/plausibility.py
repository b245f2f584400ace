"""Never an impossible number: every identified parameter checked against its physical sign and range and, where
cheap, against an independent estimate.

* **Sign and range** (:data:`PHYSICAL_RANGES`): mgd/J > 0 (the rod hangs), c/J >= 0 (a pivot does not push), a
  thrust gain > 0 (the propeller lifts at positive duty), an armature resistance between 0.05 and 20 ohm; an effect
  parameter within its catalog record's bounds and not pinned at one of them.
* **Free oscillation** (:func:`free_oscillation`): after each duty step the input is constant, so each interval
  between steps is fitted by equation error as ``y'' = -a sin y - b y' + c`` (smoothed derivatives, Savitzky-Golay
  over ~0.12 s). The median over the intervals estimates mgd/J (a) and c/J (b) with no thrust model at all. It is
  informative only where the rod rings after a step: with a heavy damping ratio (b / (2 sqrt a) above
  :data:`RINGING_DAMPING_RATIO`) or a thrust that still rises through the interval (a slow motor), the interval is
  not free and the estimate is biased low; it is then reported as not informative and not used. Because of that
  bias the comparison is one-sided (:data:`AGREEMENT_RATIO`): an identified value far *below* it fails.
  **Its premise** (a constant thrust after each step) is checked against the fit (:func:`check_premise`): when the
  fitted model's thrust lags the input by a time constant above :data:`PREMISE_LAG_RATIO` of the pendulum's
  period, the thrust still changes through much of each swing, so the estimate is shown as *not used*, with the
  reason, in the text, the JSON (``used``, ``premise``) and the report.

:func:`check_parameters` returns one warning per failing parameter; callers print it next to the number (text,
JSON, report, topic), and the verdict then says the model does not fit this data.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

#: Physical (lower, upper) bounds of the nominal parameters, SI; None: unbounded on that side. Exclusive below for
#: quantities that must be positive.
PHYSICAL_RANGES: dict[str, tuple[float | None, float | None, str]] = {
    'gravity_stiffness': (0.0, 5000.0, 'mgd/J must be positive (the rod hangs down without thrust); above 5000 '
                                       '1/s^2 the rod would swing faster than 11 Hz'),
    'damping': (0.0, 500.0, 'c/J cannot be negative (a pivot does not push the rod)'),
    'thrust_gain': (0.0, None, 'the thrust gain must be positive (the propeller lifts the rod at positive duty)'),
    'thrust_coefficient': (0.0, None, 'Kq must be positive (the propeller lifts the rod at positive duty)'),
    'armature_resistance': (0.05, 20.0, 'a small DC motor\'s armature resistance lies between 0.05 and 20 ohm'),
}
#: Free-oscillation estimates are used only where the damping ratio b / (2 sqrt(a)) is below this (the rod rings).
RINGING_DAMPING_RATIO = 0.4
#: ... from at least this many intervals between steps ...
MIN_INTERVALS = 5
#: ... whose estimates of a spread by less than this (interquartile range over median).
MAX_RELATIVE_SPREAD = 0.6
#: An identified value disagrees with the independent one below this ratio (identified / independent). One-sided:
#: a thrust that still rises (or decays) through the interval after a step biases the free-oscillation estimates
#: low (on the default simulated rig, motor lag 0.3 s: mgd/J 43 against 131.75, c/J 6.3 against 13.8), so only an
#: identified value well below them is evidence that the model does not fit.
AGREEMENT_RATIO = {'gravity_stiffness': 0.6, 'damping': 0.4}
#: The free-oscillation premise (constant thrust after a step) fails when the fitted thrust time constant exceeds
#: this share of the pendulum's period 2 pi / sqrt(mgd/J): the thrust then settles (3 time constants) only after
#: about a third of a swing or later, and the fit of ``y'' = -a sin y - b y' + c`` takes the rising thrust for a
#: weaker restoring term (on a record with a 0.15 s lag it gave mgd/J ~ 18 for a fitted 127).
PREMISE_LAG_RATIO = 0.1


@dataclass(frozen=True)
class FreeOscillation:
    """The free-oscillation estimate of mgd/J and c/J (:func:`free_oscillation`).

    Attributes
    ----------
    gravity_stiffness, damping : float [1/s^2], [1/s]
        Medians over the intervals between duty steps.
    quartiles : dict of str -> (float, float) [SI]
        Interquartile range of each.
    intervals : int [-]
        Intervals fitted.
    informative : bool [-]
        Whether the estimate may be compared with an identified value (the rod rings, enough intervals, a
        consistent spread).
    reason : str [-]
        Why not, when not informative.
    """

    gravity_stiffness: float
    damping: float
    quartiles: dict = field(default_factory=dict)
    intervals: int = 0
    informative: bool = False
    reason: str = ''
    #: How its premise was checked against the fitted model (empty: not checked), :func:`check_premise`.
    premise: str = ''

    def to_dict(self) -> dict:
        """JSON form (SI; NaN as None)."""
        def clean(v):
            return float(v) if v is not None and math.isfinite(v) else None
        return {'gravity_stiffness': clean(self.gravity_stiffness), 'damping': clean(self.damping),
                'quartiles': {k: [clean(a), clean(b)] for k, (a, b) in self.quartiles.items()},
                'intervals': self.intervals, 'informative': self.informative, 'reason': self.reason,
                'used': self.informative, 'premise': self.premise,
                'model': "y'' = -a sin y - b y' + c after each duty step (equation error)"}

    def describe(self) -> str:
        """One line for the text outputs."""
        q = self.quartiles
        if not self.intervals:
            return f'free-oscillation check: {self.reason}'
        text = (f'free-oscillation check ({self.intervals} intervals between duty steps): mgd/J ~ '
                f'{self.gravity_stiffness:.4g} 1/s^2 (IQR {q["gravity_stiffness"][0]:.3g}-'
                f'{q["gravity_stiffness"][1]:.3g}), c/J ~ {self.damping:.3g} 1/s (IQR {q["damping"][0]:.3g}-'
                f'{q["damping"][1]:.3g})')
        return text + ('' if self.informative else f'; not used: {self.reason}')


def free_oscillation(time: np.ndarray, angle: np.ndarray, input_signal: np.ndarray,
                     step_indices: np.ndarray | None = None) -> FreeOscillation:
    """Estimate mgd/J and c/J from the free oscillation after each input step (module docstring).

    Parameters
    ----------
    time : ndarray, shape (n,) [s]
        Uniform sample times.
    angle : ndarray, shape (n,) [rad]
        Measured angle.
    input_signal : ndarray, shape (n,) [V or 1]
        The held input (Va or the duty), to find the steps when `step_indices` is None.
    step_indices : ndarray of int, optional [samples]
        Where the input steps.

    Returns
    -------
    FreeOscillation
        Medians, quartiles and whether the estimate is informative.
    """
    from aeropend_core.signals.filters import savgol_filter
    from aeropend_core.signals.preprocess import detect_steps
    time, angle = np.asarray(time, dtype=float), np.asarray(angle, dtype=float)
    nan = float('nan')
    if time.size < 20:
        return FreeOscillation(nan, nan, reason='too few samples')
    dt = float(np.median(np.diff(time)))
    if step_indices is None:
        step_indices = detect_steps(np.asarray(input_signal, dtype=float), dt)
    window = max(5, int(round(0.12 / dt)) | 1)
    if window >= time.size:
        return FreeOscillation(nan, nan, reason='record shorter than the smoothing window')
    y = savgol_filter(angle, window, 3)
    dy = savgol_filter(angle, window, 3, deriv=1, delta=dt)
    ddy = savgol_filter(angle, window, 3, deriv=2, delta=dt)
    bounds = np.concatenate(([0], np.asarray(step_indices, dtype=int), [time.size]))
    a_values, b_values = [], []
    for start, stop in zip(bounds[:-1], bounds[1:]):
        first, last = start + window // 2, stop - window // 2
        if last - first < max(10, 2 * window):
            continue
        regressors = np.column_stack([-np.sin(y[first:last]), -dy[first:last], np.ones(last - first)])
        if np.linalg.matrix_rank(regressors) < 3:
            continue
        coef, *_ = np.linalg.lstsq(regressors, ddy[first:last], rcond=None)
        a_values.append(coef[0])
        b_values.append(coef[1])
    if not a_values:
        return FreeOscillation(nan, nan, reason='no interval between duty steps is long enough')
    a_q = np.percentile(a_values, [25, 50, 75])
    b_q = np.percentile(b_values, [25, 50, 75])
    quartiles = {'gravity_stiffness': (float(a_q[0]), float(a_q[2])), 'damping': (float(b_q[0]), float(b_q[2]))}
    a, b = float(a_q[1]), float(b_q[1])
    reason = ''
    if len(a_values) < MIN_INTERVALS:
        reason = f'only {len(a_values)} intervals (need {MIN_INTERVALS})'
    elif not a > 0:
        reason = 'the intervals do not show a restoring swing'
    elif b / (2 * math.sqrt(a)) > RINGING_DAMPING_RATIO:
        reason = (f'the swings are too damped (damping ratio ~{b / (2 * math.sqrt(a)):.2f} > '
                  f'{RINGING_DAMPING_RATIO}): a thrust that still rises after the step biases it')
    elif (a_q[2] - a_q[0]) / a > MAX_RELATIVE_SPREAD:
        reason = f'the intervals disagree (IQR {100 * (a_q[2] - a_q[0]) / a:.0f} % of the median)'
    return FreeOscillation(a, b, quartiles, len(a_values), not reason, reason)


def check_premise(independent: FreeOscillation, thrust_time_constant: float | None, gravity_stiffness: float | None,
                  source: str = 'the fit') -> FreeOscillation:
    """`independent` with its premise checked against a fitted thrust lag (module docstring): not used, with the
    reason, when the lag exceeds :data:`PREMISE_LAG_RATIO` of the pendulum's period.

    Parameters
    ----------
    independent : FreeOscillation
        The estimate.
    thrust_time_constant : float or None [s]
        The thrust's fitted first-order time constant (None or 0: the fit finds no lag).
    gravity_stiffness : float or None [1/s^2]
        The fitted mgd/J that sets the pendulum's period.
    source : str [-]
        Which fit found the lag, for the reason.

    Returns
    -------
    FreeOscillation
        The same estimate, ``premise`` said and, when the premise fails, ``informative`` False with the reason.
    """
    tau = thrust_time_constant
    if not independent.intervals or tau is None or not math.isfinite(tau) or tau <= 0 or gravity_stiffness is None \
            or not math.isfinite(gravity_stiffness) or gravity_stiffness <= 0:
        return replace(independent, premise='constant thrust after each step: no thrust lag fitted')
    period = 2 * math.pi / math.sqrt(gravity_stiffness)
    premise = (f'constant thrust after each step: {source} finds a thrust time constant of {tau:.3g} s, '
               f'{tau / period:.2f} of the pendulum period {period:.3g} s (premise holds up to {PREMISE_LAG_RATIO})')
    if tau <= PREMISE_LAG_RATIO * period:
        return replace(independent, premise=premise)
    reason = (f'its premise fails: it assumes the thrust is constant after each duty step, but {source} finds the '
              f'thrust lags with a time constant of {tau:.3g} s ({tau / period:.2f} of the {period:.3g} s pendulum '
              'period), so the thrust still rises through the swing and biases the estimate low')
    return replace(independent, informative=False, reason=reason, premise=premise)


def pinned_at_bound(name: str, value: float) -> bool:
    """True when the effect parameter `name` sits on a bound of its catalog range (within 1e-6 of the span; a
    lower bound of 0, the effect absent, does not count; before session 21 such a parameter was not checked at its
    upper bound either): the data want it beyond the range, its value is not determined and a 1-sigma from the
    fit's curvature there means nothing (a filter delay on its 50 ms bound came out +- 3 ms, z +5 against the
    truth, unsaid; bench/results/2026-12-07-s21-observer)."""
    from aeropend_core.model.effects import find_parameter
    found = find_parameter(name)
    if found is None or value is None or not math.isfinite(value):
        return False
    record = found[1]
    span = record.upper - record.lower
    if not record.lower <= value <= record.upper:
        return False
    return bool((record.lower != 0.0 and value - record.lower < 1e-6 * span) or record.upper - value < 1e-6 * span)


def check_parameters(parameters: Mapping[str, float], standard_errors: Mapping[str, float] | None = None,
                     independent: FreeOscillation | None = None,
                     fitted: set[str] | None = None) -> dict[str, str]:
    """The warnings of parameters that fail a physical check (name -> text; empty when all pass).

    Parameters
    ----------
    parameters : mapping of str -> float [SI]
        Identified values (nominal names, catalog effect parameter names, derived names).
    standard_errors : mapping of str -> float, optional [SI]
        Their 1σ (a value whose interval reaches into the allowed range is flagged less strongly).
    independent : FreeOscillation, optional
        The free-oscillation estimate; compared only when informative.
    fitted : set of str, optional [-]
        Names that were fitted (others, e.g. held at 0 by the model, are not checked); default all.

    Returns
    -------
    dict of str -> str
        Warning per failing parameter.
    """
    from aeropend_core.model.effects import find_parameter
    standard_errors = standard_errors or {}
    warnings: dict[str, str] = {}
    for name, value in parameters.items():
        if fitted is not None and name not in fitted:
            continue
        if value is None or not math.isfinite(value):
            warnings[name] = 'not a finite number: not identified from this data'
            continue
        if name in PHYSICAL_RANGES:
            lower, upper, why = PHYSICAL_RANGES[name]
            if (lower is not None and value <= lower) or (upper is not None and value > upper):
                warnings[name] = f'IMPOSSIBLE: {why}; the model does not fit this data'
            continue
        found = find_parameter(name)
        if found is None:
            continue
        record = found[1]
        if value < record.lower or value > record.upper:
            warnings[name] = f'outside its physical range [{record.lower:g}, {record.upper:g}] {record.unit}'
        elif pinned_at_bound(name, value):
            warnings[name] = f'at the bound of its range [{record.lower:g}, {record.upper:g}] {record.unit}: not ' \
                             'determined by this data'
    if independent is not None and independent.informative:
        for name, low in AGREEMENT_RATIO.items():
            value, reference = parameters.get(name), getattr(independent, name)
            if name in warnings or value is None or not math.isfinite(value) or not reference > 0:
                continue
            if value / reference < low:
                q = independent.quartiles[name]
                warnings[name] = (f'disagrees with the free oscillation after the duty steps ({reference:.3g}, IQR '
                                  f'{q[0]:.3g}-{q[1]:.3g}): the model does not fit this data')
    return warnings


def verdict_line(warnings: Mapping[str, str]) -> str:
    """The verdict when parameters fail (empty when none does)."""
    if not warnings:
        return ''
    return (f'THE MODEL DOES NOT FIT THIS DATA: {", ".join(warnings)} '
            f'{"fails" if len(warnings) == 1 else "fail"} a physical check (see the warnings next to '
            f'{"it" if len(warnings) == 1 else "them"}); do not use these numbers')


#: An armature resistance within this factor of the rig's stated one raises no doubt (a motor of the same kind).
RESISTANCE_RATIO = 1.5
#: ... nor one within this many combined standard errors of it.
RESISTANCE_SIGMAS = 4.0


def current_scale_ratio(motor_parameters: Mapping[str, float], rig=None) -> float:
    """How many times too small the recorded current reads, by the motor observer's own consistency [-].

    The observer fits ``de/dt = p1 (Va - e) - ...`` and ``Ia = (Va - e) / Rm`` (:mod:`aeropend_core.signals.motor`)
    with ``p1 = Kw Kt / (Jm Rm)``. The back-EMF's dynamics (p1) do not depend on the current's scale; Rm does: a
    current recorded k times too small gives Rm k times too large and the same p1. So ``p1 Rm Jm / (Kw Kt)`` is 1
    for a current in amperes on the stated motor, and k for one off by k, whatever the true Ra.

    Parameters
    ----------
    motor_parameters : mapping of str -> float [SI]
        The observer's ``motor_drive_rate`` [1/s] and ``motor_resistance`` [ohm].
    rig : RigParameters, optional
        The motor's stated Kw [V s/rad], Kt [N m/A], Jm [kg m^2] (default: the paper's rig).

    Returns
    -------
    float
        The ratio (nan when the observer gives none).
    """
    from aeropend_core.model.parameters import DEFAULT_PARAMETERS
    rig = rig or DEFAULT_PARAMETERS
    drive, resistance = motor_parameters.get('motor_drive_rate'), motor_parameters.get('motor_resistance')
    if drive is None or resistance is None or not (math.isfinite(drive) and math.isfinite(resistance)):
        return math.nan
    return drive * resistance * rig.motor_inertia / (rig.back_emf_constant * rig.torque_constant)


def resistance_doubt(value: float, sigma: float, scale_ratio: float = math.nan, stated: float | None = None,
                     stated_sigma: float | None = None, source: str = "the paper's rig, locked-rotor test") -> str:
    """The doubt on an armature resistance far from the rig's stated one ('' when none), to print beside it.

    A current recorded in the wrong unit or scale (ADC counts declared as mA, a sense resistor or amplifier gain
    mis-set) scales the observer's resistance by the same factor and fits Ia as well: Ra = 3.18 ohm for a truth of
    1.08 with counts read as mA. Neither the fit nor its ± can show it; the stated value and the observer's
    consistency (:func:`current_scale_ratio`) can.

    Parameters
    ----------
    value, sigma : float [ohm]
        The observer's Ra and its 1σ.
    scale_ratio : float [-]
        :func:`current_scale_ratio` (nan: not known).
    stated, stated_sigma : float, optional [ohm]
        The rig's stated Ra and its 1σ (default: the paper's 1.08 ± 0.04 ohm).
    source : str [-]
        Where the stated value comes from, for the text.

    Returns
    -------
    str
        One sentence without a final full stop, or '' when the value raises no doubt.
    """
    from aeropend_core.model.parameters import DEFAULT_PARAMETERS
    stated = DEFAULT_PARAMETERS.armature_resistance if stated is None else stated
    stated_sigma = 0.04 if stated_sigma is None else stated_sigma
    if not (math.isfinite(value) and value > 0 and stated > 0):
        return ''
    ratio = value / stated
    combined = math.hypot(sigma if math.isfinite(sigma) else 0.0, stated_sigma)
    if 1 / RESISTANCE_RATIO <= ratio <= RESISTANCE_RATIO or abs(value - stated) <= RESISTANCE_SIGMAS * combined:
        return ''
    text = (f'DOUBT: {ratio:.3g} x the stated {stated:.3g} ohm ({source}); a recorded current {1 / ratio:.3g} x '
            'the true one (ADC counts declared as mA, a sense resistor or gain mis-set) gives exactly this and fits '
            'Ia as well, so neither the fit nor its +- can show it')
    if math.isfinite(scale_ratio) and abs(math.log(scale_ratio / ratio)) < math.log(RESISTANCE_RATIO):
        text += (f'; the motor observer agrees: its drive rate times Ra puts the recorded current at '
                 f'{1 / scale_ratio:.3g} x the true one for the stated motor')
    elif math.isfinite(scale_ratio) and abs(math.log(scale_ratio)) < math.log(RESISTANCE_RATIO):
        text += (f'; the motor observer finds the current\'s scale right ({scale_ratio:.2f} x), so this motor\'s '
                 'resistance may really differ from the stated one')
    return text + ('; check the current\'s scale (the log profile\'s scale/unit, `aeropend calibrate`) before '
                   'using this Ra')
