"""The aeropendulum's physical model: equations (1)-(8) of the paper "Data-Driven System Identification of an
Aeropendulum" with named, unit-carrying parameters (described in ``docs/model.md``).

State of the full model (SI units)::

    armature_current  Ia  [A]      eq (1)  La dIa/dt = Va - Ra Ia - Kw w1
    motor_speed       w1  [rad/s]  eq (2)  Jm dw1/dt = Kt Ia - F w1 - T1,  T1 = Kd w2|w2| / (N1/N2)
    angle             y   [rad]    eq (7)  dy/dt = W
    angular_rate      W   [rad/s]  eq (6)  dW/dt = -(mgd/J) sin y - (c/J) W + (L/J) f

with the propeller speed w2 = w1 / (N1/N2) (eq 4), its thrust f = Kq w2|w2| [N] (eq 3), and the armature voltage
Va from the PWM duty cycle by the paper's curve fit (eq 8).  Written in the *measured* signals Va and Ia the
quasi-static thrust is eq (5): f = Kq (N2/(N1 Kw))^2 (Va - Ra Ia)^2.

Effects beyond these nominal terms (friction, cable, lag...) live in :mod:`aeropend_core.model.effects`.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

#: The rig's sampling period [s]: Timer1 PWM at 490 Hz (the paper's Ts = 2.04 ms).
SAMPLE_TIME = 1.0 / 490.0
#: Standard gravity [m/s^2] (only used to explain per-inertia numbers).
GRAVITY = 9.80665


@dataclass(frozen=True)
class RigParameters:
    """Nominal parameters of the rig. Every field is SI; per-inertia pendulum parameters as they enter dW/dt.

    The defaults are the calibrated, physically consistent set (the comment block above
    :data:`DEFAULT_PARAMETERS` says where each number comes from; ``docs/model.md`` section 3).
    :data:`PAPER_TABLE1` is the paper's Table 1 literally.

    Parameters
    ----------
    armature_resistance : float [ohm]
        Ra, eq (1).
    armature_inductance : float [H]
        La, eq (1).
    back_emf_constant : float [V s/rad]
        Kw, eq (1).
    torque_constant : float [N m/A]
        Kt, eq (2).
    motor_inertia : float [kg m^2]
        Jm, rotor plus propeller as seen from the motor shaft, eq (2).
    motor_friction : float [N m s/rad]
        F, viscous friction of the motor, eq (2).
    propeller_torque_coefficient : float [N m s^2]
        Kd, propeller drag torque Kd w2|w2| at the propeller, eq (2).
    gear_ratio : float, dimensionless
        N1/N2 = w1/w2, eq (4).
    thrust_coefficient : float [N s^2]
        Kq, thrust f = Kq w2|w2|, eq (3).
    gravity_stiffness : float [1/s^2]
        mgd/J, eq (6).
    damping : float [1/s]
        c/J, eq (6).
    lever_per_inertia : float [1/(kg m)]
        L/J, eq (6).
    duty_voltage_k0, duty_voltage_k1 : float [V]
        k0, k1 of eq (8).
    duty_voltage_k2, duty_voltage_k3 : float, dimensionless
        k2, k3 of eq (8) (duty as a fraction 0..1).

    Examples
    --------
    >>> from aeropend_core import DEFAULT_PARAMETERS, SAMPLE_TIME, RigParameters
    >>> rig = RigParameters(armature_resistance=2.0)                 # ohm; every other value the calibrated default
    >>> rig.armature_resistance, rig.back_emf_constant == DEFAULT_PARAMETERS.back_emf_constant
    (2.0, True)
    >>> round(1.0 / SAMPLE_TIME)                                     # Hz: the rig's sample rate
    490
    """

    # --- electrical, measured in the paper (section 3.6) -----------------------------------------------------
    armature_resistance: float = 1.08          # Ra [ohm], locked-rotor test, sigma 0.04 ohm
    armature_inductance: float = 2.2e-3        # La [H], from tau_e = La/Ra = 2 ms
    back_emf_constant: float = 6.606e-4        # Kw [V s/rad], eq (9), sigma 1.38e-5
    # --- motor and propeller, chosen (not measured by the paper) ---------------------------------------------
    torque_constant: float = 6.606e-4          # Kt [N m/A]; equals Kw in SI for a DC motor (Table 1's 0.235 cannot)
    motor_inertia: float = 1.5e-7              # Jm [kg m^2], rotor plus propeller reflected through the gear
    motor_friction: float = 6.5e-8             # F [N m s/rad], ~15 % of the motor torque at duty 0.7
    propeller_torque_coefficient: float = 6.0e-8  # Kd [N m s^2]: propeller drag torque Kd w2|w2| at the propeller
    gear_ratio: float = 55.0 / 9.0             # N1/N2 = w1/w2, the paper's gearbox
    thrust_coefficient: float = 5.0e-6         # Kq [N s^2]: f = Kq w2|w2|
    # --- pendulum, per unit inertia, from the paper's Table 1 ---------------------------------------------------
    gravity_stiffness: float = 131.75          # mgd/J [1/s^2]  (rad/s^2 per unit sin y)
    damping: float = 13.82                     # c/J [1/s]
    lever_per_inertia: float = 462.83          # L/J [1/(kg m)]  (rad/s^2 per newton of thrust)
    # --- duty cycle -> armature voltage, eq (8): Va = k0 + k1 sqrt(k2 duty + k3), duty as a fraction 0..1 ----
    duty_voltage_k0: float = -0.2914           # [V]
    duty_voltage_k1: float = 6.8e-4            # [V]
    duty_voltage_k2: float = 1.469e7           # [1]
    duty_voltage_k3: float = 4.3629e4          # [1]

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if not np.isfinite(value):
                raise ValueError(f'RigParameters.{field.name} must be finite, got {value!r}')
        for name in ('armature_resistance', 'armature_inductance', 'back_emf_constant', 'torque_constant',
                     'motor_inertia', 'gear_ratio', 'thrust_coefficient', 'lever_per_inertia'):
            if getattr(self, name) <= 0:
                raise ValueError(f'RigParameters.{name} must be positive, got {getattr(self, name)!r}')

    def replace(self, **changes: float) -> RigParameters:
        """A copy with some fields changed (unknown names raise TypeError)."""
        return dataclasses.replace(self, **changes)

    def scaled(self, **factors: float) -> RigParameters:
        """A copy with some fields multiplied by the given factors, e.g. ``scaled(damping=1.2)``."""
        return self.replace(**{name: getattr(self, name) * factor for name, factor in factors.items()})

    def as_dict(self) -> dict[str, float]:
        return dataclasses.asdict(self)

    # --- derived quantities -------------------------------------------------------------------------------------
    @property
    def electrical_time_constant(self) -> float:
        """La/Ra [s]."""
        return self.armature_inductance / self.armature_resistance

    @property
    def thrust_voltage_coefficient(self) -> float:
        """Kq (N2/(N1 Kw))^2 [N/V^2]: eq (5) is f = this * (Va - Ra Ia)^2."""
        return self.thrust_coefficient / (self.gear_ratio * self.back_emf_constant) ** 2

    @property
    def thrust_gain(self) -> float:
        """(L/J) Kq (N2/(N1 Kw))^2 [rad/s^2 per V^2]: the pendulum's thrust term in (Va - Ra Ia)^2."""
        return self.lever_per_inertia * self.thrust_voltage_coefficient

    def voltage_from_duty(self, duty: np.ndarray | float) -> np.ndarray | float:
        """Armature voltage [V] from the PWM duty cycle (fraction 0..1), eq (8); 0 V where the fit goes negative.

        The fit is negative below duty ~0.0095: the dead band of the H-bridge that eq (8) itself implies.
        """
        duty = np.asarray(duty, dtype=float)
        voltage = self.duty_voltage_k0 + self.duty_voltage_k1 * np.sqrt(
            np.maximum(self.duty_voltage_k2 * duty + self.duty_voltage_k3, 0.0))
        voltage = np.where(duty > 0.0, np.maximum(voltage, 0.0), 0.0)
        return voltage if voltage.ndim else float(voltage)

    def duty_from_voltage(self, voltage: np.ndarray | float) -> np.ndarray | float:
        """Inverse of eq (8): the duty fraction that gives `voltage` [V] (0 for voltage <= 0)."""
        voltage = np.asarray(voltage, dtype=float)
        root = (np.maximum(voltage, 0.0) - self.duty_voltage_k0) / self.duty_voltage_k1
        duty = (root ** 2 - self.duty_voltage_k3) / self.duty_voltage_k2
        duty = np.where(voltage > 0.0, np.maximum(duty, 0.0), 0.0)
        return duty if duty.ndim else float(duty)

    def quasi_static_thrust(self, armature_voltage: np.ndarray | float,
                            armature_current: np.ndarray | float) -> np.ndarray | float:
        """Thrust [N] from the measured Va [V] and Ia [A], eq (5), neglecting La dIa/dt and propeller inertia."""
        motor_speed = (np.asarray(armature_voltage) - self.armature_resistance * np.asarray(armature_current)) \
            / self.back_emf_constant
        propeller_speed = motor_speed / self.gear_ratio
        return self.thrust_coefficient * propeller_speed * np.abs(propeller_speed)

    def steady_state(self, armature_voltage: float) -> dict[str, float]:
        """Equilibrium of the full nominal model at constant Va [V]: current, motor speed, thrust and angle.

        The angle is the stable equilibrium in [0, pi/2] (nan if the thrust exceeds what gravity can hold).
        """
        # Motor torque balance with Ia = (Va - Kw w1)/Ra: a quadratic in w1 >= 0.
        kd_motor = self.propeller_torque_coefficient / self.gear_ratio ** 3
        linear = self.torque_constant * self.back_emf_constant / self.armature_resistance + self.motor_friction
        drive = self.torque_constant * armature_voltage / self.armature_resistance
        motor_speed = (-linear + np.sqrt(linear ** 2 + 4.0 * kd_motor * max(drive, 0.0))) / (2.0 * kd_motor)
        current = (armature_voltage - self.back_emf_constant * motor_speed) / self.armature_resistance
        thrust = self.thrust_coefficient * (motor_speed / self.gear_ratio) ** 2
        ratio = self.lever_per_inertia * thrust / self.gravity_stiffness
        angle = float(np.arcsin(ratio)) if ratio <= 1.0 else float('nan')
        return {'armature_current': float(current), 'motor_speed': float(motor_speed), 'thrust': float(thrust),
                'angle': angle}


#: Calibrated default set (physically consistent; docs/model.md section 4 explains why Table 1 is not).
#: Choices, with reasons:
#:  * Ra, La, Kw, eq (8), mgd/J, c/J, L/J and the gear are the paper's measured / tabulated values, kept as they are.
#:  * Kt = Kw: in SI a DC motor's torque and back-EMF constants are equal; Table 1's 0.235 N m/A is 350x Kw.
#:  * Kq = 5e-6 N s^2 and Kd = 6e-8 N m s^2: at duty 0.7 (Va = 1.89 V) the motor settles at ~1390 rad/s with
#:    Ia ~ 0.9 A (inside the 2 A current-sense range), the propeller at ~227 rad/s gives ~0.26 N, and the rod
#:    settles near 65 deg: "a large deflection below 90 deg" as in the paper's duty cap of 70 %. Holding 90 deg
#:    needs (mgd/J)/(L/J) = 0.285 N; Table 1's Kq = 1e-4 would give tens of newtons at 2 V.
#:    The propeller torque-to-thrust ratio Kd/Kq = 0.012 m is typical of small propellers (0.01-0.02 m).
#:  * F = 6.5e-8 N m s/rad: motor friction ~15 % of the torque at duty 0.7 (Table 1's Bm = 0.01 would stall it).
#:  * Jm = 1.5e-7 kg m^2: a small coreless rotor (~5e-8) plus a ~4e-6 kg m^2 propeller seen through (9/55)^2;
#:    with the back-EMF, friction and propeller torque slopes (~1.2e-6 N m s) the motor's mechanical time
#:    constant is ~0.12 s, so the electrical (2 ms), motor and pendulum (~0.5 s) scales stay separate.
DEFAULT_PARAMETERS = RigParameters()

#: The paper's Table 1, literally (inconsistent: Kt = 0.235 vs Kw = 6.6e-4; Kq = 1e-4 gives tens of newtons).
#: Table 1 gives Bm in "N s/m^2" and no propeller drag; the drag torque coefficient is set to 0.
PAPER_TABLE1 = RigParameters(
    armature_resistance=1.08, armature_inductance=2.2e-3, back_emf_constant=6.6e-4, torque_constant=0.235,
    motor_inertia=5.2e-5, motor_friction=0.01, propeller_torque_coefficient=0.0, gear_ratio=55.0 / 9.0,
    thrust_coefficient=1e-4, gravity_stiffness=131.75, damping=13.82, lever_per_inertia=462.83)

PRESETS: dict[str, RigParameters] = {'default': DEFAULT_PARAMETERS, 'paper-table1': PAPER_TABLE1}
