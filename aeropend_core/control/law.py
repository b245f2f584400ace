"""The controller law of the closed loop: a discrete PID on the angle plus a static feedforward, at the sample rate.

One definition, run in three places: the rig's firmware (``firmware/aeropend/aeropend_control.h``, single-precision
C, checked against :func:`law_step` on shared test vectors), the sim node (this module, in Python) and the
closed-loop simulation of the design (:mod:`aeropend_core.control.loop`, :func:`law_step` compiled by numba).

At sample k (period Ts) with reference r [rad], feedforward duty u_ff (the duty that holds r under the model) and
measured angle y [rad]::

    e = r - y                              the error: the integral's (and conditional integration's)
    D = a_d D + (-b_d) (y - y_prev)        derivative on the measurement, first-order filter (backward Euler:
                                           a_d = Tf / (Tf + Ts), b_d = d / (Tf + Ts); stable for every Tf >= 0)
    v = k_ff u_ff + p (b r - y) + I + D    unsaturated output [duty]; b the setpoint weight (0..1)
    u = clamp(v, u_min, u_max)             the duty applied from sample k
    I = clamp(I + i Ts e + aw, i_min, i_max)   the integral for the next sample, with anti-windup aw:
        back_calculation:        aw = (Ts / Tt) (u - v)        (and i Ts e always)
        conditional_integration: i Ts e only when it does not push further into saturation
        none:                    aw = 0

Setpoint weighting (Astrom & Hagglund): the proportional term acts on ``b r - y``; b = 1 is the plain PID, b < 1
lowers the proportional kick of a reference step Δr by ``p (1 - b) Δr`` (less overshoot from a fast integral)
while the integral still acts on ``r - y`` (no steady-state error). The derivative is on the measurement (c = 0).
The derivative term is primed on the first sample (D = 0, no kick). Safety: a measured angle outside
[angle_min, angle_max] sets the duty to 0 and *trips* the law (latched: duty 0, integral frozen) until it is reset.
The names follow ros2_control's ``pid_controller`` (``p``, ``i``, ``d``, ``i_clamp_*``, ``u_clamp_*``,
``antiwindup``, ``tracking_time_constant``, ``feedforward_gain``); ``derivative_filter_time`` is Tf and
``setpoint_weight`` is b.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields

import numpy as np

from aeropend_core.errors import AeropendError
from aeropend_core.model.parameters import SAMPLE_TIME

#: Anti-windup strategies and their codes in the coefficient vector (and the firmware's protocol).
ANTIWINDUP = {'none': 0, 'back_calculation': 1, 'conditional_integration': 2}

# Layout of the coefficient vector (law_step's first argument); the firmware stores the same numbers.
(P, I_TS, D_POLE, D_GAIN, I_MIN, I_MAX, U_MIN, U_MAX, AW_CODE, AW_GAIN, FF_GAIN, ANGLE_MIN, ANGLE_MAX,
 SETPOINT_WEIGHT) = range(14)
N_COEFFICIENTS = 14
# Layout of the state vector (law_step's second argument, changed in place).
INTEGRAL, DERIVATIVE, PREVIOUS_ANGLE, PRIMED, TRIPPED, UNSATURATED = range(6)
N_STATE = 6


@dataclass(frozen=True)
class PidGains:
    """Gains and limits of the law; SI units, duty as a fraction 0..1.

    Parameters
    ----------
    p : float [1/rad]
        Proportional gain: duty per radian of error.
    i : float [1/(rad s)]
        Integral gain.
    d : float [s/rad]
        Derivative gain (on the measured angle).
    derivative_filter_time : float [s]
        Tf of the derivative's first-order filter (0: a plain backward difference).
    i_clamp_min, i_clamp_max : float [1]
        Limits of the integral term, in duty.
    u_clamp_min, u_clamp_max : float [1]
        Limits of the output duty, 0 <= min <= max <= 1.
    antiwindup : str
        'back_calculation', 'conditional_integration' or 'none'.
    tracking_time_constant : float [s]
        Tt of back-calculation (how fast the integral follows the saturated output); 0 picks sqrt(Ti Td) or Ti.
    feedforward_gain : float [1]
        Weight of the model's static feedforward duty (1: all of it; 0: a plain PID).
    angle_min, angle_max : float [rad]
        Safety limits of the measured angle: outside them the duty is 0 until the law is reset.
    setpoint_weight : float [1]
        b, the weight of the reference in the proportional term ``p (b r - y)``, 0 <= b <= 1 (1: the plain PID).
    """

    p: float = 0.5
    i: float = 0.5
    d: float = 0.05
    derivative_filter_time: float = 0.02
    i_clamp_min: float = -0.3
    i_clamp_max: float = 0.3
    u_clamp_min: float = 0.0
    u_clamp_max: float = 0.8
    antiwindup: str = 'back_calculation'
    tracking_time_constant: float = 0.0
    feedforward_gain: float = 1.0
    angle_min: float = -0.35
    angle_max: float = 1.75
    setpoint_weight: float = 1.0

    def __post_init__(self) -> None:
        problems = self.problems()
        if problems:
            raise AeropendError('controller gains: ' + '; '.join(problems))

    def problems(self) -> list[str]:
        """What is wrong with these gains, one sentence each (empty when they are usable)."""
        found = []
        for field in fields(self):
            value = getattr(self, field.name)
            if field.name == 'antiwindup':
                if value not in ANTIWINDUP:
                    found.append(f"antiwindup must be one of {', '.join(ANTIWINDUP)}, got {value!r}")
            elif not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
                found.append(f'{field.name} must be a finite number, got {value!r}')
        if found:
            return found
        for name in ('p', 'i', 'd', 'derivative_filter_time', 'tracking_time_constant'):
            if getattr(self, name) < 0:
                found.append(f'{name} must be >= 0, got {getattr(self, name)!r}')
        if not 0.0 <= self.u_clamp_min <= self.u_clamp_max <= 1.0:
            found.append(f'duty limits must satisfy 0 <= u_clamp_min <= u_clamp_max <= 1, got '
                         f'{self.u_clamp_min!r} .. {self.u_clamp_max!r}')
        if not self.i_clamp_min <= self.i_clamp_max:
            found.append(f'i_clamp_min ({self.i_clamp_min!r}) must not exceed i_clamp_max ({self.i_clamp_max!r})')
        if not 0.0 <= self.setpoint_weight <= 1.0:
            found.append(f'setpoint_weight must be between 0 and 1, got {self.setpoint_weight!r}')
        if not self.angle_min < self.angle_max:
            found.append(f'angle_min ({self.angle_min!r} rad) must be below angle_max ({self.angle_max!r} rad)')
        return found

    def replace(self, **changes) -> PidGains:
        values = asdict(self)
        values.update(changes)
        return PidGains(**values)

    def as_dict(self) -> dict[str, float | str]:
        return asdict(self)

    def text(self) -> str:
        """The gains in one line (design's and check's text).

        >>> PidGains(p=0.8, setpoint_weight=0.6).text()[:74]
        'p = 0.8 1/rad, i = 0.5 1/(rad s), d = 0.05 s/rad, derivative filter 0.02 s'
        >>> PidGains(p=0.8, setpoint_weight=0.6).text()[76:]
        'setpoint weight b = 0.6, duty 0..0.8, back_calculation, feedforward x1'
        """
        return (f'p = {self.p:.4g} 1/rad, i = {self.i:.4g} 1/(rad s), d = {self.d:.4g} s/rad, derivative filter '
                f'{self.derivative_filter_time:g} s, setpoint weight b = {self.setpoint_weight:.3g}, duty '
                f'{self.u_clamp_min:g}..{self.u_clamp_max:g}, {self.antiwindup}, feedforward '
                f'x{self.feedforward_gain:g}')

    def hashed_dict(self) -> dict[str, float | str]:
        """What hashes of the gains cover: :meth:`as_dict` without ``setpoint_weight`` when it is 1 (the law before
        setpoint weighting existed), so a controller file written before then keeps its sha256."""
        values = asdict(self)
        if values['setpoint_weight'] == 1.0:
            del values['setpoint_weight']
        return values

    @classmethod
    def from_mapping(cls, values: Mapping[str, object], source: str = 'gains') -> PidGains:
        """Gains from a mapping (a YAML section); unknown names are refused with the known ones listed."""
        known = {field.name for field in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise AeropendError(f'{source}: unknown controller setting(s) {", ".join(unknown)}; known: '
                                f'{", ".join(sorted(known))}')
        converted = {}
        for name, value in values.items():
            if name == 'antiwindup':
                converted[name] = str(value)
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise AeropendError(f'{source}: {name} must be a number, got {value!r}')
            converted[name] = float(value)
        return cls(**converted)

    @property
    def effective_tracking_time(self) -> float:
        """Tt [s] actually used by back-calculation: the set value, else sqrt(Ti Td) (Ti when d = 0), else 0."""
        if self.tracking_time_constant > 0:
            return self.tracking_time_constant
        if self.i <= 0 or self.p <= 0:
            return 0.0
        integral_time = self.p / self.i
        derivative_time = self.d / self.p
        return math.sqrt(integral_time * derivative_time) if derivative_time > 0 else integral_time

    def coefficients(self, sample_time: float = SAMPLE_TIME) -> np.ndarray:
        """The coefficient vector of :func:`law_step` at sample period `sample_time` [s] (shape (14,))."""
        if not sample_time > 0:
            raise AeropendError(f'sample_time must be positive, got {sample_time!r} s')
        c = np.zeros(N_COEFFICIENTS)
        denominator = self.derivative_filter_time + sample_time
        tracking = self.effective_tracking_time
        c[P] = self.p
        c[I_TS] = self.i * sample_time
        c[D_POLE] = self.derivative_filter_time / denominator
        c[D_GAIN] = self.d / denominator
        c[I_MIN], c[I_MAX] = self.i_clamp_min, self.i_clamp_max
        c[U_MIN], c[U_MAX] = self.u_clamp_min, self.u_clamp_max
        c[AW_CODE] = ANTIWINDUP[self.antiwindup]
        c[AW_GAIN] = sample_time / tracking if tracking > 0 else 0.0
        c[FF_GAIN] = self.feedforward_gain
        c[ANGLE_MIN], c[ANGLE_MAX] = self.angle_min, self.angle_max
        c[SETPOINT_WEIGHT] = self.setpoint_weight
        return c


def new_state() -> np.ndarray:
    """A fresh law state (integral 0, derivative unprimed, not tripped), shape (6,)."""
    return np.zeros(N_STATE)


def law_step(c, state, reference, feedforward_duty, angle):
    """One sample of the law: the duty [fraction] to apply from this sample; `state` is updated in place.

    Plain float arithmetic on two arrays so that numba compiles the same source (``numba.njit(law_step)``) and the
    firmware's C mirrors it line by line (firmware/aeropend/aeropend_control.h).

    Parameters
    ----------
    c : ndarray, shape (14,)
        :meth:`PidGains.coefficients`.
    state : ndarray, shape (6,)
        integral [duty], derivative [duty], previous angle [rad], primed (0/1), tripped (0/1), last unsaturated
        output [duty].
    reference : float [rad]
    feedforward_duty : float [fraction]
    angle : float [rad]
        The measured angle of this sample.
    """
    if state[4] != 0.0:
        return 0.0
    if angle < c[11] or angle > c[12]:
        state[4] = 1.0
        state[5] = 0.0
        return 0.0
    error = reference - angle
    if state[3] == 0.0:
        state[1] = 0.0
        state[3] = 1.0
    else:
        state[1] = c[2] * state[1] - c[3] * (angle - state[2])
    state[2] = angle
    unsaturated = c[10] * feedforward_duty + c[0] * (c[13] * reference - angle) + state[0] + state[1]
    duty = unsaturated
    if duty > c[7]:
        duty = c[7]
    if duty < c[6]:
        duty = c[6]
    integral = state[0]
    if c[8] == 1.0:
        integral = integral + c[1] * error + c[9] * (duty - unsaturated)
    elif c[8] == 2.0:
        if not ((unsaturated > c[7] and error > 0.0) or (unsaturated < c[6] and error < 0.0)):
            integral = integral + c[1] * error
    else:
        integral = integral + c[1] * error
    if integral > c[5]:
        integral = c[5]
    if integral < c[4]:
        integral = c[4]
    state[0] = integral
    state[5] = unsaturated
    return duty


class PidController:
    """The law with its state, for code that runs it sample by sample (the sim node).

    >>> controller = PidController(PidGains(p=0.5, i=0.0, d=0.0, feedforward_gain=1.0))
    >>> round(controller.step(reference=0.5, feedforward_duty=0.3, angle=0.4), 6)
    0.35
    """

    def __init__(self, gains: PidGains, sample_time: float = SAMPLE_TIME) -> None:
        self.sample_time = float(sample_time)
        self.state = new_state()
        self.set_gains(gains)

    def set_gains(self, gains: PidGains) -> None:
        """New gains from the next sample; the integral and the derivative filter keep their values (bumpless
        enough for small changes; the integral is clamped to the new limits)."""
        self.gains = gains
        self.coefficients = gains.coefficients(self.sample_time)
        self.state[INTEGRAL] = min(max(self.state[INTEGRAL], gains.i_clamp_min), gains.i_clamp_max)

    def reset(self) -> None:
        """Integral 0, derivative unprimed, the safety trip cleared."""
        self.state = new_state()

    @property
    def tripped(self) -> bool:
        return bool(self.state[TRIPPED])

    @property
    def integral(self) -> float:
        return float(self.state[INTEGRAL])

    def step(self, reference: float, feedforward_duty: float, angle: float) -> float:
        """The duty for this sample (fraction 0..1); see :func:`law_step`."""
        return float(law_step(self.coefficients, self.state, float(reference), float(feedforward_duty),
                              float(angle)))
