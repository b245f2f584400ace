"""Simulator of the full rig (electrical + motor + pendulum) under a zero-order-hold duty input at 490 Hz.

The model is stiff (La/Ra ~ 2 ms against a ~0.5 s pendulum). The default path is a compiled (numba) classical RK4
with eight fixed sub-steps per sample (h = 0.26 ms, La/Ra / 8); the reference path, used for users' own effects,
integrates each stretch of constant duty with LSODA (switches to BDF where stiff) and reads the state at the
sample instants. Tests check that both agree. Any catalog effect can be
enabled as hidden truth. The sample at index k is taken at t_k = k Ts, when duty[k] starts to be applied, like the
firmware sampling in the Timer1 overflow interrupt.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numba
import numpy as np

from aeropend_core.model.effects import (FRICTION_SMOOTHING, MEASUREMENT, PENDULUM, THRUST_GATE, THRUST_LAG,
                                         get_effect, kernel_coefficients, kernel_parameter, resolve_effects)
from aeropend_core.errors import AeropendError
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, SAMPLE_TIME, RigParameters
from aeropend_core.model.sensor_filter import StreamingFilter
from aeropend_core.sim.noise import MeasurementNoise, apply_measurement_noise

#: RK4 sub-steps per sample in the compiled path: h = Ts/8 = 0.26 ms, an eighth of La/Ra (error < 1e-6 rad).
SUBSTEPS = 8


@numba.njit(cache=True, nogil=True, inline='always')
def _rig_rates(constants, row, va, g, current, speed, angle, rate, lagged, rate_sign, rate_square, angle_linear,
               lag_time_constant, smoothing):
    """The rig's state derivative (dIa/dt, dw1/dt, dy/dt, dW/dt, d lagged thrust/dt) at one state under the armature
    voltage `va` [V] and the thrust gate `g` (0/1): the one copy of the physics that :func:`_rig_kernel` and the
    closed loop's batched kernel (:mod:`aeropend_core.control.loop`) integrate. `constants` (m, 12): rigs, this
    one's in `row` (a row, not a view of it: no reference counting per call); the rest as :func:`_rig_kernel`'s."""
    c = constants
    ra, la, kw, kt, jm, fr, kd, gear, kq, grav, damp, lever = (c[row, 0], c[row, 1], c[row, 2], c[row, 3], c[row, 4],
                                                               c[row, 5], c[row, 6], c[row, 7], c[row, 8], c[row, 9],
                                                               c[row, 10], c[row, 11])
    lag = lag_time_constant > 0.0
    prop = speed / gear
    prop_sq = prop * abs(prop)
    thrust_now = g * kq * prop_sq
    thrust = lagged if lag else thrust_now
    # no Coulomb friction: its term is a zero (tanh skipped); x - 0 * t = x - 0, also for a zero x, as the rate is
    # never -0 (the state starts at +0 and only sums) and -0 - damping * rate needs rate = 0 (the damping is not 0)
    friction = rate_sign * math.tanh(rate / smoothing) if rate_sign != 0.0 else 0.0
    return ((va - ra * current - kw * speed) / la,
            (kt * current - fr * speed - kd * prop_sq / gear) / jm,
            rate,
            (-grav * math.sin(angle) - damp * rate + lever * thrust
             - friction - rate_square * rate * abs(rate)
             - angle_linear * angle),
            (thrust_now - lagged) / lag_time_constant if lag else 0.0)


@numba.njit(cache=True, nogil=True, inline='always')
def _rk4_sample(constants, volts, gate, x, k, xt, h, rate_sign, rate_square, angle_linear, lag_time_constant,
                smoothing):
    """Advance m rigs over one sample: SUBSTEPS classical RK4 steps of size `h` [s] on :func:`_rig_rates`, the
    input held (`volts` [V], `gate` (m,): each rig's armature voltage and thrust gate), the rigs' stages
    interleaved. The one copy of the integrator that :func:`_rig_kernel` (m = 1) and the closed loop's batched
    kernel (:mod:`aeropend_core.control.loop`) run. `constants` (m, 12); `x` (m, 5) the states, updated in place;
    `k` (4, m, 5) and `xt` (m, 5) scratch; the effect coefficients as :func:`_rig_kernel`'s."""
    m = x.shape[0]
    for _ in range(SUBSTEPS):
        for stage in range(4):
            for d in range(m):
                if stage == 0:
                    for j in range(5):
                        xt[d, j] = x[d, j]
                else:
                    factor = h if stage == 3 else 0.5 * h
                    for j in range(5):
                        xt[d, j] = x[d, j] + factor * k[stage - 1, d, j]
                k[stage, d, 0], k[stage, d, 1], k[stage, d, 2], k[stage, d, 3], k[stage, d, 4] = _rig_rates(
                    constants, d, volts[d], gate[d], xt[d, 0], xt[d, 1], xt[d, 2], xt[d, 3], xt[d, 4], rate_sign,
                    rate_square, angle_linear, lag_time_constant, smoothing)
        for d in range(m):
            for j in range(5):
                x[d, j] += h / 6.0 * (k[0, d, j] + 2.0 * k[1, d, j] + 2.0 * k[2, d, j] + k[3, d, j])


@numba.njit(cache=True, nogil=True)
def _rig_kernel(constants, voltage, gate, state, sample_time, rate_sign, rate_square, angle_linear,
                lag_time_constant, smoothing, states_out):
    """Full rig model, RK4 with SUBSTEPS fixed sub-steps per sample (:func:`_rk4_sample`, one rig), input held over
    each sample.

    constants: Ra, La, Kw, Kt, Jm, F, Kd, N1/N2, Kq, mgd/J, c/J, L/J. State: Ia, w1, y, W, lagged thrust.
    Compiled effects enter as the coefficients of the generic kernel kinds (``KERNEL_KINDS`` of the catalog):
    -rate_sign tanh(W/smoothing), -rate_square W|W|, -angle_linear y; lag_time_constant 0 = no lag.
    Writes the state at the start of each sample into states_out (n, 5); returns the final state.
    """
    h = sample_time / SUBSTEPS
    table = constants.reshape((1, constants.shape[0]))
    x = np.empty((1, 5))
    for j in range(5):
        x[0, j] = state[j]
    k = np.empty((4, 1, 5))
    xt = np.empty((1, 5))
    volts = np.empty(1)
    held_gate = np.empty(1)
    for i in range(voltage.shape[0]):
        for j in range(5):
            states_out[i, j] = x[0, j]
        volts[0] = voltage[i]
        held_gate[0] = gate[i]
        _rk4_sample(table, volts, held_gate, x, k, xt, h, rate_sign, rate_square, angle_linear, lag_time_constant,
                    smoothing)
    return x[0].copy()


#: Measured signals, in the CSV/bag column order, with their units.
MEASURED_SIGNALS = {'duty': '1', 'armature_voltage': 'V', 'armature_current': 'A', 'angle': 'rad'}
#: Truth signals of the simulator (never available on the rig), with their units.
TRUTH_SIGNALS = {'armature_current': 'A', 'motor_speed': 'rad/s', 'angle': 'rad', 'angular_rate': 'rad/s',
                 'thrust': 'N'}


@dataclass
class Trajectory:
    """Samples of one run. Arrays have shape (n_samples,); SI units.

    ``armature_voltage``, ``armature_current`` and ``angle`` are what the rig measures (with measurement effects,
    noise and quantisation if asked for); ``truth`` holds the noise-free states: ``armature_current`` [A],
    ``motor_speed`` [rad/s], ``angle`` [rad] (true, without sensor offset), ``angular_rate`` [rad/s], ``thrust`` [N].
    """

    time: np.ndarray
    duty: np.ndarray
    armature_voltage: np.ndarray
    armature_current: np.ndarray
    angle: np.ndarray
    truth: dict[str, np.ndarray] = field(default_factory=dict)
    sample_time: float = SAMPLE_TIME

    def __len__(self) -> int:
        return len(self.time)

    def columns(self, with_truth: bool = True) -> dict[str, np.ndarray]:
        """Columns for a CSV: ``t`` and the measured signals, then ``true_*`` truth columns."""
        columns = {'t': self.time, 'duty': self.duty, 'armature_voltage': self.armature_voltage,
                   'armature_current': self.armature_current, 'angle': self.angle}
        if with_truth:
            columns.update({f'true_{name}': values for name, values in self.truth.items()})
        return columns


class RigSimulator:
    """Streaming simulator: each :meth:`run` call advances the rig by ``len(duty)`` samples.

    Parameters
    ----------
    parameters : RigParameters [SI, see RigParameters]
        Nominal parameters of the rig.
    effects : mapping, optional [SI unit of each effect parameter]
        Hidden effects, ``{name: {parameter: value}}`` or ``{name: value}`` for one-parameter effects.
    sample_time : float [s]
        Ts; 1/490 s on the rig.
    noise : MeasurementNoise, optional [-]
        Measurement noise and ADC quantisation added to Va, Ia and the angle. For a stream the PSNR refers to the
        fixed peaks in ``noise.peaks`` (defaults: the rig's full-scale values).
    seed : int, optional [-]
        Seed of the noise generator; the simulation itself is deterministic.
    initial_angle : float [rad]
        Initial rod angle, at rest.
    method : {'auto', 'compiled', 'lsoda'} [-]
        'compiled': fixed-step RK4 (Ts/8) compiled with numba, built-in effects only; 'lsoda': scipy's LSODA on
        each stretch of constant input (any effect, the reference); 'auto' picks 'compiled' when it can.

    Examples
    --------
    >>> import numpy as np
    >>> from aeropend_core import RigSimulator
    >>> simulator = RigSimulator()                                   # the default rig, state kept between calls
    >>> first, second = simulator.run(np.full(490, 0.5)), simulator.run(np.full(490, 0.5))     # two 1 s blocks
    >>> len(first.angle), bool(second.angle[0] != 0.0)               # the second block goes on from the first
    (490, True)
    """

    def __init__(self, parameters: RigParameters = DEFAULT_PARAMETERS,
                 effects: Mapping[str, Mapping[str, float] | float] | None = None,
                 sample_time: float = SAMPLE_TIME, noise: MeasurementNoise | None = None,
                 seed: int | None = None, initial_angle: float = 0.0, method: str = 'auto') -> None:
        if not sample_time > 0:
            raise AeropendError(f'sample_time must be positive, got {sample_time!r} s')
        self.parameters = parameters
        self.effects = resolve_effects(effects)
        self.sample_time = float(sample_time)
        self.noise = noise
        self.rng = np.random.default_rng(seed)
        self.sample_index = 0
        self._pendulum_terms = []
        self._measurement_terms = []
        self._gates = []
        self._lag_time_constant = 0.0
        lag_parameter = kernel_parameter(list(self.effects), 'thrust_lag_time')
        for name, values in self.effects.items():
            effect = get_effect(name)
            if effect.kind == PENDULUM:
                self._pendulum_terms.append((effect.function, values))
            elif effect.kind == MEASUREMENT:
                self._measurement_terms.append((effect.function, values))
            elif effect.kind == THRUST_GATE:
                self._gates.append((effect.function, values))
            elif effect.kind == THRUST_LAG:
                self._lag_time_constant = values[lag_parameter]
        self._has_lag = self._lag_time_constant > 0.0
        if method not in ('auto', 'compiled', 'lsoda'):
            raise AeropendError(f"method must be 'auto', 'compiled' or 'lsoda', got {method!r}")
        compiled = all(get_effect(name).compiled for name in self.effects)
        if method == 'compiled' and not compiled:
            raise AeropendError('the compiled path runs only effects with kernel terms (the built-in ones); use '
                                'method="lsoda" for your own')
        self.method = 'compiled' if method == 'auto' and compiled else ('lsoda' if method == 'auto' else method)
        self._coefficients = kernel_coefficients(self.effects)
        delay = self._coefficients['measured_lowpass']
        self._sensor_filter = StreamingFilter(delay, self.sample_time) if delay > 0 else None
        # State: Ia [A], w1 [rad/s], y [rad], W [rad/s] (+ lagged thrust f [N]).
        self.state = np.zeros(5 if self._has_lag else 4)
        self.state[2] = initial_angle
        p = parameters
        # Absolute tolerances per state: 1 uA, 1 mrad/s, 0.1 urad, 1 urad/s, 0.1 uN.
        self._atol = np.array([1e-6, 1e-3, 1e-7, 1e-6, 1e-7][:len(self.state)])
        self._constants = (p.armature_resistance, p.armature_inductance, p.back_emf_constant, p.torque_constant,
                           p.motor_inertia, p.motor_friction, p.propeller_torque_coefficient, p.gear_ratio,
                           p.thrust_coefficient, p.gravity_stiffness, p.damping, p.lever_per_inertia)

    # ------------------------------------------------------------------------------------------------------------
    def _thrust_gate(self, armature_voltage: float) -> float:
        gate = 1.0
        for function, values in self._gates:
            gate *= float(function(armature_voltage, **values))
        return gate

    def _thrust_gates(self, voltage: np.ndarray) -> np.ndarray:
        """Thrust gate per sample (gate functions are written with numpy operations, so they take arrays)."""
        gate = np.ones(voltage.shape)
        for function, values in self._gates:
            gate = gate * np.broadcast_to(np.asarray(function(voltage, **values), dtype=float), voltage.shape)
        return gate

    def _rhs_factory(self, armature_voltage: float):
        (ra, la, kw, kt, jm, friction, kd, gear, kq, gravity, damping, lever) = self._constants
        gate = self._thrust_gate(armature_voltage)
        terms = self._pendulum_terms
        from aeropend_core.model.effects import wants_thrust
        has_lag = self._has_lag
        tau = self._lag_time_constant
        sin = math.sin

        def rhs(_t, x):
            current, motor_speed, angle, rate = x[0], x[1], x[2], x[3]
            propeller_speed = motor_speed / gear
            propeller_square = propeller_speed * abs(propeller_speed)
            motor_accel = (kt * current - friction * motor_speed - kd * propeller_square / gear) / jm
            thrust_now = gate * kq * propeller_square
            thrust = x[4] if has_lag else thrust_now
            accel = -gravity * sin(angle) - damping * rate + lever * thrust
            for function, values in terms:
                accel += function(angle, rate, **values, thrust=lever * thrust) if wants_thrust(function) \
                    else function(angle, rate, **values)
            derivative = [(armature_voltage - ra * current - kw * motor_speed) / la, motor_accel, rate, accel]
            if has_lag:
                derivative.append((thrust_now - x[4]) / tau)
            return derivative

        return rhs

    def run(self, duty: np.ndarray) -> Trajectory:
        """Advance by ``len(duty)`` samples holding ``duty[k]`` (fraction 0..1) over [t_k, t_k + Ts).

        Returns the samples at t_k (measured signals and truth).
        """
        duty = np.asarray(duty, dtype=float).ravel()
        if duty.size and (not np.all(np.isfinite(duty)) or duty.min() < 0.0 or duty.max() > 1.0):
            raise AeropendError('duty must be finite fractions in [0, 1] (e.g. 0.7 for 70 %)')
        n = duty.size
        ts = self.sample_time
        voltage = np.asarray(self.parameters.voltage_from_duty(duty), dtype=float).reshape(n)
        if self.method == 'compiled':
            return self._run_compiled(duty, voltage)
        states = np.empty((n, len(self.state)))
        # Stretches of constant input, integrated one solve each.
        change = np.flatnonzero(np.diff(voltage)) + 1
        starts = np.concatenate(([0], change)).astype(int)
        stops = np.concatenate((change, [n])).astype(int)
        state = self.state
        from scipy.integrate import solve_ivp      # here: ~0.5 s of import that the compiled path never needs
        for start, stop in zip(starts, stops):
            if stop <= start:
                continue
            t_eval = np.arange(start, stop + 1) * ts
            try:
                solution = solve_ivp(self._rhs_factory(float(voltage[start])), (t_eval[0], t_eval[-1]), state,
                                     method='LSODA', t_eval=t_eval, rtol=1e-6, atol=self._atol,
                                     first_step=min(ts / 20, 1e-4))
            except (ValueError, OverflowError, ZeroDivisionError):   # math.sin(inf): the state left every bound
                raise AeropendError(_diverged(t_eval[0], self.effects)) from None
            if not solution.success or not np.all(np.isfinite(solution.y)):
                raise AeropendError(_diverged(t_eval[0], self.effects, solution.message))
            states[start:stop] = solution.y[:, :-1].T
            state = _flush_denormals(solution.y[:, -1])
        self.state = np.array(state, dtype=float)
        time = (self.sample_index + np.arange(n)) * ts
        self.sample_index += n
        return self._measure(time, duty, voltage, states)

    def _run_compiled(self, duty: np.ndarray, voltage: np.ndarray) -> Trajectory:
        n = duty.size
        gate = self._thrust_gates(voltage)
        c = self._coefficients
        state = np.zeros(5)
        state[:len(self.state)] = self.state
        if not self._has_lag and len(self.state) == 4:
            state[4] = 0.0
        states = np.empty((n, 5))
        final = _rig_kernel(np.array(self._constants, dtype=float), voltage, gate, state, self.sample_time,
                            c['rate_sign'], c['rate_square'], c['angle_linear'],
                            self._lag_time_constant, FRICTION_SMOOTHING, states)
        if not np.all(np.isfinite(states)):
            first = int(np.flatnonzero(~np.all(np.isfinite(states), axis=1))[0])
            raise AeropendError(_diverged((self.sample_index + first) * self.sample_time, self.effects))
        self.state = _flush_denormals(final[:len(self.state)])
        time = (self.sample_index + np.arange(n)) * self.sample_time
        self.sample_index += n
        return self._measure(time, duty, voltage, states[:, :len(self.state)])

    def _measure(self, time, duty, voltage, states) -> Trajectory:
        p = self.parameters
        propeller_speed = states[:, 1] / p.gear_ratio
        if self._has_lag:
            thrust = states[:, 4]
        else:
            gate = self._thrust_gates(voltage)
            thrust = gate * p.thrust_coefficient * propeller_speed * np.abs(propeller_speed)
        truth = {'armature_voltage': voltage, 'armature_current': states[:, 0], 'motor_speed': states[:, 1],
                 'angle': states[:, 2], 'angular_rate': states[:, 3], 'thrust': thrust}
        measured_angle = states[:, 2]
        for function, values in self._measurement_terms:
            measured_angle = function(measured_angle, **values)
        if self._sensor_filter is not None:
            measured_angle = self._sensor_filter(measured_angle)
        measured = {'armature_voltage': voltage.copy(), 'armature_current': states[:, 0].copy(),
                    'angle': np.asarray(measured_angle, dtype=float).copy()}
        if self.noise is not None:
            measured = apply_measurement_noise(measured, self.noise, self.rng)
        return Trajectory(time=time, duty=duty.copy(), truth=truth, sample_time=self.sample_time, **measured)


def _diverged(time: float, effects, reason: str = '') -> str:
    """The message for a simulation whose state left every bound (an unstable equation), from `time` [s] on."""
    sizes = '; '.join(f'{name} ' + ', '.join(f'{k} = {v:g}' for k, v in dict(values).items())
                      for name, values in dict(effects).items()) or 'none'
    detail = f' ({reason})' if reason else ''
    return (f'the simulation diverged in the stretch starting at t = {time:.3f} s{detail}: the rod\'s equation is '
            f'unstable with these parameters and effects (effects: {sizes}); make an effect smaller or change its '
            'sign, or lower the duty')


def _flush_denormals(state: np.ndarray) -> np.ndarray:
    """Zero the state components that decayed below 1e-200 (after long rests the state decays into subnormal
    numbers, which LSODA turns into NaN and which slow arithmetic down)."""
    state = np.array(state, dtype=float)
    state[np.abs(state) < 1e-200] = 0.0
    return state


def simulate(duty: np.ndarray, parameters: RigParameters = DEFAULT_PARAMETERS,
             effects: Mapping[str, Mapping[str, float] | float] | None = None,
             sample_time: float = SAMPLE_TIME, noise: MeasurementNoise | None = None,
             seed: int | None = None, initial_angle: float = 0.0, method: str = 'auto') -> Trajectory:
    """Simulate a whole record from rest. With `noise`, the PSNR refers to each signal's own max |x| in the record.

    Deterministic for a given seed.

    Parameters
    ----------
    duty : ndarray, shape (n,), dimensionless
        PWM duty fraction 0..1 per sample, held over [t_k, t_k + Ts) (Va from it by eq (8)).
    parameters : RigParameters [SI, see RigParameters]
        Nominal parameters of the rig.
    effects : mapping, optional [SI unit of each effect parameter]
        Hidden effects, ``{name: {parameter: value}}`` or ``{name: value}`` for one-parameter effects.
    sample_time : float [s]
        Ts; 1/490 s on the rig.
    noise : MeasurementNoise, optional [-]
        Measurement noise and quantisation of Va, Ia and the angle (PSNR against each record's own peak).
    seed : int, optional [-]
        Seed of the noise generator.
    initial_angle : float [rad]
        Initial rod angle, at rest.
    method : {'auto', 'compiled', 'lsoda'} [-]
        Integration path, as :class:`RigSimulator`.

    Returns
    -------
    Trajectory
        ``time`` [s], ``duty``, the measured ``armature_voltage`` [V], ``armature_current`` [A], ``angle`` [rad]
        and the noise-free ``truth`` (shape (n,) each).

    Examples
    --------
    >>> import numpy as np
    >>> from aeropend_core import simulate
    >>> run = simulate(np.full(980, 0.5), seed=1)                    # 2 s at duty 0.5, sampled at 490 Hz
    >>> len(run.time), bool(run.angle[-1] > 0.1)                     # rad: the thrust lifts the rod
    (980, True)
    """
    simulator = RigSimulator(parameters, effects, sample_time, None, seed, initial_angle, method)
    trajectory = simulator.run(duty)
    if noise is not None:
        clean = {'armature_voltage': trajectory.armature_voltage, 'armature_current': trajectory.armature_current,
                 'angle': trajectory.angle}
        noisy = apply_measurement_noise(clean, noise, simulator.rng, peaks_from_data=True)
        trajectory.armature_voltage = noisy['armature_voltage']
        trajectory.armature_current = noisy['armature_current']
        trajectory.angle = noisy['angle']
    return trajectory
