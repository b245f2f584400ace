"""Discovery in the motor equation: a term outside the model of the armature circuit, found where the current is
measured, and proven like a catalog effect.

A part of the discovery stage (:mod:`aeropend_core.diagnosis.discovery`), run by the diagnosis whenever the armature
current is recorded: the motor observer (:mod:`aeropend_core.signals.motor`: ``tau_e dIa/dt = (Va - e)/R - Ia``,
``de/dt = q1 Ia - p2 e - p3 e|e|``) may miss a voltage in the armature circuit, and then biases the thrust the
pendulum sees. Records without the current (the reduced model) skip it and say so. Steps:

1. **States from the observer.** Its simulated current ``current`` [A] and back-EMF ``back_emf`` [V] (the motor
   speed times Kw), the dissipated-power proxy ``heat`` [A^2] (the modelled current squared through a
   :data:`HEATING_TIME` lag) and the time ``time`` [s] from the record's middle. No derivative of noisy data.
2. **Sparse regression.** The armature equation ``dIa/dt = (Va - R Ia - e)/La + (1/La) Σ c_k θ_k`` is regressed in
   weak form (the project's WSINDy: test functions, GLS noise model with the current's noise, MSTLS) with Va, Ia and
   e kept and each typed term θ_k of :data:`MOTOR_VOCABULARY` alone (nearly collinear terms split the evidence
   jointly); a term must pass the weak form's significance test (:data:`SIGNIFICANCE`, Bonferroni over the terms).
   This screen is the gate: when no term passes, nothing is refitted (a clean motor costs about 2 s for 60 s).
3. **Proof.** The strongest (at most :data:`MAX_REFITS`) are each added to the observer as a voltage in the armature
   circuit, ``La dIa/dt = Va - R Ia - e + c θ``, and the observer is refitted by output error on the training part
   (before the diagnosis's split) with and without it; judged by the catalog's evidence
   (:mod:`aeropend_core.diagnosis.candidates`' thresholds): the HAC t of ``c``, the training BIC with the effective
   sample count, the held-out Diebold--Mariano statistic of the current's error and materiality (the held-out
   mean-square error falls by more than (``MATERIAL`` x the current's noise)^2).

The proven term is reported with ``c ± σ`` [SI], the current's held-out error beyond its noise before -> after and a
physical reading; :func:`pendulum_with_term` rebuilds the pendulum's thrust input from the corrected observer and
refits the pendulum, so the verdict can say how much of the angle's error the motor term explains. Its ``add``
(``--motor-term EXPRESSION``) puts it in the observer for the whole diagnosis (:func:`with_motor_term`: the pendulum
is then fitted with the corrected back-EMF as its thrust input, and the search reports the term instead of searching
a second one). A record longer than :data:`WINDOW_SECONDS` is searched on a window around its split (the pendulum is
then not refitted).

The coefficient's σ is a sandwich with the scores summed over each interval of one Va level, plus the spread the
stepped Va levels' own errors cause (:func:`_fit`: level by level, or by a seeded ensemble of all levels moved at
once where Va has too many levels to move one by one, e.g. a chirp); bench/bench_motor_coverage.py checks it
against known truth.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numba
import numpy as np
from scipy.optimize import least_squares
from threadpoolctl import threadpool_limits

from aeropend_core.diagnosis.candidates import BIC_MARGIN, DM_MIN, DM_WEAK, MAJOR_SHARE, MATERIAL, T_MIN
from aeropend_core.diagnosis.compare import PreparedRecord, excess_error
from aeropend_core.diagnosis.evidence import TermEvidence, finite_or_none, screening_doubt
from aeropend_core.diagnosis.motor_terms import MOTOR_VOCABULARY, AddedMotorTerm, MotorTerm
from aeropend_core.errors import AeropendError, InsufficientDataError
from aeropend_core.signals.filters import first_order_lag
from aeropend_core.signals.motor import interval_of_samples, moved_levels
from aeropend_core.stats import diebold_mariano, effective_samples, hac_covariance, input_covariance

#: Time constant [s] of the dissipated-power proxy (the winding's thermal lag; tens of seconds for a small motor).
HEATING_TIME = 30.0
#: Current scale [A] of the smooth sign of the current.
CURRENT_SMOOTHING = 0.01
#: At most this many terms are refitted by output error.
MAX_REFITS = 2
#: Family-wise significance of the weak-form screening (Bonferroni over the terms screened one at a time).
SIGNIFICANCE = 0.01
#: Half-width of the weak-form test functions [s] (the current's quasi-static balance; ~40 samples at 490 Hz).
TEST_HALF_WIDTH = 0.08
#: Function evaluations of one observer refit.
MAX_EVALUATIONS = 15
#: RK4 sub-steps per sample (as the observer with the inductance).
SUBSTEPS = 8


@numba.njit(cache=True, nogil=True, inline='always')
def _term_value(code, i, e, slow):
    if code == 0:
        return 1.0
    if code == 1:
        return math.tanh(i / CURRENT_SMOOTHING)
    if code == 2:
        return i * e
    if code == 3:
        return e * e
    if code == 4:
        return i * i
    if code == 5 or code == 6:
        return slow * i
    return 0.0


@numba.njit(cache=True, nogil=True)
def _columns(code, current, emf, slow):
    out = np.empty(current.shape[0])
    for k in range(current.shape[0]):
        out[k] = _term_value(code, current[k], emf[k], slow[k])
    return out


@numba.njit(cache=True, nogil=True, inline='always')
def _derivatives(r, tau, q1, p2, p3, code, c, v, slow, i, e):
    di = ((v - e + c * _term_value(code, i, e, slow)) / r - i) / tau
    de = q1 * i - p2 * e - p3 * e * abs(e)
    return di, de


@numba.njit(cache=True, nogil=True)
def _observer_kernel(x, code, voltage, slow, switch, sample_time, substeps, out_current, out_emf):
    """RK4 of the observer with the armature inductance and one extra voltage ``c θ`` (x: R, tau, q1, p2, p3, Ia0,
    e0, c); Va changes to voltage[k + 1] at the fraction switch[k] of interval k (as the observer's kernel)."""
    r, tau, q1, p2, p3, c = x[0], x[1], x[2], x[3], x[4], x[7]
    i, e = x[5], x[6]
    n = voltage.shape[0]
    for k in range(n):
        out_current[k] = i
        out_emf[k] = e
        s = slow[k]
        for q in range(substeps):
            start, stop = q / substeps, (q + 1) / substeps
            if start < switch[k] < stop:
                pieces = ((start, switch[k]), (switch[k], stop))
            else:
                pieces = ((start, stop), (stop, stop))
            for a, b in pieces:
                h = (b - a) * sample_time
                if h <= 0.0:
                    continue
                v = voltage[k + 1] if (a >= switch[k] - 1e-12 and k + 1 < n) else voltage[k]
                d1i, d1e = _derivatives(r, tau, q1, p2, p3, code, c, v, s, i, e)
                d2i, d2e = _derivatives(r, tau, q1, p2, p3, code, c, v, s, i + 0.5 * h * d1i, e + 0.5 * h * d1e)
                d3i, d3e = _derivatives(r, tau, q1, p2, p3, code, c, v, s, i + 0.5 * h * d2i, e + 0.5 * h * d2e)
                d4i, d4e = _derivatives(r, tau, q1, p2, p3, code, c, v, s, i + h * d3i, e + h * d3e)
                i = i + h / 6.0 * (d1i + 2.0 * d2i + 2.0 * d3i + d4i)
                e = e + h / 6.0 * (d1e + 2.0 * d2e + 2.0 * d3e + d4e)


@dataclass
class MotorFitResult:
    """One output-error fit of the observer (with or without a term) on the training part."""

    solution: np.ndarray
    current: np.ndarray
    back_emf: np.ndarray
    train_rms: float
    heldout_error: np.ndarray
    effective: float
    covariance: np.ndarray


@dataclass(kw_only=True)
class MotorDiscoveredTerm(TermEvidence):
    """A motor-equation term the search reports, with its evidence (:class:`TermEvidence`, currents in A;
    coefficients SI).

    ``status``: ``'proven'`` (the catalog's evidence holds) or ``'not_proven'`` (``why_not`` says why).
    """

    term: MotorTerm
    equation_of: str = 'motor'
    #: The pendulum's held-out angle error beyond the noise [rad] with the observer as fitted, and with the thrust
    #: input rebuilt from the observer corrected by this term (:func:`pendulum_with_term`; nan: not refitted).
    pendulum_excess_before: float = math.nan
    pendulum_excess_after: float = math.nan
    #: The corrected observer's back-EMF [V] (n,) and state vector (R, tau_e, q1, p2, p3, Ia0, e0, c).
    back_emf: np.ndarray | None = field(default=None, repr=False)
    solution: np.ndarray | None = field(default=None, repr=False)

    @property
    def add(self) -> list[str]:
        """Command-line arguments that put it in the motor observer (``aeropend diagnose FILE --motor-term ...``)."""
        return ['--motor-term', self.term.expression]

    def to_dict(self) -> dict:
        value, sigma = self.coefficient()
        return {'expression': self.term.expression, 'status': self.status, 'reading': self.term.reading,
                'equation_of': 'motor', 'equation': self.term.equation,
                'parameters': {f'motor_{self.term.slug}_coefficient': {
                    'value': finite_or_none(value), 'sigma': finite_or_none(sigma), 'unit': self.term.unit}},
                'estimator': 'output_error_on_current' if self.refitted else 'weak_sindy',
                'signal': 'armature_current', 'error_unit': 'A',
                **self.evidence_dict(),
                'pendulum_error_beyond_noise_before': finite_or_none(self.pendulum_excess_before),
                'pendulum_error_beyond_noise_after': finite_or_none(self.pendulum_excess_after),
                'why_not_proven': self.why_not, 'add': self.add}


@dataclass
class MotorDiscovery:
    """Outcome of :func:`discover_motor`: the terms tried (best first); ``note`` says why nothing ran, if so."""

    terms: list[MotorDiscoveredTerm] = field(default_factory=list)
    note: str = ''
    noise_rms: float = math.nan
    excess_before: float = math.nan
    #: The term given with ``--motor-term`` (:class:`AddedMotorTerm`), in the observer before the search.
    added: AddedMotorTerm | None = None

    @property
    def proven(self) -> list[MotorDiscoveredTerm]:
        return [t for t in self.terms if t.status == 'proven']

    def to_dict(self) -> dict:
        out = {'note': self.note, 'current_noise_rms': self.noise_rms if math.isfinite(self.noise_rms) else None,
               'current_error_beyond_noise': self.excess_before if math.isfinite(self.excess_before) else None,
               'terms': [t.to_dict() for t in self.terms]}
        if self.added is not None:
            out['added_term'] = self.added.to_dict()
        return out


def motor_term_of(text: str) -> MotorTerm:
    """The vocabulary's term written `text` (spaces ignored); AeropendError naming the accepted terms otherwise.

    Parameters
    ----------
    text : str [-]
        An expression of :data:`MOTOR_VOCABULARY`, e.g. ``'sign(current)'``.

    Returns
    -------
    MotorTerm
    """
    wanted = ''.join(str(text).split())
    for term in MOTOR_VOCABULARY:
        if term.expression == wanted:
            return term
    raise AeropendError(f'--motor-term {text!r} is not a motor term; give one of '
                        f'{", ".join(repr(t.expression) for t in MOTOR_VOCABULARY)} (the expressions of '
                        f'"discovered_motor_terms" in aeropend diagnose --json)')


def _lagged(signal: np.ndarray, time_constant: float, sample_time: float) -> np.ndarray:
    decay = math.exp(-sample_time / time_constant)
    return first_order_lag(signal, decay)


def _starting_observer(prep: PreparedRecord):
    """The observer's state vector (R, tau, q1, p2, p3, Ia0, e0), the stepped Va and the switch positions."""
    from aeropend_core.signals.motor import fit_motor
    from aeropend_core.signals.preprocess import step_switches
    voltage = np.asarray(prep.gate_voltage, dtype=float)
    motor = prep.motor
    switch = motor.switch if motor is not None and motor.switch is not None else step_switches(
        prep.step_indices, voltage.size, prep.sample_time)
    if motor is None:       # the observer was not adequate: fit it again (its fit is the base of the search)
        try:
            motor = fit_motor(voltage, prep.armature_current, prep.step_indices, prep.sample_time, switch)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError):
            return None
        if motor.switch is not None:
            switch = motor.switch
    x = np.asarray(motor.solution, dtype=float)
    if motor.kind != 'inductance':      # p1, p2, p3, R, e0 -> R, tau, q1, p2, p3, Ia0, e0
        x = np.array([x[3], 2e-3, x[0] * x[3], x[1], x[2], float(prep.armature_current[0]), x[4]])
    return x, voltage, np.asarray(switch, dtype=float), motor.current_noise_rms


#: A longer record is searched on a window of this length [s] around its split (80 % before it): the observer is
#: simulated from the window's start, its state there taken from the observer's run over the whole record.
WINDOW_SECONDS = 300.0


def _window(prep, voltage, switch, valid, x0):
    """The record (or its window around the split, see :data:`WINDOW_SECONDS`) as the search uses it: a view with
    ``armature_current``, ``time``, ``split``, ``sample_time``, and the sliced Va, switch positions, valid mask and
    the observer's state vector at the window's start."""
    from types import SimpleNamespace
    n = voltage.size
    length = int(round(WINDOW_SECONDS / prep.sample_time))
    if n <= length:
        return prep, voltage, switch, valid, x0
    start = int(min(max(prep.split - int(0.8 * length), 0), n - length))
    current, emf = _simulate(np.append(x0[:7], 0.0), -1, voltage, np.zeros(n), switch, prep.sample_time)
    x0 = np.array(x0, dtype=float)
    x0[5], x0[6] = current[start], emf[start]
    window = slice(start, start + length)
    view = SimpleNamespace(armature_current=np.asarray(prep.armature_current)[window], time=prep.time[window],
                           split=prep.split - start, sample_time=prep.sample_time, motor=prep.motor, window=window)
    return view, voltage[window], switch[window], valid[window], x0


def _simulate(x, code, voltage, slow, switch, sample_time):
    if not voltage.size == np.size(slow) == np.size(switch):     # the compiled kernel does not check its indices
        raise ValueError(f'motor observer: Va, slow signal and switch positions differ in length '
                         f'({voltage.size}, {np.size(slow)}, {np.size(switch)})')
    current, emf = np.empty(voltage.size), np.empty(voltage.size)
    _observer_kernel(np.asarray(x, dtype=float), int(code), voltage, slow, switch, sample_time, SUBSTEPS, current,
                     emf)
    return current, emf


#: A change of one Va level is followed for this long [s] after its interval ends (the motor's speed settles within
#: a fraction of a second; beyond it the change of the current is below the simulation's rounding).
LEVEL_HORIZON = 5.0


def _intervals(voltage: np.ndarray) -> np.ndarray:
    """Boundaries [samples] of the stepped Va's intervals of one level: 0, each change, n."""
    return np.concatenate(([0], np.flatnonzero(np.diff(voltage) != 0) + 1, [voltage.size]))


#: Above this many numbers (levels x samples) the levels' errors are propagated by :func:`_level_ensemble`, not level
#: by level: a Va that changes at every sample (a chirp) has as many levels as samples, and (levels, n) would take
#: gigabytes (29,400 x 29,400 for 60 s at 490 Hz).
LEVELS_ONE_BY_ONE = 12_000_000
#: Members of :func:`_level_ensemble` (its variance's relative standard error is sqrt(2 / members), 18 %).
LEVEL_MEMBERS = 64


def _level_ensemble(x, code, voltage, slow, switch, sample_time, level_sigma, bounds):
    """Change of the current [A], shape (LEVEL_MEMBERS, n), when every Va interval's level is moved at once by its
    own draw of N(0, `level_sigma` [V]) (a fixed seed, so the diagnosis repeats).

    The levels' errors are independent and small, so their effects on the current add: the mean over members of
    the parameters' moves ``dz dz'`` estimates the sum over levels that :func:`_level_changes` computes one by one,
    with a cost of LEVEL_MEMBERS runs of the observer however many levels there are."""
    current, _ = _simulate(x, code, voltage, slow, switch, sample_time)
    level = interval_of_samples(bounds)
    rng = np.random.default_rng(20261207)
    changes = np.empty((LEVEL_MEMBERS, voltage.size))
    for k in range(LEVEL_MEMBERS):
        moved = moved_levels(voltage, level_sigma, level, rng)
        changes[k] = _simulate(x, code, moved, slow, switch, sample_time)[0] - current
    return changes


def _level_changes(x, code, voltage, slow, switch, sample_time, level_sigma, bounds):
    """d current / d level of each Va interval times its level's standard error [A], shape (levels, n).

    Each interval's level is moved by `level_sigma` [V] alone and the observer simulated from its start (state of
    the unmoved run there) for the interval plus :data:`LEVEL_HORIZON`; zero elsewhere."""
    current, emf = _simulate(x, code, voltage, slow, switch, sample_time)
    horizon = int(round(LEVEL_HORIZON / sample_time))
    changes = np.zeros((len(bounds) - 1, voltage.size))
    for j, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
        if not level_sigma[j] > 0:
            continue
        stop = min(int(b) + horizon, voltage.size)
        moved = voltage[a:stop].copy()
        moved[:b - a] += level_sigma[j]
        if a > 0:       # the switch into this level sits in the previous sample: start there, on the old level
            a -= 1
            moved = np.concatenate(([voltage[a]], moved))
        start = np.array(x, dtype=float)
        start[5], start[6] = current[a], emf[a]
        shifted, _ = _simulate(start, code, moved, slow[a:stop], switch[a:stop], sample_time)
        changes[j, a:stop] = shifted - current[a:stop]
    return changes


def _fit(prep, x0, code, coefficient, voltage, slow, switch, train, heldout, level_sigma=None) -> MotorFitResult:
    """Output-error fit of the observer (+ term `code` when >= 0) on the `train` samples.

    The parameters' covariance is a sandwich with the scores summed over each interval of one Va level (the
    current's noise held at a level -- an ADC that does not dither -- or slow, as in the observer's own standard
    errors, :func:`aeropend_core.signals.motor.back_emf_ensemble`) plus, with `level_sigma` [V] (one per interval of
    :func:`_intervals`), the spread the error of each stepped Va level causes: the fit treats the levels as exact,
    and a voltage term (a constant, a brush drop) is nearly an offset of every level."""
    free = 8 if code >= 0 else 7
    start = np.append(np.asarray(x0, dtype=float)[:7], coefficient)
    scale = np.maximum(np.abs(start), np.array([0.1, 1e-4, 1e-3, 1e-3, 1e-3, 0.01, 0.01, 1e-3]))
    measured = prep.armature_current[train]

    def full(z):
        x = start.copy()
        x[:free] = z * scale[:free]
        return x

    def residuals(z):
        current, _ = _simulate(full(z), code, voltage, slow, switch, prep.sample_time)
        r = current[train] - measured
        return np.clip(np.nan_to_num(r, nan=100.0, posinf=100.0, neginf=-100.0), -100.0, 100.0)

    lower = np.array([1e-3, 1e-5, 0.0, 0.0, 0.0, -np.inf, -np.inf, -np.inf])[:free] / scale[:free]
    upper = np.array([100.0, 0.05, np.inf, 1e4, 1e4, np.inf, np.inf, np.inf])[:free] / scale[:free]
    z0 = np.clip(start[:free] / scale[:free], lower + 1e-9, upper - 1e-9)
    with np.errstate(all='ignore'), threadpool_limits(1):
        result = least_squares(residuals, z0, bounds=(lower, upper), method='trf', x_scale='jac', diff_step=1e-6,
                               max_nfev=MAX_EVALUATIONS)
    x = full(result.x)
    current, emf = _simulate(x, code, voltage, slow, switch, prep.sample_time)
    r = result.fun
    bounds = _intervals(voltage)
    labels = interval_of_samples(bounds)[train]
    covariance_z = hac_covariance(result.jac, r, groups=labels, width=r.size)
    if level_sigma is not None and (len(bounds) - 1) * voltage.size <= LEVELS_ONE_BY_ONE:
        changes = _level_changes(x, code, voltage, slow, switch, prep.sample_time, level_sigma, bounds)[:, train]
        covariance_z = covariance_z + input_covariance(result.jac, changes) * changes.shape[0]
    elif level_sigma is not None:       # the mean over members is already the sum over the levels
        changes = _level_ensemble(x, code, voltage, slow, switch, prep.sample_time, level_sigma, bounds)[:, train]
        covariance_z = covariance_z + input_covariance(result.jac, changes)
    covariance = covariance_z * np.outer(scale[:free], scale[:free])
    return MotorFitResult(x, current, emf, float(np.sqrt(np.mean(r ** 2))),
                          prep.armature_current[heldout] - current[heldout], effective_samples(r), covariance)


def _weak_screen(prep, x, voltage, switch, terms, noise) -> dict[str, tuple[float, float, float]]:
    """Each term alone in the weak-form armature equation (Va, Ia, e kept): {expression: (c, ranking σ, σ)} [term
    units]; the noise-only σ ranks the terms as the weak form's significance guard selects them, the sandwich σ is
    the one reported."""
    from aeropend_core.wsindy import library
    from aeropend_core.wsindy.weak_form import Equation, fit_weak_sindy
    current_model, emf = _simulate(np.append(x[:7], 0.0), -1, voltage, np.zeros(voltage.size), switch,
                                   prep.sample_time)
    heat = _lagged(current_model ** 2, HEATING_TIME, prep.sample_time)
    time = prep.time - 0.5 * (prep.time[0] + prep.time[-1])
    signals = {'current': np.asarray(prep.armature_current, dtype=float), 'voltage': voltage, 'back_emf': emf}
    for term in terms:
        slow = heat if term.code == 5 else time
        signals[term.slug] = _columns(term.code, current_model, emf, slow)
    inductance = float(x[0] * x[1])        # La = R tau_e [H]
    kept = [library.variable('voltage', hold=True), library.variable('current'), library.variable('back_emf')]
    noise_std = {name: 0.0 for name in signals}
    noise_std['current'] = float(noise)
    half_width = max(8, int(round(TEST_HALF_WIDTH / prep.sample_time)))
    first = max(2, min(prep.split // 10, int(0.05 / prep.sample_time)))
    train = slice(first, prep.split)
    pieces = {k: v[train] for k, v in signals.items()}
    screened = {}
    for term in terms:
        column = library.Term(term.expression, (term.slug,), lambda s, k=term.slug: s[k], partial=library._ones)
        equation = Equation('current', tuple(kept + [column]), order=1, keep=tuple(t.name for t in kept))
        try:
            fit = fit_weak_sindy(prep.time[train], {k: pieces[k] for k in ('current', 'voltage', 'back_emf',
                                                                            term.slug)}, [equation],
                                 half_width=half_width, noise_std={k: noise_std[k] for k in (
                                     'current', 'voltage', 'back_emf', term.slug)},
                                 significance=SIGNIFICANCE / len(terms), exhaustive_terms=1).equations[0]
        except (InsufficientDataError, AeropendError, np.linalg.LinAlgError, ValueError):
            continue
        if term.expression in fit.coefficients:      # dIa/dt += (c / La) θ: c = La times the weak coefficient
            screened[term.expression] = (float(fit.coefficients[term.expression]) * inductance,
                                         fit.model_standard_errors.get(term.expression, math.nan) * inductance,
                                         fit.standard_errors.get(term.expression, math.nan) * inductance)
    return screened


def discover_motor(prep: PreparedRecord, say: Callable[[str], None] = lambda message: None) -> MotorDiscovery:
    """Search the motor equation's discrepancy for a term outside the observer's model (module docstring).

    Parameters
    ----------
    prep : PreparedRecord [-]
        The record (its armature current, stepped Va, training / held-out split).
    say : callable [-]
        Progress messages.

    Returns
    -------
    MotorDiscovery
        The terms tried, best first (``note`` says why the search did not run, when it did not).
    """
    if prep.reduced:
        return MotorDiscovery(note='the armature current is not recorded (reduced model): the motor equation was not '
                                   'searched')
    if prep.gaps is not None and prep.gaps.joins is not None and np.any(prep.gaps.joins):
        # one observer state runs through the whole search, and each record's motor starts afresh
        return MotorDiscovery(note='several records diagnosed together: the motor equation is searched on one record '
                                   'at a time (diagnose each record alone for it)')
    added = getattr(prep, 'motor_term', None)
    if added is not None:       # the observer carries one extra voltage: the term given, no second one is searched
        return MotorDiscovery(note=f'the motor term {added.term.expression} given with --motor-term is in the '
                                   f'observer (c = {added.value:.4g} +- {added.sigma:.2g} {added.term.unit}); a '
                                   f'second motor term is not searched (the observer carries one extra voltage)',
                              noise_rms=float(prep.motor.current_noise_rms), excess_before=added.current_excess_after,
                              added=added)
    started = _starting_observer(prep)
    if started is None:
        return MotorDiscovery(note='the motor observer could not be fitted: the motor equation was not searched')
    x0, voltage, switch, noise = started
    from aeropend_core.signals.preprocess import noise_rms
    voltage_noise = noise_rms(np.asarray(prep.armature_voltage, dtype=float))     # the measured Va's [V]
    valid = prep.gaps.valid if prep.gaps is not None else np.ones(voltage.size, dtype=bool)
    full_length = voltage.size
    prep, voltage, switch, valid, x0 = _window(prep, voltage, switch, valid, x0)
    n = voltage.size
    index = np.arange(n)
    train = (index >= 2) & (index < prep.split) & valid
    heldout = (index >= prep.split) & valid
    if train.sum() < 100 or heldout.sum() < 100:
        return MotorDiscovery(note='too little data on either side of the split to search the motor equation')
    zero = np.zeros(n)
    # each stepped Va level is the median of its interval's samples: standard error 1.2533 sigma / sqrt(length)
    level_sigma = 1.2533 * voltage_noise / np.sqrt(np.maximum(np.diff(_intervals(voltage)), 1))
    say('discovery: sparse regression of the motor equation\'s discrepancy (weak form)')
    screened = _weak_screen(prep, x0, voltage, switch, MOTOR_VOCABULARY, noise)
    # the weak form's own significance guard is the gate: the output-error refits run only for terms that stand out
    ranked = sorted(screened.items(), key=lambda kv: -(abs(kv[1][0]) / kv[1][1] if kv[1][1] > 0 else 0.0))
    if not ranked:
        return MotorDiscovery(note='no term of the motor vocabulary stands out from the current\'s noise',
                              noise_rms=float(noise))
    say('discovery: refitting the motor observer on the training part (base of the motor equation\'s search)')
    base = _fit(prep, x0, -1, 0.0, voltage, zero, switch, train, heldout)
    base_rms = float(np.sqrt(np.mean(base.heldout_error ** 2)))
    excess_now = excess_error(base_rms, noise)
    outcome = MotorDiscovery(noise_rms=float(noise), excess_before=excess_now)
    if n < full_length:
        outcome.note = (f'searched on {n * prep.sample_time:.0f} s around the split of a '
                        f'{full_length * prep.sample_time:.0f} s record (training before it, held-out after)')
    by_expression = {t.expression: t for t in MOTOR_VOCABULARY}
    heat = _lagged(base.current ** 2, HEATING_TIME, prep.sample_time)
    time = prep.time - 0.5 * (prep.time[0] + prep.time[-1])
    beyond = max(base_rms ** 2 - noise ** 2, 0.0)
    doubt = screening_doubt(excess_now, noise, 'mA', 1e3)
    for rank, (expression, (value, _, sigma)) in enumerate(ranked):
        term = by_expression[expression]
        entry = MotorDiscoveredTerm(term=term, status='not_proven', weak_coefficient=value, weak_sigma=sigma,
                                    weak_doubt=doubt, excess_before=excess_now)
        outcome.terms.append(entry)
        if rank >= MAX_REFITS:
            entry.why_not = f'not refitted: weaker weak-form evidence than the {MAX_REFITS} terms refitted before it'
            continue
        say(f'discovery: refitting the motor observer with {term.expression}')
        slow = heat if term.code == 5 else (time if term.code == 6 else zero)
        augmented = _fit(prep, base.solution, term.code, value, voltage, slow, switch, train, heldout,
                         level_sigma)
        _judge(entry, base, augmented, noise, beyond)
    outcome.terms.sort(key=lambda t: (t.status != 'proven', t.excess_after if math.isfinite(t.excess_after)
                                      else math.inf))
    return outcome


def _judge(entry: MotorDiscoveredTerm, base: MotorFitResult, augmented: MotorFitResult, noise: float,
           beyond: float) -> None:
    """The catalog's evidence (candidates.assess's thresholds) on the current's output-error fits."""
    entry.back_emf, entry.solution = augmented.back_emf, augmented.solution
    entry.value = float(augmented.solution[7])
    entry.sigma = float(math.sqrt(max(augmented.covariance[7, 7], 0.0)))
    entry.t_statistic = abs(entry.value) / entry.sigma if entry.sigma > 0 else 0.0
    effective = max(augmented.effective, 2.0)
    ratio = (base.train_rms / max(augmented.train_rms, 1e-300)) ** 2
    entry.delta_bic = float(-effective * math.log(max(ratio, 1e-300)) + math.log(effective))
    dm, gain = diebold_mariano(base.heldout_error, augmented.heldout_error)
    entry.dm_statistic = float(dm)
    entry.excess_after = excess_error(float(np.sqrt(np.mean(augmented.heldout_error ** 2))), noise)
    entry.share_removed = float(np.clip(gain / beyond, 0.0, 1.0)) if beyond > 0 and np.isfinite(gain) else 0.0
    predictive = np.isfinite(dm) and (dm >= DM_MIN or (dm >= DM_WEAK and entry.share_removed >= MAJOR_SHARE))
    material = np.isfinite(gain) and gain >= (MATERIAL * noise) ** 2
    reasons = []
    if not entry.t_statistic >= T_MIN:
        reasons.append(f'its coefficient is only {entry.t_statistic:.1f} HAC standard errors from zero (needs '
                       f'{T_MIN:g})')
    if not entry.delta_bic < -BIC_MARGIN:
        reasons.append(f'the training BIC changes by {entry.delta_bic:+.1f} (needs < -{BIC_MARGIN:g})')
    if not (predictive and material):
        reasons.append(f'the held-out current does not improve enough (Diebold-Mariano {dm:+.1f}, '
                       f'{entry.share_removed * 100:.0f} % of the error beyond the noise removed)')
    entry.status = 'not_proven' if reasons else 'proven'
    entry.why_not = '; '.join(reasons)


def _corrected_record(prep: PreparedRecord, x: np.ndarray, back_emf: np.ndarray, current_rms: float, noise: float,
                      errors: dict[str, float], switch: np.ndarray | None) -> PreparedRecord:
    """`prep` with the thrust input rebuilt from the observer `x` (R, tau_e, q1, p2, p3, Ia0, e0, c) and its
    back-EMF [V] (n,): the pendulum then sees the corrected motor's speed."""
    from dataclasses import replace

    from aeropend_core.signals.motor import MotorFit
    observer = MotorFit(parameters={'motor_drive_rate': float(x[2] / x[0]), 'motor_friction_rate': float(x[3]),
                                    'motor_drag_rate': float(x[4]), 'motor_resistance': float(x[0]),
                                    'electrical_time_constant': float(x[1])},
                        back_emf=np.asarray(back_emf, dtype=float), current_rms_error=current_rms,
                        current_noise_rms=noise, solution=tuple(float(v) for v in x[:7]), kind='inductance',
                        standard_errors=errors, switch=switch)
    return replace(prep, voltage=np.asarray(back_emf, dtype=float), current=np.zeros(len(prep.time)),
                   motor=observer, voltage_ensemble=prep.voltage_ensemble if prep.motor is not None else None)


def with_motor_term(prep: PreparedRecord, expression: str | MotorTerm,
                    say: Callable[[str], None] = lambda message: None) -> PreparedRecord:
    """`prep` with a motor term in the observer (``aeropend diagnose FILE --motor-term EXPRESSION``).

    The observer is refitted by output error on the training part without and with the term (as the search's proof,
    module docstring step 3, on the whole record), and the pendulum's thrust input is rebuilt from the corrected
    observer's back-EMF. The returned record carries the term (``motor_term``, an :class:`AddedMotorTerm`):
    :func:`discover_motor` reports it and searches no second term.

    Parameters
    ----------
    prep : PreparedRecord [-]
        The record as :func:`aeropend_core.diagnosis.compare.prepare` returns it (armature current recorded).
    expression : str or MotorTerm [-]
        A term of :data:`MOTOR_VOCABULARY` (AeropendError naming them otherwise).
    say : callable [-]
        Progress messages.

    Returns
    -------
    PreparedRecord
        The record with the corrected observer (``motor``, ``voltage``) and ``motor_term`` set.
    """
    term = expression if isinstance(expression, MotorTerm) else motor_term_of(expression)
    if prep.reduced:
        raise AeropendError(f'--motor-term {term.expression!r} needs the armature current (the motor equation), and '
                            f'this record has none (the reduced model); drop --motor-term')
    if prep.gaps is not None and prep.gaps.joins is not None and np.any(prep.gaps.joins):
        raise AeropendError('--motor-term works on one record at a time; diagnose each record alone with it')
    started = _starting_observer(prep)
    if started is None:
        raise AeropendError(f'--motor-term {term.expression!r}: the motor observer could not be fitted on this '
                            f'record; diagnose it without --motor-term')
    x0, voltage, switch, noise = started
    from aeropend_core.signals.preprocess import noise_rms
    n = voltage.size
    index = np.arange(n)
    valid = prep.gaps.valid if prep.gaps is not None else np.ones(n, dtype=bool)
    train = (index >= 2) & (index < prep.split) & valid
    heldout = (index >= prep.split) & valid
    if train.sum() < 100 or heldout.sum() < 100:
        raise AeropendError(f'--motor-term {term.expression!r}: too little data on either side of the split to fit '
                            f'the term; record longer')
    level_sigma = (1.2533 * noise_rms(np.asarray(prep.armature_voltage, dtype=float))
                   / np.sqrt(np.maximum(np.diff(_intervals(voltage)), 1)))
    say(f'fitting the motor observer with {term.expression} (--motor-term)')
    zero = np.zeros(n)
    base = _fit(prep, x0, -1, 0.0, voltage, zero, switch, train, heldout)
    time = prep.time - 0.5 * (prep.time[0] + prep.time[-1])
    slow = (_lagged(base.current ** 2, HEATING_TIME, prep.sample_time) if term.code == 5 else
            time if term.code == 6 else zero)
    start = _weak_screen(prep, x0, voltage, switch, [term], noise).get(term.expression, (0.0, 0.0))[0]
    fit = _fit(prep, base.solution, term.code, start, voltage, slow, switch, train, heldout, level_sigma)
    measured = np.asarray(prep.armature_current, dtype=float)
    added = AddedMotorTerm(term, float(fit.solution[7]), float(math.sqrt(max(fit.covariance[7, 7], 0.0))),
                           excess_error(float(np.sqrt(np.mean(base.heldout_error ** 2))), noise),
                           excess_error(float(np.sqrt(np.mean(fit.heldout_error ** 2))), noise))
    errors = {'motor_resistance': float(math.sqrt(max(fit.covariance[0, 0], 0.0))),
              'electrical_time_constant': float(math.sqrt(max(fit.covariance[1, 1], 0.0)))}
    current_rms = float(np.sqrt(np.mean((measured - fit.current)[valid & (index >= 2)] ** 2)))
    from dataclasses import replace
    corrected = _corrected_record(prep, fit.solution, fit.back_emf, current_rms, noise, errors, switch)
    return replace(corrected, motor_term=added)


def pendulum_with_term(prep: PreparedRecord, entry: MotorDiscoveredTerm, model: tuple[str, ...],
                       fixed: dict[str, float], excess_before: float) -> PreparedRecord | None:
    """Refit the pendulum (nominal + `model`) with its thrust input rebuilt from the observer corrected by `entry`.

    Sets ``entry.pendulum_excess_before`` (`excess_before` [rad]) and ``entry.pendulum_excess_after`` [rad].

    Returns
    -------
    PreparedRecord or None
        The record with the corrected back-EMF as its thrust voltage (None when it could not be refitted).
    """
    from aeropend_core.diagnosis.compare import compare
    from aeropend_core.diagnosis.long_record import search_record
    entry.pendulum_excess_before = excess_before
    if (entry.back_emf is None or len(entry.back_emf) != len(prep.time)
            or not np.all(np.isfinite(entry.back_emf))):
        return None         # searched on a window of a long record: the pendulum is not refitted on it
    errors = dict(prep.motor.standard_errors) if prep.motor is not None else {}
    corrected = _corrected_record(prep, entry.solution, entry.back_emf, math.nan, math.nan, errors, None)
    try:
        search, _ = search_record(corrected)
        refit = compare(search, model, fixed=dict(fixed))
    except (InsufficientDataError, AeropendError):
        return None
    entry.pendulum_excess_after = excess_error(refit.rms_error, refit.noise_rms)
    return corrected


__all__ = ['pendulum_with_term', 'MOTOR_VOCABULARY', 'MotorTerm', 'MotorDiscoveredTerm', 'MotorDiscovery',
           'discover_motor', 'with_motor_term', 'motor_term_of', 'AddedMotorTerm']
