"""Shared test vectors of the controller law: the Python reference against the firmware's single-precision C.

:func:`generate` draws seeded vectors of :func:`aeropend_core.control.law.law_step`: coefficients from realistic
:class:`~aeropend_core.control.law.PidGains` (all three anti-windup codes; the setpoint weight b uniform in [0, 1]
in :data:`WEIGHTED_SHARE` of the sets, b = 1 in the others; several vectors per gain set), states
(unprimed, tripped, integrals at and inside their clamps), references, feedforward duties and angles (small steps,
large errors that saturate the output on both sides, angles outside the safety window and exactly on its edges).
Every input is a float32 value, so the C (``firmware/aeropend/aeropend_control.h``, run by
``firmware/sim/law_vectors.c`` on the host and in simavr) and the float64 Python start from the same numbers.

:func:`expected` runs the Python law; :func:`encode_input` / :func:`decode_output` speak law_vectors.c's binary
records; :func:`compare` checks every output against the tolerance of :func:`tolerance`:

    |C - Python| <= 10 * 2**-24 * M + 1e-7

where M is the sum of the magnitudes of the terms that make the output (recursively: the derivative's terms are in
the unsaturated output's, whose terms are in the back-calculated integral's). Each float32 operation rounds by at
most 2**-24 of its result; a sum of terms computed through at most n operations each is off by at most
n 2**-24 / (1 - n 2**-24) times the sum of their magnitudes. The law's deepest term goes through 9 operations
(b r, minus y, times p and the three sums of the unsaturated output, then duty minus it, times Ts/Tt and the
integral's last sum), so 10 * 2**-24 * M bounds the accumulated rounding; 1e-7 covers results near zero.
The branches (trip, saturation high / low, conditional integration holding the integral) are compared exactly.
bench code can reuse :func:`generate` for timing.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from aeropend_core.control.law import (
    ANTIWINDUP,
    N_COEFFICIENTS,
    N_STATE,
    SETPOINT_WEIGHT,
    PidGains,
    law_step,
)

__all__ = ['LawVectors', 'compare', 'decode_output', 'encode_input', 'expected', 'generate', 'tolerance',
           'OUTPUT_RECORD', 'BRANCH_TRIPPED', 'BRANCH_HIGH', 'BRANCH_LOW', 'BRANCH_HELD']

#: Sample period of the firmware [s] (64 * 510 / 16 MHz), at which the device's coefficients are computed.
FIRMWARE_SAMPLE_TIME = 64 * 510 / 16e6
#: Bits of the branch byte (law_vectors.c).
BRANCH_TRIPPED, BRANCH_HIGH, BRANCH_LOW, BRANCH_HELD = 1, 2, 4, 8
#: Bytes of one answer of law_vectors.c: 7 float32 + the branch byte.
OUTPUT_RECORD = 29
#: Share of the gain sets whose setpoint weight b is drawn uniformly in [0, 1] (the others: b = 1, the plain PID).
WEIGHTED_SHARE = 0.5
#: Relative rounding allowance per unit of term magnitude (9 float32 roundings deep, module docstring), and the
#: absolute floor.
RELATIVE = 10 * 2.0 ** -24
ABSOLUTE = 1e-7


def f32(values):
    """Round to the nearest float32, returned as float64 (exactly representable in both)."""
    return np.asarray(values, dtype=np.float32).astype(np.float64)


@dataclass(frozen=True)
class LawVectors:
    """Inputs of `count` law steps; ``coefficients[set_index[k]]`` is vector k's coefficient vector."""

    coefficients: np.ndarray   #: (sets, 14)
    set_index: np.ndarray      #: (count,) int
    state: np.ndarray          #: (count, 6) the state before the step
    reference: np.ndarray      #: (count,)
    feedforward: np.ndarray    #: (count,)
    angle: np.ndarray          #: (count,)

    @property
    def count(self) -> int:
        return len(self.angle)


def _random_gains(rng: np.random.Generator, antiwindup: str) -> PidGains:
    def log_uniform(low, high):
        return float(np.exp(rng.uniform(np.log(low), np.log(high))))
    u_min = float(rng.choice([0.0, rng.uniform(0.0, 0.2)]))
    return PidGains(
        p=log_uniform(0.05, 5.0),
        i=float(rng.choice([0.0, log_uniform(0.01, 5.0), log_uniform(0.01, 5.0)])),
        d=float(rng.choice([0.0, log_uniform(0.001, 0.2), log_uniform(0.001, 0.2)])),
        derivative_filter_time=float(rng.choice([0.0, rng.uniform(0.001, 0.1)])),
        i_clamp_min=float(rng.uniform(-0.5, 0.0)),
        i_clamp_max=float(rng.uniform(0.0, 0.5)),
        u_clamp_min=u_min,
        u_clamp_max=float(rng.uniform(max(u_min, 0.3), 1.0)),
        antiwindup=antiwindup,
        tracking_time_constant=float(rng.choice([0.0, rng.uniform(0.005, 1.0)])),
        feedforward_gain=float(rng.uniform(0.0, 1.2)),
        angle_min=float(rng.uniform(-0.6, -0.05)),
        angle_max=float(rng.uniform(1.0, 2.0)),
        setpoint_weight=float(rng.uniform(0.0, 1.0)) if rng.random() < WEIGHTED_SHARE else 1.0)


def generate(count: int = 10_000, seed: int = 0, per_set: int = 8,
             sample_time: float = FIRMWARE_SAMPLE_TIME) -> LawVectors:
    """`count` seeded vectors, `per_set` of them per random gain set (the anti-windup codes in turn)."""
    rng = np.random.default_rng(seed)
    sets = -(-count // per_set)
    names = list(ANTIWINDUP)
    coefficients = np.array([_random_gains(rng, names[k % len(names)]).coefficients(sample_time)
                             for k in range(sets)])
    coefficients = f32(coefficients)
    set_index = np.arange(count) // per_set
    c = coefficients[set_index]
    lo, hi = c[:, 11], c[:, 12]
    state = np.zeros((count, N_STATE))
    kind = rng.random(count)
    state[:, 0] = rng.uniform(c[:, 4], c[:, 5])
    state[kind < 0.05, 0] = c[kind < 0.05, 4]                          # integral on its clamps
    state[(kind >= 0.05) & (kind < 0.1), 0] = c[(kind >= 0.05) & (kind < 0.1), 5]
    state[:, 1] = rng.normal(0.0, 0.2, count)
    state[:, 2] = rng.uniform(lo, hi)
    state[:, 3] = (rng.random(count) > 0.15).astype(float)             # 15 % unprimed
    state[:, 4] = (rng.random(count) < 0.04).astype(float)             # 4 % already tripped
    state[:, 5] = rng.normal(0.3, 0.3, count)
    reference = rng.uniform(lo, hi)
    feedforward = rng.uniform(0.0, 0.8, count)
    angle = state[:, 2] + rng.normal(0.0, 0.02, count)                 # one sample's motion
    big = rng.random(count) < 0.3                                      # large errors: saturate both sides
    angle[big] = rng.uniform(lo[big], hi[big])
    far = rng.random(count)
    below, above = far < 0.03, (far >= 0.03) & (far < 0.06)            # outside the window: trips
    angle[below] = lo[below] - rng.uniform(1e-3, 0.5, below.sum())
    angle[above] = hi[above] + rng.uniform(1e-3, 0.5, above.sum())
    edge = rng.random(count)
    angle[edge < 0.01] = lo[edge < 0.01]                               # exactly on the edges: no trip
    angle[(edge >= 0.01) & (edge < 0.02)] = hi[(edge >= 0.01) & (edge < 0.02)]
    state = f32(state)
    return LawVectors(coefficients, set_index, state, f32(reference), f32(feedforward), f32(angle))


def branches(c: np.ndarray, state_after: np.ndarray, reference: float, angle: float) -> int:
    """The branch byte of one step (as law_vectors.c computes it) from the state after it."""
    if state_after[4] != 0.0:
        return BRANCH_TRIPPED
    unsaturated = state_after[5]
    error = reference - angle
    out = 0
    if unsaturated > c[7]:
        out |= BRANCH_HIGH
    if unsaturated < c[6]:
        out |= BRANCH_LOW
    if c[8] == 2.0 and ((unsaturated > c[7] and error > 0.0) or (unsaturated < c[6] and error < 0.0)):
        out |= BRANCH_HELD
    return out


def expected(vectors: LawVectors) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The float64 Python law on every vector: ``(duty (n,), state after (n, 6), branch bytes (n,))``."""
    n = vectors.count
    duty = np.empty(n)
    state_after = np.empty((n, N_STATE))
    branch = np.empty(n, dtype=np.int64)
    for k in range(n):
        c = vectors.coefficients[vectors.set_index[k]]
        s = vectors.state[k].copy()
        duty[k] = law_step(c, s, float(vectors.reference[k]), float(vectors.feedforward[k]),
                           float(vectors.angle[k]))
        state_after[k] = s
        branch[k] = branches(c, s, vectors.reference[k], vectors.angle[k])
    return duty, state_after, branch


def tolerance(vectors: LawVectors, duty: np.ndarray) -> np.ndarray:
    """Allowed |C - Python| of each output ``(n, 7)``: duty, then the 6 state elements (module docstring)."""
    c = vectors.coefficients[vectors.set_index]
    s = vectors.state
    r, ff, y = vectors.reference, vectors.feedforward, vectors.angle
    error = np.abs(r) + np.abs(y)
    weighted_error = np.abs(c[:, SETPOINT_WEIGHT] * r) + np.abs(y)                  # b r - y, the proportional term's
    derivative = np.abs(c[:, 2] * s[:, 1]) + np.abs(c[:, 3]) * (np.abs(y) + np.abs(s[:, 2]))
    unsaturated = np.abs(c[:, 10] * ff) + np.abs(c[:, 0]) * weighted_error + np.abs(s[:, 0]) + derivative
    integral = np.abs(s[:, 0]) + np.abs(c[:, 1]) * error + np.abs(c[:, 9]) * (np.abs(duty) + unsaturated)
    magnitude = np.stack([unsaturated, integral, derivative, np.zeros_like(r), np.zeros_like(r),
                          np.zeros_like(r), unsaturated], axis=1)
    return RELATIVE * magnitude + ABSOLUTE


def encode_input(vectors: LawVectors, timed: bool = False) -> bytes:
    """law_vectors.c's input: a 'C' record at each new coefficient set, a 'V' record per vector (`timed`: 'T',
    answered by the step's CPU cycles, u16), then 'Q'."""
    out = bytearray()
    tag = b'T' if timed else b'V'
    current = -1
    coefficient = struct.Struct(f'<c{N_COEFFICIENTS}f')
    vector = struct.Struct('<c9f')
    for k in range(vectors.count):
        index = int(vectors.set_index[k])
        if index != current:
            out += coefficient.pack(b'C', *vectors.coefficients[index])
            current = index
        out += vector.pack(tag, *vectors.state[k], vectors.reference[k], vectors.feedforward[k],
                           vectors.angle[k])
    out += b'Q'
    return bytes(out)


def decode_output(data: bytes, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """law_vectors.c's answers: ``(duty, state after, branch bytes)`` as float64 / int arrays."""
    if len(data) != count * OUTPUT_RECORD:
        raise ValueError(f'expected {count * OUTPUT_RECORD} bytes ({count} answers), got {len(data)}')
    records = np.frombuffer(data, dtype=np.dtype([('values', '<f4', 7), ('branches', 'u1')]))
    values = records['values'].astype(np.float64)
    return values[:, 0], values[:, 1:], records['branches'].astype(np.int64)


@dataclass(frozen=True)
class Comparison:
    """How far the C is from the Python law on a set of vectors."""

    count: int
    branch_agreement: int          #: vectors whose branch byte is the same
    trips: int                     #: vectors the Python law trips on (or that were tripped)
    held: int                      #: vectors where conditional integration held the integral (Python)
    saturated_high: int
    saturated_low: int
    unprimed: int
    weighted: int                  #: vectors whose setpoint weight b is below 1
    within_tolerance: int          #: vectors whose 7 outputs are all within tolerance
    worst_ratio: float             #: max over vectors and outputs of |C - Python| / tolerance
    max_error: float               #: max |C - Python| over all outputs
    worst: tuple                   #: (vector, output) of worst_ratio

    def summary(self) -> str:
        return (f'{self.count} vectors: {self.within_tolerance} within tolerance (worst |error| / tolerance '
                f'{self.worst_ratio:.3g} at {self.worst}, max |error| {self.max_error:.3g}); branches agree on '
                f'{self.branch_agreement}; {self.trips} trips, {self.held} held integrals, {self.saturated_high} / '
                f'{self.saturated_low} saturated high / low, {self.unprimed} unprimed, {self.weighted} with a setpoint '
                f'weight below 1')


def compare(vectors: LawVectors, got: tuple[np.ndarray, np.ndarray, np.ndarray],
            want: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> Comparison:
    """Compare the C's answers `got` (:func:`decode_output`) with the Python law's (`want`, computed if None)."""
    if want is None:
        want = expected(vectors)
    got_values = np.column_stack([got[0], got[1]])
    want_values = np.column_stack([want[0], want[1]])
    error = np.abs(got_values - want_values)
    error[np.isnan(got_values) != np.isnan(want_values)] = np.inf
    allowed = tolerance(vectors, want[0])
    ratio = error / allowed
    worst = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
    return Comparison(
        count=vectors.count,
        branch_agreement=int(np.sum(got[2] == want[2])),
        trips=int(np.sum(want[2] & BRANCH_TRIPPED != 0)),
        held=int(np.sum(want[2] & BRANCH_HELD != 0)),
        saturated_high=int(np.sum(want[2] & BRANCH_HIGH != 0)),
        saturated_low=int(np.sum(want[2] & BRANCH_LOW != 0)),
        unprimed=int(np.sum((vectors.state[:, 3] == 0) & (vectors.state[:, 4] == 0))),
        weighted=int(np.sum(vectors.coefficients[vectors.set_index, SETPOINT_WEIGHT] < 1.0)),
        within_tolerance=int(np.sum(np.all(ratio <= 1.0, axis=1))),
        worst_ratio=float(ratio.max()),
        max_error=float(error.max()),
        worst=(int(worst[0]), int(worst[1])))
