"""Output-error fit of the pendulum equation driven by the measured Va and Ia (multiple shooting).

The model simulated here is what can be known from the rig's three signals::

    dy/dt = W
    dW/dt = -a sin y - b W + g(Va) k e|e|  (+ pendulum effects),   e = Va - R Ia   (eq 5 in volts)
    measured angle = y (+ offset)

with a = mgd/J [1/s^2], b = c/J [1/s], k = (L/J) Kq (N2/(N1 Kw))^2 [rad/s^2 per V^2] and R the armature
resistance [ohm] (fitted too: eq 5's thrust vanishes at Va = R Ia). A thrust lag filters k e|e| through a
first-order lag; a dead zone gates it by Va.

The angle is simulated free-running from the measured inputs (no angle feedback) over segments of ~10 s, each with
its own fitted initial angle and rate; parameters come from :func:`scipy.optimize.least_squares` (trust region)
with a Jacobian by forward differences computed as one batched simulation. Built-in effects run in a compiled
(numba) kernel, and so do discovered terms and a user's own pendulum effect that numba compiles
(:mod:`aeropend_core.diagnosis.user_kernel`); one it cannot compile runs in a vectorised numpy loop that implements
the same scheme.

Integration: classical RK4 with step 2 Ts, so the input at the half step is an actual sample.
"""
from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field

import numba
import numpy as np
from scipy.optimize import least_squares
from threadpoolctl import threadpool_limits

from aeropend_core.errors import AeropendError, InsufficientDataError
from aeropend_core.model.effects import (FRICTION_SMOOTHING, KERNEL_KINDS, PENDULUM, find_parameter, get_effect,
                                         kernel_parameter, wants_thrust)
from aeropend_core.model.names import NOMINAL_PARAMETERS
from aeropend_core.diagnosis.jacobian_blocks import block_jacobian
from aeropend_core.parallel import in_segment_chunks, map_in_order, workers_for
from aeropend_core.diagnosis.sensitivity import EXACT_COLUMNS, friction_term, sensitivity_kernel
from aeropend_core.diagnosis.term_kernel import term_value
from aeropend_core.diagnosis.user_kernel import EXTRA_TYPE, compiled_user_terms, no_extra
from aeropend_core.model.sensor_filter import filter_angle
from aeropend_core.diagnosis.slow_remainder import named_remainder, sandwich_and_remainder
from aeropend_core.stats import effective_samples, held_bias_covariance, input_covariance

#: Column of each nominal parameter, then of each kernel kind, in the kernel's parameter row.
NOMINAL_COLUMNS = {name: column for column, name in enumerate(NOMINAL_PARAMETERS)}
KIND_COLUMNS = {kind: len(NOMINAL_PARAMETERS) + i for i, kind in enumerate(KERNEL_KINDS)}
N_BUILTIN = len(NOMINAL_COLUMNS) + len(KIND_COLUMNS)
#: Samples per integration step (RK4 half step lands on a sample).
STRIDE = 2
#: Smallest thrust-lag time constant the explicit RK4 step handles [s].
MIN_TIME_CONSTANT = 0.005
#: Dry friction is the catalog's law, Fc tanh(W / FRICTION_SMOOTHING), the one the effect is defined (and
#: simulated) with. Its stiffness Fc / width times the step h must stay below RK4's stability limit (2.78): the
#: width is widened to Fc h / FRICTION_STABILITY only beyond that (Fc > ~6 rad/s^2 at 490 Hz). A width of
#: max(5 mrad/s, Fc h / 2) used before made the model's friction sharper than the law below Fc ~ 5 and smoother
#: above: a bias of several percent in Fc that longer records turned into many sigma (3.0 -> 2.88 +- 0.012).
FRICTION_STABILITY = 2.5


# A thrust gate (dead zone) switches with Va, which the rig holds over each sample [t_i, t_i + Ts). Over one RK4
# step [t_i, t_i + 2 Ts] the gate is g_i, then g_{i+1}: the step's start uses g_i, its midpoint their mean and its
# end g_{i+1}, so Simpson's weights give the exact impulse Ts (g_i + g_{i+1}). Reading the gate as a point value at
# t_i, t_i + Ts, t_i + 2 Ts (as the continuous back-EMF is read) switched the thrust half a sample early on
# average, a lead the fit absorbed by shrinking every per-inertia parameter: -0.75 % on gravity_stiffness and
# thrust_gain of 300 s dead-zone records (z -5 to -16).
_F1, _F2, _F3, _I1 = numba.float64[::1], numba.float64[:, ::1], numba.float64[:, :, ::1], numba.int64[::1]


# One explicit signature (C-contiguous arrays; :func:`_run_kernel` converts): the users' term comes in as a
# first-class function of one fixed type, so this kernel is compiled once and cached for every user effect.
@numba.njit(numba.void(_F2, _F1, _F1, _F1, _I1, _I1, _F3, numba.float64, numba.boolean, numba.boolean, _F2,
                       numba.int64, numba.int64, EXTRA_TYPE, numba.boolean, numba.float64), cache=True, nogil=True)
def _simulate_kernel(theta, voltage, current, gate_signal, seg_start, seg_stop, initial, sample_time, lag_on, gate_on,
                     out, term_code, term_column, extra, extra_on, friction_smoothing):
    """RK4 free-run of every parameter row over every segment; writes predicted measured angle into `out`.

    Row columns: the nominal parameters, then the kernel kinds in ``KERNEL_KINDS`` order (rate_sign, rate_square,
    angle_linear, measured_offset, thrust_lag_time, thrust_threshold); a discovered term `term_code`
    (:mod:`aeropend_core.diagnosis.term_kernel`, -1: none) enters with the coefficient in column `term_column`;
    with `extra_on`, the users' effects enter as ``extra(angle, rate, thrust, row)``
    (:mod:`aeropend_core.diagnosis.user_kernel`); dry friction's sign is smoothed over `friction_smoothing`
    [rad/s] (the catalog's FRICTION_SMOOTHING but in the refits of :mod:`aeropend_core.diagnosis.friction_doubt`)."""
    h = STRIDE * sample_time
    n_rows = theta.shape[0]
    for row in range(n_rows):
        a = theta[row, 0]
        b = theta[row, 1]
        k = theta[row, 2]
        r = theta[row, 3]
        fc = theta[row, 4]
        cd = theta[row, 5]
        kc = theta[row, 6]
        offset = theta[row, 7]
        tau = max(theta[row, 8], MIN_TIME_CONSTANT)
        vth = theta[row, 9]
        smooth = max(friction_smoothing, fc * h / FRICTION_STABILITY)
        c = theta[row, term_column] if term_code >= 0 else 0.0
        for s in range(seg_start.shape[0]):
            start = seg_start[s]
            stop = seg_stop[s]
            y = initial[row, s, 0]
            w = initial[row, s, 1]
            # Lagged thrust at the segment start: the lag filter run over the preceding 5 time constants.
            pre = start - int(5.0 * tau / sample_time) if lag_on else start
            if pre < 0:
                pre = 0
            decay = math.exp(-sample_time / tau)
            f = 0.0
            for j in range(pre, start + 1):
                e = voltage[j] - r * current[j]
                u = k * e * abs(e)
                if gate_on and gate_signal[j] < vth:
                    u = 0.0
                f = u if j == pre else decay * f + (1.0 - decay) * u
            i = start
            while True:
                out[row, i] = y + offset
                if i + STRIDE >= stop:
                    break
                # thrust input at t, t + h/2, t + h; the gate is held over each sample (note above the kernel)
                g_first = 1.0
                g_second = 1.0
                if gate_on:
                    g_first = 0.0 if gate_signal[i] < vth else 1.0
                    g_second = 0.0 if gate_signal[i + 1] < vth else 1.0
                u0 = 0.0
                u1 = 0.0
                u2 = 0.0
                for j in range(3):
                    idx = i + j
                    e = voltage[idx] - r * current[idx]
                    u = k * e * abs(e)
                    if j == 0:
                        u *= g_first
                    elif j == 1:
                        u *= 0.5 * (g_first + g_second)
                    else:
                        u *= g_second
                    if j == 0:
                        u0 = u
                    elif j == 1:
                        u1 = u
                    else:
                        u2 = u
                # RK4 on (y, w, f)
                t1 = f if lag_on else u0
                dy1 = w
                dw1 = -a * math.sin(y) - b * w + t1 - friction_term(fc, w, smooth) - cd * w * abs(w) - kc * y
                dw1 += c * term_value(term_code, y, w, t1)
                if extra_on:
                    dw1 += extra(y, w, t1, theta[row])
                df1 = (u0 - f) / tau
                y2 = y + 0.5 * h * dy1
                w2 = w + 0.5 * h * dw1
                f2 = f + 0.5 * h * df1
                t2 = f2 if lag_on else u1
                dy2 = w2
                dw2 = -a * math.sin(y2) - b * w2 + t2 - friction_term(fc, w2, smooth) - cd * w2 * abs(w2) - kc * y2
                dw2 += c * term_value(term_code, y2, w2, t2)
                if extra_on:
                    dw2 += extra(y2, w2, t2, theta[row])
                df2 = (u1 - f2) / tau
                y3 = y + 0.5 * h * dy2
                w3 = w + 0.5 * h * dw2
                f3 = f + 0.5 * h * df2
                t3 = f3 if lag_on else u1
                dy3 = w3
                dw3 = -a * math.sin(y3) - b * w3 + t3 - friction_term(fc, w3, smooth) - cd * w3 * abs(w3) - kc * y3
                dw3 += c * term_value(term_code, y3, w3, t3)
                if extra_on:
                    dw3 += extra(y3, w3, t3, theta[row])
                df3 = (u1 - f3) / tau
                y4 = y + h * dy3
                w4 = w + h * dw3
                f4 = f + h * df3
                t4 = f4 if lag_on else u2
                dy4 = w4
                dw4 = -a * math.sin(y4) - b * w4 + t4 - friction_term(fc, w4, smooth) - cd * w4 * abs(w4) - kc * y4
                dw4 += c * term_value(term_code, y4, w4, t4)
                if extra_on:
                    dw4 += extra(y4, w4, t4, theta[row])
                df4 = (u2 - f4) / tau
                y = y + h / 6.0 * (dy1 + 2.0 * dy2 + 2.0 * dy3 + dy4)
                w = w + h / 6.0 * (dw1 + 2.0 * dw2 + 2.0 * dw3 + dw4)
                if lag_on:
                    f = f + h / 6.0 * (df1 + 2.0 * df2 + 2.0 * df3 + df4)
                i += STRIDE


def _simulate_numpy(theta, voltage, current, gate_signal, seg_start, seg_stop, initial, sample_time, lag_on, gate_on,
                    out, user_terms, friction_smoothing=FRICTION_SMOOTHING):
    """The kernel's scheme in numpy, vectorised over parameter rows; also runs users' pendulum effects.

    `user_terms` is a list of ``(function, {parameter name: column})``; a function with a ``thrust`` keyword also gets
    the thrust's angular acceleration [rad/s^2] (:func:`aeropend_core.model.effects.wants_thrust`); dry friction's
    sign is smoothed over `friction_smoothing` [rad/s] as in the kernel.
    """
    h = STRIDE * sample_time
    a, b, k, r, fc, cd, kc, offset = (theta[:, c] for c in range(8))
    tau = np.maximum(theta[:, 8], MIN_TIME_CONSTANT)
    vth = theta[:, 9]
    smooth = np.maximum(friction_smoothing, fc * h / FRICTION_STABILITY)

    def gate(idx):
        return np.where(gate_signal[idx] < vth, 0.0, 1.0) if gate_on else 1.0

    def thrust(idx, factor=None):
        e = voltage[idx] - r * current[idx]
        return k * e * np.abs(e) * (gate(idx) if factor is None else factor)

    def accel(y, w, t):
        value = -a * np.sin(y) - b * w + t - fc * np.tanh(w / smooth) - cd * w * np.abs(w) - kc * y
        for function, columns in user_terms:
            values = {name: theta[:, c] for name, c in columns.items()}
            value = value + (function(y, w, **values, thrust=t) if wants_thrust(function) else function(y, w, **values))
        return value

    for s in range(len(seg_start)):
        start, stop = int(seg_start[s]), int(seg_stop[s])
        y, w = initial[:, s, 0].copy(), initial[:, s, 1].copy()
        f = thrust(start)
        if lag_on:  # lagged thrust at the start: the lag filter over the preceding 5 time constants
            decay = np.exp(-sample_time / tau)
            first = max(0, start - int(5.0 * np.max(tau) / sample_time))
            f = thrust(first)
            for j in range(first + 1, start + 1):
                f = decay * f + (1.0 - decay) * thrust(j)
        i = start
        while True:
            out[:, i] = y + offset
            if i + STRIDE >= stop:
                break
            # the gate is held over each sample (note above _simulate_kernel): samples i, i + 1 cover this step
            g_first, g_second = gate(i), gate(i + 1)
            u0, u1, u2 = thrust(i, g_first), thrust(i + 1, 0.5 * (g_first + g_second)), thrust(i + 2, g_second)
            t1 = f if lag_on else u0
            dy1, dw1, df1 = w, accel(y, w, t1), (u0 - f) / tau
            y2, w2, f2 = y + 0.5 * h * dy1, w + 0.5 * h * dw1, f + 0.5 * h * df1
            dy2, dw2, df2 = w2, accel(y2, w2, f2 if lag_on else u1), (u1 - f2) / tau
            y3, w3, f3 = y + 0.5 * h * dy2, w + 0.5 * h * dw2, f + 0.5 * h * df2
            dy3, dw3, df3 = w3, accel(y3, w3, f3 if lag_on else u1), (u1 - f3) / tau
            y4, w4, f4 = y + h * dy3, w + h * dw3, f + h * df3
            dy4, dw4, df4 = w4, accel(y4, w4, f4 if lag_on else u2), (u2 - f4) / tau
            y = y + h / 6.0 * (dy1 + 2 * dy2 + 2 * dy3 + dy4)
            w = w + h / 6.0 * (dw1 + 2 * dw2 + 2 * dw3 + dw4)
            if lag_on:
                f = f + h / 6.0 * (df1 + 2 * df2 + 2 * df3 + df4)
            i += STRIDE


@dataclass(frozen=True)
class Structure:
    """Which effects the pendulum model has, and how their parameters map onto the simulation row."""

    effects: tuple[str, ...] = ()
    #: Rate over which dry friction's sign is smoothed [rad/s]: the catalog's law, varied only to measure how much
    #: the parameters depend on the law's shape (:mod:`aeropend_core.diagnosis.friction_doubt`).
    friction_smoothing: float = FRICTION_SMOOTHING

    def __post_init__(self) -> None:
        for name in self.effects:
            effect = get_effect(name)
            if not effect.compiled and effect.kind != PENDULUM:
                raise AeropendError(f'effect {name!r}: only pendulum-kind user effects can be fitted '
                                    f'(it is {effect.kind!r})')

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """All physical parameter names, nominal first (effect parameters keep their catalog names)."""
        names = list(NOMINAL_PARAMETERS)
        for name in self.effects:
            names.extend(get_effect(name).parameter_names)
        return tuple(names)

    @property
    def lag_on(self) -> bool:
        return kernel_parameter(self.effects, 'thrust_lag_time') is not None

    @property
    def gate_on(self) -> bool:
        return kernel_parameter(self.effects, 'thrust_threshold') is not None

    @property
    def filter_on(self) -> bool:
        return kernel_parameter(self.effects, 'measured_lowpass') is not None

    @property
    def offset_parameter(self) -> str | None:
        """The parameter that offsets the measured angle, if an effect in the model has one."""
        return kernel_parameter(self.effects, 'measured_offset')

    @property
    def gate_parameter(self) -> str | None:
        """The thrust gate's threshold parameter [V] (profiled over the input levels), if any."""
        return kernel_parameter(self.effects, 'thrust_threshold')

    def kernel_columns(self) -> dict[str, int]:
        """Row column of each compiled effect parameter."""
        columns = {}
        for name in self.effects:
            for kind, parameter in get_effect(name).kernel_terms:
                columns[parameter] = KIND_COLUMNS[kind]
        return columns

    def user_terms(self) -> list[tuple]:
        """User (non-built-in) effects with the row column of each of their parameters."""
        terms, column = [], N_BUILTIN
        for name in self.effects:
            effect = get_effect(name)
            if effect.compiled:
                continue
            columns = {}
            for parameter in effect.parameter_names:
                columns[parameter] = column
                column += 1
            terms.append((effect.function, columns))
        return terms

    def row(self, values: dict[str, float]) -> np.ndarray:
        """The simulation row for a parameter dict (absent effects contribute zeros)."""
        terms = self.user_terms()
        width = N_BUILTIN + sum(len(columns) for _, columns in terms)
        row = np.zeros(width)
        columns = {**NOMINAL_COLUMNS, **self.kernel_columns()}
        for name, value in values.items():
            if name in columns:
                row[columns[name]] += value
        for _, columns in terms:
            for name, column in columns.items():
                row[column] = values[name]
        return row


@dataclass
class SegmentedData:
    """Conditioned inputs and measured angle with the segments to simulate.

    Attributes
    ----------
    voltage, current : ndarray, shape (n,)
        Thrust voltage and current [V], [A]: the thrust term uses e = voltage - R current (conditioned Va and Ia,
        or the motor observer's back-EMF with zero current).
    angle : ndarray, shape (n,)
        Measured angle [rad].
    segments : list of (start, stop)
        Sample ranges simulated independently, each with its own initial state.
    sample_time : float
        Ts [s].
    gate_signal : ndarray, shape (n,), optional
        The armature voltage [V] a thrust gate compares with its threshold (default: `voltage`).
    valid : ndarray of bool, shape (n,), optional
        Samples that were measured (False: filled in a gap of lost samples); only valid samples give residuals.
    voltage_ensemble : ndarray, shape (members, n), optional
        Changes of `voltage` [V] that its own estimation allows (the motor observer's back-EMF ensemble): a fit
        adds the spread they cause in its parameters to their covariance (:func:`fit_output_error`).
    hold_starts : ndarray of int, optional
        Samples where the input steps: the angle is held between them.
    held_bias_rms : float [rad]
        RMS of a bias of the measured angle held over each input interval (an ADC that does not dither,
        :func:`aeropend_core.signals.preprocess.quantisation_bias_rms`); added to the covariance of a fit.
    min_samples : int [-]
        Fewest samples a segment may have (4 integration steps for a fit; one step, 2 STRIDE, for a k-step
        prediction, which fits nothing: at 25-60 Hz a 0.1 s horizon is 2-6 samples).
    """

    voltage: np.ndarray
    current: np.ndarray
    angle: np.ndarray
    segments: list[tuple[int, int]]
    sample_time: float
    gate_signal: np.ndarray | None = None
    valid: np.ndarray | None = None
    voltage_ensemble: np.ndarray | None = None
    hold_starts: np.ndarray | None = None
    held_bias_rms: float = 0.0
    min_samples: int = 4 * STRIDE

    def __post_init__(self) -> None:
        if self.gate_signal is None:
            self.gate_signal = self.voltage
        starts = np.array([s for s, _ in self.segments], dtype=np.int64)
        stops = np.array([e for _, e in self.segments], dtype=np.int64)
        if len(starts) == 0 or np.any(stops - starts < self.min_samples):
            short = int(np.min(stops - starts)) if len(starts) else 0
            raise InsufficientDataError(f'each segment needs at least {self.min_samples} samples ({short} given: '
                                        f'{short * self.sample_time:.3g} s at {1 / self.sample_time:.4g} Hz); give a '
                                        'longer record')
        self.seg_start, self.seg_stop = starts, stops
        # Residuals are taken where the integrator lands: every STRIDE-th sample of each segment.
        self.residual_index = np.concatenate([np.arange(s, e, STRIDE) for s, e in self.segments])
        self.segment_of_residual = np.concatenate([np.full(len(range(s, e, STRIDE)), i)
                                                   for i, (s, e) in enumerate(self.segments)])
        if self.valid is not None:
            keep = np.asarray(self.valid, dtype=bool)[self.residual_index]
            self.residual_index = self.residual_index[keep]
            self.segment_of_residual = self.segment_of_residual[keep]

    def simulate(self, structure: Structure, rows: np.ndarray, initial: np.ndarray,
                 voltage: np.ndarray | None = None) -> np.ndarray:
        """Predicted measured angle for each row: array (n_rows, n); NaN outside the residual samples.

        `voltage` [V] replaces the thrust voltage (e.g. a member of the input ensemble).
        """
        voltage = self.voltage if voltage is None else np.asarray(voltage, dtype=float)
        rows = np.atleast_2d(np.asarray(rows, dtype=float))
        initial = np.asarray(initial, dtype=float).reshape(len(rows), len(self.segments), 2)
        out = np.full((len(rows), len(self.angle)), np.nan)
        terms = structure.user_terms()
        code = getattr(terms[0][0], 'term_code', -1) if len(terms) == 1 else -1
        if code >= 0:       # a discovered term: compiled too (aeropend_core.diagnosis.term_kernel)
            _run_kernel(self, structure, rows, voltage, initial, out, code, next(iter(terms[0][1].values())))
        elif terms and (extra := compiled_user_terms(terms)) is not None:     # users' effects, compiled by numba
            _run_kernel(self, structure, rows, voltage, initial, out, extra=extra)
        elif terms:         # a user's effect numba cannot compile (said once, aeropend_core.diagnosis.user_kernel)
            _simulate_numpy(rows, voltage, self.current, self.gate_signal, self.seg_start, self.seg_stop, initial,
                            self.sample_time, structure.lag_on, structure.gate_on, out, terms,
                            structure.friction_smoothing)
        else:
            _run_kernel(self, structure, rows, voltage, initial, out)
        if structure.filter_on:
            # the sensor's low-pass acts on the simulated measured angle (linear: after the offset is the same)
            column = KIND_COLUMNS['measured_lowpass']
            for row in range(len(rows)):
                delay = rows[row, column]
                if delay <= 0:
                    continue
                for s, (start, stop) in enumerate(zip(self.seg_start, self.seg_stop)):
                    index = np.arange(start, stop, STRIDE)
                    index = index[np.isfinite(out[row, index])]
                    out[row, index] = filter_angle(out[row, index], delay, STRIDE * self.sample_time,
                                                   initial[row, s, 1])
        return out


def _run_kernel(data: SegmentedData, structure: Structure, rows: np.ndarray, voltage: np.ndarray,
                initial: np.ndarray, out: np.ndarray, term_code: int = -1, term_column: int = 0, extra=None) -> None:
    """:func:`_simulate_kernel` with its arguments in the types of its one signature (C-contiguous float64 and
    int64 arrays); writes into `out` [rad] (C-contiguous float64). Segments split over threads but users' effects."""
    f = np.ascontiguousarray
    rows, voltage, current, gate = (f(x, dtype=np.float64) for x in (rows, voltage, data.current, data.gate_signal))
    start, stop, initial = f(data.seg_start, dtype=np.int64), f(data.seg_stop, dtype=np.int64), f(initial, dtype=float)
    def run(a, b):
        _simulate_kernel(rows, voltage, current, gate, start[a:b], stop[a:b], f(initial[:, a:b]),
                         float(data.sample_time), bool(structure.lag_on), bool(structure.gate_on), out, int(term_code),
                         int(term_column), no_extra if extra is None else extra, extra is not None,
                         float(structure.friction_smoothing))
    in_segment_chunks(run, start, stop) if extra is None else run(0, len(start))


@dataclass
class OutputErrorFit:
    """Result of :func:`fit_output_error`. Parameter dicts are SI (see :data:`NOMINAL_PARAMETERS` and the catalog);
    ``estimator`` is ``'output_error'``.

    ``standard_errors`` are 1-sigma from the sandwich (HAC) covariance, valid under correlated residuals
    (:mod:`aeropend_core.diagnosis.evidence`); ``residuals`` are the training residuals [rad] at
    ``data.residual_index``.
    ``correlation`` is the parameter correlation matrix in ``free_names`` order.
    """

    structure: Structure
    parameters: dict[str, float]
    standard_errors: dict[str, float]
    initial_states: np.ndarray
    residual_rms: float
    n_residuals: int
    n_free: int
    free_names: tuple[str, ...]
    correlation: np.ndarray
    effective_samples: float
    success: bool
    message: str = ''
    residuals: np.ndarray | None = field(default=None, repr=False)
    extra: dict = field(default_factory=dict)

    @property
    def bic(self) -> float:
        """Bayesian information criterion with the effective number of independent residuals."""
        n = self.effective_samples
        return float(n * math.log(max(self.residual_rms, 1e-300) ** 2) + self.n_free * math.log(n))


def initial_states_from_data(data: SegmentedData, offset: float = 0.0) -> np.ndarray:
    """Initial (angle, rate) per segment from the measured angle: local line fit over the first 40 ms."""
    states = np.zeros((len(data.segments), 2))
    window = max(3, int(round(0.04 / data.sample_time)))
    for s, (start, stop) in enumerate(data.segments):
        piece = data.angle[start:min(start + window, stop)] - offset
        t = np.arange(piece.size) * data.sample_time
        slope, intercept = np.polyfit(t, piece, 1)
        states[s] = intercept, slope
    return states


#: Magnitude of a meaningful change of each nominal parameter (optimiser scaling).
_NOMINAL_SCALE = {'gravity_stiffness': 100.0, 'damping': 10.0, 'thrust_gain': 100.0, 'armature_resistance': 1.0}


def _default_scale(name: str, value: float) -> float:
    found = find_parameter(name)
    typical = _NOMINAL_SCALE.get(name, (found[1].scale if found and found[1].scale else 1.0))
    return max(abs(value), typical * 0.1, 1e-6)


#: Above this many multiple-shooting segments the Jacobian is kept sparse and the trust-region steps use LSMR
#: (a 60 s record has ~6 training segments: the exact dense solver, as before).
SPARSE_SEGMENTS = 12
#: Optimiser scale of a segment's initial angle [rad] and rate [rad/s].
IC_SCALE = np.array([0.1, 1.0])


def fit_output_error(data: SegmentedData, structure: Structure, start: dict[str, float],
                     fixed: dict[str, float] | None = None, max_iterations: int = 60,
                     initial_states: np.ndarray | None = None, covariance: bool = True) -> OutputErrorFit:
    """Fit the parameters of `structure` and the segments' initial states to the measured angle.

    Parameters
    ----------
    data : SegmentedData
    structure : Structure
    start : dict
        Starting values for every parameter in ``structure.parameter_names`` (SI).
    fixed : dict, optional
        Parameters held at given values (e.g. a profiled dead-zone threshold).
    max_iterations : int [-]
        Most residual evaluations of the optimiser.
    initial_states : ndarray, shape (segments, 2), optional [rad, rad/s]
        Starting (angle, rate) per segment, e.g. a related model's fitted ones on the same segments. Used on the
        long-record (sparse) path only, where re-converging hundreds of initial states from the data's line fits
        costs most of a fit's iterations; short records always start from the data (their results unchanged).
    covariance : bool
        False: the parameters and the residuals only, for a refit whose standard errors nobody reads (a profile's
        or a doubt's refits read the cost and the parameters): ``standard_errors`` and ``correlation`` are NaN,
        and the simulations of the input ensemble's spread (one per member) are not run.
    """
    fixed = dict(fixed or {})
    names = structure.parameter_names
    missing = [n for n in names if n not in start and n not in fixed]
    if missing:
        raise ValueError(f'no starting value for {missing}')
    free = tuple(n for n in names if n not in fixed)
    scale = np.array([_default_scale(n, start[n]) for n in free])
    lower, upper = _bounds(free)
    x0 = np.clip(np.array([start[n] for n in free]), lower + 1e-9 * scale, upper - 1e-9 * scale) / scale
    n_seg = len(data.segments)
    offset_name = structure.offset_parameter
    initial0 = initial_states_from_data(data, start.get(offset_name, fixed.get(offset_name, 0.0)) if offset_name
                                        else 0.0)
    ic_scale = IC_SCALE
    z0 = np.concatenate([x0, (initial0 / ic_scale).ravel()])
    base_values = {n: fixed.get(n, start.get(n)) for n in names}
    residual_index = data.residual_index
    measured = data.angle[residual_index]
    n_free = len(free)

    def unpack(z):
        values = dict(base_values)
        values.update(zip(free, z[:n_free] * scale))
        return values, z[n_free:].reshape(n_seg, 2) * ic_scale

    def rows_for(zs):
        rows, initials = [], []
        for z in zs:
            values, initial = unpack(z)
            rows.append(structure.row(values))
            initials.append(initial)
        return np.array(rows), np.array(initials)

    cache, exact = {}, exact_columns(structure, free)

    def residuals(z):
        key = z.tobytes()
        if key not in cache:
            rows, initials = rows_for([z])
            cache.clear()
            # exact sensitivities: their pass simulates the same numbers; its Jacobian is asked at each accepted point
            cache[key] = (_exact_jacobian(data, structure, rows[0], initials[0], exact, scale, measured)[::-1]
                          if exact is not None else
                          (_bounded(data.simulate(structure, rows, initials)[0, residual_index] - measured),))
        return cache[key][0]

    def jacobian(z):
        r0 = residuals(z)
        seg = data.segment_of_residual
        if exact is not None:
            # exact sensitivities in one pass (aeropend_core.diagnosis.sensitivity); differences for the rest
            initial, dense = cache[z.tobytes()][1:]
            differenced = [i for i in range(n_free) if exact[i] < 0]
            if differenced:
                step = 1e-6 * np.maximum(np.abs(z), 1.0)
                perturbed = [z.copy() for _ in differenced]
                for row, i in enumerate(differenced):
                    perturbed[row][i] += step[i]
                rows, initials = rows_for(perturbed)
                predictions = _bounded(data.simulate(structure, rows, initials)[:, residual_index] - measured)
                for row, i in enumerate(differenced):
                    dense[:, i] = (predictions[row] - r0) / step[i]
        else:
            step = 1e-6 * np.maximum(np.abs(z), 1.0)
            perturbed = [z.copy() for _ in range(n_free + 2)]
            for i in range(n_free):
                perturbed[i][i] += step[i]
            # one row perturbs every segment's initial angle, one every initial rate: segments are independent
            ic_angle = n_free + 2 * np.arange(n_seg)
            perturbed[n_free][ic_angle] += step[ic_angle]
            perturbed[n_free + 1][ic_angle + 1] += step[ic_angle + 1]
            rows, initials = rows_for(perturbed)
            predictions = _bounded(data.simulate(structure, rows, initials)[:, residual_index] - measured)
            dense = ((predictions[:n_free] - r0) / step[:n_free, None]).T            # (residuals, parameters)
            initial = [(predictions[n_free + j] - r0) / step[n_free + 2 * seg + j] for j in range(2)]
        if sparse_jacobian:
            return block_jacobian(dense, initial, seg, len(z))     # [parameters | block-diagonal initial states]
        jac = np.zeros((len(r0), len(z)))
        jac[:, :n_free] = dense
        for j in range(2):
            jac[np.arange(len(r0)), n_free + 2 * seg + j] = initial[j]
        return jac

    if initial_states is not None and n_seg > SPARSE_SEGMENTS and np.shape(initial_states) == (n_seg, 2) \
            and np.all(np.isfinite(initial_states)):
        # the given states or the data's line fits, whichever simulates the data better from the start values
        # (600 s record with Coulomb friction: adding cable torque or an angle offset to a model that holds the
        # friction took 41-51 evaluations from the data's states, 18-23 from the model's; adding the friction to
        # the nominal model took 48 instead of 26, the whole diagnosis 40.8 -> 38.0 s of CPU)
        z_given = np.concatenate([x0, (np.asarray(initial_states, dtype=float) / ic_scale).ravel()])
        if float(np.sum(residuals(z_given) ** 2)) < float(np.sum(residuals(z0) ** 2)):
            z0 = z_given
    # Long records: many segments make the dense Jacobian's SVD (trust-region step) grow like the cube of the
    # record length; with the block structure kept sparse, LSMR steps keep the fit linear in the record. Without
    # LSMR's extra regularisation the steps are the trust-region ones: on a 600 s record with Coulomb friction the
    # fit converged (ftol) in 41 evaluations to a lower cost, where the regularised steps used all 60 and stopped.
    sparse_jacobian = n_seg > SPARSE_SEGMENTS
    lower_z = np.concatenate([lower / scale, np.full(2 * n_seg, -np.inf)])
    upper_z = np.concatenate([upper / scale, np.full(2 * n_seg, np.inf)])
    # Small dense problems: multithreaded BLAS only adds contention (10x slower SVDs on a busy 2-core machine).
    with np.errstate(all='ignore'), threadpool_limits(1):
        result = least_squares(residuals, z0, jac=jacobian, bounds=(lower_z, upper_z), method='trf',
                               x_scale='jac', max_nfev=max_iterations, xtol=1e-8, ftol=1e-8,
                               tr_solver='lsmr' if sparse_jacobian else 'exact',
                               tr_options={'regularize': False} if sparse_jacobian else {})
    values, initial = unpack(result.x)
    r = result.fun
    n = len(r)
    rms = float(np.sqrt(np.mean(r ** 2)))
    effective = effective_samples(r)
    jac = result.jac
    p = jac.shape[1]
    if not covariance:
        nothing = np.full((n_free, n_free), np.nan)
        return OutputErrorFit(structure=structure, parameters={name: float(values[name]) for name in names},
                              standard_errors=dict.fromkeys(names, float('nan')), initial_states=initial,
                              residual_rms=rms, n_residuals=n, n_free=n_free + 2 * n_seg, free_names=free,
                              correlation=nothing, effective_samples=effective, success=bool(result.success),
                              message=str(result.message), residuals=r)
    # block-sum sandwich (correlated residuals); a slow remainder's extra variance only for the reported +-
    covariance_z, remainder = sandwich_and_remainder(jac, r, data.segment_of_residual, STRIDE * data.sample_time)
    covariance_z = covariance_z * n / max(n - p, 1)
    if data.voltage_ensemble is not None and len(data.voltage_ensemble) > 1:
        # the thrust input is itself an estimate: add the spread its estimation error causes in the parameters
        rows, initials = rows_for([result.x])

        def change(member):
            return _bounded(data.simulate(structure, rows, initials, data.voltage + member)[0, residual_index]
                            - measured) - r
        # one simulation per member, independent: side by side on the cores (serial inside a round's worker and
        # for long records; the same numbers either way)
        changes = map_in_order(change, data.voltage_ensemble, workers_for(len(data.angle)))
        covariance_z = covariance_z + input_covariance(jac, np.array(changes))
    if data.held_bias_rms > 0 and data.hold_starts is not None:
        blocks = np.searchsorted(np.asarray(data.hold_starts), residual_index, side='right')
        covariance_z = covariance_z + held_bias_covariance(jac, blocks, data.held_bias_rms)
    cov = covariance_z[:n_free, :n_free] * np.outer(scale, scale)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    # A parameter the simulated angle does not move carries no information: the pseudo-inverse would give it a
    # variance of ~0 (a filter delay of 0.09 ms on a 22 Hz log came out +- 5e-21 s, 1.8e16 sigma from zero); its
    # sigma is infinite instead
    sd[blind_columns(jac, n_free)] = np.inf
    with np.errstate(invalid='ignore', divide='ignore'):
        correlation = cov / np.outer(sd, sd)
    errors = {name: float(s) for name, s in zip(free, sd)}
    errors.update({name: float('nan') for name in fixed})      # held, not estimated: no sigma to claim
    parameters = {name: float(values[name]) for name in names}
    return OutputErrorFit(structure=structure, parameters=parameters, standard_errors=errors,
                          initial_states=initial, residual_rms=rms, n_residuals=n, n_free=n_free + 2 * n_seg,
                          free_names=free, correlation=correlation, effective_samples=effective,
                          success=bool(result.success), message=str(result.message), residuals=r,
                          extra={'slow_remainder': named_remainder(remainder, free, scale, n / max(n - p, 1))})


def blind_columns(jacobian, n_columns: int) -> np.ndarray:
    """Which of the first `n_columns` columns of `jacobian` (dense or sparse; parameters scaled to their typical
    size) are blind: every entry below 1e-10 of the largest column's size, so the data say nothing about that
    parameter. Boolean array of length `n_columns` [-]."""
    sizes = np.asarray(abs(jacobian[:, :n_columns]).sum(axis=0), dtype=float).ravel()
    largest = float(sizes.max()) if sizes.size else 0.0
    return sizes <= 1e-10 * largest if largest > 0 else np.ones(n_columns, dtype=bool)


#: Set AEROPEND_JACOBIAN=differences to fit with forward-difference Jacobians only (the method before exact
#: sensitivities; for comparisons).
JACOBIAN_VARIABLE = 'AEROPEND_JACOBIAN'


def exact_columns(structure: Structure, free: Sequence[str]) -> np.ndarray | None:
    """Row column of each free parameter whose derivative the sensitivity kernel gives exactly, -1 for one it
    does not (differenced); None where the whole Jacobian is differenced (users' effects, discovered terms, a
    sensor low-pass, or ``AEROPEND_JACOBIAN=differences``)."""
    if os.environ.get(JACOBIAN_VARIABLE, '').strip().lower() == 'differences':
        return None
    if structure.user_terms() or structure.filter_on:
        return None
    columns = {**NOMINAL_COLUMNS, **structure.kernel_columns()}
    return np.array([columns[name] if columns.get(name, -1) in EXACT_COLUMNS else -1 for name in free],
                    dtype=np.int64)


def _kernel_window(data: SegmentedData, structure: Structure, row: np.ndarray) -> tuple[int, int]:
    """[lo, hi) [samples] the kernels read: the first segment's start less the lag's run-in (5 time constants + 2
    samples; lo >= 0) to the last stop."""
    steps = 5.0 * max(float(row[KIND_COLUMNS['thrust_lag_time']]), MIN_TIME_CONSTANT) / data.sample_time
    run_in = (int(steps) + 2 if math.isfinite(steps) else len(data.angle)) if structure.lag_on else 0
    return max(int(np.min(data.seg_start)) - run_in, 0), int(np.max(data.seg_stop))


def _exact_jacobian(data: SegmentedData, structure: Structure, row: np.ndarray, initial: np.ndarray,
                    exact: np.ndarray, scale: np.ndarray, measured: np.ndarray) -> tuple[np.ndarray, list]:
    """(d residual / d free parameter (scaled), [d residual / d initial angle, d residual / d initial rate (scaled)],
    the bounded residuals [rad]) from one pass of :func:`aeropend_core.diagnosis.sensitivity.sensitivity_kernel`;
    columns of differenced parameters are left zero. Rows where the residual is clipped (a diverging trial) have
    zero derivative, as the clipped residual has."""
    tracked = np.array(sorted({int(c) for c in exact if c >= 0}), dtype=np.int64)
    # on the window its segments cover: a drift stretch of a long record fills no arrays of the record's length
    lo, hi = _kernel_window(data, structure, row)
    n = hi - lo
    out = np.full((1, n), np.nan)
    d_columns = np.zeros((n, len(tracked)))
    d_initial = np.zeros((n, 2))
    f = np.ascontiguousarray
    args = [f(x, dtype=np.float64) for x in (row, data.voltage[lo:hi], data.current[lo:hi], data.gate_signal[lo:hi])]
    start, stop, initial = f(data.seg_start - lo, dtype=np.int64), f(data.seg_stop - lo, dtype=np.int64), f(initial)
    in_segment_chunks(lambda a, b: sensitivity_kernel(
        *args, start[a:b], stop[a:b], f(initial[a:b], dtype=np.float64), float(data.sample_time),
        bool(structure.lag_on), bool(structure.gate_on), float(structure.friction_smoothing), float(MIN_TIME_CONSTANT),
        float(FRICTION_STABILITY), float(STRIDE), tracked, out, d_columns, d_initial), start, stop)
    index = data.residual_index - lo
    raw = out[0, index] - measured
    inside = np.isfinite(raw) & (np.abs(raw) < DIVERGED_RESIDUAL)
    position, gathered = {int(c): j for j, c in enumerate(tracked)}, d_columns[index]     # one gather of the rows
    dense = np.zeros((len(index), len(exact)))
    for i, column in enumerate(exact):
        if column >= 0:
            dense[:, i] = gathered[:, position[int(column)]] * scale[i]
    initial_columns = [d_initial[index, j] * IC_SCALE[j] for j in range(2)]
    dense[~(inside[:, None] & np.isfinite(dense))] = 0.0
    initial_columns = [np.where(inside & np.isfinite(c), c, 0.0) for c in initial_columns]
    return dense, initial_columns, _bounded(raw)


#: A simulation that diverges (unstable parameter trial) is scored as this many radians off, so the optimiser
#: backs away instead of failing on NaN.
DIVERGED_RESIDUAL = 10.0


def _bounded(residuals: np.ndarray) -> np.ndarray:
    return np.clip(np.nan_to_num(residuals, nan=DIVERGED_RESIDUAL, posinf=DIVERGED_RESIDUAL,
                                 neginf=-DIVERGED_RESIDUAL), -DIVERGED_RESIDUAL, DIVERGED_RESIDUAL)


def _bounds(free: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    lower, upper = [], []
    for name in free:
        if name in NOMINAL_PARAMETERS:
            lo, hi = (0.0, np.inf) if name != 'armature_resistance' else (0.0, 20.0)
        else:
            found = find_parameter(name)
            lo, hi = (found[1].lower, found[1].upper) if found else (-np.inf, np.inf)
            if found and ('thrust_lag_time', name) in found[0].kernel_terms:
                lo = max(lo, MIN_TIME_CONSTANT)     # the explicit RK4 step's smallest lag
        lower.append(lo)
        upper.append(hi)
    return np.array(lower, dtype=float), np.array(upper, dtype=float)


def simulate_angle(data: SegmentedData, fit_parameters: dict[str, float], structure: Structure,
                   initial: np.ndarray) -> np.ndarray:
    """Predicted measured angle [rad] over `data`'s segments (NaN where the integrator does not land)."""
    return data.simulate(structure, structure.row(fit_parameters)[None, :], initial[None])[0]


__all__ = ['NOMINAL_PARAMETERS', 'Structure', 'SegmentedData', 'OutputErrorFit', 'fit_output_error',
           'simulate_angle', 'initial_states_from_data']
