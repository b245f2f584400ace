"""Simulator of the full rig (electrical + motor + pendulum) under a zero-order-hold duty input at 490 Hz.

The model is stiff (La/Ra ~ 2 ms against a ~0.5 s pendulum), so each stretch of constant duty is integrated with
LSODA (switches to BDF where stiff) and the state is read at the sample instants. Any catalog effect can be
enabled as hidden truth. The sample at index k is taken at t_k = k Ts, when duty[k] starts to be applied, like the
firmware sampling in the Timer1 overflow interrupt.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import solve_ivp

from aeropend_core.effects import MEASUREMENT, PENDULUM, THRUST_GATE, THRUST_LAG, get_effect, resolve_effects
from aeropend_core.errors import AeropendError
from aeropend_core.model import DEFAULT_PARAMETERS, SAMPLE_TIME, RigParameters
from aeropend_core.noise import MeasurementNoise, apply_measurement_noise

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
    parameters : RigParameters
        Nominal parameters of the rig.
    effects : mapping, optional
        Hidden effects, ``{name: {parameter: value}}`` or ``{name: value}`` for one-parameter effects.
    sample_time : float
        Ts [s]; 1/490 s on the rig.
    noise : MeasurementNoise, optional
        Measurement noise and ADC quantisation added to Va, Ia and the angle. For a stream the PSNR refers to the
        fixed peaks in ``noise.peaks`` (defaults: the rig's full-scale values).
    seed : int, optional
        Seed of the noise generator; the simulation itself is deterministic.
    initial_angle : float
        Initial rod angle [rad], at rest.
    """

    def __init__(self, parameters: RigParameters = DEFAULT_PARAMETERS,
                 effects: Mapping[str, Mapping[str, float] | float] | None = None,
                 sample_time: float = SAMPLE_TIME, noise: MeasurementNoise | None = None,
                 seed: int | None = None, initial_angle: float = 0.0) -> None:
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
        for name, values in self.effects.items():
            effect = get_effect(name)
            if effect.kind == PENDULUM:
                self._pendulum_terms.append((effect.function, values))
            elif effect.kind == MEASUREMENT:
                self._measurement_terms.append((effect.function, values))
            elif effect.kind == THRUST_GATE:
                self._gates.append((effect.function, values))
            elif effect.kind == THRUST_LAG:
                self._lag_time_constant = values['time_constant']
        self._has_lag = self._lag_time_constant > 0.0
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

    def _rhs_factory(self, armature_voltage: float):
        (ra, la, kw, kt, jm, friction, kd, gear, kq, gravity, damping, lever) = self._constants
        gate = self._thrust_gate(armature_voltage)
        terms = self._pendulum_terms
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
                accel += function(angle, rate, **values)
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
        states = np.empty((n, len(self.state)))
        # Stretches of constant input, integrated one solve each.
        change = np.flatnonzero(np.diff(voltage)) + 1
        starts = np.concatenate(([0], change)).astype(int)
        stops = np.concatenate((change, [n])).astype(int)
        state = self.state
        for start, stop in zip(starts, stops):
            if stop <= start:
                continue
            t_eval = np.arange(start, stop + 1) * ts
            solution = solve_ivp(self._rhs_factory(float(voltage[start])), (t_eval[0], t_eval[-1]), state,
                                 method='LSODA', t_eval=t_eval, rtol=1e-6, atol=self._atol,
                                 first_step=min(ts / 20, 1e-4))
            if not solution.success:
                raise RuntimeError(f'simulation failed at t = {t_eval[0]:.3f} s: {solution.message}')
            states[start:stop] = solution.y[:, :-1].T
            state = solution.y[:, -1]
        self.state = np.array(state, dtype=float)
        time = (self.sample_index + np.arange(n)) * ts
        self.sample_index += n
        return self._measure(time, duty, voltage, states)

    def _measure(self, time, duty, voltage, states) -> Trajectory:
        p = self.parameters
        propeller_speed = states[:, 1] / p.gear_ratio
        if self._has_lag:
            thrust = states[:, 4]
        else:
            gate = np.array([self._thrust_gate(v) for v in voltage]) if self._gates else 1.0
            thrust = gate * p.thrust_coefficient * propeller_speed * np.abs(propeller_speed)
        truth = {'armature_voltage': voltage, 'armature_current': states[:, 0], 'motor_speed': states[:, 1],
                 'angle': states[:, 2], 'angular_rate': states[:, 3], 'thrust': thrust}
        measured_angle = states[:, 2]
        for function, values in self._measurement_terms:
            measured_angle = function(measured_angle, **values)
        measured = {'armature_voltage': voltage.copy(), 'armature_current': states[:, 0].copy(),
                    'angle': np.asarray(measured_angle, dtype=float).copy()}
        if self.noise is not None:
            measured = apply_measurement_noise(measured, self.noise, self.rng)
        return Trajectory(time=time, duty=duty.copy(), truth=truth, sample_time=self.sample_time, **measured)


def simulate(duty: np.ndarray, parameters: RigParameters = DEFAULT_PARAMETERS,
             effects: Mapping[str, Mapping[str, float] | float] | None = None,
             sample_time: float = SAMPLE_TIME, noise: MeasurementNoise | None = None,
             seed: int | None = None, initial_angle: float = 0.0) -> Trajectory:
    """Simulate a whole record from rest. With `noise`, the PSNR refers to each signal's own max |x| in the record.

    Parameters and returns as :class:`RigSimulator` / :class:`Trajectory`; deterministic for a given seed.
    """
    simulator = RigSimulator(parameters, effects, sample_time, None, seed, initial_angle)
    trajectory = simulator.run(duty)
    if noise is not None:
        clean = {'armature_voltage': trajectory.armature_voltage, 'armature_current': trajectory.armature_current,
                 'angle': trajectory.angle}
        noisy = apply_measurement_noise(clean, noise, simulator.rng, peaks_from_data=True)
        trajectory.armature_voltage = noisy['armature_voltage']
        trajectory.armature_current = noisy['armature_current']
        trajectory.angle = noisy['angle']
    return trajectory
