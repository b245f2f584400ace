"""The rig's analog front end for the fake device: what lies between the physics and the firmware's ADC counts.

:class:`MeasurementChain` (settings) and :class:`ChainState` (its filter and noise state, one per device) turn the
simulator's angle, armature current and voltage into the raw 10-bit counts the firmware would send:

* **Angle** (``A2``): the AS5040 magnetic encoder's absolute 10-bit position, which **wraps** from 1023 to 0 (the
  counts are ``(angle / angle_scale + angle_zero) mod 1024``: mount the magnet so the hanging rod reads near 512),
  is output as a 975.6 Hz PWM and smoothed by a passive 2nd-order RC ladder, R1 = R2 = 4.7 kOhm, C1 = C2 = 1 uF
  (README wiring table): ``H(s) = 1 / (tau^2 s^2 + 3 tau s + 1)`` with tau = RC = 4.7 ms, a DC group delay of
  3 tau = 14.1 ms and -58 dB at 975.6 Hz. The filter is integrated exactly over each sample period with the input
  taken as the mean of its values at both ends; the remaining PWM ripple (fundamental, ~0.8 counts peak at
  mid-scale) is added at the sample instants, where it aliases to a slow beat (975.6 Hz - 2 x 490.196 Hz =
  4.8 Hz).
* **Armature current** (``A0``): with La/Ra ~ Ts the current ripples within each PWM period. The drive is modelled
  as a square wave of height Va/duty for duty x Ts per period (its mean is eq (8)'s Va, so the period-average
  current is the simulator's), continuous conduction assumed; the current is read at the sample-and-hold instant,
  ``hold_delay`` (16.19 us, the firmware's auto-triggered conversion) after the pulse centre in phase-correct mode
  (after the pulse start in fast mode). That reading exceeds the period average by tens of mA (default Ra, La:
  +0.045 A at duty 0.02, +0.071 A at 0.1, +0.055 A at 0.5, +0.034 A at 0.7; at the exact pulse centre +0.035 A
  at 0.1, checked against a brute-force integration of the circuit).
* **ADC noise**: Gaussian, ``adc_noise_counts`` (0.5 count) standard deviation per conversion on every channel,
  then rounding and clipping to 0..1023.

Without a chain (``DeviceEmulator(chain=None)``) the emulator sends the ideal counts of the simulator's values.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from aeropend_core.model.parameters import RigParameters
from aeropend_core.rig import protocol as P
from aeropend_core.rig.calibration import HOLD_DELAY, held_current_offset, hold_after_pulse_start

__all__ = ['ChainState', 'MeasurementChain']

#: ADC full scale in counts + 1 (the encoder's and the ADC's 10 bits)
COUNTS = 1024


@dataclass(frozen=True)
class MeasurementChain:
    """Settings of the analog front end (see the module docstring); SI units."""

    angle_filter: bool = True                 #: 2nd-order RC low-pass on the encoder's PWM
    filter_resistance: float = 4.7e3          #: R1 = R2 [ohm]
    filter_capacitance: float = 1e-6          #: C1 = C2 [F]
    encoder_pwm_frequency: float = 975.6      #: AS5040 PWM output [Hz]
    encoder_ripple: bool = True               #: add the filtered PWM ripple at the sample instants
    encoder_wrap: bool = True                 #: absolute encoder: counts modulo 1024
    pwm_current: bool = True                  #: current read at the hold instant of the PWM-resolved current
    hold_delay: float = HOLD_DELAY            #: sample-and-hold after the overflow [s] (datasheet, ADC clk/128)
    adc_noise_counts: float = 0.5             #: Gaussian ADC noise, standard deviation [counts]

    def __post_init__(self) -> None:
        for name in ('filter_resistance', 'filter_capacitance', 'encoder_pwm_frequency'):
            if not getattr(self, name) > 0:
                raise ValueError(f'{name} must be positive, got {getattr(self, name)!r}')
        if not (0 <= self.adc_noise_counts < 100 and 0 <= self.hold_delay < P.SAMPLE_PERIOD):
            raise ValueError('adc_noise_counts must be in [0, 100) counts and hold_delay in [0, Ts)')

    @property
    def group_delay(self) -> float:
        """DC group delay of the angle filter [s]: 3 RC for the unbuffered ladder (0 without the filter)."""
        return 3.0 * self.filter_resistance * self.filter_capacitance if self.angle_filter else 0.0

    def start(self, calibration: P.Calibration, parameters: RigParameters, pwm_mode: int = P.PWM_PHASE_CORRECT,
              seed: int = 0) -> ChainState:
        """A fresh front end (filter settled on its first input) for one device."""
        return ChainState(self, calibration, parameters, pwm_mode, seed)


class ChainState:
    """One device's front end: filter state, encoder PWM phase, noise generator (see :class:`MeasurementChain`)."""

    def __init__(self, chain: MeasurementChain, calibration: P.Calibration, parameters: RigParameters,
                 pwm_mode: int, seed: int) -> None:
        self.chain = chain
        self.calibration = calibration
        self.parameters = parameters
        self.pwm_mode = pwm_mode
        self.rng = np.random.default_rng(seed)
        tau = chain.filter_resistance * chain.filter_capacitance
        # Ladder states (v1 on C1, v2 on C2 = output), input u held over a sample period: x' = A x + B u.
        a_matrix = np.array([[-2.0 / tau, 1.0 / tau], [1.0 / tau, -1.0 / tau]])
        b_vector = np.array([1.0 / tau, 0.0])
        block = np.zeros((3, 3))
        block[:2, :2] = a_matrix * P.SAMPLE_PERIOD
        block[:2, 2] = b_vector * P.SAMPLE_PERIOD
        discrete = expm(block)
        self._phi, self._gamma = discrete[:2, :2], discrete[:2, 2]
        omega = 2 * math.pi * chain.encoder_pwm_frequency
        self._ripple_gain = 1.0 / abs(complex(1 - (tau * omega) ** 2, 3 * tau * omega))
        self._ripple_phase = float(self.rng.uniform(0, 2 * math.pi))
        self._filter: np.ndarray | None = None
        self._samples = 0

    def encoder_counts(self, angle: np.ndarray) -> np.ndarray:
        """The encoder's position in counts (wrapping at 1024 when the chain says so), before the filter."""
        counts = np.asarray(angle, dtype=float) / self.calibration.angle_scale + self.calibration.angle_zero
        return np.mod(counts, COUNTS) if self.chain.encoder_wrap else counts

    def counts(self, angle, current, voltage, duty) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Raw ADC counts ``(current, angle, voltage)`` of consecutive samples (SI inputs, duty fraction)."""
        chain = self.chain
        angle = np.asarray(angle, dtype=float)
        n = angle.size
        position = self.encoder_counts(angle)
        if chain.angle_filter:
            if self._filter is None:
                self._filter = np.array([position[0], position[0]])
                self._last_position = position[0]
            filtered = np.empty(n)
            state, last = self._filter, self._last_position
            for k in range(n):
                # the encoder's PWM average moves continuously: taken as linear between samples (trapezoid)
                state = self._phi @ state + self._gamma * (0.5 * (last + position[k]))
                filtered[k] = state[1]
                last = position[k]
            self._filter, self._last_position = state, last
        else:
            filtered = position
        if chain.encoder_ripple and chain.angle_filter:
            k = self._samples + np.arange(n)
            duty_encoder = np.clip(position / COUNTS, 0.0, 1.0)
            amplitude = 2 * COUNTS / math.pi * np.abs(np.sin(math.pi * duty_encoder)) * self._ripple_gain
            filtered = filtered + amplitude * np.cos(2 * math.pi * chain.encoder_pwm_frequency * k * P.SAMPLE_PERIOD
                                                     + self._ripple_phase)
        self._samples += n

        current = np.asarray(current, dtype=float)
        if chain.pwm_current:
            duty = np.asarray(duty, dtype=float)
            p = self.parameters
            hold = hold_after_pulse_start(duty, P.SAMPLE_PERIOD, self.pwm_mode == P.PWM_PHASE_CORRECT) \
                - HOLD_DELAY + chain.hold_delay
            current = current + held_current_offset(duty, p.voltage_from_duty(duty), p.armature_resistance,
                                                    p.armature_inductance, P.SAMPLE_PERIOD, hold)
        cal = self.calibration
        raw = (current / cal.current_scale + cal.current_offset, filtered,
               np.asarray(voltage, dtype=float) / cal.voltage_scale + cal.voltage_offset)
        noise = chain.adc_noise_counts
        return tuple(np.clip(np.rint(values + (self.rng.normal(0.0, noise, n) if noise else 0.0)), 0, COUNTS - 1)
                     .astype(np.int64) for values in raw)
