"""A second truth simulator of an aeropendulum, written apart from the model code (ground of bench/second_rig.py).

**Independent of the model code.** This module imports only numpy and scipy: nothing from aeropend_core's model,
simulator, signals or diagnosis (tests/test_architecture.py checks it). It has its own physical parameterisation,
its own nominal numbers, its own integrator, excitation and noise, so that a benchmark on its records tests the
diagnosis against a rig it was not written with, not against the model's own equations read back.

**The rig, in physical SI parameters** (:class:`PhysicalRig`): a rod (mass, length) with a motor pod (mass at the
thrust lever) on a pivot with viscous friction; a DC motor (armature resistance and inductance, back-EMF constant,
torque constant equal to it in SI, rotor inertia, viscous friction) driving a propeller (thrust coefficient in
N per (rad/s)^2, drag-torque coefficient, inertia) through a reduction gear; an H-bridge whose average output is
``duty * supply - drop`` (0 below the drop). The equations::

    La dIa/dt = Va - Ra Ia - Ke w_m
    (Jr + Jp/n^2) dw_m/dt = Ke Ia - b_m w_m - cQ (w_m/n)^2 / n
    f = cT (w_m/n)^2                           (propeller thrust, N)
    J dW/dt = -g (m_r l/2 + m_p L) sin y - c W + L f,   dy/dt = W

**Effects this rig can carry**, each in its own physical terms (:class:`RigEffects`): a dry pivot friction torque
[N m]; an aerodynamic drag torque of the rod [N m s^2] (times W|W|); a cable acting as a torsion spring [N m/rad];
the encoder's zero not at the hanging rod [rad]; an inflow lag of the thrust (first order, time constant [s]); a
propeller that gives no thrust below an armature voltage [V] (a slipping hub at low speed); and the encoder's PWM
output read through a two-stage RC ladder (R1 = R2 = R, C1 = C2 = C, an RC product [s]).

**Its own integrator**: a fixed step of a tenth of the sample period, the armature current advanced exactly over the
step for the momentary back-EMF (exponential Euler; La/Ra is about one sample period), every other state by Heun's
method (explicit trapezoid). The duty is held over each sample period.

**The mapping to the model's lumped coefficients** (:meth:`PhysicalRig.lumped`), derived from the equations above
and the model's pendulum equation ``dW/dt = -(mgd/J) sin y - (c/J) W + k (Va - Ra Ia)^2``: with the electrical
transient neglected the motor speed is ``w_m = (Va - Ra Ia)/Ke``, so

* gravity stiffness mgd/J = g (m_r l/2 + m_p L) / J [1/s^2], J = m_r l^2/3 + m_p L^2 [kg m^2];
* damping c/J [1/s];
* thrust gain k = (L/J) cT / (n Ke)^2 [rad/s^2 per V^2]; armature resistance Ra [ohm];
* per kernel term of the catalog (keyed by kind, so that this module names no catalog effect): dry friction
  torque / J [rad/s^2] (``rate_sign``); drag torque coefficient / J [1/rad] (``rate_square``); cable spring / J
  [1/s^2] (``angle_linear``); encoder zero [rad] (``measured_offset``); inflow time constant [s]
  (``thrust_lag_time``); hub voltage [V] (``thrust_threshold``); 3 RC [s] (``measured_lowpass``: the DC delay of the
  ladder, whose transfer function is 1/((RC s)^2 + 3 RC s + 1)).

Records are written in aeropend's CSV format (``t,duty,armature_voltage,armature_current,angle``, SI) by
:func:`write_csv`; :func:`draw` draws a random rig, effect set, excitation and noise from a seed.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace

import numpy as np

GRAVITY = 9.81                        #: [m/s^2]
SAMPLE_RATE = 490.0                   #: [Hz] one sample per PWM period of the rig's Timer1
ANGLE_COUNT = 2 * math.pi / 1024      #: [rad] one count of a 10-bit magnetic encoder
CURRENT_COUNT = 2.0 / 3.3 * 5.0 / 1024  #: [A] one ADC count of the current sense (3.3 V for 2 A, 5 V ADC)
SUBSTEPS = 10                         #: integration steps per sample period
FRICTION_WIDTH = 0.005                #: [rad/s] speed over which the dry friction changes sign (tanh)
HIGHEST_ANGLE = math.radians(80.0)    #: [rad] the duty cap keeps the steady rod below this


@dataclass(frozen=True)
class PhysicalRig:
    """Physical SI parameters of the second rig (nominal values: a small rod with a geared coreless motor).

    Attributes
    ----------
    rod_mass, rod_length : float [kg], [m]
    pod_mass : float [kg]
        Motor, gear and propeller, taken as a point mass at the thrust lever.
    lever : float [m]
        Distance of the propeller's thrust line (and the pod) from the pivot.
    pivot_damping : float [N m s/rad]
    armature_resistance, armature_inductance : float [ohm], [H]
    back_emf_constant : float [V s/rad]
        Also the torque constant [N m/A] (equal in SI).
    rotor_inertia, motor_friction : float [kg m^2], [N m s/rad]
    gear_ratio : float [-]
        Motor turns per propeller turn.
    thrust_coefficient : float [N/(rad/s)^2]
    drag_torque_coefficient : float [N m/(rad/s)^2]
    propeller_inertia : float [kg m^2]
    supply_voltage, bridge_drop : float [V]
        H-bridge: average armature voltage = duty * supply - drop, 0 below.
    """

    rod_mass: float = 0.008
    rod_length: float = 0.20
    pod_mass: float = 0.010
    lever: float = 0.18
    pivot_damping: float = 3.0e-3
    armature_resistance: float = 1.25
    armature_inductance: float = 1.7e-3
    back_emf_constant: float = 7.2e-4
    rotor_inertia: float = 4.0e-8
    motor_friction: float = 5.0e-8
    gear_ratio: float = 6.0
    thrust_coefficient: float = 4.0e-6
    drag_torque_coefficient: float = 1.0e-7
    propeller_inertia: float = 3.5e-6
    supply_voltage: float = 3.0
    bridge_drop: float = 0.15

    @property
    def inertia(self) -> float:
        """Moment of inertia of rod and pod about the pivot [kg m^2]."""
        return self.rod_mass * self.rod_length ** 2 / 3 + self.pod_mass * self.lever ** 2

    @property
    def gravity_moment(self) -> float:
        """m g d of rod and pod [N m]."""
        return GRAVITY * (self.rod_mass * self.rod_length / 2 + self.pod_mass * self.lever)

    def armature_voltage(self, duty: np.ndarray) -> np.ndarray:
        """Average armature voltage of the H-bridge [V] for a duty fraction 0..1."""
        return np.maximum(np.asarray(duty, dtype=float) * self.supply_voltage - self.bridge_drop, 0.0)

    def lumped(self, effects: RigEffects | None = None) -> dict[str, float]:
        """The model's coefficients for this rig (module docstring), SI: the nominal ones by the model's names, the
        effects' by the catalog's kernel kinds (only those present)."""
        inertia = self.inertia
        out = {'gravity_stiffness': self.gravity_moment / inertia, 'damping': self.pivot_damping / inertia,
               'thrust_gain': self.lever / inertia * self.thrust_coefficient
               / (self.gear_ratio * self.back_emf_constant) ** 2,
               'armature_resistance': self.armature_resistance}
        effects = effects or RigEffects()
        kinds = {'rate_sign': effects.friction_torque / inertia, 'rate_square': effects.drag_torque / inertia,
                 'angle_linear': effects.cable_spring / inertia, 'measured_offset': effects.encoder_zero,
                 'thrust_lag_time': effects.inflow_time_constant, 'thrust_threshold': effects.hub_voltage,
                 'measured_lowpass': 3 * effects.filter_rc}
        out.update({kind: float(value) for kind, value in kinds.items() if value})
        return out


@dataclass(frozen=True)
class RigEffects:
    """The second rig's effects in physical terms (0: absent).

    Attributes
    ----------
    friction_torque : float [N m]
        Dry friction at the pivot.
    drag_torque : float [N m s^2/rad^2]
        Aerodynamic drag of rod and pod, times W|W|.
    cable_spring : float [N m/rad]
        The motor cable as a torsion spring about the hanging position.
    encoder_zero : float [rad]
        Measured minus true angle.
    inflow_time_constant : float [s]
        First-order lag of the thrust behind the propeller speed.
    hub_voltage : float [V]
        No thrust below this armature voltage.
    filter_rc : float [s]
        RC product of each stage of the encoder's two-stage RC ladder.
    """

    friction_torque: float = 0.0
    drag_torque: float = 0.0
    cable_spring: float = 0.0
    encoder_zero: float = 0.0
    inflow_time_constant: float = 0.0
    hub_voltage: float = 0.0
    filter_rc: float = 0.0

    def present(self) -> list[str]:
        """Names of the effects switched on."""
        return [name for name, value in asdict(self).items() if value]


@dataclass
class Record:
    """One record of the second rig, with the truth that made it.

    Attributes
    ----------
    columns : dict of str -> ndarray [SI]
        ``t`` [s], ``duty`` [1], ``armature_voltage`` [V], ``armature_current`` [A], ``angle`` [rad] as measured.
    rig : PhysicalRig
    effects : RigEffects
    psnr_db : float [dB]
        Noise level of Va, Ia and the angle, 20 log10(max |x| / sigma).
    seed : int [-]
    excitation : str [-]
    truth : dict of str -> float [SI]
        :meth:`PhysicalRig.lumped` of the rig and its effects.
    true_angle : ndarray [rad]
        The rod's angle without sensor, noise or quantisation.
    """

    columns: dict
    rig: PhysicalRig
    effects: RigEffects
    psnr_db: float
    seed: int
    excitation: str
    truth: dict = field(default_factory=dict)
    true_angle: np.ndarray | None = None


def steady_angle(rig: PhysicalRig, duty: float) -> float:
    """The rod's resting angle [rad] at a held duty (thrust balances gravity; nan beyond the horizontal)."""
    from scipy.optimize import brentq
    voltage = float(rig.armature_voltage(duty))
    n, ke, ra = rig.gear_ratio, rig.back_emf_constant, rig.armature_resistance

    def torque_balance(speed):      # motor torque minus load at motor speed `speed`
        return ke * (voltage - ke * speed) / ra - rig.motor_friction * speed - rig.drag_torque_coefficient \
            * (speed / n) ** 2 / n
    if voltage <= 0:
        return 0.0
    speed = brentq(torque_balance, 0.0, voltage / ke)
    ratio = rig.lever * rig.thrust_coefficient * (speed / n) ** 2 / rig.gravity_moment
    return math.asin(ratio) if ratio < 1 else float('nan')


def duty_cap(rig: PhysicalRig, highest: float = HIGHEST_ANGLE) -> float:
    """Largest duty (0.9 down to 0.3 in steps of 0.02) whose resting angle stays below `highest` [rad]."""
    cap = 0.9
    while cap > 0.3:
        angle = steady_angle(rig, cap)
        if math.isfinite(angle) and angle < highest:
            return cap
        cap -= 0.02
    return cap


#: The blocks of :func:`excitation`: ``mixed`` (steps twice, PRBS, chirp) or ``no_chirp`` (steps twice, PRBS).
EXCITATIONS = {'mixed': ('steps', 'prbs', 'chirp', 'steps'), 'no_chirp': ('steps', 'prbs', 'steps')}


def excitation(duration: float, cap: float, rng: np.random.Generator, sample_rate: float = SAMPLE_RATE,
               kind: str = 'mixed') -> np.ndarray:
    """A duty sequence [1] per sample: blocks of random steps (dwell 0.4-2.5 s, with rests at 0), a pseudo-random
    binary stretch (0.1 s bits) and a linear chirp (0.1-2.5 Hz), in a random order, each 20-40 % of the record
    (`kind`: :data:`EXCITATIONS`)."""
    count = int(round(duration * sample_rate))
    duty = np.zeros(count)
    order = rng.permutation(list(EXCITATIONS[kind]))
    shares = rng.uniform(0.2, 0.4, len(order))
    edges = np.concatenate(([0], np.cumsum(shares / shares.sum() * count))).astype(int)
    for kind, start, stop in zip(order, edges[:-1], edges[1:]):
        k = start
        if kind == 'steps':
            while k < stop:
                dwell = int(rng.uniform(0.4, 2.5) * sample_rate)
                level = 0.0 if rng.random() < 0.25 else rng.uniform(0.05, 1.0) * cap
                duty[k:min(stop, k + dwell)] = level
                k += dwell
        elif kind == 'prbs':
            low, high = sorted(rng.uniform(0.1, 0.9, 2) * cap)
            bit = int(0.1 * sample_rate)
            while k < stop:
                duty[k:min(stop, k + bit)] = high if rng.random() < 0.5 else low
                k += bit
        else:
            t = np.arange(stop - start) / sample_rate
            sweep = 0.1 * t + (2.5 - 0.1) / (2 * max(t[-1], 1e-9)) * t ** 2 if t.size else t
            middle, swing = rng.uniform(0.35, 0.6) * cap, rng.uniform(0.2, 0.35) * cap
            duty[start:stop] = np.clip(middle + swing * np.sin(2 * np.pi * sweep), 0.0, cap)
    duty[:int(0.5 * sample_rate)] = 0.0       # start at rest
    return duty


def integrate(duty: np.ndarray, rig: PhysicalRig, effects: RigEffects, sample_rate: float = SAMPLE_RATE) -> dict:
    """Integrate the rig (module docstring) under `duty` [1] held per sample; returns the true signals per sample
    [SI]: ``armature_voltage``, ``armature_current``, ``motor_speed``, ``angle``, ``angular_rate``, ``thrust``,
    ``sensor`` (the angle at the encoder's filtered output, before its zero offset)."""
    h = 1.0 / sample_rate / SUBSTEPS
    voltage = rig.armature_voltage(duty)
    ra, la, ke = rig.armature_resistance, rig.armature_inductance, rig.back_emf_constant
    n, cq, ct, bm = rig.gear_ratio, rig.drag_torque_coefficient, rig.thrust_coefficient, rig.motor_friction
    motor_inertia = rig.rotor_inertia + rig.propeller_inertia / n ** 2
    inertia, mgd, lever, c = rig.inertia, rig.gravity_moment, rig.lever, rig.pivot_damping
    fc, cd, kc = effects.friction_torque, effects.drag_torque, effects.cable_spring
    tau, hub, rc = effects.inflow_time_constant, effects.hub_voltage, effects.filter_rc
    decay = math.exp(-h * ra / la)

    def mechanics(speed, current, angle, rate, thrust, filter1, filter2, volts):
        """Derivatives of motor speed, angle, rate, thrust, filter stages (the current is advanced exactly)."""
        prop = speed / n
        quasi = ct * prop * abs(prop) * (volts >= hub if hub else 1.0)
        acting = thrust if tau else quasi
        d_speed = (ke * current - bm * speed - cq * prop * abs(prop) / n) / motor_inertia
        d_rate = (-mgd * math.sin(angle) - c * rate + lever * acting - fc * math.tanh(rate / FRICTION_WIDTH)
                  - cd * rate * abs(rate) - kc * angle) / inertia
        d_thrust = (quasi - thrust) / tau if tau else 0.0
        d_f1 = ((angle - filter1) - (filter1 - filter2)) / rc if rc else 0.0
        d_f2 = (filter1 - filter2) / rc if rc else 0.0
        return d_speed, rate, d_rate, d_thrust, d_f1, d_f2

    count = len(voltage)
    names = ('armature_voltage', 'armature_current', 'motor_speed', 'angle', 'angular_rate', 'thrust', 'sensor')
    out = {name: np.empty(count) for name in names}
    current = speed = angle = rate = thrust = filter1 = filter2 = 0.0
    for k in range(count):
        volts = float(voltage[k])
        out['armature_voltage'][k], out['armature_current'][k], out['motor_speed'][k] = volts, current, speed
        out['angle'][k], out['angular_rate'][k] = angle, rate
        out['thrust'][k], out['sensor'][k] = (thrust if tau else ct * (speed / n) ** 2), (filter2 if rc else angle)
        for _ in range(SUBSTEPS):
            state = (speed, angle, rate, thrust, filter1, filter2)
            first = mechanics(speed, current, angle, rate, thrust, filter1, filter2, volts)
            guess = [s + h * d for s, d in zip(state, first)]
            target = (volts - ke * 0.5 * (speed + guess[0])) / ra
            next_current = target + (current - target) * decay
            second = mechanics(*guess[:1], next_current, *guess[1:], volts)
            speed, angle, rate, thrust, filter1, filter2 = (s + 0.5 * h * (a + b)
                                                            for s, a, b in zip(state, first, second))
            current = next_current
    return out


def measure(true: dict, effects: RigEffects, psnr_db: float, rng: np.random.Generator) -> dict:
    """Measured Va, Ia and angle [SI] from the true signals: encoder zero, white noise at `psnr_db` per signal
    (sigma = max |x| / 10^(psnr/20)), 10-bit angle and current quantisation."""
    out = {}
    for name, signal in (('armature_voltage', true['armature_voltage']),
                         ('armature_current', true['armature_current']),
                         ('angle', true['sensor'] + effects.encoder_zero)):
        sigma = float(np.max(np.abs(signal))) / 10 ** (psnr_db / 20)
        out[name] = signal + rng.normal(0.0, sigma, signal.size)
    out['angle'] = np.round(out['angle'] / ANGLE_COUNT) * ANGLE_COUNT
    out['armature_current'] = np.round(out['armature_current'] / CURRENT_COUNT) * CURRENT_COUNT
    return out


#: What :func:`draw` may switch on and the range of each size, in physical units per unit rig (scaled by the
#: drawn rig's inertia where the size is a torque, so the lumped size lands in a detectable range).
EFFECT_RANGES = {
    'friction_torque': (1.5, 8.0),            # rad/s^2 after division by the inertia
    'drag_torque': (1.0, 6.0),                # 1/rad after division by the inertia
    'cable_spring': (8.0, 40.0),              # 1/s^2 after division by the inertia
    'encoder_zero': (0.02, 0.08),             # rad, either sign
    'inflow_time_constant': (0.05, 0.30),     # s
    'hub_voltage': (0.35, 0.8),               # V
    'filter_rc': (0.0141 / 3, 0.045 / 3),     # s (3 RC: 14-45 ms)
}
TORQUES = ('friction_torque', 'drag_torque', 'cable_spring')


def draw_rig(rng: np.random.Generator, spread: float = 0.25) -> PhysicalRig:
    """Every physical parameter of the nominal rig moved by an independent factor U(1 - spread, 1 + spread)."""
    nominal = PhysicalRig()
    return replace(nominal, **{name: value * float(rng.uniform(1 - spread, 1 + spread))
                               for name, value in asdict(nominal).items()})


def draw_effects(rng: np.random.Generator, rig: PhysicalRig, names: list[str] | None = None) -> RigEffects:
    """Random sizes (:data:`EFFECT_RANGES`) for `names` (default: each effect switched on with probability 0.3)."""
    if names is None:
        names = [name for name in EFFECT_RANGES if rng.random() < 0.3]
    sizes = {}
    for name in names:
        low, high = EFFECT_RANGES[name]
        value = float(rng.uniform(low, high))
        if name in TORQUES:
            value *= rig.inertia
        if name == 'encoder_zero':
            value *= float(rng.choice([-1.0, 1.0]))
        sizes[name] = value
    return RigEffects(**sizes)


def draw(seed: int, duration: float = 40.0, effects: list[str] | None = None, psnr_db: float | None = None,
         sample_rate: float = SAMPLE_RATE, excitation_kind: str = 'mixed',
         inputs_psnr_db: float | None = None) -> Record:
    """A record of a random rig (:func:`draw_rig`), with the effects `effects` (physical names of
    :class:`RigEffects`; None: drawn at random, [] none), noise U(30, 60) dB unless given, :func:`excitation` of
    `excitation_kind`. With `inputs_psnr_db` [dB], Va and Ia are measured at that PSNR instead (their own noise
    draw; a clean current sense beside a noisy encoder), the angle as without it."""
    rng = np.random.default_rng(seed)
    rig = draw_rig(rng)
    chosen = draw_effects(rng, rig, effects)
    psnr = float(rng.uniform(30.0, 60.0)) if psnr_db is None else float(psnr_db)
    cap = duty_cap(rig)
    duty = excitation(duration, cap, rng, sample_rate, excitation_kind)
    true = integrate(duty, rig, chosen, sample_rate)
    measured = measure(true, chosen, psnr, rng)
    if inputs_psnr_db is not None:
        inputs = measure(true, chosen, float(inputs_psnr_db), np.random.default_rng(seed + 104_729))
        measured.update({name: inputs[name] for name in ('armature_voltage', 'armature_current')})
    columns = {'t': np.arange(duty.size) / sample_rate, 'duty': duty, **measured}
    return Record(columns, rig, chosen, psnr, seed, f'{excitation_kind}, duty cap {cap:.2f}',
                  rig.lumped(chosen), true['angle'])


def write_csv(path: str, record: Record) -> None:
    """Write `record` in aeropend's CSV format (header ``t,duty,armature_voltage,armature_current,angle``, SI)."""
    names = ('t', 'duty', 'armature_voltage', 'armature_current', 'angle')
    table = np.column_stack([record.columns[name] for name in names])
    np.savetxt(path, table, delimiter=',', header=','.join(names), comments='', fmt='%.9g')
