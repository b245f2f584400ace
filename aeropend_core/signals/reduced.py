"""The reduced model: what a record with the duty (or Va) and the angle, but no usable armature current, supports.

Many rigs log only the PWM duty and the angle, or a current that is not the period-average armature current (a
one-sided sense amplifier read at a fixed phase inside the PWM on-pulse, which falls as the duty rises because the
back-EMF rises). Eq (5)'s thrust, written in Va and Ia, then cannot be formed. The reduced model drives the thrust
from Va alone (from the duty by the paper's eq (8) when only the duty is recorded) through the motor's own
first-order dynamics with the armature current eliminated (eqs (1)-(2), La neglected)::

    T de/dt = Va - e - q e|e|          (e: the back-EMF in volts, up to a scale that the thrust gain absorbs)
    dW/dt = -a sin y - b W + k e|e|    (+ pendulum effects)

``T`` [s] is the motor's mechanical time constant near standstill (1/(p1 + p2) of the motor observer,
:mod:`aeropend_core.signals.motor`) and ``q`` [1/V] the curvature of the static map from Va to the speed (the
propeller's drag torque: ``q = p3/(p1 + p2)``, after the scale). The steady state is the static map
``e = (sqrt(1 + 4 q Va) - 1)/(2 q)``; the lag grows shorter as the speed rises, as on the rig. T and q are
profiled (:mod:`aeropend_core.diagnosis.reduced_fit`); a, b, k and the effects are fitted by output error as usual.

What it can identify (:data:`IDENTIFIABLE`) and what not (:data:`NOT_IDENTIFIABLE`): the pendulum's own
parameters (mgd/J, c/J) and the effects of the pendulum and of the angle sensor; the thrust gain only as one
product with the unmeasured speed per volt (Kq, Kw, Kt, the gear and the scale of e together); not the armature
resistance (no current), and not a thrust lag apart from the motor's lag (two lags in series).
"""
from __future__ import annotations

import numpy as np

from aeropend_core.signals.motor import _back_emf_kernel

#: Name of the reduced model (JSON ``model`` field).
REDUCED_MODEL = 'reduced'
#: The motor-map parameters the reduced model adds, with units.
MAP_PARAMETERS = {'motor_time_constant': 's', 'voltage_map_curvature': '1/V'}
#: What the reduced model identifies, with how.
IDENTIFIABLE = {
    'gravity_stiffness': 'mgd/J, from the swings and the settled angles',
    'damping': 'c/J, from the decay of the swings after each step',
    'thrust_gain': 'thrust per squared volt of the motor map: one product of Kq, Kw, the gear and the speed per volt',
    'motor_time_constant': 'the motor\'s mechanical lag near standstill (profiled)',
    'voltage_map_curvature': 'curvature of the static map from Va to the motor speed (profiled)',
    # effects named in words: a catalog effect's name lives in its record (tests/test_effect_records.py)
    'effects': 'dry friction, quadratic drag, the angle offset, the angle filter, the dead zone; a cable torque only '
               'weakly (it reshapes the static curve from Va to the angle as the map\'s curvature does)',
}
#: What it cannot identify, and why.
NOT_IDENTIFIABLE = {
    'armature_resistance': 'no period-average armature current: Va - Ra Ia cannot be formed',
    'thrust_coefficient, back_emf_constant, torque_constant': 'only their product enters the thrust gain; the '
                                                              'motor speed is not measured',
    'a thrust lag': 'a thrust lag and the motor\'s lag act in series: the motor time constant carries both',
}


def motor_map(armature_voltage: np.ndarray, time_constant: float, curvature: float,
              sample_time: float, switch: np.ndarray | None = None) -> np.ndarray:
    """The reduced model's thrust voltage: ``T de/dt = Va - e - q e|e|`` from rest, Va held over each sample.

    Parameters
    ----------
    armature_voltage : ndarray, shape (n,) [V]
        Va (held over each sample interval).
    time_constant : float [s]
        T, the motor's mechanical time constant near standstill (> 0).
    curvature : float [1/V]
        q, the static map's curvature (>= 0).
    sample_time : float [s]
        Ts.
    switch : ndarray, shape (n,), optional [1]
        Where inside interval i Va changes to the next sample's level, as a fraction of the interval
        (:func:`aeropend_core.signals.preprocess.step_switches`: at a low rate a duty step lands between two
        samples); default Va held over each whole interval.

    Returns
    -------
    ndarray, shape (n,) [V]
        e at each sample (the thrust is ``thrust_gain * e|e|``).
    """
    voltage = np.ascontiguousarray(armature_voltage, dtype=float)
    out = np.empty((1, voltage.size))
    rate = 1.0 / time_constant
    steps = max(1, int(np.ceil(sample_time / (0.25 * time_constant))))     # RK4 stable for any rate
    switch = np.ones(voltage.size) if switch is None else np.ascontiguousarray(switch, dtype=float)
    _back_emf_kernel(np.array([[rate, 0.0, curvature * rate]]), voltage, np.zeros(1), sample_time, steps, out,
                     switch)
    return out[0]


def voltage_from_duty(duty: np.ndarray, parameters=None) -> np.ndarray:
    """Va [V] from the duty fraction 0..1 by the paper's eq (8) (``parameters.voltage_from_duty``), shape (n,).

    Parameters
    ----------
    duty : ndarray, shape (n,) [1]
        Commanded duty as a fraction 0..1.
    parameters : RigParameters, optional [SI]
        Eq (8)'s constants k0..k3; default the paper's.

    Returns
    -------
    ndarray, shape (n,) [V]
        The armature voltage the map gives (0 in its dead zone).
    """
    from aeropend_core.model.parameters import DEFAULT_PARAMETERS
    parameters = parameters or DEFAULT_PARAMETERS
    return np.maximum(np.asarray(parameters.voltage_from_duty(np.asarray(duty, dtype=float)), dtype=float), 0.0)
