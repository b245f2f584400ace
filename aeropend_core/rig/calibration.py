"""Rig calibration from raw measurements: sensor zeros, angle scale, locked-rotor Ra, back-EMF constant Kw.

Pure functions on arrays (no serial port): ``aeropend calibrate`` (aeropend_core/cli/calibrate.py) records the data
from the device and calls these. Every function checks that its data can support the answer and raises
:class:`~aeropend_core.errors.InsufficientDataError` with what to do otherwise.

* zero: rod hanging still, motor off -> ``angle_zero`` [counts] and ``current_offset`` [counts];
* angle scale: rod held at a known angle -> ``angle_scale`` [rad/count] (sign included);
* locked rotor: propeller held, a few low duties -> with the rotor still there is no back-EMF, so in steady state
  Va = Ra Ia: the slope of Va against Ia over the steps is Ra [ohm] (an intercept absorbs a brush/bridge drop);
* back-EMF: motor spinning freely at a steady duty, speed measured externally (optical tachometer) ->
  Kw = (Va - Ra Ia) / w1 [V s/rad];
* angle filter: the measurement chain's low-pass on the angle (the AS5040's PWM output through a 2nd-order RC
  ladder, R1 = R2 = R, C1 = C2 = C on the board) -> its DC group delay ``angle_filter_delay`` = 3 R C [s], from the
  component values (:func:`rc_ladder_delay`). The calibration file carries it so that the diagnosis can hold the
  filter at its hardware value (:func:`read_measurement_chain`) instead of confusing it with a thrust lag.

The calibration file is the serial bridge's parameter YAML (``config/serial_bridge_node.yaml``):
:func:`read_calibration_file` returns its ``ros__parameters``.

The firmware reads the current once per PWM period, at the pulse centre (phase-correct PWM). With La/Ra about one
period the armature current ripples, and that reading exceeds the period average (:func:`held_current_offset`,
a first-order armature under a square-wave drive: tens of mA). The calibration subtracts this estimate and says so.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from aeropend_core.errors import AeropendError, InsufficientDataError

#: The firmware's current sample-and-hold after the Timer1 overflow [s]: an auto-triggered conversion holds 2 ADC
#: clocks (prescaler 128) + 3 CPU cycles after its trigger (ATmega2560 datasheet), at 16 MHz.
HOLD_DELAY = (2 * 128 + 3) / 16e6

#: The key of the serial bridge's section in its parameter YAML (the node in any namespace).
NODE_KEY = '/**/serial_bridge_node'
#: Calibration-file key of the angle filter's DC group delay [s] (0: no filter on the angle).
ANGLE_FILTER_KEY = 'angle_filter_delay'
#: Largest believable angle-filter delay [s] (the catalog's bound: a slower filter would blur the pendulum itself).
MAX_ANGLE_FILTER_DELAY = 0.05

__all__ = [
    'ANGLE_FILTER_KEY',
    'LineFit',
    'MeasurementChain',
    'ZeroResult',
    'angle_scale_from_reference',
    'back_emf_constant',
    'held_current_offset',
    'hold_after_pulse_start',
    'locked_rotor_resistance',
    'rc_ladder_delay',
    'read_calibration_file',
    'read_measurement_chain',
    'steady_mean',
    'zero_offsets',
]


@dataclass(frozen=True)
class ZeroResult:
    """Sensor zeros: ``angle_zero`` and ``current_offset`` [ADC counts] with their sample standard deviations."""

    angle_zero: float
    current_offset: float
    angle_std: float
    current_std: float
    samples: int


@dataclass(frozen=True)
class LineFit:
    """A fitted constant with its 1-sigma standard error and the fit's offset (e.g. Ra [ohm] and a drop [V])."""

    value: float
    sigma: float
    intercept: float
    points: int


def zero_offsets(angle_counts: np.ndarray, current_counts: np.ndarray, max_angle_std: float = 2.0) -> ZeroResult:
    """Zeros from a record with the rod hanging still and the motor off.

    Parameters
    ----------
    angle_counts, current_counts : array, shape (n_samples,)
        Raw ADC counts.
    max_angle_std : float
        Largest believable angle scatter [counts] for a rod at rest (default 2 counts).
    """
    angle = np.asarray(angle_counts, dtype=float)
    current = np.asarray(current_counts, dtype=float)
    if angle.size < 100:
        raise InsufficientDataError(f'only {angle.size} samples: record at least 0.2 s (100 samples)')
    if angle.std() > max_angle_std:
        raise InsufficientDataError(f'the angle reading scatters by {angle.std():.1f} counts: the rod is moving; '
                                    'let it hang still (motor off) and repeat')
    return ZeroResult(float(angle.mean()), float(current.mean()), float(angle.std()), float(current.std()),
                      int(angle.size))


def angle_scale_from_reference(angle_counts: np.ndarray, angle_zero: float, reference_angle: float) -> float:
    """rad per count from a record with the rod held at `reference_angle` [rad] (e.g. pi/2, horizontal)."""
    counts = float(np.mean(angle_counts)) - angle_zero
    if abs(reference_angle) < math.radians(10):
        raise InsufficientDataError('use a reference angle of at least 10 degrees (e.g. 90, the rod horizontal)')
    if abs(counts) < 10:
        raise InsufficientDataError(f'the reading moved only {counts:.1f} counts from the zero: is the rod at the '
                                    'reference angle, and was the zero taken hanging down?')
    return reference_angle / counts


def steady_mean(values: np.ndarray, settle_fraction: float = 0.5) -> float:
    """Mean of the last (1 - settle_fraction) of a step record (the transient at its start excluded)."""
    values = np.asarray(values, dtype=float)
    return float(values[int(len(values) * settle_fraction):].mean())


def _line(x: np.ndarray, y: np.ndarray) -> LineFit:
    design = np.column_stack([x, np.ones_like(x)])
    coefficients, *_ = np.linalg.lstsq(design, y, rcond=None)
    residual = y - design @ coefficients
    dof = max(len(x) - 2, 1)
    covariance = np.linalg.inv(design.T @ design) * float(residual @ residual) / dof
    return LineFit(float(coefficients[0]), float(math.sqrt(max(covariance[0, 0], 0.0))), float(coefficients[1]),
                   len(x))


def locked_rotor_resistance(armature_voltage: np.ndarray, armature_current: np.ndarray) -> LineFit:
    """Ra [ohm] from steady (Va [V], Ia [A]) pairs with the rotor locked: the slope of Va = Ra Ia + drop.

    Parameters
    ----------
    armature_voltage, armature_current : array, shape (n_steps,)
        Steady-state means of each duty step (at least 3 steps spanning 0.1 A).
    """
    voltage = np.asarray(armature_voltage, dtype=float)
    current = np.asarray(armature_current, dtype=float)
    if voltage.size < 3:
        raise InsufficientDataError(f'{voltage.size} duty steps: use at least 3 (e.g. --duties 0.1,0.15,0.2,0.25)')
    if np.ptp(current) < 0.1:
        raise InsufficientDataError(f'the current changed by only {np.ptp(current):.3f} A over the steps: use '
                                    'larger duty steps, and check that the motor is connected')
    fit = _line(current, voltage)
    if fit.value <= 0:
        raise InsufficientDataError(f'Va does not rise with Ia (slope {fit.value:.3g} ohm): is the rotor locked?')
    return fit


def back_emf_constant(armature_voltage: np.ndarray, armature_current: np.ndarray, motor_speed: np.ndarray,
                      resistance: float) -> LineFit:
    """Kw [V s/rad] from steady free-running points: (Va - Ra Ia) = Kw w1 (+ drop).

    Parameters
    ----------
    armature_voltage, armature_current, motor_speed : array, shape (n_points,)
        Steady means [V], [A] and the externally measured motor-shaft speed [rad/s]. With one point the
        result is the ratio (no drop, no sigma); with several, a line fit.
    resistance : float
        Ra [ohm] from the locked-rotor step.
    """
    voltage = np.atleast_1d(np.asarray(armature_voltage, dtype=float))
    current = np.atleast_1d(np.asarray(armature_current, dtype=float))
    speed = np.atleast_1d(np.asarray(motor_speed, dtype=float))
    if np.any(speed <= 0):
        raise InsufficientDataError('motor speeds must be positive (rad/s; measure them with a tachometer)')
    emf = voltage - resistance * current
    if np.any(emf <= 0):
        raise InsufficientDataError('Va - Ra Ia is not positive: is the motor spinning freely, and is Ra right?')
    if speed.size == 1:
        return LineFit(float(emf[0] / speed[0]), float('nan'), 0.0, 1)
    if speed.size == 2:
        slope = float((emf[1] - emf[0]) / (speed[1] - speed[0]))
        return LineFit(slope, float('nan'), float(emf[0] - slope * speed[0]), 2)
    return _line(speed, emf)


def held_current_offset(duty, armature_voltage, resistance: float, inductance: float, period: float,
                        hold_after_pulse_start) -> np.ndarray:
    """Armature current at the hold instant minus the period average [A], in periodic steady state.

    The drive is ``armature_voltage / duty`` for ``duty x period`` from the pulse start, 0 for the rest;
    ``La dI/dt = v(t) - Ra I - e`` with a back-EMF ``e`` constant over a period (the motor is ~100 times slower),
    so the ripple does not depend on ``e``. Arrays broadcast; duty 0 gives 0.
    """
    duty = np.asarray(duty, dtype=float)
    voltage = np.asarray(armature_voltage, dtype=float)
    hold = np.asarray(hold_after_pulse_start, dtype=float)
    tau = inductance / resistance
    on = duty > 0
    safe_duty = np.where(on, duty, 1.0)
    drive = np.where(on, voltage / safe_duty, 0.0) / resistance           # current the pulse drives towards [A]
    pulse = safe_duty * period
    a = np.exp(-pulse / tau)
    b = np.exp(-(period - pulse) / tau)
    high = drive * (1 - a) / np.maximum(1 - a * b, 1e-300)               # at the pulse end
    low = b * high                                                       # at the pulse start
    inside = hold <= pulse
    during = low * np.exp(-hold / tau) + drive * (1 - np.exp(-hold / tau))
    after = high * np.exp(-(hold - pulse) / tau)
    value = np.where(inside, during, after) - voltage / resistance
    return np.where(on, value, 0.0)


def hold_after_pulse_start(duty, period: float, phase_correct: bool = True):
    """When the firmware holds the current, measured from the start of the pulse [s].

    Phase-correct PWM (the shipped build): the overflow is at BOTTOM, the pulse centre, so ``duty x period / 2``
    after the pulse start, plus :data:`HOLD_DELAY`; fast PWM: :data:`HOLD_DELAY` after the pulse start.
    """
    duty = np.asarray(duty, dtype=float)
    return (duty * period / 2 if phase_correct else 0.0 * duty) + HOLD_DELAY


def rc_ladder_delay(resistance: float, capacitance: float) -> float:
    """DC group delay [s] of an unbuffered 2nd-order RC ladder with R1 = R2 and C1 = C2: 3 R C.

    Parameters
    ----------
    resistance : float
        R1 = R2 [ohm] (4.7e3 on the rig's board).
    capacitance : float
        C1 = C2 [F] (1e-6 on the rig's board).

    Returns
    -------
    float
        The delay [s] (0.0141 for 4.7 kOhm and 1 uF); its cut-off is 0.1787 / delay [Hz].
    """
    for name, value, unit in (('resistance', resistance, 'ohm'), ('capacitance', capacitance, 'F')):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise AeropendError(f'the angle filter\'s {name} must be a positive number of {unit}, got {value!r}')
    delay = 3.0 * float(resistance) * float(capacitance)
    if delay > MAX_ANGLE_FILTER_DELAY:
        raise AeropendError(f'R = {resistance:g} ohm and C = {capacitance:g} F give a filter delay of {delay:g} s, '
                            f'more than {MAX_ANGLE_FILTER_DELAY:g} s: check the units (ohm and farad, e.g. 4700 '
                            f'and 1e-6)')
    return delay


def read_calibration_file(path: str | Path) -> dict:
    """The ``ros__parameters`` of the serial bridge's section of a calibration YAML file (``{}`` when absent).

    Raises
    ------
    AeropendError
        The file cannot be read or is not YAML, naming the file.
    """
    import yaml

    from aeropend_core.io.inputs import load_yaml
    path = Path(path)
    try:
        document = load_yaml(path, 'the calibration file')       # a FIFO, device or a too deep YAML: refused
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as error:
        raise AeropendError(f'cannot read the calibration file {path}: {error}') from error
    if not isinstance(document, dict):      # an empty file, a lone value (.nan), a list: nothing to calibrate from
        raise AeropendError(f'{path} is not a calibration file ({"empty" if document is None else "no mapping"}: '
                            f'it needs {NODE_KEY}: ros__parameters: ...; see config/serial_bridge_node.yaml)')
    key = next((k for k in (NODE_KEY, NODE_KEY.removeprefix('/**/')) if k in document), None)  # old files: no '/**/'
    if key is None:
        raise AeropendError(f'{path} has no {NODE_KEY} section (it holds {", ".join(map(str, document)) or "nothing"}'
                            f'): not a calibration file; see config/serial_bridge_node.yaml')
    section = document[key] or {}
    values = section.get('ros__parameters') if isinstance(section, dict) else None
    values = dict(values) if isinstance(values, dict) else {}
    for name, value in values.items():
        if isinstance(value, float) and not math.isfinite(value):
            raise AeropendError(f'{path}: {name} is {value!r}, not a number a calibration can hold; fix or remove it')
    return values


@dataclass(frozen=True)
class MeasurementChain:
    """The measurement-chain values a calibration file states (None: the file does not say).

    Attributes
    ----------
    angle_filter_delay : float or None
        DC group delay of the angle's low-pass [s]; 0.0 when the file states that the angle is not filtered.
    source : str
        Where the values came from (the file's path), for the reports.
    """

    angle_filter_delay: float | None
    source: str


def read_measurement_chain(path: str | Path) -> MeasurementChain:
    """The measurement-chain values of a calibration file (``angle_filter_delay`` [s]; see the module docstring).

    Raises
    ------
    AeropendError
        Unreadable file, or a value that is not a delay in seconds between 0 and ``MAX_ANGLE_FILTER_DELAY``.
    """
    values = read_calibration_file(path)
    delay = values.get(ANGLE_FILTER_KEY)
    if delay is not None:
        if isinstance(delay, bool) or not isinstance(delay, (int, float)) or not \
                0.0 <= float(delay) <= MAX_ANGLE_FILTER_DELAY:
            raise AeropendError(f'{path}: {ANGLE_FILTER_KEY} must be the angle filter\'s delay in seconds, between 0 '
                                f'(no filter) and {MAX_ANGLE_FILTER_DELAY:g} (e.g. 0.0141 for the 4.7 kOhm / 1 uF '
                                f'RC ladder: `aeropend calibrate angle-filter`), got {delay!r}')
        delay = float(delay)
    return MeasurementChain(delay, str(path))
