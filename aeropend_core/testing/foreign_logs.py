"""Logs the way other rigs write them, made from a simulation with known truth (for tests and sweeps).

The source paper's kind of rig (Arduino Mega, motor shield, AS5040) runs Timer1 PWM at 490 Hz and prints one line
every N PWM periods (N = 22: 22.28 Hz), read by a PC that stamps each line with its own date-time as the serial
buffer delivers it. What such a log holds, and how this generator makes it from :func:`aeropend_core.sim.simulate`
run at 490 Hz (one simulated sample per PWM period):

* **one line per N periods**: the simulated samples 0, N, 2N, ... (picked, not averaged: a logger that prints
  every Nth period does not filter);
* **the current read inside the PWM on-pulse** at a fixed time after the pulse starts, by a one-sided sense
  resistor: not the period average. During the on-pulse the armature sees the supply voltage ``V_s``;
  ``La dIa/dt = V_s - Ra Ia - e`` from the current at the pulse start (zero: the current decays to zero in the
  off-time of a small motor, discontinuous conduction) gives ``Ia(t_read) = (V_s - e)/Ra (1 - exp(-t_read Ra/La))``,
  which *falls* as the duty rises because the back-EMF ``e = Kw w1`` rises; then ADC counts;
* **the angle in encoder counts** (AS5040: 1024 per turn, from a zero that is not 0, wrapped into 0..1023), or in
  degrees, or absent never (it is what the log is for);
* **the duty as the timer's register** 0..255, or in percent;
* **host date-time stamps** with buffering: a delay of a few ms, and stalls of up to ``stall_max`` s after which
  the buffered lines arrive at once (stamps 0 ms apart), in milliseconds; or the device's own ``millis()``;
* columns that are **missing** (no current) or extra (a line counter that is not there).

:func:`generate` returns the log's text, a matching log profile (the mapping ``aeropend import`` reads) and the
truth. Nothing here is tuned to a particular analysis: the variants are drawn at random by :func:`random_spec`.
"""
from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass, field, replace

import numpy as np

from aeropend_core.model.effects import CATALOG, MEASUREMENT, PENDULUM, THRUST_LAG

#: The rig's PWM frequency [Hz] (Timer1 phase-correct at 16 MHz / 64 / 510).
PWM_RATE = 490.0


@dataclass(frozen=True)
class ForeignLogSpec:
    """How the foreign log is written.

    Attributes
    ----------
    periods_per_line : int [-]
        PWM periods per printed line (rate = 490 / N Hz).
    duration : float [s]
        Record length.
    seed : int [-]
        Seed of the excitation, the noise, the host stalls.
    duty_low, duty_high : int [register counts 0..255]
        Range of the shuffled duty levels.
    dwell_low, dwell_high : float [s]
        Range of the time each level is held.
    current : {'in_pulse', 'average', 'none'} [-]
        Current column: read inside the on-pulse, the period average, or absent.
    read_time : float [s]
        Time after the pulse start at which the ADC reads the current.
    supply_voltage : float [V]
        Voltage across the armature during the on-pulse.
    current_counts_per_amp : float [counts/A]
        ADC counts per ampere (sense resistor, amplifier, reference).
    current_offset_counts : float [counts]
        ADC reading at zero current.
    angle : {'counts', 'degrees', 'radians'} [-]
        How the angle is written.
    counts_per_turn : int [counts]
        Encoder resolution.
    angle_zero_counts : int [counts]
        Encoder reading with the rod hanging still.
    duty : {'register', 'percent'} [-]
        How the duty is written.
    stamps : {'host', 'device_ms', 'none'} [-]
        Host date-time stamps with buffering, the device's millis(), or no time column.
    stall_probability : float [-]
        Chance per line that the host stalls.
    stall_max : float [s]
        Longest stall.
    angle_psnr : float [dB]
        Angle noise before the encoder's quantisation (PSNR against the record's peak angle).
    effects : dict [SI unit of each effect parameter]
        Hidden effects for the simulator (``{name: value}``).
    column_names : dict of str -> str [-]
        The log's column names for 'time', 'current', 'angle', 'duty'.
    """

    periods_per_line: int = 22
    duration: float = 25.0
    seed: int = 0
    duty_low: int = 70
    duty_high: int = 125
    dwell_low: float = 1.5
    dwell_high: float = 4.0
    current: str = 'in_pulse'
    read_time: float = 0.4e-3
    supply_voltage: float = 5.0
    current_counts_per_amp: float = 1023 * 3.3 / 5.0 / 2.0
    current_offset_counts: float = 0.0
    angle: str = 'counts'
    counts_per_turn: int = 1024
    angle_zero_counts: int = 40
    duty: str = 'register'
    stamps: str = 'host'
    stall_probability: float = 0.03
    stall_max: float = 0.36
    angle_psnr: float = 50.0
    effects: dict = field(default_factory=dict)
    column_names: dict = field(default_factory=lambda: {'time': 'pc_time', 'current': 'A0', 'angle': 'enc',
                                                        'duty': 'pwm'})

    @property
    def rate(self) -> float:
        """Line rate [Hz]."""
        return PWM_RATE / self.periods_per_line


@dataclass(frozen=True)
class ForeignLog:
    """A generated log.

    Attributes
    ----------
    text : str [-]
        The CSV text as the foreign logger writes it.
    profile : dict [-]
        The log profile that maps it onto a recording (YAML-able; see ``docs/log-import.md``).
    truth : dict [-]
        ``rate`` [Hz], ``parameters`` (the simulator's nominal values, SI), ``effects``, and ``line_times`` [s]
        (the device's emission time of each line).
    spec : ForeignLogSpec [-]
    """

    text: str
    profile: dict
    truth: dict
    spec: ForeignLogSpec


def _duty_schedule(spec: ForeignLogSpec, rng: np.random.Generator, n_pwm: int) -> np.ndarray:
    """Shuffled register levels held for random dwells, one value per PWM period, with a rest at the start."""
    registers = np.empty(n_pwm, dtype=int)
    k = 0
    rest = int(1.0 * PWM_RATE)
    registers[:rest] = 0
    k = rest
    while k < n_pwm:
        dwell = int(rng.uniform(spec.dwell_low, spec.dwell_high) * PWM_RATE)
        level = int(rng.integers(spec.duty_low, spec.duty_high + 1)) if rng.random() > 0.15 else 0
        registers[k:k + dwell] = level
        k += dwell
    return registers


def _host_stamps(line_times: np.ndarray, spec: ForeignLogSpec, rng: np.random.Generator) -> np.ndarray:
    """Host receive times [s]: each line's emission time plus a few ms, held back to the end of a stall."""
    stamps = np.empty_like(line_times)
    stall_until = -math.inf
    for i, t in enumerate(line_times):
        if t > stall_until and rng.random() < spec.stall_probability:
            stall_until = t + rng.uniform(0.1, 1.0) * spec.stall_max
        base = t + rng.uniform(0.5e-3, 4e-3)
        stamps[i] = max(base, stall_until) if t <= stall_until else base
        if i and stamps[i] < stamps[i - 1]:
            stamps[i] = stamps[i - 1]
    return np.floor(stamps * 1e3) / 1e3          # a host clock printed in milliseconds


def generate(spec: ForeignLogSpec) -> ForeignLog:
    """Simulate the rig at 490 Hz and write the log as `spec` says.

    Parameters
    ----------
    spec : ForeignLogSpec

    Returns
    -------
    ForeignLog
    """
    from aeropend_core.model.parameters import DEFAULT_PARAMETERS as P
    from aeropend_core.sim.simulate import simulate
    rng = np.random.default_rng(spec.seed)
    n_pwm = int(spec.duration * PWM_RATE)
    registers = _duty_schedule(spec, rng, n_pwm)
    trajectory = simulate(registers / 255.0, effects=spec.effects or None, sample_time=1.0 / PWM_RATE,
                          seed=spec.seed)
    lines = np.arange(0, n_pwm, spec.periods_per_line)
    line_times = lines / PWM_RATE
    names = spec.column_names
    columns: dict[str, list[str]] = {}
    profile_columns: dict[str, dict] = {}
    if spec.stamps == 'host':
        start = _dt.datetime(2026, 3, 14, 15, 9, 26, tzinfo=None) + _dt.timedelta(seconds=float(rng.uniform(0, 3600)))
        stamps = _host_stamps(line_times, spec, rng)
        columns[names['time']] = [(start + _dt.timedelta(seconds=float(s))).isoformat(sep=' ', timespec='milliseconds')
                                  for s in stamps]
        clock = {'column': names['time'], 'kind': 'datetime', 'source': 'host'}
    elif spec.stamps == 'device_ms':
        columns[names['time']] = [str(int(t * 1e3) + 1234) for t in line_times]
        clock = {'column': names['time'], 'kind': 'milliseconds', 'source': 'device'}
    else:
        clock = {'rate': spec.rate}
    if spec.stamps != 'none' and rng.random() < 0.5:
        clock['rate'] = spec.rate                   # the device's rate written in the profile, half the time
    register = registers[lines]
    if spec.duty == 'register':
        columns[names['duty']] = [str(int(v)) for v in register]
        profile_columns['duty'] = {'column': names['duty'], 'scale': 1.0 / 255.0}
    else:
        columns[names['duty']] = [f'{100 * v / 255:.1f}' for v in register]
        profile_columns['duty'] = {'column': names['duty'], 'unit': 'percent'}
    if spec.current != 'none':
        if spec.current == 'in_pulse':
            emf = P.back_emf_constant * trajectory.truth['motor_speed'][lines]
            tau = P.armature_inductance / P.armature_resistance
            amps = (spec.supply_voltage - emf) / P.armature_resistance * (1.0 - math.exp(-spec.read_time / tau))
            amps = np.where(register > 0, np.maximum(amps, 0.0), 0.0)     # no pulse, no current
        else:
            amps = trajectory.truth['armature_current'][lines]
        amps = amps + rng.normal(0.0, 0.01, amps.size)
        counts = np.clip(np.round(spec.current_offset_counts + amps * spec.current_counts_per_amp), 0, 1023)
        columns[names['current']] = [str(int(c)) for c in counts]
        profile_columns['armature_current'] = {'column': names['current'],
                                               'scale': 1.0 / spec.current_counts_per_amp,
                                               'offset': -spec.current_offset_counts / spec.current_counts_per_amp}
    angle = trajectory.angle[lines]              # as the sensor reads it (an angle offset included)
    peak = max(float(np.max(np.abs(angle))), 1e-3)
    angle = angle + rng.normal(0.0, peak * 10 ** (-spec.angle_psnr / 20), angle.size)
    if spec.angle == 'counts':
        counts = np.mod(np.round(spec.angle_zero_counts + angle / (2 * math.pi) * spec.counts_per_turn),
                        spec.counts_per_turn)
        columns[names['angle']] = [str(int(c)) for c in counts]
        profile_columns['angle'] = {'column': names['angle'], 'unit': 'count', 'counts_per_turn': spec.counts_per_turn,
                                    'zero': spec.angle_zero_counts, 'wrap': True}
    elif spec.angle == 'degrees':
        columns[names['angle']] = [f'{np.degrees(a):.2f}' for a in angle]
        profile_columns['angle'] = {'column': names['angle'], 'unit': 'degree'}
    else:
        columns[names['angle']] = [f'{a:.5f}' for a in angle]
        profile_columns['angle'] = {'column': names['angle'], 'unit': 'rad'}
    header = list(columns)
    rows = [','.join(values) for values in zip(*(columns[h] for h in header))]
    text = ','.join(header) + '\n' + '\n'.join(rows) + '\n'
    profile = {'name': f'generated foreign log (seed {spec.seed})', 'format': 'csv', 'clock': clock,
               'columns': profile_columns}
    truth = {'rate': spec.rate, 'parameters': P.as_dict(), 'effects': dict(spec.effects),
             'line_times': line_times, 'current': spec.current}
    return ForeignLog(text=text, profile=profile, truth=truth, spec=spec)


#: Hidden effects the random variants draw from (name -> a size: 0.6 x the record's typical one), one or none per
#: variant: the catalog's effects on the pendulum, the angle and the thrust's lag (a dead zone needs small duties these
#: logs do not have; the angle filter is the measurement chain's).
RANDOM_EFFECTS = {name: 0.6 * effect.parameters[0].typical for name, effect in CATALOG.items()
                  if effect.builtin and effect.kind in (PENDULUM, MEASUREMENT, THRUST_LAG)}


def random_spec(seed: int, duration: tuple[float, float] = (15.0, 40.0)) -> ForeignLogSpec:
    """A random variant: rate (10-24 PWM periods per line, 20.4-49 Hz), current kind, angle and duty encodings, stamps,
    stalls, encoder zero, ADC scale, and one hidden effect or none.

    Parameters
    ----------
    seed : int [-]
    duration : (float, float) [s]
        Range of the record length.

    Returns
    -------
    ForeignLogSpec
    """
    rng = np.random.default_rng(10_000 + seed)
    effect = rng.choice([*RANDOM_EFFECTS, 'none', 'none'])
    effects = {} if effect == 'none' else {str(effect): RANDOM_EFFECTS[str(effect)] * float(rng.uniform(0.5, 1.5))}
    offset = float(rng.choice([0.0, 0.0, 512.0]))       # a one-sided sensor, or one centred in the ADC's range
    return replace(ForeignLogSpec(), seed=seed,
                   periods_per_line=int(rng.integers(10, 25)),
                   duration=float(rng.uniform(*duration)),
                   duty_low=int(rng.integers(50, 90)), duty_high=int(rng.integers(110, 200)),
                   current=str(rng.choice(['in_pulse', 'in_pulse', 'average', 'none'])),
                   read_time=float(rng.uniform(0.1e-3, 1.0e-3)),
                   # the ADC's scale leaves room for the largest in-pulse current (~2.5 A): no saturated rig
                   current_counts_per_amp=float(rng.uniform(200, 400)) / (2.0 if offset else 1.0),
                   current_offset_counts=offset,
                   angle=str(rng.choice(['counts', 'counts', 'degrees', 'radians'])),
                   counts_per_turn=int(rng.choice([1024, 4096])),
                   angle_zero_counts=int(rng.integers(0, 1024)),
                   duty=str(rng.choice(['register', 'register', 'percent'])),
                   stamps=str(rng.choice(['host', 'host', 'device_ms', 'none'])),
                   stall_probability=float(rng.uniform(0.0, 0.06)),
                   stall_max=float(rng.uniform(0.05, 0.36)),
                   angle_psnr=float(rng.uniform(35, 60)),
                   effects=effects)


__all__ = ['ForeignLogSpec', 'ForeignLog', 'generate', 'random_spec', 'PWM_RATE', 'RANDOM_EFFECTS']
