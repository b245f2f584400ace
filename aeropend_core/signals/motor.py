"""The motor as an observer: estimate the back-EMF (motor speed) from Va, fitted to the measured Ia.

Eq (5) computes the thrust from e = Va - Ra Ia = Kw w1, but the measured Ia is noisy, and the slow part of that
noise (inside the pendulum's bandwidth) cannot be filtered away: it ends up in the simulated angle as an error
floor and biases a thrust-lag estimate. Va, on the other hand, is a clean step sequence (it follows the duty).

Eqs (1)-(2) with La dIa/dt neglected (La/Ra ~ 2 ms) and the propeller torque quadratic in speed give, for the
back-EMF e = Kw w1 [V]::

    Ia = (Va - e) / Rm
    de/dt = p1 (Va - e) - p2 e - p3 e|e|

with p1 = Kw Kt / (Jm Rm) [1/s], p2 = F / Jm [1/s], p3 = Kd (N2/N1)^3 / (Jm Kw) [1/(V s)]. These four numbers are
fitted first (output error on Ia, the electrical transient after each step excluded). The fit is then refined with
the armature inductance, tau_e dIa/dt = (Va - e)/Rm - Ia (tau_e = La/Rm fitted too), because neglecting La dIa/dt
while the motor speeds up biases Rm by ~1 % and the thrust by ~2 %; the refinement is kept only if it explains Ia
better (it nests the quasi-static model: it is dropped only when that one explains Ia significantly better on the
samples it was fitted to, a Diebold-Mariano test; comparing raw RMS there favoured the quasi-static model by its
in-sample optimism). The model's e(t) is then a noise-free thrust input. If the model cannot explain Ia to within
its noise, the caller falls back to the measured Va - R Ia, unless the observer's thrust voltage is still the better
one: its error bound (R x the current's error beyond the noise) at most half the fallback's own error (La dIa/dt and
R x the noise, by the fitted model; :attr:`MotorFit.kept_against_fallback`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np
from scipy.optimize import least_squares
from threadpoolctl import threadpool_limits

from aeropend_core.parallel import default_workers, map_in_order
from aeropend_core.signals.preprocess import noise_rms, settling_samples

PARAMETER_NAMES = ('motor_drive_rate', 'motor_friction_rate', 'motor_drag_rate', 'motor_resistance')
PARAMETER_UNITS = {'motor_drive_rate': '1/s', 'motor_friction_rate': '1/s', 'motor_drag_rate': '1/(V s)',
                   'motor_resistance': 'ohm', 'electrical_time_constant': 's'}


@numba.njit(cache=True, nogil=True, inline='always')
def _back_emf_step(p1, p2, p3, v, e, h):
    """One RK4 step of length h [s] of de/dt = p1 (Va - e) - p2 e - p3 e|e|."""
    k1 = p1 * (v - e) - p2 * e - p3 * e * abs(e)
    e2 = e + 0.5 * h * k1
    k2 = p1 * (v - e2) - p2 * e2 - p3 * e2 * abs(e2)
    e3 = e + 0.5 * h * k2
    k3 = p1 * (v - e3) - p2 * e3 - p3 * e3 * abs(e3)
    e4 = e + h * k3
    k4 = p1 * (v - e4) - p2 * e4 - p3 * e4 * abs(e4)
    return e + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


@numba.njit(cache=True, nogil=True, inline='always')
def _input_at(voltage, switch, i, start, stop):
    """Va held over the sub-step [start, stop) [fraction of sample i's interval]: voltage[i] before the interval's
    switch (``switch[i]``, a fraction; 1 = none), voltage[i + 1] after it (a sub-step never straddles it)."""
    if start >= switch[i] - 1e-12 and i + 1 < voltage.shape[0]:
        return voltage[i + 1]
    return voltage[i]


@numba.njit(cache=True, nogil=True, inline='always')
def _sub_steps(switch, i, substeps):
    """Boundaries [fraction of the interval] of the RK4 sub-steps of interval i: `substeps` equal steps, the one that
    holds the switch of Va (``switch[i]`` < 1) split at it, so that the hold is integrated exactly."""
    bounds = np.empty(substeps + 2)
    count = 0
    bounds[0] = 0.0
    for q in range(1, substeps + 1):
        edge = q / substeps
        previous = bounds[count]
        if previous + 1e-12 < switch[i] < edge - 1e-12:
            count += 1
            bounds[count] = switch[i]
        count += 1
        bounds[count] = edge
    return bounds[:count + 1]


@numba.njit(cache=True, nogil=True)
def _back_emf_kernel(parameters, voltage, initial, sample_time, substeps, out, switch):
    """RK4 of de/dt = p1 (Va - e) - p2 e - p3 e|e| with Va held over each sample, for every parameter row, in
    `substeps` steps per sample (1 at 490 Hz; more at a low rate, where one step per sample is unstable).

    `switch` (n,) [fraction of the sample interval]: where in interval i Va changes to voltage[i + 1] (a duty step
    that landed between two samples of a low-rate log); 1 where it is held over the whole interval."""
    for row in range(parameters.shape[0]):
        p1 = parameters[row, 0]
        p2 = parameters[row, 1]
        p3 = parameters[row, 2]
        e = initial[row]
        for i in range(voltage.shape[0]):
            out[row, i] = e
            if switch[i] >= 1.0:
                v = voltage[i]
                h = sample_time / substeps
                for _ in range(substeps):
                    e = _back_emf_step(p1, p2, p3, v, e, h)
                continue
            bounds = _sub_steps(switch, i, substeps)
            for q in range(bounds.shape[0] - 1):
                v = _input_at(voltage, switch, i, bounds[q], bounds[q + 1])
                e = _back_emf_step(p1, p2, p3, v, e, (bounds[q + 1] - bounds[q]) * sample_time)


#: RK4 sub-steps per sample for the observer with the armature inductance (La/Ra ~ one sample at 490 Hz).
ELECTRICAL_SUBSTEPS = 8


def _substeps(sample_time: float, per_rig_sample: int) -> int:
    """RK4 steps [-] per sample of `sample_time` [s]: `per_rig_sample` per 1/490 s (the rig's rate), so that the
    step length, not the count, is the same at every rate (at 490 Hz exactly `per_rig_sample`)."""
    return per_rig_sample * max(1, int(math.ceil(sample_time * 490.0 - 1e-6)))
#: Time after the start over which the initial back-EMF is taken [s] (20 samples at 490 Hz).
INITIAL_SPAN = 20.0 / 490.0
#: Time on either side of a Va step from which the current is extrapolated to the step [s] (6 samples at 490 Hz).
RESISTANCE_SPAN = 6.0 / 490.0


@numba.njit(cache=True, nogil=True, inline='always')
def _motor_step(r, tau, q1, p2, p3, v, i, e, h):
    """One RK4 step of length h [s] of tau_e dIa/dt = (Va - e)/R - Ia, de/dt = q1 Ia - p2 e - p3 e|e|."""
    di1 = ((v - e) / r - i) / tau
    de1 = q1 * i - p2 * e - p3 * e * abs(e)
    i2 = i + 0.5 * h * di1
    e2 = e + 0.5 * h * de1
    di2 = ((v - e2) / r - i2) / tau
    de2 = q1 * i2 - p2 * e2 - p3 * e2 * abs(e2)
    i3 = i + 0.5 * h * di2
    e3 = e + 0.5 * h * de2
    di3 = ((v - e3) / r - i3) / tau
    de3 = q1 * i3 - p2 * e3 - p3 * e3 * abs(e3)
    i4 = i + h * di3
    e4 = e + h * de3
    di4 = ((v - e4) / r - i4) / tau
    de4 = q1 * i4 - p2 * e4 - p3 * e4 * abs(e4)
    return i + h / 6.0 * (di1 + 2.0 * di2 + 2.0 * di3 + di4), e + h / 6.0 * (de1 + 2.0 * de2 + 2.0 * de3 + de4)


@numba.njit(cache=True, nogil=True)
def _motor_kernel(parameters, voltage, initial, sample_time, substeps, out_current, out_emf, switch):
    """RK4 of  tau_e dIa/dt = (Va - e)/R - Ia,  de/dt = q1 Ia - p2 e - p3 e|e|  (Va held over each sample, changing
    to voltage[i + 1] at the fraction ``switch[i]`` of interval i; 1: no change, as in :func:`_back_emf_kernel`).

    parameters rows: R [ohm], tau_e = La/R [s], q1 = Kw Kt / Jm [V/(A s)], p2 [1/s], p3 [1/(V s)];
    initial rows: Ia0 [A], e0 [V]. Writes Ia and e at the start of each sample.
    """
    for row in range(parameters.shape[0]):
        r = parameters[row, 0]
        tau = parameters[row, 1]
        q1 = parameters[row, 2]
        p2 = parameters[row, 3]
        p3 = parameters[row, 4]
        i = initial[row, 0]
        e = initial[row, 1]
        for k in range(voltage.shape[0]):
            out_current[row, k] = i
            out_emf[row, k] = e
            if switch[k] >= 1.0:
                v = voltage[k]
                h = sample_time / substeps
                for _ in range(substeps):
                    i, e = _motor_step(r, tau, q1, p2, p3, v, i, e, h)
                continue
            bounds = _sub_steps(switch, k, substeps)
            for q in range(bounds.shape[0] - 1):
                v = _input_at(voltage, switch, k, bounds[q], bounds[q + 1])
                i, e = _motor_step(r, tau, q1, p2, p3, v, i, e, (bounds[q + 1] - bounds[q]) * sample_time)


@dataclass(frozen=True)
class MotorFit:
    """Fitted motor observer.

    Attributes
    ----------
    parameters : dict
        ``motor_drive_rate`` p1 [1/s], ``motor_friction_rate`` p2 [1/s], ``motor_drag_rate`` p3 [1/(V s)],
        ``motor_resistance`` Rm [ohm].
    back_emf : ndarray, shape (n,)
        Estimated e = Kw w1 [V] at each sample.
    current_rms_error : float
        RMS of measured minus modelled Ia [A] (electrical transients excluded).
    current_noise_rms : float
        Ia's own noise RMS [A], estimated from the data.
    """

    parameters: dict[str, float]
    back_emf: np.ndarray
    current_rms_error: float
    current_noise_rms: float
    #: The fitted model's state vector (``'inductance'``: R, tau_e, q1, p2, p3, Ia0, e0; ``'quasi_static'``: p1, p2,
    #: p3, R, e0) and which model it is, for :func:`back_emf_ensemble`.
    solution: tuple[float, ...] = ()
    kind: str = 'quasi_static'
    #: 1-sigma of the parameters the observer reports (``motor_resistance`` [ohm], ...), filled in by the caller
    #: from :func:`back_emf_ensemble` (empty: not computed).
    standard_errors: dict[str, float] = field(default_factory=dict)
    #: Where inside each sample interval the observer's Va changed to the next sample's level [fraction of the
    #: interval] (see :func:`fit_motor`; None: held over whole intervals).
    switch: np.ndarray | None = field(default=None, repr=False, compare=False)

    #: RMS [V] of the error the fallback thrust voltage Va - R Ia would carry, by this observer's own model: its
    #: La dIa/dt (Va - R Ia - e of the fitted model) and R times the current's noise; NaN where not computed (the
    #: quasi-static model, whose fallback has no La term to weigh).
    fallback_voltage_error: float = math.nan

    @property
    def voltage_error_bound(self) -> float:
        """Largest thrust-voltage error [V] the observer's current misfit allows: R times the current's RMS error
        beyond its noise (as if all of it came from a wrong back-EMF; a misfit in the electrical transients moves
        the back-EMF far less)."""
        excess = math.sqrt(max(self.current_rms_error ** 2 - self.current_noise_rms ** 2, 0.0))
        return float(self.parameters.get('motor_resistance', math.nan)) * excess

    @property
    def kept_against_fallback(self) -> bool:
        """True when the current's error exceeds 1.5x its noise but the observer's thrust voltage is still the
        better one: its error bound (:attr:`voltage_error_bound`) at most :data:`FALLBACK_MARGIN` times the
        fallback's (:attr:`fallback_voltage_error`). On a clean current channel (Va, Ia at 70 dB, the angle at
        45 dB) the observer's small model error is many times the current's tiny noise, yet 8x below the La dIa/dt
        error of Va - R Ia, which bent the fit (the angle filter's delay at its bound with z +5; bench/results/
        2026-12-07-s21-observer)."""
        if self.current_rms_error <= 1.5 * self.current_noise_rms + 1e-4:
            return False
        bound, fallback = self.voltage_error_bound, self.fallback_voltage_error
        return bool(math.isfinite(bound) and math.isfinite(fallback) and bound <= FALLBACK_MARGIN * fallback)

    @property
    def adequate(self) -> bool:
        """True when the model explains Ia to within 1.5x its noise, or when its thrust voltage is the better one
        anyway (:attr:`kept_against_fallback`); else use the measured Va - R Ia."""
        return self.current_rms_error <= 1.5 * self.current_noise_rms + 1e-4 or self.kept_against_fallback


def held_switches(switch: np.ndarray | None, n: int) -> np.ndarray:
    """The kernels' `switch` array (n,) [fraction of a sample interval]: `switch` as floats, or 1 (Va held over
    every whole interval) when None."""
    if switch is None:
        return np.ones(n)
    switch = np.ascontiguousarray(switch, dtype=float)
    if switch.shape != (n,):
        raise ValueError(f'switch has shape {switch.shape}; expected ({n},)')
    return switch


def _simulate(parameters: np.ndarray, voltage: np.ndarray, initial: np.ndarray, sample_time: float,
              switch: np.ndarray) -> np.ndarray:
    out = np.empty((parameters.shape[0], voltage.size))
    _back_emf_kernel(parameters, voltage, initial, sample_time, _substeps(sample_time, 1), out, switch)
    return out


def _fitted_samples(kind: str, n: int, step_indices, sample_time: float) -> np.ndarray:
    """Mask (n,) of the samples an observer of `kind` is fitted to: the inductance model all but the first two;
    the quasi-static one none within the settling time (:func:`~aeropend_core.signals.preprocess.settling_samples`
    at `sample_time` [s]) of the start or of a Va step (its electrical transient is not in that model)."""
    mask = np.ones(n, dtype=bool)
    if kind == 'inductance':
        mask[:2] = False
        return mask
    settling = settling_samples(sample_time)
    for k in step_indices:
        mask[k:k + settling] = False
    mask[:settling] = False
    return mask


def fit_motor(voltage: np.ndarray, current: np.ndarray, step_indices: np.ndarray,
              sample_time: float, switch: np.ndarray | None = None) -> MotorFit:
    """Fit the motor observer to a step-input Va [V] (piecewise constant) and the measured Ia [A].

    `switch` (n,) [fraction of a sample interval], optional: where inside interval i Va changes to voltage[i + 1]
    (:func:`aeropend_core.signals.preprocess.step_switches`: a low-rate log's duty step lands between two samples);
    default Va held over each whole interval.
    """
    voltage = np.asarray(voltage, dtype=float)
    current = np.asarray(current, dtype=float)
    n = voltage.size
    switch = held_switches(switch, n)
    keep = _fitted_samples('quasi_static', n, step_indices, sample_time)
    resistance0 = _resistance_from_steps(voltage, current, step_indices, sample_time)
    e_measured = voltage - resistance0 * current
    ratio2, ratio3 = _rate_ratios_from_steady_states(voltage, e_measured, step_indices, sample_time)
    settling = settling_samples(sample_time)
    # the first ~40 ms after the settling (20 samples at 490 Hz), at least 3 samples at a low rate
    initial_emf = float(np.median(e_measured[settling:max(settling + 3, int(round(INITIAL_SPAN / sample_time)))]))
    measured = current[keep]
    # The overall rate p1 sets the speed of the response: scan it on a log grid (mechanical time constants
    # from ~10 ms to ~10 s), the steady-state ratios fixed, then fit everything from the best.
    grid = np.logspace(-1.5, 2.5, 41)
    rows = np.column_stack([grid, grid * ratio2, grid * ratio3])
    # one rate at a time: 41 rows of a 1-hour record would take 0.6 GB, and their temporaries several times that
    scan = np.empty(grid.size)
    for i in range(grid.size):
        emf = _simulate(rows[i:i + 1], voltage, np.full(1, initial_emf), sample_time, switch)[0]
        scan[i] = np.mean(((voltage - emf) / resistance0 - current)[keep] ** 2)
    p1_0 = float(grid[int(np.argmin(np.nan_to_num(scan, nan=np.inf)))])
    p2_0, p3_0 = p1_0 * ratio2, p1_0 * ratio3
    scale = np.array([max(p1_0, 1e-3), max(p2_0, 0.01 * p1_0), max(p3_0, 0.01 * p1_0), max(resistance0, 0.1), 1.0])
    x0 = np.array([p1_0, p2_0, p3_0, resistance0, initial_emf]) / scale

    def model_current(rows):
        emf = _simulate(rows[:, :3], voltage, rows[:, 4], sample_time, switch)
        return (voltage[None, :] - emf) / rows[:, 3:4]

    last = {}     # the model at the point the optimiser evaluated last: its Jacobian there starts from it

    def residuals(x):
        modelled = model_current((x * scale)[None, :])[0]
        last.clear()
        last[x.tobytes()] = modelled
        return _bounded(modelled[keep] - measured)

    def jacobian(x):
        step = 1e-6 * np.maximum(np.abs(x), 1.0)
        rows = np.tile(x, (len(x) + 1, 1))
        rows[1:] += np.diag(step)
        # one row at a time (the same numbers): a 1-hour record's rows and their temporaries would take ~0.7 GB
        modelled = last.get(x.tobytes())
        base = _bounded((model_current(rows[:1] * scale)[0] if modelled is None else modelled)[keep])
        jac = np.empty((base.size, len(x)))
        for i in range(len(x)):
            jac[:, i] = (_bounded(model_current(rows[i + 1:i + 2] * scale)[0, keep]) - base) / step[i]
        return jac

    lower = np.array([1e-3, 0.0, 0.0, 1e-3, -np.inf]) / scale
    upper = np.array([1e4, 1e4, 1e4, 100.0, np.inf]) / scale
    x0 = np.clip(x0, lower + 1e-9, upper - 1e-9)
    with np.errstate(all='ignore'), threadpool_limits(1):
        result = least_squares(residuals, x0, jac=jacobian, bounds=(lower, upper), method='trf', x_scale='jac',
                               max_nfev=100)
    x = result.x * scale
    emf = _simulate(x[None, :3], voltage, x[None, 4], sample_time, switch)[0]
    error = float(np.sqrt(np.mean(result.fun ** 2)))
    quasi_static = MotorFit(parameters=_parameters('quasi_static', x), back_emf=emf, current_rms_error=error,
                            current_noise_rms=noise_rms(current[keep]), solution=tuple(float(v) for v in x),
                            kind='quasi_static', switch=switch)
    with_inductance = _fit_with_inductance(voltage, current, keep, sample_time, quasi_static, x[4], switch,
                                           step_indices)
    return with_inductance if with_inductance is not None else quasi_static


def _parameters(kind: str, x: np.ndarray) -> dict[str, float]:
    """The named motor parameters (SI, :data:`PARAMETER_UNITS`) of an observer's state vector `x` of `kind`."""
    if kind == 'inductance':
        return {'motor_drive_rate': float(x[2] / x[0]), 'motor_friction_rate': float(x[3]),
                'motor_drag_rate': float(x[4]), 'motor_resistance': float(x[0]),
                'electrical_time_constant': float(x[1])}
    return dict(zip(PARAMETER_NAMES, (float(v) for v in x[:4])))


#: Lower bounds of the entries of an observer's state vector that belong to the motor (the rest are a record's
#: initial state), by kind: the fits' own (a resistance and an electrical time constant above 0).
SHARED_LOWER = {'inductance': (1e-3, 1e-5, 0.0, 0.0, 0.0), 'quasi_static': (1e-3, 0.0, 0.0, 1e-3)}


def refit_shared(fits: list[MotorFit], voltages: list[np.ndarray], currents: list[np.ndarray],
                 step_indices: list[np.ndarray], sample_time: float) -> list[MotorFit] | None:
    """The observers of several records of one motor refitted with one set of motor parameters.

    Each record's own observer fits the motor to that record's noise; records judged together (a joint diagnosis)
    then drive the pendulum with back-EMFs of slightly different motors, and the shared thrust gain cannot fit them
    all: a designed record and its first record, each fitted within the noise alone, left 9.9 mrad beyond the
    15.8 mrad noise together (a 10 mrad offset then read as 8.6 +- 1.1 mrad and "unexplained"). Here the motor's
    parameters are fitted to every record's current at once (least squares over the samples each observer is
    fitted to, from the mean of the records' own values), each record keeping its initial state and its step
    positions.

    Parameters
    ----------
    fits : list of MotorFit
        Each record's own observer (all of one kind, with their state vectors).
    voltages, currents : list of ndarray
        Each record's piecewise-constant Va [V] the observer was fitted to, and its measured Ia [A].
    step_indices : list of ndarray of int
        Each record's Va steps.
    sample_time : float
        Ts [s], the same for all.

    Returns
    -------
    list of MotorFit or None
        One per record, with the shared parameters and that record's back-EMF [V]; None when the observers are not
        of one kind or the joint fit fails (then each record keeps its own).
    """
    kinds = {fit.kind for fit in fits}
    if len(kinds) != 1 or not all(fit.solution for fit in fits):
        return None
    kind = kinds.pop()
    shared = len(SHARED_LOWER[kind])
    solutions = [np.asarray(fit.solution, dtype=float) for fit in fits]
    own = len(solutions[0]) - shared
    switches = [fit.switch if fit.switch is not None and len(fit.switch) == len(v) else None
                for fit, v in zip(fits, voltages)]
    used = [_fitted_samples(kind, len(v), steps, sample_time) for v, steps in zip(voltages, step_indices)]
    start = np.concatenate([np.mean([x[:shared] for x in solutions], axis=0)] + [x[shared:] for x in solutions])
    scale = np.maximum(np.abs(start), 1e-3)

    def record(z: np.ndarray, k: int) -> np.ndarray:
        x = z * scale
        return np.concatenate([x[:shared], x[shared + k * own:shared + (k + 1) * own]])

    def residuals(z: np.ndarray) -> np.ndarray:
        return np.concatenate([_bounded(_predict(kind, record(z, k), voltages[k], sample_time, switches[k])[0][used[k]]
                                        - currents[k][used[k]]) for k in range(len(fits))])

    lower = np.full(start.size, -np.inf)
    lower[:shared] = SHARED_LOWER[kind]
    z0 = np.maximum(start, lower + 1e-9 * scale) / scale
    with np.errstate(all='ignore'), threadpool_limits(1):
        result = least_squares(residuals, z0, bounds=(lower / scale, np.inf), method='trf', x_scale='jac',
                               max_nfev=40)
    refitted = []
    for k, fit in enumerate(fits):
        x = record(result.x, k)
        modelled, emf = _predict(kind, x, voltages[k], sample_time, switches[k])
        if not (np.all(np.isfinite(emf)) and np.all(np.isfinite(modelled))):
            return None
        error = float(np.sqrt(np.mean((modelled - currents[k])[used[k]] ** 2)))
        refitted.append(MotorFit(parameters=_parameters(kind, x), back_emf=emf, current_rms_error=error,
                                 current_noise_rms=fit.current_noise_rms, solution=tuple(float(v) for v in x),
                                 kind=kind, switch=fit.switch, standard_errors=dict(fit.standard_errors)))
    return refitted


#: Gauss-Newton passes of :func:`_fit_switches` (the current is nearly linear in a step's position).
SWITCH_ITERATIONS = 3
#: Change of a step's position [fraction of the interval] for its finite-difference derivative.
SWITCH_DELTA = 0.1


def _fit_switches(predict, switch: np.ndarray, step_indices: np.ndarray, current: np.ndarray,
                  used: np.ndarray, iterations: int = SWITCH_ITERATIONS) -> np.ndarray:
    """Where inside its interval each duty step landed [fraction], by Gauss-Newton on the current after it.

    `predict(switch)` gives the modelled Ia [A] (n,) for switch positions `switch` (n,); only intervals with a switch
    (< 1) are moved, each from the samples `used` between its step and the next. Steps are moved in two interleaved
    sets (even, odd), so a derivative holds one step's effect and not its neighbour's (the back-EMF a step leaves
    decays at the motor's time constant, ~0.4 s, against dwells of ~1 s). Positions stay in [0, 1).
    """
    n = switch.size
    steps = np.array([k for k in np.asarray(step_indices, dtype=int) if 1 <= k < n and switch[k - 1] < 1.0])
    if steps.size == 0:
        return switch
    ends = np.append(steps[1:], n)
    switch = np.array(switch, dtype=float)
    for _ in range(iterations):
        base = predict(switch)
        residual = current - base
        update = switch.copy()
        for parity in (0, 1):
            chosen = np.arange(parity, steps.size, 2)
            trial = switch.copy()
            delta = np.where(switch[steps[chosen] - 1] <= 0.5, SWITCH_DELTA, -SWITCH_DELTA)
            trial[steps[chosen] - 1] += delta
            moved = predict(trial)
            for j, d in zip(chosen, delta):
                block = np.arange(steps[j], ends[j])
                block = block[used[block]]
                slope = (moved[block] - base[block]) / d
                weight = float(slope @ slope)
                if weight > 0 and np.isfinite(weight):
                    position = switch[steps[j] - 1] + float(slope @ residual[block]) / weight
                    update[steps[j] - 1] = min(max(position, 0.0), 0.999)
        switch = update
    return switch


def _fit_with_inductance(voltage, current, keep, sample_time, start: MotorFit, initial_emf: float, switch,
                        step_indices=()):
    """Refine the observer with the armature inductance (all samples but the first few are then usable).

    Neglecting La dIa/dt biases the fitted resistance while the motor speeds up or slows down (Ia moves at the
    motor's time constant); with tau_e = La/R in the model that bias goes. Returns None if this model does not
    explain the current better than the quasi-static one on the samples both use.
    """
    p = start.parameters
    r0 = p['motor_resistance']
    x0 = np.array([r0, 2e-3, p['motor_drive_rate'] * r0, p['motor_friction_rate'], p['motor_drag_rate'],
                   float(current[0]), initial_emf])
    scale = np.maximum(np.abs(x0), np.array([0.1, 1e-4, 1e-3, 1e-3, 1e-3, 0.01, 0.01]))
    use = _fitted_samples('inductance', voltage.size, (), sample_time)
    measured = current[use]

    def model(rows):
        out_current = np.empty((rows.shape[0], voltage.size))
        out_emf = np.empty_like(out_current)
        _motor_kernel(rows[:, :5], voltage, rows[:, 5:7], sample_time, _substeps(sample_time, ELECTRICAL_SUBSTEPS),
                      out_current, out_emf, switch)
        return out_current, out_emf

    last = {}     # the model at the point the optimiser evaluated last, with the step positions it used

    def residuals(z):
        modelled = model((z * scale)[None, :])[0][0]
        last.clear()
        last[z.tobytes()] = (switch, modelled)
        return _bounded(modelled[use] - measured)

    def jacobian(z):
        step = 1e-6 * np.maximum(np.abs(z), 1.0)
        rows = np.tile(z, (len(z) + 1, 1))
        rows[1:] += np.diag(step)
        # one row per kernel call (the same numbers): memory of two records' length per worker, not two per parameter;
        # the columns on the machine's cores (the kernel is nogil; each call writes only its own column)
        held, modelled = last.get(z.tobytes(), (None, None))
        if modelled is None or held is not switch:
            modelled = model(rows[:1] * scale)[0][0]
        base = _bounded(modelled[use])
        jac = np.empty((base.size, len(z)))

        def column(i):
            jac[:, i] = (_bounded(model(rows[i + 1:i + 2] * scale)[0][0, use]) - base) / step[i]
        map_in_order(column, range(len(z)))
        return jac

    lower = np.array([1e-3, 1e-5, 0.0, 0.0, 0.0, -np.inf, -np.inf]) / scale
    upper = np.array([100.0, 0.05, np.inf, 1e4, 1e4, np.inf, np.inf]) / scale
    z0 = np.clip(x0 / scale, lower + 1e-9, upper - 1e-9)
    with np.errstate(all='ignore'), threadpool_limits(1):
        result = least_squares(residuals, z0, jac=jacobian, bounds=(lower, upper), method='trf', x_scale='jac',
                               max_nfev=60)
    if np.any(switch < 1.0):
        # where each duty step landed inside its interval: estimated from the current after it (the back-EMF it
        # leaves at the next sample decays at the motor's time constant over the following samples), then the
        # parameters refitted with those positions
        def predict(trial_switch):
            nonlocal switch
            held, switch = switch, trial_switch
            try:
                return model(result.x[None, :] * scale)[0][0]
            finally:
                switch = held
        switch = _fit_switches(predict, switch, step_indices, current, use)
        with np.errstate(all='ignore'), threadpool_limits(1):
            result = least_squares(residuals, result.x, jac=jacobian, bounds=(lower, upper), method='trf',
                                   x_scale='jac', max_nfev=60)
    x = result.x * scale
    fitted_current, emf = model(x[None, :])
    if not np.all(np.isfinite(emf)) or not np.all(np.isfinite(fitted_current)):
        return None
    # compared on the samples both models were fitted to: at a low rate the quasi-static mask leaves the second
    # sample in (one settling sample), which the refinement does not fit (its free initial current and back-EMF):
    # a record that starts with the motor switching on put 1.3 A there at 49 Hz, and that one sample made the
    # observer look inadequate (39 mA RMS against 21 mA of noise; 20 mA without it)
    keep = keep & use
    refined_error = (fitted_current[0] - current)[keep]
    quasi_static_error = ((voltage - start.back_emf) / p['motor_resistance'] - current)[keep]
    error_on_keep = float(np.sqrt(np.mean(refined_error ** 2)))
    # The quasi-static model was fitted to exactly these samples, the refinement to all of them: on these samples
    # the quasi-static one is ahead by its in-sample optimism (~ its 5 parameters x the noise variance / n) even
    # when it is the worse model. Deciding on the raw RMS threw away the refinement in about half the records with
    # noisy Va and Ia (e.g. 9.8146 vs 9.8133 mA), and the quasi-static observer's bias (Rm -1 %, rates 1.5-4 %)
    # bent the thrust input enough for the pendulum fit to absorb it as a 1.4 mrad "angle offset" (t = 9) on a
    # clean record. The refinement nests the quasi-static model (La -> 0): it is kept unless the quasi-static one
    # explains the current significantly better (one-sided Diebold-Mariano test on the squared errors).
    from aeropend_core.stats import diebold_mariano
    statistic, _ = diebold_mariano(refined_error, quasi_static_error)
    if np.isfinite(statistic) and statistic > REFINEMENT_REJECT:
        return None
    # what the fallback Va - R Ia would carry instead, by this model: La dIa/dt (= Va - R Ia - e) and R x the noise
    inductive = (voltage - x[0] * fitted_current[0] - emf[0])[use]
    fallback = math.sqrt(float(np.mean(inductive ** 2)) + (x[0] * start.current_noise_rms) ** 2)
    return MotorFit(parameters=_parameters('inductance', x), back_emf=emf[0], current_rms_error=error_on_keep,
                    current_noise_rms=start.current_noise_rms, solution=tuple(float(v) for v in x), kind='inductance',
                    switch=switch, fallback_voltage_error=fallback)


def _predict(kind: str, x: np.ndarray, voltage: np.ndarray, sample_time: float,
             switch: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Modelled Ia [A] and back-EMF [V] of a fitted observer (`kind`, state vector `x`) for the input `voltage`
    (changing inside interval i at the fraction `switch[i]`, see :func:`fit_motor`)."""
    switch = held_switches(switch, voltage.size)
    if kind == 'inductance':
        out_current = np.empty((1, voltage.size))
        out_emf = np.empty_like(out_current)
        _motor_kernel(x[None, :5], voltage, x[None, 5:7], sample_time, _substeps(sample_time, ELECTRICAL_SUBSTEPS),
                      out_current, out_emf, switch)
        return out_current[0], out_emf[0]
    # the initial back-EMF as a 1-D array of one row (a (1, 1) slice made the kernel's state an array: TypingError)
    emf = _simulate(x[None, :3], voltage, x[4:5], sample_time, switch)[0]
    return (voltage - emf) / x[3], emf


#: The observer whose current misfits beyond 1.5x the noise is still kept when its thrust-voltage error bound is at
#: most this share of the fallback's (:attr:`MotorFit.kept_against_fallback`): a margin of 2 for the bound's and the
#: fallback's estimates both coming from the observer's fit.
FALLBACK_MARGIN = 0.5


#: Members of the back-EMF ensemble (:func:`back_emf_ensemble`): the standard errors it adds are known to about
#: 1/sqrt(2 x 16) = 18 %.
ENSEMBLE_SIZE = 16


def moved_levels(voltage: np.ndarray, level_sigma: np.ndarray, interval: np.ndarray,
                 rng: np.random.Generator) -> np.ndarray:
    """`voltage` [V] with every input interval's level moved at once by its own draw of N(0, `level_sigma` [V]).

    `interval` gives each sample's interval (as :func:`interval_of_samples`); one standard-normal draw per interval
    is taken from `rng`, so callers that interleave other draws keep their sequence."""
    return voltage + (rng.standard_normal(level_sigma.size) * level_sigma)[interval]


def interval_of_samples(bounds: np.ndarray) -> np.ndarray:
    """Each sample's input interval (0, 1, ...) for interval `bounds` [samples] ``[0, ..., n]``."""
    return np.repeat(np.arange(len(bounds) - 1), np.diff(bounds))


def back_emf_ensemble(fit: MotorFit, voltage: np.ndarray, measured_voltage: np.ndarray, current: np.ndarray,
                      step_indices: np.ndarray, sample_time: float, count: int = ENSEMBLE_SIZE,
                      seed: int = 0, with_errors: bool = False, blocks: np.ndarray | None = None):
    """Back-EMF changes [V] that the observer's own estimation error allows: shape (count, n), float32.

    The observer is fitted to noisy data (Ia's noise, per-level errors of the measured Va, an ADC that does not
    dither), and the pendulum fit then treats its back-EMF as an exact input: an error in it bends the thrust and
    can be absorbed by a pendulum parameter (an angle offset) with a standard error that knows nothing about it.
    Each member redraws the data the observer saw, refits it by one Gauss-Newton step from the solution, and
    returns its back-EMF minus the fitted one:

    * Ia: wild bootstrap by input interval, the fitted current plus the residual of each interval between two Va
      steps times a random sign (keeps the noise's size and the slow part of it, e.g. a quantisation bias held
      at one level);
    * Va: each interval's level moved by a normal draw of its median's standard error (1.2533 sigma / sqrt(n)),
      sigma the measured Va's noise (zero for a noise-free Va).

    Parameters
    ----------
    fit : MotorFit
        The fitted observer (with its ``solution``).
    voltage : ndarray, shape (n,)
        The piecewise-constant Va [V] the observer was fitted to.
    measured_voltage : ndarray, shape (n,)
        The measured Va [V] (for its noise).
    current : ndarray, shape (n,)
        The measured Ia [A].
    step_indices : ndarray of int
        Samples where a Va step lands.
    sample_time : float
        Ts [s].
    count : int [-]
        Number of members.
    seed : int [-]
        Seed of the draws (the ensemble is reproducible).
    with_errors : bool [-]
        Also return the observer's standard errors (see Returns).
    blocks : ndarray of int, optional [samples]
        Where the bootstrap's intervals start, instead of `step_indices`: for a continuously varying Va, whose one
        or two steps leave one or two intervals and a covariance of one or two scores (Ra's 1-sigma came out 1e-5 of
        itself where its error was 2e-4).

    Returns
    -------
    ndarray, shape (count, n), or None
        None when the fit has no state vector or a member diverges.
    dict of str -> float
        Only with `with_errors`: 1-sigma of ``motor_resistance`` [ohm] (and ``electrical_time_constant`` [s] for
        the inductance model), from the same two sources as the members: the exact covariance of the wild
        bootstrap by input interval (a sandwich with the scores summed over each interval between two Va steps:
        honest for noise that is slow or held at one level) plus the spread the Va level draws cause.
    """
    if not fit.solution:
        return (None, {}) if with_errors else None
    voltage = np.asarray(voltage, dtype=float)
    current = np.asarray(current, dtype=float)
    n = voltage.size
    x = np.asarray(fit.solution, dtype=float)
    kind = fit.kind
    used = _fitted_samples(kind, n, step_indices, sample_time)
    switch = fit.switch if fit.switch is not None and len(fit.switch) == n else None
    modelled, emf = _predict(kind, x, voltage, sample_time, switch)
    residual = current - modelled
    # Jacobian of the modelled current on the fitted samples (forward differences), and d back-EMF / d state (a
    # member's back-EMF after its step, linearised); float32 columns and products column by column keep a 1-hour
    # record's temporaries to one column of float64
    steps = 1e-6 * np.maximum(np.abs(x), 1e-4)
    jacobian = np.empty((int(used.sum()), x.size), dtype=np.float32)
    emf_jacobian = np.empty((n, x.size), dtype=np.float32)

    def column(i):                  # on the machine's cores, each call writing only its own columns
        shifted = x.copy()
        shifted[i] += steps[i]
        shifted_current, shifted_emf = _predict(kind, shifted, voltage, sample_time, switch)
        jacobian[:, i] = (shifted_current - modelled)[used] / steps[i]
        emf_jacobian[:, i] = (shifted_emf - emf) / steps[i]
    map_in_order(column, range(x.size))
    if not (np.all(np.isfinite(jacobian)) and np.all(np.isfinite(emf_jacobian))):
        return (None, {}) if with_errors else None
    gram = np.array([[np.dot(jacobian[:, i].astype(float), jacobian[:, j]) for j in range(x.size)]
                     for i in range(x.size)])
    inverse = np.linalg.pinv(gram)
    bounds = np.concatenate(([0], np.asarray(step_indices if blocks is None else blocks, dtype=int), [n]))
    block = interval_of_samples(bounds)
    lengths = np.maximum(np.diff(bounds), 1)
    level_sigma = 1.2533 * noise_rms(np.asarray(measured_voltage, dtype=float)) / np.sqrt(lengths)
    rng = np.random.default_rng(seed)
    members = np.empty((count, n), dtype=np.float32)
    level_changes = np.zeros((count, x.size))

    def simulated():        # members drawn in order (the same draws), simulated one per core at a time
        chunk = default_workers()
        for first in range(0, count, chunk):
            drawn = [(rng.choice((-1.0, 1.0), size=len(lengths)), moved_levels(voltage, level_sigma, block, rng))
                     for _ in range(min(chunk, count - first))]
            predicted = map_in_order(lambda draw: _predict(kind, x, draw[1], sample_time, switch), drawn)
            yield from ((signs, *result) for (signs, _), result in zip(drawn, predicted))
    for k, (signs, moved, member) in enumerate(simulated()):
        redrawn = modelled + signs[block] * residual
        target = (redrawn - moved)[used]
        change = inverse @ np.array([np.dot(jacobian[:, i].astype(float), target) for i in range(x.size)])
        level_target = (modelled - moved)[used]
        level_changes[k] = inverse @ np.array([np.dot(jacobian[:, i].astype(float), level_target)
                                               for i in range(x.size)])
        for i in range(x.size):
            member += emf_jacobian[:, i] * change[i]
        if not np.all(np.isfinite(member)):
            return (None, {}) if with_errors else None
        members[k] = member - emf
    if not with_errors:
        return members
    # the wild bootstrap's exact covariance: scores J_t r_t summed over each input interval
    scores = np.zeros((len(lengths), x.size))
    for i in range(x.size):
        np.add.at(scores[:, i], block[used], jacobian[:, i].astype(float) * residual[used])
    covariance = inverse @ (scores.T @ scores) @ inverse + level_changes.T @ level_changes / count
    sigma = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    errors = {'motor_resistance': float(sigma[0 if kind == 'inductance' else 3])}
    if kind == 'inductance':
        errors['electrical_time_constant'] = float(sigma[1])
    return members, errors


#: The inductance refinement is dropped when the quasi-static observer explains the current better with this
#: Diebold-Mariano statistic (one-sided, ~1 %), in spite of the refinement nesting it.
REFINEMENT_REJECT = 2.33
#: A diverging trial (an unstable rate for the sample time) is scored as this many amperes off.
DIVERGED_CURRENT = 100.0


def _bounded(values: np.ndarray) -> np.ndarray:
    return np.clip(np.nan_to_num(values, nan=DIVERGED_CURRENT, posinf=DIVERGED_CURRENT, neginf=-DIVERGED_CURRENT),
                   -DIVERGED_CURRENT, DIVERGED_CURRENT)


def _resistance_from_steps(voltage: np.ndarray, current: np.ndarray, step_indices: np.ndarray,
                           sample_time: float) -> float:
    """Rm from the current jump across each step (e is continuous): median of dVa/dIa over the larger steps.

    The current is extrapolated to the step from ~12 ms on either side (6 samples at 490 Hz, at least 3 at a
    low rate, where the motor speed moves between samples and the estimate is rougher).
    """
    ratios, weights = [], []
    n = voltage.size
    settling = settling_samples(sample_time)
    span = max(3, int(round(RESISTANCE_SPAN / sample_time)))
    for k in step_indices:
        a, b = k - span, k + settling + span
        if a < 0 or b > n:
            continue
        d_voltage = np.median(voltage[k:b]) - np.median(voltage[a:k])
        before = np.polyval(np.polyfit(np.arange(a, k), current[a:k], 1), k)
        after_index = np.arange(k + settling, b)
        after = np.polyval(np.polyfit(after_index, current[after_index], 1), k)
        d_current = after - before
        if abs(d_voltage) > 0.05 and d_current * d_voltage > 0:
            ratios.append(d_voltage / d_current)
            weights.append(abs(d_voltage))
    if not ratios:
        return 1.0
    order = np.argsort(ratios)
    cumulative = np.cumsum(np.asarray(weights)[order])
    return float(np.asarray(ratios)[order][np.searchsorted(cumulative, cumulative[-1] / 2)])


def _rate_ratios_from_steady_states(voltage, emf, step_indices, sample_time) -> tuple[float, float]:
    """p2/p1 and p3/p1 from the steady state at the end of each long step: p1 (Va - e) = p2 e + p3 e|e|."""
    bounds = np.concatenate(([0], step_indices, [voltage.size])).astype(int)
    rows, rhs = [], []
    for a, b in zip(bounds[:-1], bounds[1:]):
        if b - a < int(0.4 / sample_time):
            continue
        tail = slice(b - int(0.1 / sample_time), b)
        e_end = float(np.median(emf[tail]))
        rows.append([e_end, e_end * abs(e_end)])
        rhs.append(float(np.median(voltage[tail])) - e_end)
    if len(rows) < 2:
        return 0.1, 0.1
    ratios, *_ = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)
    return tuple(max(float(r), 0.0) for r in ratios)


__all__ = ['MotorFit', 'fit_motor', 'refit_shared', 'back_emf_ensemble', 'interval_of_samples', 'moved_levels',
           'PARAMETER_NAMES', 'PARAMETER_UNITS']
