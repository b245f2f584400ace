"""The law's static feedforward: the duty that holds the rod at an angle under a model, at rest.

At rest the pendulum's equation (6) balances gravity, the pendulum effects (cable torque, ...) and the thrust:
``(L/J) f = (mgd/J) sin y + effects(y, 0)``; the thrust at a constant duty is the motor's steady state (eq (1)-(4)
at rest, :meth:`RigParameters.steady_state`) times the thrust gate (dead zone). The duty is found by bisection on
that monotone map. Coulomb friction at rest is undetermined (anything within the friction band holds): it is left
out, and the integral term takes up what the feedforward misses.
"""
from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from aeropend_core.errors import AeropendError
from aeropend_core.model.effects import (PENDULUM, THRUST_GATE, get_effect, kernel_coefficients, resolve_effects,
                                         wants_thrust)
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, RigParameters

#: Kernel kinds whose rest torque is not a function of the angle (dry friction holds anything inside its band).
REST_UNDETERMINED_KINDS = frozenset({'rate_sign'})


def undetermined_at_rest(name: str) -> bool:
    """Whether an effect's torque at rest is undetermined (a dry friction: its kernel has a sign of the rate)."""
    return any(kind in REST_UNDETERMINED_KINDS for kind, _ in get_effect(name).kernel_terms)


def rest_thrust_torque(duty: float, parameters: RigParameters = DEFAULT_PARAMETERS,
                       effects: Mapping[str, Mapping[str, float]] | None = None) -> float:
    """(L/J) f at rest [rad/s^2] for a constant `duty` (fraction 0..1): the motor's steady state through the gate."""
    voltage = float(parameters.voltage_from_duty(duty))
    if voltage <= 0.0:
        return 0.0
    thrust = parameters.steady_state(voltage)['thrust']
    for name, values in resolve_effects(effects).items():
        effect = get_effect(name)
        if effect.kind == THRUST_GATE:
            thrust *= float(np.asarray(effect.function(voltage, **values)))
    return parameters.lever_per_inertia * thrust


def holding_torque(angle: float, parameters: RigParameters = DEFAULT_PARAMETERS,
                   effects: Mapping[str, Mapping[str, float]] | None = None) -> float:
    """(L/J) f [rad/s^2] needed to hold the true angle `angle` [rad] at rest: gravity plus the pendulum effects."""
    needed = parameters.gravity_stiffness * math.sin(angle)
    for name, values in resolve_effects(effects).items():
        effect = get_effect(name)
        if effect.kind != PENDULUM or undetermined_at_rest(name):
            continue
        function = effect.function
        extra = function(angle, 0.0, **values, thrust=0.0) if wants_thrust(function) else function(angle, 0.0,
                                                                                                   **values)
        needed -= float(np.asarray(extra))
    return needed


def static_duty(angle: float, parameters: RigParameters = DEFAULT_PARAMETERS,
                effects: Mapping[str, Mapping[str, float]] | None = None, measured: bool = True) -> float:
    """The duty (fraction 0..1) that holds the rod at `angle` [rad] at rest under the model.

    `measured`: `angle` is what the sensor reads (a sensor offset of the catalog is taken off to get the true
    angle).
    Raises AeropendError when no duty up to 1 holds that angle.

    >>> round(static_duty(0.0), 6)
    0.0
    >>> 0.2 < static_duty(0.7) < 0.7
    True
    """
    effects = resolve_effects(effects)
    true_angle = angle - kernel_coefficients(effects)['measured_offset'] if measured else angle
    needed = holding_torque(true_angle, parameters, effects)
    if needed <= 0.0:
        return 0.0
    most = rest_thrust_torque(1.0, parameters, effects)
    if most < needed:
        raise AeropendError(f'no duty holds {math.degrees(angle):.1f} deg under this model: duty 1 gives '
                            f'{most:.1f} rad/s^2 of thrust, {needed:.1f} are needed; choose a smaller angle')
    return _bisect(lambda duty: rest_thrust_torque(duty, parameters, effects) - needed)


def _bisect(function, tolerance: float = 1e-10) -> float:
    """The root in [0, 1] of the increasing `function` (negative at 0, >= 0 at 1) by bisection to `tolerance`
    (34 evaluations; scipy.optimize's brentq cost ~0.6 s of import in `control check`)."""
    low, high = 0.0, 1.0
    while high - low > tolerance:
        middle = 0.5 * (low + high)
        if function(middle) < 0.0:
            low = middle
        else:
            high = middle
    return 0.5 * (low + high)
