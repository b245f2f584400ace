"""One vocabulary for the fitted pendulum model: parameter names, SI units and what estimated them.

Every fit of the pendulum equation (weak SINDy in :mod:`aeropend_core.identify.pendulum`, the output-error fit in
:mod:`aeropend_core.diagnosis.output_error`, the online window analysis, the JSON outputs, the HTML report and the
monitor) reports its values under these names; an effect's parameters keep the names of its catalog record
(:mod:`aeropend_core.model.effects`), which are unique across the catalog. Where two estimators give the same
quantity, the output names the estimator (:data:`ESTIMATORS`). A leaf module: it imports nothing of aeropend, and
the unit of any parameter, catalog effects included, is :func:`aeropend_core.model.effects.parameter_unit`.
"""
from __future__ import annotations

#: Parameters of the nominal pendulum equation
#: ``dW/dt = -gravity_stiffness sin y - damping W + thrust_gain e|e|``, ``e = Va - armature_resistance Ia``.
NOMINAL_PARAMETERS: dict[str, tuple[str, str]] = {
    'gravity_stiffness': ('1/s^2', 'mgd/J, gravity term per unit sin(angle)'),
    'damping': ('1/s', 'c/J, viscous damping of the pivot'),
    'thrust_gain': ('rad/s^2/V^2', '(L/J) Kq (N2/(N1 Kw))^2, thrust term per (Va - Ra Ia)^2'),
    'armature_resistance': ('ohm', 'Ra in Va - Ra Ia: the armature resistance as seen by the thrust'),
}
#: Quantities derived from the nominal parameters with known rig constants.
DERIVED_PARAMETERS: dict[str, tuple[str, str]] = {
    'thrust_coefficient': ('N s^2', 'Kq, from thrust_gain with the known gear, Kw and L/J'),
    'armature_resistance_from_current_square': ('ohm', 'Ra from the Ia^2 term of the weak form, sqrt(theta3/theta1)'),
}
#: Who estimated a value (the ``estimator`` field of JSON outputs).
ESTIMATORS = {
    'weak_sindy': 'weak-form regression of the pendulum equation (identify)',
    'output_error': 'free-run simulation fitted to the measured angle (diagnose, online refinement)',
    'motor_observer': 'motor observer fitted to the armature current (armature resistance with the observer)',
}


__all__ = ['NOMINAL_PARAMETERS', 'DERIVED_PARAMETERS', 'ESTIMATORS']
