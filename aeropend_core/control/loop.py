"""Closed-loop simulation: the rig simulator's code driven sample by sample by the controller law.

Two paths, as the simulator's: the *compiled* one (built-in effects) runs the simulator's RK4
(:func:`aeropend_core.sim.simulate._rk4_sample`, the one :func:`~aeropend_core.sim.simulate._rig_kernel` runs) one
sample at a time inside a numba loop with the law compiled from the same source (:func:`law_step`) and the
measurement chain (offset, the sensor filter's coefficients of :mod:`aeropend_core.model.sensor_filter`, noise,
10-bit rounding): ~2 us a sample; several loops (noise draws, rigs) step together in one call
(:func:`simulate_loops`), each with the numbers it has alone, in fewer CPU seconds. The *streaming* one steps a
:class:`RigSimulator` sample by sample from Python (any effect; what the sim node runs): ~30 us a sample. Without
noise both give the same samples (a test compares them); with noise they draw different random numbers.

Timing is the firmware's: the angle of sample k is read at t_k, the law computes the duty from it, and that duty is
applied from the next PWM period (t_{k+1}); one sample of latency. The controller sees the *measured* angle (the
simulator's measurement chain: sensor offset and filter, noise, 10-bit quantisation), and the feedforward is the
static duty of the model the controller was designed on, not of the simulated truth.
"""
from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

import math

import numba

from aeropend_core.control.feedforward import static_duty
from aeropend_core.control.law import INTEGRAL, TRIPPED, UNSATURATED, PidController, PidGains, law_step, new_state
from aeropend_core.model.effects import FRICTION_SMOOTHING, get_effect, kernel_coefficients, resolve_effects
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, SAMPLE_TIME, RigParameters
from aeropend_core.model.sensor_filter import MIN_DELAY
from aeropend_core.model.sensor_filter import coefficients as filter_coefficients
from aeropend_core.sim.noise import ANGLE_LSB, CURRENT_LSB, FULL_SCALE, MeasurementNoise, sigma_for_psnr
from aeropend_core.sim.simulate import SUBSTEPS, RigSimulator, _rk4_sample

_law = numba.njit(cache=True)(law_step)


@numba.njit(cache=True, nogil=True)
def _loop_kernel(constants, voltage_fit, law, law_state, reference, feedforward, kinds, filter_b, filter_a,
                 noise, quanta, duty_limit, state, sample_time, out, law_noise):
    """Closed loops, compiled, several side by side: per sample the rig over one period (the simulator's RK4,
    :func:`~aeropend_core.sim.simulate._rk4_sample`, the loops' stages interleaved), the measured angle, then the
    law. The loops are independent (each its own rig, law and noise) and each computes
    exactly what it computes alone; stepping them together lets the processor overlap their arithmetic (~1.5x
    fewer CPU seconds a loop with 20 than one by one).

    constants (m, 12): each loop's rig (as ``_rig_kernel``'s); voltage_fit: k0..k3 of eq (8); law (m, 14),
    law_state (m, 6): each loop's :meth:`PidGains.coefficients` and law state (updated); reference [rad],
    feedforward [duty] (n,): shared; kinds: rate_sign, rate_square, angle_linear, lag time [s], friction smoothing
    [rad/s], dead-zone threshold [V], angle offset [rad]; filter_b/filter_a: the sensor filter (empty: none);
    noise (m, n, 3): Va [V], Ia [A], angle [rad] noise; quanta: current and angle counts [A, rad] (0: no rounding);
    state (m, 5): each rig's initial state, updated to its final one; law_noise (m, n) [rad]: added to the angle
    the law reads only, not to the state nor to the measured angle written out (the noise a record fed back:
    :func:`simulate_loops`); shape (0, 0): none.
    out (m, n, 10): duty applied, unsaturated, integral, tripped, measured angle, Va, Ia, true angle, true rate,
    motor speed.
    """
    m = constants.shape[0]
    n = reference.shape[0]
    h = sample_time / SUBSTEPS
    filtered = filter_b.shape[0] == 3
    fed = law_noise.shape[0] > 0
    z0 = np.zeros(m)
    z1 = np.zeros(m)
    applied = np.zeros(m)
    volts = np.empty(m)
    gate = np.empty(m)
    start = np.empty((m, 5))
    k = np.empty((4, m, 5))
    xt = np.empty((m, 5))
    x = state
    for i in range(n):
        for d in range(m):
            duty = applied[d]
            va = 0.0
            if duty > 0.0:
                root = voltage_fit[2] * duty + voltage_fit[3]
                va = voltage_fit[0] + voltage_fit[1] * math.sqrt(root if root > 0.0 else 0.0)
                if va < 0.0:
                    va = 0.0
            volts[d] = va
            gate[d] = 1.0 if va >= kinds[5] else 0.0
            for j in range(5):
                start[d, j] = x[d, j]
        _rk4_sample(constants, volts, gate, x, k, xt, h, kinds[0], kinds[1], kinds[2], kinds[3], kinds[4])
        for d in range(m):
            true_angle = start[d, 2]
            angle = true_angle + kinds[6]
            if filtered:
                if i == 0:      # at rest on the first sample (unit DC gain): scipy's lfilter_zi times the input
                    z0[d] = angle * (1.0 - filter_b[0])
                    z1[d] = angle * (filter_b[2] - filter_a[2])
                y = filter_b[0] * angle + z0[d]
                z0[d] = filter_b[1] * angle - filter_a[1] * y + z1[d]
                z1[d] = filter_b[2] * angle - filter_a[2] * y
                angle = y
            angle += noise[d, i, 2]
            current = start[d, 0] + noise[d, i, 1]
            if quanta[1] > 0.0:
                angle = np.round(angle / quanta[1]) * quanta[1]
            if quanta[0] > 0.0:
                current = np.round(current / quanta[0]) * quanta[0]
            read = angle + law_noise[d, i] if fed else angle
            next_duty = _law(law[d], law_state[d], reference[i], feedforward[i], read)
            if next_duty > duty_limit:
                next_duty = duty_limit
            if next_duty < 0.0:
                next_duty = 0.0
            out[d, i, 0] = applied[d]
            applied[d] = next_duty
            out[d, i, 1] = law_state[d, 5]
            out[d, i, 2] = law_state[d, 0]
            out[d, i, 3] = law_state[d, 4]
            out[d, i, 4] = angle
            out[d, i, 5] = volts[d] + noise[d, i, 0]
            out[d, i, 6] = current
            out[d, i, 7] = true_angle
            out[d, i, 8] = start[d, 3]
            out[d, i, 9] = start[d, 1]


class FeedforwardMap:
    """Reference [rad] -> feedforward duty under a design model, cached per distinct reference value."""

    def __init__(self, parameters: RigParameters = DEFAULT_PARAMETERS,
                 effects: Mapping[str, Mapping[str, float]] | None = None) -> None:
        self.parameters = parameters
        self.effects = dict(effects or {})
        self._cache: dict[float, float] = {}

    def __call__(self, reference: float) -> float:
        key = round(float(reference), 9)
        if key not in self._cache:
            self._cache[key] = static_duty(key, self.parameters, self.effects)
        return self._cache[key]


@dataclass
class ClosedLoopRecord:
    """Samples of a closed-loop run; shape (n,) each, SI units, duty as a fraction."""

    time: np.ndarray
    reference: np.ndarray
    feedforward: np.ndarray
    duty: np.ndarray
    unsaturated: np.ndarray
    integral: np.ndarray
    tripped: np.ndarray
    angle: np.ndarray
    armature_voltage: np.ndarray
    armature_current: np.ndarray
    truth: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.time)

    @classmethod
    def concatenate(cls, parts: list[ClosedLoopRecord]) -> ClosedLoopRecord:
        names = ('time', 'reference', 'feedforward', 'duty', 'unsaturated', 'integral', 'tripped', 'angle',
                 'armature_voltage', 'armature_current')
        joined = {name: np.concatenate([getattr(part, name) for part in parts]) for name in names}
        truth_names = parts[0].truth.keys() if parts else ()
        joined['truth'] = {name: np.concatenate([part.truth[name] for part in parts]) for name in truth_names}
        return cls(**joined)


class ClosedLoopSimulation:
    """A simulated rig under the law, advanced block by block (the sim node) or in one go (:func:`simulate_loop`).

    Parameters
    ----------
    gains : PidGains
        The controller.
    feedforward : callable, optional
        Reference [rad] -> feedforward duty; default the nominal model's :class:`FeedforwardMap`.
    parameters, effects, noise, seed, initial_angle, sample_time
        The simulated truth, as :class:`~aeropend_core.sim.simulate.RigSimulator`.
    duty_limit : float [fraction]
        The rig's own duty cap after the law (the firmware's maximum duty).
    """

    def __init__(self, gains: PidGains, feedforward: Callable[[float], float] | None = None,
                 parameters: RigParameters = DEFAULT_PARAMETERS,
                 effects: Mapping[str, Mapping[str, float] | float] | None = None,
                 noise: MeasurementNoise | None = None, seed: int | None = None, initial_angle: float = 0.0,
                 sample_time: float = SAMPLE_TIME, duty_limit: float = 1.0) -> None:
        self.simulator = RigSimulator(parameters, effects, sample_time, noise, seed, initial_angle)
        self.controller = PidController(gains, sample_time)
        self.feedforward = feedforward or FeedforwardMap()
        self.sample_time = sample_time
        self.duty_limit = float(duty_limit)
        self.next_duty = 0.0

    def advance(self, reference: np.ndarray) -> ClosedLoopRecord:
        """Simulate one sample per `reference` value [rad]; the duty applied at each sample is the law's answer to
        the previous sample's measured angle."""
        reference = np.asarray(reference, dtype=float).ravel()
        n = reference.size
        out = {name: np.empty(n) for name in ('feedforward', 'duty', 'unsaturated', 'integral', 'tripped',
                                              'angle', 'armature_voltage', 'armature_current')}
        truths: list[dict[str, np.ndarray]] = []
        times = np.empty(n)
        controller = self.controller
        for k in range(n):
            applied = self.next_duty
            sample = self.simulator.run(np.array([applied]))
            angle = float(sample.angle[0])
            feedforward = self.feedforward(reference[k])
            duty = controller.step(reference[k], feedforward, angle)
            self.next_duty = min(max(duty, 0.0), self.duty_limit)
            times[k] = sample.time[0]
            out['feedforward'][k] = feedforward
            out['duty'][k] = applied
            out['unsaturated'][k] = controller.state[UNSATURATED]
            out['integral'][k] = controller.state[INTEGRAL]
            out['tripped'][k] = controller.state[TRIPPED]
            out['angle'][k] = angle
            out['armature_voltage'][k] = sample.armature_voltage[0]
            out['armature_current'][k] = sample.armature_current[0]
            truths.append(sample.truth)
        truth = {name: np.array([t[name][0] for t in truths]) for name in (truths[0] if truths else {})}
        return ClosedLoopRecord(time=times, reference=reference.copy(), truth=truth, **out)


def feedforward_per_sample(feedforward, reference: np.ndarray) -> np.ndarray:
    """The duty [fraction] `feedforward` gives each sample of `reference` [rad], evaluated once per distinct
    reference value (a schedule holds a few), not per sample."""
    values, where = np.unique(reference, return_inverse=True)
    return np.array([feedforward(value) for value in values], dtype=float)[where.reshape(-1)]


def _simulate_compiled(gains, reference, feedforward, parameters, effects, noise, seed, initial_angle, sample_time,
                       duty_limit, law_noise=None) -> ClosedLoopRecord:
    return simulate_loops([(gains, parameters, seed)], reference, feedforward, effects, noise, initial_angle,
                          sample_time, duty_limit, law_noise)[0]


def simulate_loops(runs, reference: np.ndarray, feedforward, effects=None, noise: MeasurementNoise | None = None,
                   initial_angle: float = 0.0, sample_time: float = SAMPLE_TIME,
                   duty_limit: float = 1.0, law_noise: np.ndarray | None = None) -> list[ClosedLoopRecord]:
    """Several closed loops on one compiled call, one per (gains, parameters, seed) of `runs`, each the record
    :func:`simulate_loop` gives for it alone (compiled path; tests/test_control_loop.py compares them bit for bit):
    the same reference [rad per sample], feedforward (a function of the reference, or one duty per sample),
    effects (built-in, compiled ones only), noise, initial angle [rad], sample time [s] and duty cap [fraction].

    `law_noise` [rad], shape (n,) for every run or (len(runs), n): a sequence added to the angle the law reads and
    to nothing else (not the state, not the angle recorded): a record's own measurement noise fed back, so the
    simulated duty carries the jitter the rig's did (:func:`~aeropend_core.control.loop_diagnosis.fed_back_noise`).
    None: the law reads the simulated measured angle alone. Not rounded to the angle's counts: the rounding makes
    the fits' cost step in the parameters and stops the optimiser short of the truth (s26)."""
    runs = list(runs)
    reference = np.asarray(reference, dtype=float).ravel()
    n = reference.size
    effects = resolve_effects(effects)
    if not all(get_effect(name).compiled for name in effects):
        raise ValueError('simulate_loops runs the compiled loop: built-in effects only (simulate_loop streams others)')
    c = kernel_coefficients(effects)
    kinds = np.array([c['rate_sign'], c['rate_square'], c['angle_linear'], c['thrust_lag_time'], FRICTION_SMOOTHING,
                      c['thrust_threshold'], c['measured_offset']])
    if c['measured_lowpass'] >= MIN_DELAY:
        filter_b, filter_a = filter_coefficients(float(c['measured_lowpass']), float(sample_time))
        filter_b = np.ascontiguousarray(filter_b, dtype=float)
        filter_a = np.ascontiguousarray(filter_a, dtype=float)
    else:
        filter_b = filter_a = np.zeros(0)
    m = len(runs)
    noise_values = np.zeros((m, n, 3))
    constants = np.empty((m, 12))
    law = np.empty((m, 14))
    for d, (gains, parameters, seed) in enumerate(runs):
        rng = np.random.default_rng(seed)
        if noise is not None and noise.psnr_db is not None:
            for column, name in enumerate(('armature_voltage', 'armature_current', 'angle')):
                if name in noise.signals:
                    peak = noise.peaks.get(name, FULL_SCALE[name])
                    noise_values[d, :, column] = rng.normal(0.0, sigma_for_psnr(peak, noise.psnr_db), n)
        p = parameters
        constants[d] = [p.armature_resistance, p.armature_inductance, p.back_emf_constant, p.torque_constant,
                        p.motor_inertia, p.motor_friction, p.propeller_torque_coefficient, p.gear_ratio,
                        p.thrust_coefficient, p.gravity_stiffness, p.damping, p.lever_per_inertia]
        law[d] = gains.coefficients(sample_time)
    quanta = np.array([CURRENT_LSB, ANGLE_LSB]) if noise is not None and noise.quantise else np.zeros(2)
    # one duty-to-voltage fit for every run (the kernel takes one): runs on rigs with different fits are refused
    voltage_fits = {(p.duty_voltage_k0, p.duty_voltage_k1, p.duty_voltage_k2, p.duty_voltage_k3) for _g, p, _s in runs}
    if len(voltage_fits) > 1:
        raise ValueError('simulate_loops: the runs\' rigs must share the duty-to-voltage fit (k0..k3)')
    voltage_fit = np.array(voltage_fits.pop() if voltage_fits else (0.0, 0.0, 0.0, 0.0))
    if callable(feedforward):
        feedforward_values = feedforward_per_sample(feedforward, reference)
    else:                   # the feedforward played, sample by sample (a record's telemetry)
        feedforward_values = np.ascontiguousarray(feedforward, dtype=float)
        if feedforward_values.shape != reference.shape:
            raise ValueError('a feedforward array must have one value per reference sample')
    state = np.zeros((m, 5))
    state[:, 2] = initial_angle
    law_state = np.stack([new_state() for _ in runs]) if runs else np.zeros((0, 6))
    if law_noise is None:
        law_values = np.zeros((0, 0))
    else:
        law_values = np.asarray(law_noise, dtype=float)
        if law_values.shape not in ((n,), (m, n)) or not np.all(np.isfinite(law_values)):
            raise ValueError(f'law_noise must be finite, shape ({n},) for every run or ({m}, {n}), got '
                             f'{law_values.shape}')
        law_values = np.ascontiguousarray(np.broadcast_to(law_values, (m, n)))
    out = np.empty((m, n, 10))
    if m:
        _loop_kernel(constants, voltage_fit, law, law_state, reference, feedforward_values, kinds, filter_b, filter_a,
                     noise_values, quanta, float(duty_limit), state, float(sample_time), out, law_values)
    time = np.arange(n) * sample_time
    return [ClosedLoopRecord(time=time.copy(), reference=reference.copy(), feedforward=feedforward_values.copy(),
                             duty=o[:, 0].copy(), unsaturated=o[:, 1].copy(), integral=o[:, 2].copy(),
                             tripped=o[:, 3].copy(), angle=o[:, 4].copy(), armature_voltage=o[:, 5].copy(),
                             armature_current=o[:, 6].copy(),
                             truth={'angle': o[:, 7].copy(), 'angular_rate': o[:, 8].copy(),
                                    'motor_speed': o[:, 9].copy()}) for o in out]


def simulate_loop(gains: PidGains, reference: np.ndarray, feedforward: Callable[[float], float] | None = None,
                  parameters: RigParameters = DEFAULT_PARAMETERS,
                  effects: Mapping[str, Mapping[str, float] | float] | None = None,
                  noise: MeasurementNoise | None = None, seed: int | None = None, initial_angle: float = 0.0,
                  sample_time: float = SAMPLE_TIME, duty_limit: float = 1.0,
                  method: str = 'auto', law_noise: np.ndarray | None = None) -> ClosedLoopRecord:
    """Simulate the closed loop on a whole reference [rad per sample] from rest at `initial_angle` [rad].

    >>> from aeropend_core.control.law import PidGains
    >>> record = simulate_loop(PidGains(), np.full(490, 0.3))
    >>> len(record), float(record.duty[0])
    (490, 0.0)

    `feedforward`: a function of the reference [rad -> duty], or (compiled path) one duty per sample.

    `method`: 'compiled' (built-in effects, ~1 us a sample), 'streaming' (any effect, ~30 us a sample) or 'auto'.

    `law_noise` [rad per sample]: added to the angle the law reads only (compiled path; :func:`simulate_loops`).
    """
    resolved = resolve_effects(effects)
    compiled = all(get_effect(name).compiled for name in resolved)
    if method not in ('auto', 'compiled', 'streaming'):
        raise ValueError(f"method must be 'auto', 'compiled' or 'streaming', got {method!r}")
    if method == 'compiled' or (method == 'auto' and compiled):
        return _simulate_compiled(gains, np.asarray(reference, dtype=float).ravel(),
                                  FeedforwardMap() if feedforward is None else feedforward, parameters, resolved,
                                  noise, seed, initial_angle,
                                  sample_time, duty_limit, law_noise)
    if law_noise is not None:
        raise ValueError('law_noise runs on the compiled loop only (built-in effects)')
    simulation = ClosedLoopSimulation(gains, feedforward, parameters, effects, noise, seed, initial_angle,
                                      sample_time, duty_limit)
    return simulation.advance(reference)


def noise_draws(gains: PidGains, reference: np.ndarray, feedforward, parameters: RigParameters, effects,
                noise: MeasurementNoise | None, seeds, schedule, sample_time: float = SAMPLE_TIME,
                duty_limit: float = 1.0, pool=None, workers: int = 2) -> list:
    """(run, its per-step metrics) of the closed loop on the model, one per seed of `seeds` (noise draws), in
    seed order: the one helper behind the design's noise-edge judgement and the check's settling range.

    `reference` [rad per sample]; `feedforward` [duty per sample, or a function of the reference]; `schedule` the
    :class:`~aeropend_core.control.reference.ReferenceSchedule` the metrics read
    (:func:`~aeropend_core.control.metrics.schedule_metrics`, the judgement of a record). The compiled loop
    releases the GIL: the draws (built-in effects) go in up to `workers` contiguous groups, each one compiled call
    of :func:`simulate_loops` (the loops stepped together), the groups on `pool`'s threads, else on threads of their
    own; with other effects each draw streams on its own."""
    from aeropend_core.control.metrics import schedule_metrics

    def judged(run):
        return run, schedule_metrics(run.time, run.angle, run.duty, schedule)

    def one(seed):
        return judged(simulate_loop(gains, reference, feedforward, parameters, effects, noise, seed,
                                    sample_time=sample_time, duty_limit=duty_limit))

    def batch(seeds):       # the draws of one thread in one compiled call (each as simulate_loop's)
        return [judged(run) for run in simulate_loops([(gains, parameters, seed) for seed in seeds], reference,
                                                      feedforward, effects, noise, sample_time=sample_time,
                                                      duty_limit=duty_limit)]

    seeds = list(seeds)
    compiled = all(get_effect(name).compiled for name in resolve_effects(effects))
    threads = min(workers, os.cpu_count() or 1, len(seeds))
    if not compiled:
        if pool is not None:
            return list(pool.map(one, seeds))
        if threads <= 1:
            return [one(seed) for seed in seeds]
        from concurrent.futures import ThreadPoolExecutor
        with ThreadPoolExecutor(threads) as own:
            return list(own.map(one, seeds))
    # contiguous groups of seeds, one compiled call each, the groups side by side on threads (nogil)
    groups = [seeds[a:b] for a, b in _bounds(len(seeds), max(threads, 1))]
    if len(groups) <= 1:
        return [pair for group in groups for pair in batch(group)]
    if pool is not None:
        return [pair for done in pool.map(batch, groups) for pair in done]
    from concurrent.futures import ThreadPoolExecutor
    with ThreadPoolExecutor(len(groups)) as own:
        return [pair for done in own.map(batch, groups) for pair in done]


def _bounds(count: int, parts: int) -> list[tuple[int, int]]:
    """`parts` contiguous (start, stop) index ranges of nearly equal size covering range(count) (empty ones left
    out)."""
    edges = [round(count * j / parts) for j in range(parts + 1)]
    return [(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]
