"""The model linearised at an operating angle: state space and transfer function from duty to measured angle.

The Jacobian is taken by central differences of the rig simulator's own right-hand side (the same equations the
simulation integrates, with the model's effects), at the equilibrium that holds the angle (:func:`static_duty`),
times the slope of eq (8) (volts per unit duty). Effects that have no linearisation at rest are left out and named:
Coulomb friction (its smoothed sign function would read as a huge damping at zero rate). The angle sensor's filter
is appended as its 2nd-order low-pass; the sensor offset has no small-signal effect. python-control (0.10) holds the
result: ``StateSpace`` / ``TransferFunction`` objects, discretised with a zero-order hold at the sample period and
one sample of latency (the firmware applies each duty from the next PWM period).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from aeropend_core.control.feedforward import static_duty, undetermined_at_rest
from aeropend_core.errors import AeropendError
from aeropend_core.model.effects import kernel_coefficients, resolve_effects
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, SAMPLE_TIME, RigParameters

#: Why an effect is left out of the linearisation (no derivative at rest: a dry friction's sign of the rate).
NOT_LINEARISED_REASON = 'dry friction has no slope at rest (left to the nonlinear check)'
STATE_NAMES = ('armature_current', 'motor_speed', 'angle', 'angular_rate', 'thrust', 'filter_1', 'filter_2')
STATE_UNITS = ('A', 'rad/s', 'rad', 'rad/s', 'N', 'rad', 'rad/s')


@dataclass(frozen=True)
class Linearisation:
    """The continuous small-signal model ``dx/dt = A x + B du, dy = C x`` around an equilibrium.

    Attributes: ``A, B, C, D`` (arrays), ``states`` (names, units in :data:`STATE_UNITS`), the operating
    ``angle`` [rad, measured] and ``duty`` [fraction], ``voltage_slope`` [V per unit duty], ``left_out`` effects.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    states: tuple[str, ...]
    angle: float
    duty: float
    voltage_slope: float
    left_out: dict[str, str]

    @property
    def dc_gain(self) -> float:
        """Measured angle per unit duty at DC [rad]."""
        return float((self.D - self.C @ np.linalg.solve(self.A, self.B)).item())

    def state_space(self):
        """python-control ``StateSpace`` (continuous), input duty [1], output measured angle [rad]."""
        import control
        return control.ss(self.A, self.B, self.C, self.D, inputs=['duty'], outputs=['angle'],
                          states=list(self.states))

    def transfer_function(self):
        """python-control ``TransferFunction`` (continuous) duty -> measured angle."""
        import control
        return control.ss2tf(self.state_space())

    def zero_order_hold(self, sample_time: float = SAMPLE_TIME) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Ad, Bd, C) of the zero-order-hold discretisation at `sample_time` [s], without latency: the matrix
        exponential of [[A, B], [0, 0]] Ts, as python-control's ``c2d(..., 'zoh')`` (scipy's cont2discrete) computes
        it, without importing python-control (~1.5 s of CPU at `control design`'s start)."""
        from scipy.linalg import expm
        n, m = self.B.shape
        block = np.zeros((n + m, n + m))
        block[:n, :n] = self.A
        block[:n, n:] = self.B
        exponential = expm(block * sample_time)
        return (np.ascontiguousarray(exponential[:n, :n]), np.ascontiguousarray(exponential[:n, n:]),
                np.ascontiguousarray(self.C))

    def discrete(self, sample_time: float = SAMPLE_TIME, latency: bool = True):
        """Zero-order-hold discretisation, times z^-1 for one sample of latency (``latency``)."""
        import control
        system = control.c2d(self.state_space(), sample_time, 'zoh')
        if latency:
            system = control.series(control.ss([[0.0]], [[1.0]], [[1.0]], [[0.0]], sample_time), system)
        return system

    def to_dict(self) -> dict:
        poles = np.linalg.eigvals(self.A)
        tf = self.transfer_function()
        return {'operating_angle': self.angle, 'operating_duty': self.duty, 'voltage_slope': self.voltage_slope,
                'states': [{'name': name, 'unit': STATE_UNITS[STATE_NAMES.index(name)]} for name in self.states],
                'input': {'name': 'duty', 'unit': '1'}, 'output': {'name': 'measured angle', 'unit': 'rad'},
                'A': self.A.tolist(), 'B': self.B.tolist(), 'C': self.C.tolist(), 'D': self.D.tolist(),
                'transfer_function': {'numerator': np.ravel(tf.num[0][0]).tolist(),
                                      'denominator': np.ravel(tf.den[0][0]).tolist(), 'variable': 's'},
                'poles': [{'real': float(p.real), 'imag': float(p.imag)} for p in poles],
                'dc_gain': self.dc_gain, 'left_out': dict(self.left_out)}


def linearise(angle: float, parameters: RigParameters = DEFAULT_PARAMETERS,
              effects: Mapping[str, Mapping[str, float] | float] | None = None) -> Linearisation:
    """Linearise the model at the measured angle `angle` [rad] held at rest.

    >>> lin = linearise(0.7)
    >>> lin.states[:4]
    ('armature_current', 'motor_speed', 'angle', 'angular_rate')
    >>> bool(lin.dc_gain > 0)
    True
    """
    from aeropend_core.sim.simulate import RigSimulator

    effects = resolve_effects(effects)
    left_out = {name: NOT_LINEARISED_REASON for name in effects if undetermined_at_rest(name)}
    kept = {name: values for name, values in effects.items() if name not in left_out}
    coefficients = kernel_coefficients(kept)
    duty = static_duty(angle, parameters, kept)
    if duty <= 0.0:
        raise AeropendError(f'at {np.degrees(angle):.1f} deg the model needs no thrust: linearise at an angle the '
                            'propeller holds (above the hanging position)')
    voltage = float(parameters.voltage_from_duty(duty))
    offset = coefficients['measured_offset']
    true_angle = angle - offset
    simulator = RigSimulator(parameters, kept, method='lsoda')
    steady = parameters.steady_state(voltage)
    state = [steady['armature_current'], steady['motor_speed'], true_angle, 0.0]
    if len(simulator.state) == 5:
        state.append(steady['thrust'])
    state = np.array(state)

    def rhs(x, va):
        return np.asarray(simulator._rhs_factory(va)(0.0, x), dtype=float)

    n = state.size
    scale = np.array([1e-3, 1.0, 1e-4, 1e-4, 1e-4][:n])
    a = np.empty((n, n))
    for j in range(n):
        step = np.zeros(n)
        step[j] = scale[j]
        a[:, j] = (rhs(state + step, voltage) - rhs(state - step, voltage)) / (2 * scale[j])
    dv = 1e-4
    b_voltage = (rhs(state, voltage + dv) - rhs(state, voltage - dv)) / (2 * dv)
    slope = float((parameters.voltage_from_duty(duty + 1e-6) - parameters.voltage_from_duty(duty - 1e-6)) / 2e-6)
    b = (b_voltage * slope).reshape(n, 1)
    c = np.zeros((1, n))
    c[0, 2] = 1.0
    names = list(STATE_NAMES[:4]) + (['thrust'] if n == 5 else [])
    delay = coefficients['measured_lowpass']
    if delay > 0:
        # H(s) = 1 / ((tau s)^2 + 3 tau s + 1) on the angle: states z1 (filtered angle), z2 = dz1/dt.
        tau = delay / 3.0
        a = np.block([[a, np.zeros((n, 2))], [np.zeros((2, n)), np.zeros((2, 2))]])
        a[n, n + 1] = 1.0
        a[n + 1, 2] = 1.0 / tau ** 2
        a[n + 1, n] = -1.0 / tau ** 2
        a[n + 1, n + 1] = -3.0 / tau
        b = np.vstack([b, np.zeros((2, 1))])
        c = np.zeros((1, n + 2))
        c[0, n] = 1.0
        names += ['filter_1', 'filter_2']
    return Linearisation(a, b, c, np.zeros((1, 1)), tuple(names), float(angle), float(duty), slope, left_out)
