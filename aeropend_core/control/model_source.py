"""A model to design on, linearise or simulate: the nominal parameters, or those of an ``identify``/``diagnose``
JSON (its fitted pendulum parameters, its armature resistance and the effects it added, with their fitted values).

A diagnosis fits the thrust as one gain, (L/J) Kq (N2/(N1 Kw))^2 [rad/s^2/V^2]; the model here keeps the motor's
nominal Kq and Kw and scales L/J so that the product equals the fitted gain (the loop only sees the product).

The thrust the diagnosis fitted that gain on is the square of the back-EMF its motor observer
(:mod:`aeropend_core.signals.motor`) computed from Va, fitted to the measured Ia: de/dt = p1 (Va - e) - p2 e -
p3 e|e|, Ia = (Va - e)/Rm. The model takes that motor too (the JSON's ``motor_observer``): with Kw and Kt kept,
Jm = Kw Kt/(p1 Rm), F = p2 Jm, Kd = p3 Jm Kw (N1/N2)^3 and La = tau_e Rm, so that the simulated motor's speed, its
lag and its static map from Va are the rig's that the fit saw, not the nominal motor's.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import dataclass, field

from aeropend_core.errors import AeropendError
from aeropend_core.model.effects import find_parameter, resolve_effects
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, RigParameters


@dataclass(frozen=True)
class ModelSource:
    """Parameters and effects of a model and where they came from; `doubts` are said next to every number made
    with it."""

    parameters: RigParameters = DEFAULT_PARAMETERS
    effects: dict = field(default_factory=dict)
    source: str = 'nominal'
    doubts: tuple[str, ...] = ()
    #: angle noise of the source record as a PSNR on the 90 deg full scale [dB] (50, the simulator's, if unknown)
    psnr_db: float = 50.0
    #: the rig's thrust relative to this model's that a design must tolerate: +-2 sigma of the fitted thrust gain
    #: (at least +-5 %, at most +-15 %); a nominal model -20 % to +25 %
    thrust_tolerance: tuple[float, float] = (0.8, 1.25)

    def with_hold_doubt(self, doubt) -> ModelSource:
        """This model with its thrust tolerance widened to the doubt of the open-loop record's rests (a
        :class:`~aeropend_core.control.hold_doubt.HoldDoubt`, or None: no rests found, said as a doubt)."""
        from aeropend_core.control.hold_doubt import widened
        if doubt is None:
            return dataclasses.replace(self, doubts=(*self.doubts, 'the record has too few rests (constant-duty '
                                                     'holds above 10 deg) to check the feedforward: the thrust '
                                                     'doubt is the fit\'s alone'))
        tolerance, beyond = widened(self.thrust_tolerance, doubt)
        band = ', each within the band the model\'s dry friction holds the rod in' if doubt.within_friction_band else ''
        said = (f'the feedforward checked on the record: the rig\'s thrust at its rests is '
                f'{doubt.tolerance[0]:.3f}-{doubt.tolerance[1]:.3f} x the model\'s (mean +-2 sd of '
                f'{len(doubt.factors)} rests{band}); the design tolerates {tolerance[0]:.3f}-{tolerance[1]:.3f} x')
        if beyond:
            said += (' (wider than the nominal model\'s 0.8-1.25: the identified model\'s thrust map is off there; '
                     'the design may refuse)')
        return dataclasses.replace(self, thrust_tolerance=tolerance, doubts=(*self.doubts, said))


def load_model(path: str | os.PathLike | None) -> ModelSource:
    """The nominal model (`path` None) or the model of a diagnose/identify JSON file."""
    if path is None:
        return ModelSource()
    from aeropend_core.io.inputs import read_input_text
    text = read_input_text(path, 'model JSON')
    try:
        data = json.loads(text)
    except json.JSONDecodeError as error:
        raise AeropendError(f'model JSON {path}: not valid JSON ({error.msg} at line {error.lineno}); give the file '
                            'written by `aeropend diagnose --json FILE`') from None
    return model_from_dict(data, str(path))


def model_from_dict(data, source: str) -> ModelSource:
    if not isinstance(data, dict) or not isinstance(data.get('parameters'), dict):
        raise AeropendError(f'{source}: no "parameters" in it; give the JSON of `aeropend diagnose --json FILE` '
                            'or `aeropend identify --json FILE`')
    fitted = data['parameters']
    changes = {}
    for name in ('gravity_stiffness', 'damping', 'armature_resistance'):
        if _number(fitted.get(name)):
            changes[name] = float(fitted[name])
    parameters = DEFAULT_PARAMETERS.replace(**changes, **observer_motor(data.get('motor_observer'),
                                                                        changes.get('armature_resistance')))
    if _number(fitted.get('thrust_gain')) and fitted['thrust_gain'] > 0:
        parameters = parameters.replace(lever_per_inertia=float(fitted['thrust_gain'])
                                        / parameters.thrust_voltage_coefficient)
    effects: dict[str, dict[str, float]] = {}
    for name in data.get('model_effects') or []:
        effects[str(name)] = {}
    for parameter, value in fitted.items():
        found = find_parameter(parameter)
        if found is None or not _number(value):
            continue
        effect, _ = found
        if effect.name in effects:
            effects[effect.name][parameter] = float(value)
    try:
        effects = resolve_effects(effects)
    except (AeropendError, TypeError, ValueError) as error:
        raise AeropendError(f'{source}: its effects cannot be read: {error}') from None
    doubts = []
    verdict = data.get('verdict')
    if verdict not in (None, 'nothing_missing'):
        # a diagnose JSON lists each found effect as an object ({'effect': name, ...}); the closed-loop one as a name
        names = [str(entry.get('effect')) if isinstance(entry, dict) else str(entry)
                 for entry in data.get('missing_effects') or []]
        missing = ', '.join(names) or str(data.get('missing_effect') or '')
        doubts.append(f'this diagnosis says the model misses something ({verdict}{": " + missing if missing else ""}'
                      f'); a design on it inherits the miss: add it (--add) and diagnose again')
    for warning in data.get('parameter_warnings') or {}:
        doubts.append(f'parameter {warning} failed a physical check in the diagnosis')
    if data.get('warnings'):
        doubts.append(f'the diagnosed record had {len(data["warnings"])} data warning(s)')
    if not isinstance(data.get('motor_observer'), dict):
        # `identify --json` fits the thrust on Va - R Ia, with no motor observer: the motor's speed, its lag and its
        # static map from Va stay the nominal rig's under the fitted thrust gain (11 % off in static thrust on a rig
        # whose motor constants were 15 % off, s21)
        doubts.append('the model carries no motor fit (no "motor_observer": an identify JSON, or a record without the '
                      'current): the motor\'s inertia, friction, drag and inductance are the nominal rig\'s; a design '
                      'on `aeropend diagnose --json` of the same record keeps the fitted motor')
    psnr = 50.0
    if _number(data.get('noise_rms')) and data['noise_rms'] > 0:
        psnr = min(80.0, 20.0 * math.log10((math.pi / 2) / float(data['noise_rms'])))
    tolerance = (0.8, 1.25)
    sigma = (data.get('standard_errors') or {}).get('thrust_gain')
    gain = fitted.get('thrust_gain')
    if _number(sigma) and _number(gain) and gain > 0:
        relative = min(0.15, max(0.05, 2.0 * float(sigma) / float(gain)))
        tolerance = (1.0 - relative, 1.0 + relative)
    return ModelSource(parameters, effects, source, tuple(doubts), psnr, tolerance)


def observer_motor(observer, resistance: float | None = None) -> dict[str, float]:
    """The rig's motor constants (Jm [kg m^2], F [N m s/rad], Kd [N m s^2], La [H]) that make the simulator's motor
    the diagnosis's motor observer (`observer`: its ``motor_drive_rate`` p1 [1/s], ``motor_friction_rate`` p2
    [1/s], ``motor_drag_rate`` p3 [1/(V s)], ``motor_resistance`` Rm [ohm] and, when fitted,
    ``electrical_time_constant`` [s]), with the nominal Kw and Kt; {} when there is none or a value is not usable.
    `resistance` [ohm]: the model's Ra when it is given apart (the diagnosis reports the observer's Rm as Ra)."""
    if not isinstance(observer, dict):
        return {}
    drive, friction, drag = (observer.get(key) for key in ('motor_drive_rate', 'motor_friction_rate',
                                                             'motor_drag_rate'))
    rm = observer.get('motor_resistance') if resistance is None else resistance
    if not all(_number(value) for value in (drive, friction, drag, rm)) or drive <= 0 or rm <= 0 or \
            friction < 0 or drag <= 0:
        return {}
    base = DEFAULT_PARAMETERS
    inertia = base.back_emf_constant * base.torque_constant / (drive * rm)
    motor = {'motor_inertia': inertia, 'motor_friction': friction * inertia,
             'propeller_torque_coefficient': drag * inertia * base.back_emf_constant * base.gear_ratio ** 3}
    tau = observer.get('electrical_time_constant')
    if _number(tau) and tau > 0:
        motor['armature_inductance'] = tau * rm
    return motor


def motor_rates(parameters: RigParameters) -> dict[str, float]:
    """The motor of `parameters` as an observer's numbers (the inverse of :func:`observer_motor`, same names and
    units): what a closed-loop diagnosis's JSON carries so that a design on it keeps its controller model's motor."""
    p = parameters
    return {'motor_drive_rate': p.back_emf_constant * p.torque_constant / (p.motor_inertia * p.armature_resistance),
            'motor_friction_rate': p.motor_friction / p.motor_inertia,
            'motor_drag_rate': p.propeller_torque_coefficient / p.gear_ratio ** 3 / (p.motor_inertia
                                                                                     * p.back_emf_constant),
            'motor_resistance': p.armature_resistance,
            'electrical_time_constant': p.armature_inductance / p.armature_resistance}


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and value == value and abs(value) < 1e300
