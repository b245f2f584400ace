"""The catalog of physical effects that the nominal model leaves out, each switchable with parameters.

An effect has a name, a one-line physical description, the signature it leaves in the data, the equation it
enters, and SI parameters. Four kinds say where it enters:

``pendulum``
    an extra angular acceleration [rad/s^2] added to eq (6): ``function(angle, angular_rate, **params)``.
    Written with numpy operations it works on scalars (simulator) and arrays (diagnosis) alike.
``measurement``
    a change to the measured angle: ``function(angle, **params) -> measured angle`` [rad].
``thrust_gate``
    a factor 0..1 on the thrust given the armature voltage: ``function(armature_voltage, **params)``.
``thrust_lag``
    thrust dynamics: the thrust follows its quasi-static value through a first-order lag (built in).

Parameters of pendulum-side effects are per unit inertia, as they enter dW/dt.  A user adds an effect with one
small function::

    from aeropend_core.model.effects import register_effect, EffectParameter

    @register_effect('cubic_spring', 'a hardening spring at the pivot', signature='residual ~ angle^3',
                     parameters=[EffectParameter('stiffness', '1/(s^2 rad^2)', 'cubic spring per inertia', 5.0)])
    def cubic_spring(angle, angular_rate, stiffness):
        return -stiffness * angle ** 3
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from aeropend_core.errors import AeropendError, UnknownEffectError

PENDULUM, MEASUREMENT, THRUST_GATE, THRUST_LAG = 'pendulum', 'measurement', 'thrust_gate', 'thrust_lag'
KINDS = (PENDULUM, MEASUREMENT, THRUST_GATE, THRUST_LAG)
EQUATION_OF_KIND = {
    PENDULUM: 'eq (6): dW/dt = ... + term(angle, W)',
    MEASUREMENT: 'measured angle = h(angle)',
    THRUST_GATE: 'eq (6): thrust f -> gate(Va) * f',
    THRUST_LAG: 'eq (6): f -> lagged thrust, time_constant * df/dt = f_eq5 - f',
}


@dataclass(frozen=True)
class EffectParameter:
    """One parameter of an effect: name, SI unit, meaning, a typical (physically plausible) value and bounds.

    Parameters
    ----------
    name : str [-]
        Parameter name, unique across the catalog (it names the value in every output).
    unit : str [-]
        Its SI unit as text, e.g. ``'rad/s^2'``.
    description : str [-]
        What it means, one line.
    typical : float [unit]
        A typical, physically plausible value (simulation default; the fit starts from a fraction of it).
    lower, upper : float [unit]
        Bounds of the value (the fit keeps it inside them).
    """

    name: str
    unit: str
    description: str
    typical: float
    lower: float = 0.0
    upper: float = np.inf


@dataclass(frozen=True)
class Effect:
    """A physical effect that can be added to the nominal model."""

    name: str
    description: str
    signature: str
    kind: str
    parameters: tuple[EffectParameter, ...]
    function: Callable[..., np.ndarray | float] | None = None
    equation: str = ''
    builtin: bool = field(default=False, compare=False)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f'effect {self.name!r}: kind must be one of {KINDS}, got {self.kind!r}')
        if self.kind != THRUST_LAG and self.function is None:
            raise ValueError(f'effect {self.name!r} of kind {self.kind!r} needs a function')
        if not self.equation:
            object.__setattr__(self, 'equation', EQUATION_OF_KIND[self.kind])

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    def typical_parameters(self) -> dict[str, float]:
        return {p.name: p.typical for p in self.parameters}

    def validate(self, values: Mapping[str, float]) -> dict[str, float]:
        """Check a parameter dict (names, finiteness, bounds) and return it as floats."""
        unknown = set(values) - set(self.parameter_names)
        if unknown:
            raise AeropendError(f'effect {self.name!r} has no parameter {sorted(unknown)}; '
                                f'its parameters are {list(self.parameter_names)}')
        checked = {}
        for parameter in self.parameters:
            if parameter.name not in values:
                raise AeropendError(f'effect {self.name!r} needs a value for {parameter.name!r} '
                                    f'[{parameter.unit}] ({parameter.description})')
            value = float(values[parameter.name])
            if not np.isfinite(value) or not parameter.lower <= value <= parameter.upper:
                raise AeropendError(
                    f'effect {self.name!r}: {parameter.name} = {value!r} {parameter.unit} is outside '
                    f'[{parameter.lower}, {parameter.upper}]')
            checked[parameter.name] = value
        return checked


CATALOG: dict[str, Effect] = {}


def add_effect(effect: Effect, *, replace: bool = False) -> Effect:
    """Put an effect into the catalog (``replace=True`` to overwrite one of the same name)."""
    if effect.name in CATALOG and not replace:
        raise AeropendError(f'an effect named {effect.name!r} is already registered; pick another name')
    CATALOG[effect.name] = effect
    return effect


def register_effect(name: str, description: str, *, parameters: list[EffectParameter], signature: str = '',
                    kind: str = PENDULUM, replace: bool = False) -> Callable[[Callable], Callable]:
    """Decorator registering a user's effect function in the catalog (see the module docstring).

    Parameters
    ----------
    name : str [-]
        Name of the effect (``--add NAME``, ``effects={NAME: ...}``); must not be taken unless `replace`.
    description : str [-]
        One-line physical description.
    parameters : list of EffectParameter [-]
        Its parameters, SI units, with typical values and bounds.
    signature : str [-]
        The trace it leaves in the data, e.g. ``'residual ~ angle^3'``.
    kind : {'pendulum', 'measurement', 'thrust_gate'} [-]
        Where the function enters: ``pendulum`` returns an angular acceleration [rad/s^2] added to dW/dt from
        ``(angle [rad], angular_rate [rad/s], **params)``; ``measurement`` returns the measured angle [rad] from
        ``(angle, **params)``; ``thrust_gate`` returns a factor 0..1 on the thrust from
        ``(armature_voltage [V], **params)``.
    replace : bool [-]
        Overwrite an effect of the same name instead of refusing.

    Returns
    -------
    callable
        The decorator; it returns the function unchanged.
    """

    def decorator(function: Callable) -> Callable:
        add_effect(Effect(name=name, description=description, signature=signature or 'user-defined', kind=kind,
                          parameters=tuple(parameters), function=function), replace=replace)
        return function

    return decorator


def get_effect(name: str) -> Effect:
    """The catalog entry for `name`; an unknown name raises :class:`UnknownEffectError` listing the known ones."""
    try:
        return CATALOG[name]
    except KeyError:
        raise UnknownEffectError(
            f'unknown effect {name!r}; known effects: {", ".join(sorted(CATALOG))} '
            f'(`aeropend effects` describes them)') from None


def find_parameter(parameter: str) -> tuple[Effect, EffectParameter] | None:
    """The catalog effect that has a parameter of this name, and that parameter (None if no effect has it)."""
    for effect in CATALOG.values():
        for candidate in effect.parameters:
            if candidate.name == parameter:
                return effect, candidate
    return None


def resolve_effects(effects: Mapping[str, Mapping[str, float] | float] | None) -> dict[str, dict[str, float]]:
    """Normalise an effects specification to ``{name: {parameter: value}}`` with validated values.

    A single-parameter effect may be given as ``{name: value}``.
    """
    resolved: dict[str, dict[str, float]] = {}
    for name, values in (effects or {}).items():
        effect = get_effect(name)
        if not isinstance(values, Mapping):
            if len(effect.parameters) != 1:
                raise AeropendError(f'effect {name!r} has parameters {list(effect.parameter_names)}: give them '
                                    f'by name, e.g. {name}.{effect.parameters[0].name}=VALUE')
            values = {effect.parameters[0].name: values}
        resolved[name] = effect.validate(values)
    return resolved


def parse_effect_assignments(assignments: list[str]) -> dict[str, dict[str, float]]:
    """Parse CLI ``NAME=VALUE`` or ``NAME.PARAM=VALUE`` strings into a validated effects dict."""
    raw: dict[str, dict[str, float] | float] = {}
    for text in assignments:
        key, sep, value_text = text.partition('=')
        try:
            value = float(value_text)
        except ValueError:
            value = None
        if not sep or value is None:
            raise AeropendError(f'cannot read effect {text!r}: write NAME=VALUE (e.g. coulomb_friction=3.0) or '
                                f'NAME.PARAMETER=VALUE')
        name, _, parameter = key.partition('.')
        if parameter:
            entry = raw.setdefault(name, {})
            if not isinstance(entry, dict):
                raise AeropendError(f'effect {name!r} given twice')
            entry[parameter] = value
        else:
            raw[name] = value
    return resolve_effects(raw)


# ----------------------------------------------------------------------------------------------------------------
# Built-in catalog. Typical values are physically plausible for this rig (docs/model.md section 5) and detectable.

#: Width [rad/s] of the smooth sign used for dry friction: tanh(W / width). Below it the pivot is "stuck".
FRICTION_SMOOTHING = 0.01


def _coulomb_friction(angle, angular_rate, friction_acceleration):
    return -friction_acceleration * np.tanh(angular_rate / FRICTION_SMOOTHING)


def _quadratic_drag(angle, angular_rate, drag_coefficient):
    return -drag_coefficient * angular_rate * np.abs(angular_rate)


def _cable_torque(angle, angular_rate, cable_stiffness):
    return -cable_stiffness * angle


def _angle_offset(angle, offset):
    return angle + offset


def _dead_zone(armature_voltage, threshold_voltage):
    return (np.asarray(armature_voltage) >= threshold_voltage).astype(float)


for _effect in (
    Effect('coulomb_friction', 'dry (Coulomb) friction in the pivot bearing, opposing the motion',
           'residual ~ sign(W): steps at direction reversals, linear (not exponential) decay of swings',
           PENDULUM, (EffectParameter('friction_acceleration', 'rad/s^2',
                                      'friction torque per unit inertia, Fc', 4.0, 0.0, 200.0),),
           _coulomb_friction, 'eq (6): dW/dt = ... - Fc sign(W)', builtin=True),
    Effect('quadratic_drag', 'aerodynamic drag of the rod and motor pod, growing with the square of the speed',
           'residual ~ W|W|: damping that grows with swing speed',
           PENDULUM, (EffectParameter('drag_coefficient', '1/rad',
                                      'drag per unit inertia, Cd', 4.0, 0.0, 100.0),),
           _quadratic_drag, 'eq (6): dW/dt = ... - Cd W|W|', builtin=True),
    Effect('cable_torque', 'the motor cable acting as a torsion spring about the pivot',
           'residual ~ y (linear) next to gravity\'s sin y: differs only at large angles',
           PENDULUM, (EffectParameter('cable_stiffness', '1/s^2',
                                      'cable spring per unit inertia, Kc', 20.0, 0.0, 1000.0),),
           _cable_torque, 'eq (6): dW/dt = ... - Kc y', builtin=True),
    Effect('angle_offset', 'the angle sensor\'s zero is not the hanging position',
           'constant offset of the measured angle; looks like a cos(y) term next to sin(y)',
           MEASUREMENT, (EffectParameter('offset', 'rad', 'measured minus true angle', 0.05, -0.5, 0.5),),
           _angle_offset, 'measured angle = y + offset', builtin=True),
    Effect('thrust_lag', 'thrust builds up and decays slower than the motor speed (air inflow, propeller inertia)',
           'residual correlates with past input steps: the angle lags the model after each step',
           THRUST_LAG, (EffectParameter('time_constant', 's', 'first-order lag of the thrust', 0.15, 0.0, 5.0),),
           None, 'tau df/dt = f_eq5 - f, thrust f in eq (6)', builtin=True),
    Effect('dead_zone', 'no thrust below a threshold armature voltage (stiction of motor and propeller at low duty)',
           'model pushes at small duty where the rod does not move',
           THRUST_GATE, (EffectParameter('threshold_voltage', 'V',
                                         'armature voltage below which the thrust is zero', 0.6, 0.0, 3.0),),
           _dead_zone, 'eq (6): f = 0 where Va < threshold', builtin=True),
):
    add_effect(_effect)
