"""Rigs that differ from the model in ways no catalog effect describes (tests and benchmarks of the diagnosis).

* :func:`simulate_drifting` -- the full rig simulator run in one-second blocks whose parameters change with time
  (e.g. a thrust coefficient that sags by 15 % over the record, as a sagging supply would);
* :func:`simulate_thrust_power` -- the thrust law f = Kq' |w2|^n instead of eq (3)'s w2|w2| (n = 2), with Kq'
  chosen so that both laws give the same thrust at a reference propeller speed. The motor does not feel the
  thrust law (the propeller's drag torque is unchanged), so the motor is simulated by the rig simulator and the
  pendulum integrated again with the other thrust.

Both return a :class:`aeropend_core.sim.simulate.Trajectory` with noise applied like :func:`simulate`.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.integrate import solve_ivp

from aeropend_core.model.parameters import DEFAULT_PARAMETERS, RigParameters
from aeropend_core.sim.noise import MeasurementNoise, apply_measurement_noise
from aeropend_core.sim.simulate import RigSimulator, Trajectory, simulate


def _noisy(trajectory: Trajectory, noise: MeasurementNoise | None, seed: int | None) -> Trajectory:
    if noise is None:
        return trajectory
    clean = {'armature_voltage': trajectory.armature_voltage, 'armature_current': trajectory.armature_current,
             'angle': trajectory.angle}
    noisy = apply_measurement_noise(clean, noise, np.random.default_rng(seed), peaks_from_data=True)
    trajectory.armature_voltage, trajectory.armature_current = noisy['armature_voltage'], noisy['armature_current']
    trajectory.angle = noisy['angle']
    return trajectory


def simulate_drifting(duty: np.ndarray, parameters_at: Callable[[float], RigParameters], block_seconds: float = 1.0,
                      effects=None, noise: MeasurementNoise | None = None, seed: int | None = None) -> Trajectory:
    """Simulate with parameters ``parameters_at(t)`` [t in s] held over blocks of `block_seconds`."""
    duty = np.asarray(duty, dtype=float)
    simulator = RigSimulator(parameters_at(0.0), effects)
    block = max(1, int(round(block_seconds / simulator.sample_time)))
    pieces = []
    for start in range(0, duty.size, block):
        fresh = RigSimulator(parameters_at(start * simulator.sample_time), effects)
        fresh.state, fresh.sample_index = simulator.state, simulator.sample_index
        simulator = fresh
        pieces.append(simulator.run(duty[start:start + block]))
    truth = {name: np.concatenate([p.truth[name] for p in pieces]) for name in pieces[0].truth}
    trajectory = Trajectory(np.concatenate([p.time for p in pieces]), duty.copy(),
                            np.concatenate([p.armature_voltage for p in pieces]),
                            np.concatenate([p.armature_current for p in pieces]),
                            np.concatenate([p.angle for p in pieces]), truth, simulator.sample_time)
    return _noisy(trajectory, noise, seed)


def simulate_thrust_power(duty: np.ndarray, exponent: float, parameters: RigParameters = DEFAULT_PARAMETERS,
                          reference_speed: float = 227.0, noise: MeasurementNoise | None = None,
                          seed: int | None = None) -> Trajectory:
    """Simulate with thrust ``Kq (w2/w_ref)^(n-2) w2|w2|`` (n = `exponent`; w_ref = `reference_speed` [rad/s])."""
    base = simulate(duty, parameters)
    ts = base.sample_time
    propeller = base.truth['motor_speed'] / parameters.gear_ratio
    thrust = parameters.thrust_coefficient * reference_speed ** (2.0 - exponent) * np.sign(propeller) \
        * np.abs(propeller) ** exponent
    time = base.time

    def rhs(t, x):
        f = np.interp(t, time, thrust)
        return [x[1], -parameters.gravity_stiffness * np.sin(x[0]) - parameters.damping * x[1]
                + parameters.lever_per_inertia * f]

    solution = solve_ivp(rhs, (time[0], time[-1]), [0.0, 0.0], t_eval=time, max_step=ts, rtol=1e-8, atol=1e-10)
    base.angle = solution.y[0].copy()
    base.truth['angle'], base.truth['angular_rate'], base.truth['thrust'] = solution.y[0], solution.y[1], thrust
    return _noisy(base, noise, seed)


__all__ = ['simulate_drifting', 'simulate_thrust_power']
