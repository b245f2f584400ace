"""Rigs whose motor differs from the model in ways no catalog effect describes (tests and benchmarks of the motor
equation's discovery, :mod:`aeropend_core.diagnosis.motor_discovery`).

The rig simulator (:class:`aeropend_core.sim.simulate.RigSimulator`, LSODA path) with one extra voltage in the
armature circuit, eq (1): ``La dIa/dt = Va - Ra Ia - Kw w1 - drop``:

* ``'heating'`` -- the winding's resistance rises with its temperature, which follows the dissipated power through
  a thermal lag: ``drop = Ra alpha dT Ia`` with ``tau_th d(dT)/dt = R_th Ra Ia^2 - dT`` (copper: alpha = 0.0039 /K;
  `size` is the thermal resistance R_th [K/W], `time_constant` tau_th [s]);
* ``'brush_drop'`` -- a brush / commutation voltage drop ``drop = V_b tanh(Ia / s)`` (`size` is V_b [V], s the
  `brush_smoothing`, 0.02 A by default: not the discovery library's 0.01 A, so the search meets a shape it does not
  have exactly);
* ``'armature_reaction'`` -- the field weakens with the armature current (armature reaction): the back-EMF and the
  torque constants fall to ``K (1 - beta Ia)`` (`size` is beta [1/A]); with ``reaction_on_torque=False`` only the
  back-EMF does, which is exactly the discovery library's ``current*back_emf`` with c = beta (the torque's share has
  no term in the observer's speed equation, so with it the fitted c is not beta).

Returns a :class:`aeropend_core.sim.simulate.Trajectory` with noise applied like :func:`~aeropend_core.sim.simulate
.simulate`.
"""
from __future__ import annotations

import numpy as np

from aeropend_core.errors import AeropendError
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, RigParameters
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import SAMPLE_TIME, RigSimulator, Trajectory

#: Temperature coefficient of copper's resistance [1/K].
COPPER_ALPHA = 0.0039
#: Current scale [A] of the brush drop's smooth sign.
BRUSH_SMOOTHING = 0.02
MOTOR_EFFECTS = ('heating', 'brush_drop', 'armature_reaction')


class _MotorEffectSimulator(RigSimulator):
    """The rig simulator (LSODA) with an extra voltage in the armature circuit (module docstring)."""

    def __init__(self, effect: str, size: float, time_constant: float, parameters: RigParameters,
                 noise: MeasurementNoise | None, seed: int | None, sample_time: float,
                 brush_smoothing: float = BRUSH_SMOOTHING, reaction_on_torque: bool = True) -> None:
        super().__init__(parameters, None, sample_time, noise, seed, 0.0, 'lsoda')
        self.reaction_on_torque = bool(reaction_on_torque)
        self.effect, self.size, self.time_constant = effect, float(size), float(time_constant)
        self.brush_smoothing = float(brush_smoothing)
        if effect == 'heating':       # one more state: the winding's temperature rise [K]
            self.state = np.append(self.state, 0.0)
            self._atol = np.append(self._atol, 1e-6)

    def _rhs_factory(self, armature_voltage: float):
        base = super()._rhs_factory(armature_voltage)
        p = self.parameters
        la, ra, kw, kt, jm = (p.armature_inductance, p.armature_resistance, p.back_emf_constant, p.torque_constant,
                              p.motor_inertia)
        effect, size, tau, smoothing = self.effect, self.size, self.time_constant, self.brush_smoothing
        torque_share = 1.0 if self.reaction_on_torque else 0.0

        def rhs(t, x):
            derivative = base(t, x[:4])
            current, speed = x[0], x[1]
            if effect == 'heating':
                derivative[0] -= ra * COPPER_ALPHA * x[4] * current / la
                derivative.append((size * ra * current * current - x[4]) / tau)
            elif effect == 'brush_drop':
                derivative[0] -= size * np.tanh(current / smoothing) / la
            else:       # armature reaction: Kw and Kt fall to K (1 - beta Ia)
                derivative[0] += size * current * kw * speed / la
                derivative[1] -= torque_share * size * current * kt * current / jm
            return derivative

        return rhs


def simulate_motor_effect(duty: np.ndarray, effect: str, size: float, time_constant: float = 20.0,
                          parameters: RigParameters = DEFAULT_PARAMETERS, noise: MeasurementNoise | None = None,
                          seed: int | None = None, sample_time: float = SAMPLE_TIME,
                          brush_smoothing: float = BRUSH_SMOOTHING, reaction_on_torque: bool = True) -> Trajectory:
    """Simulate the rig with one motor effect outside the catalog (module docstring).

    Parameters
    ----------
    duty : ndarray, shape (n,) [-]
        Duty per sample, fractions 0..1.
    effect : str [-]
        One of :data:`MOTOR_EFFECTS`.
    size : float [K/W, V or 1/A]
        The effect's size: thermal resistance (heating), brush drop (brush_drop), beta (armature_reaction).
    time_constant : float [s]
        The winding's thermal time constant (heating only).
    parameters : RigParameters [SI]
        Nominal parameters.
    noise : MeasurementNoise, optional [-]
        Measurement noise and quantisation of Va, Ia and the angle.
    seed : int, optional [-]
        Seed of the noise.
    sample_time : float [s]
        Ts.
    brush_smoothing : float [A]
        Current scale of the brush drop's smooth sign (brush_drop only).
    reaction_on_torque : bool [-]
        Armature reaction weakens the torque as well as the back-EMF (armature_reaction only; the physics).

    Returns
    -------
    Trajectory
        Measured signals and truth, like :func:`aeropend_core.sim.simulate.simulate`.
    """
    if effect not in MOTOR_EFFECTS:
        raise AeropendError(f'unknown motor effect {effect!r}; one of {", ".join(MOTOR_EFFECTS)}')
    simulator = _MotorEffectSimulator(effect, size, time_constant, parameters, noise, seed, sample_time,
                                      brush_smoothing, reaction_on_torque)
    return simulator.run(np.asarray(duty, dtype=float))


__all__ = ['simulate_motor_effect', 'MOTOR_EFFECTS', 'COPPER_ALPHA']
