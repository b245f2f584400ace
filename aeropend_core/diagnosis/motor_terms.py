"""The motor equation's vocabulary: :class:`MotorTerm`, :data:`MOTOR_VOCABULARY` and a term put in the observer from
the command line, :class:`AddedMotorTerm`.

A leaf below the motor discovery (:mod:`aeropend_core.diagnosis.motor_discovery`, whose docstring explains the
vocabulary) and the comparison that carries an added term (:mod:`aeropend_core.diagnosis.compare`): both import
these types from here, so the imports point one way.
"""
from __future__ import annotations

from dataclasses import dataclass

from aeropend_core.diagnosis.evidence import finite_or_none


@dataclass(frozen=True)
class MotorTerm:
    """One candidate voltage in the armature circuit: ``La dIa/dt = Va - R Ia - e + coefficient * value``.

    Attributes
    ----------
    expression : str
        The term in the vocabulary's names: ``current`` [A] (the observer's Ia), ``back_emf`` [V] (Kw times the motor
        speed), ``heat`` [A^2] (Ia^2 through a 30 s lag), ``time`` [s].
    slug : str
        Short identifier.
    unit : str
        SI unit of the coefficient (the term times it is a voltage).
    reading : str
        Its physical reading.
    code : int
        The term's code in the compiled observer (:func:`_term_value`).
    """

    expression: str
    slug: str
    unit: str
    reading: str
    code: int

    @property
    def equation(self) -> str:
        return f'La dIa/dt = Va - R Ia - e + c * {self.expression}  (dIa/dt += c * {self.expression} / La)'


#: The motor equation's library (motor_discovery's docstring, step 2).
MOTOR_VOCABULARY: tuple[MotorTerm, ...] = (
    MotorTerm('1', 'motor_constant', 'V', 'a constant voltage error (an offset of the measured Va, a bridge drop)', 0),
    MotorTerm('sign(current)', 'current_sign', 'V', 'a brush / commutation voltage drop (constant while current '
              'flows)', 1),
    MotorTerm('current*back_emf', 'current_emf', '1/A', 'the field weakens with the armature current (armature '
              'reaction): back-EMF falls with load and speed', 2),
    MotorTerm('back_emf^2', 'emf_square', '1/V', 'a voltage growing with the speed squared (commutation, eddy '
              'losses)', 3),
    MotorTerm('current^2', 'current_square', 'V/A^2', 'a resistance that grows with the current (brush contact, '
              'a loose connection)', 4),
    MotorTerm('heat*current', 'heat_current', 'V/A^3', 'the winding\'s resistance rises with the dissipated power '
              '(copper heating through a thermal lag)', 5),
    MotorTerm('time*current', 'time_current', 'V/(A s)', 'the resistance drifts with time (warming, a connector)', 6),
)


@dataclass(frozen=True)
class AddedMotorTerm:
    """A motor term put in the observer from the command line (``--motor-term``), refitted on the training part.

    Attributes
    ----------
    term : MotorTerm
        The term.
    value, sigma : float [unit of the term]
        Its coefficient ``c`` and 1-sigma (output error on the current, sandwich by Va level plus the levels' error).
    current_excess_before, current_excess_after : float [A]
        The current's held-out error beyond its noise with the observer without and with the term.
    """

    term: MotorTerm
    value: float
    sigma: float
    current_excess_before: float
    current_excess_after: float

    def to_dict(self) -> dict:
        return {'expression': self.term.expression, 'equation': self.term.equation,
                'parameters': {f'motor_{self.term.slug}_coefficient': {
                    'value': finite_or_none(self.value), 'sigma': finite_or_none(self.sigma),
                    'unit': self.term.unit}},
                'estimator': 'output_error_on_current', 'error_unit': 'A',
                'error_beyond_noise_before': finite_or_none(self.current_excess_before),
                'error_beyond_noise_after': finite_or_none(self.current_excess_after)}
