"""Closed-loop simulation: the rig simulator's code driven sample by sample by the controller law.

Timing is the firmware's: the angle of sample k is read at t_k, the law computes the duty from it, and that duty is
applied from the next PWM period (t_{k+1}); one sample of latency. The controller sees the *measured* angle (the
simulator's measurement chain: sensor offset and filter, noise, 10-bit quantisation), and the feedforward is the
static duty of the model the controller was designed on, not of the simulated truth.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from aeropend_core.control.feedforward import static_duty
from aeropend_core.control.law import INTEGRAL, TRIPPED, UNSATURATED, PidController, PidGains
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, SAMPLE_TIME, RigParameters
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import RigSimulator


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


def simulate_loop(gains: PidGains, reference: np.ndarray, feedforward: Callable[[float], float] | None = None,
                  parameters: RigParameters = DEFAULT_PARAMETERS,
                  effects: Mapping[str, Mapping[str, float] | float] | None = None,
                  noise: MeasurementNoise | None = None, seed: int | None = None, initial_angle: float = 0.0,
                  sample_time: float = SAMPLE_TIME, duty_limit: float = 1.0) -> ClosedLoopRecord:
    """Simulate the closed loop on a whole reference [rad per sample] from rest at `initial_angle` [rad].

    >>> from aeropend_core.control.law import PidGains
    >>> record = simulate_loop(PidGains(), np.full(490, 0.3))
    >>> len(record), float(record.duty[0])
    (490, 0.0)
    """
    simulation = ClosedLoopSimulation(gains, feedforward, parameters, effects, noise, seed, initial_angle,
                                      sample_time, duty_limit)
    return simulation.advance(reference)
