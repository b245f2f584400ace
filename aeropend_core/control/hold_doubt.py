"""The thrust doubt of an identified model, from the open-loop record it was identified on.

The feedforward is the model's static duty: what holds the rod still. The open-loop excitation holds the duty
constant for 0.6-2 s at a time, and the damped rod comes to rest within each long hold, so the record itself shows
the duty that held the rod at each rest angle. For each rest, the thrust the model needs at that angle (gravity and
the pendulum effects, :func:`holding_torque`) over the thrust the model gives at the held duty
(:func:`rest_thrust_torque`) is the factor by which the rig's thrust differs from the model's there. Their spread
over the rests (mean +-2 standard deviations) is how far the feedforward can be off: it carries what the fit's
standard error does not, the motor constants the fit kept at their nominal values (only the thrust product and R
are fitted), a thrust map of the wrong shape (a dead zone), and the band a dry friction holds the rod in.

When the model itself has the dry friction, that band is the model's, not a doubt about the thrust: each rest then
allows a range of factors (the holding torque plus or minus the friction's), and the factor taken at each rest is
the one within its range nearest the rests' consensus (not nearest 1: a rig whose thrust is 0.85 x the model's
keeps 0.85 where the bands allow it). On the benchmark's friction rigs the band alone widened the doubt to 0.81-1.22
and the design refused a template the rig meets.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from aeropend_core.control.feedforward import holding_torque, rest_thrust_torque
from aeropend_core.model.effects import kernel_coefficients, resolve_effects
from aeropend_core.model.parameters import RigParameters

#: A hold shorter than this [s] is not used (the rod has not come to rest; the damped pendulum settles in ~0.6 s).
MIN_HOLD = 0.9
#: The rest window: the last this many seconds of a hold [s].
REST_WINDOW = 0.3
#: Rests below this angle [rad] are not used: gravity's torque there is too small for a ratio.
MIN_ANGLE = math.radians(10)
#: The fewest rests a doubt is stated from.
MIN_RESTS = 4


@dataclass(frozen=True)
class HoldDoubt:
    """Rig-to-model thrust factors at the record's rests; `tolerance` = mean -+ 2 standard deviations."""

    factors: tuple[float, ...]
    angles: tuple[float, ...]
    tolerance: tuple[float, float]
    #: the model's dry friction gave each rest a band of factors (the factor taken within it, nearest the consensus)
    within_friction_band: bool = False


def rests(time, angle, duty, min_hold: float = MIN_HOLD, window: float = REST_WINDOW):
    """(mean angle [rad], duty) of the last `window` seconds of every constant-duty hold longer than `min_hold`
    [s] whose angle is still there (its spread within the window under 3 noise sigma of the record)."""
    time, angle, duty = (np.asarray(x, dtype=float) for x in (time, angle, duty))
    if time.size < 10:
        return []
    noise = float(np.std(np.diff(angle))) / math.sqrt(2.0)
    edges = np.flatnonzero(np.abs(np.diff(duty)) > 1e-9) + 1
    starts = np.concatenate(([0], edges))
    stops = np.concatenate((edges, [time.size]))
    found = []
    for start, stop in zip(starts, stops):
        if stop - start < 2 or time[stop - 1] - time[start] < min_hold:
            continue
        inside = (time[start:stop] >= time[stop - 1] - window)
        values = angle[start:stop][inside]
        # at rest: no drift over the window beyond what the noise explains
        drift = abs(float(np.mean(values[: values.size // 2]) - np.mean(values[values.size // 2:])))
        if drift > 3.0 * noise / math.sqrt(max(values.size / 2, 1)) + math.radians(0.3):
            continue
        found.append((float(np.mean(values)), float(duty[start])))
    return found


def hold_doubt(time, angle, duty, parameters: RigParameters,
               effects: Mapping[str, Mapping[str, float]] | None = None) -> HoldDoubt | None:
    """The rig-to-model thrust factor at every rest of an open-loop record (`time` [s], measured `angle` [rad],
    `duty` [fraction]); None when fewer than ``MIN_RESTS`` rests above ``MIN_ANGLE`` are found."""
    effects = resolve_effects(effects)
    coefficients = kernel_coefficients(effects)
    offset = coefficients['measured_offset']
    # a dry friction of the model holds the rod anywhere its torque covers: a rest needs the holding torque within
    # +- the friction [rad/s^2], so it allows a range of thrust factors
    band = abs(float(coefficients['rate_sign']))
    lows, highs, angles = [], [], []
    for measured, held in rests(time, angle, duty):
        true_angle = measured - offset
        if true_angle < MIN_ANGLE:
            continue
        given = rest_thrust_torque(held, parameters, effects)
        if given <= 0.0:
            continue
        needed = holding_torque(true_angle, parameters, effects)
        lows.append((needed - band) / given)
        highs.append((needed + band) / given)
        angles.append(measured)
    if len(lows) < MIN_RESTS:
        return None
    lows, highs = np.array(lows), np.array(highs)
    factors = _nearest_consensus(lows, highs)
    mean, sd = float(np.mean(factors)), float(np.std(factors, ddof=1))
    low, high = mean - 2.0 * sd, mean + 2.0 * sd
    # the rests whose bands hold the consensus cannot tell it from any other factor all their bands share: every
    # such factor stays in the doubt (else a band would shrink the doubt to the consensus alone)
    holding = (lows <= mean + 1e-12) & (highs >= mean - 1e-12)
    if holding.any():
        low, high = min(low, float(np.max(lows[holding]))), max(high, float(np.min(highs[holding])))
    return HoldDoubt(tuple(float(f) for f in factors), tuple(angles), (low, high),
                     within_friction_band=bool(np.any(highs > lows)))


def _nearest_consensus(lows: np.ndarray, highs: np.ndarray, rounds: int = 50) -> np.ndarray:
    """Per rest, the factor within [low, high] nearest the mean of the factors so chosen (a fixed point; equal to
    the midpoints' mean when every range is a point)."""
    factors = 0.5 * (lows + highs)
    for _ in range(rounds):
        chosen = np.clip(np.mean(factors), lows, highs)
        if np.allclose(chosen, factors, rtol=0.0, atol=1e-12):
            break
        factors = chosen
    return factors


def widened(tolerance: tuple[float, float], doubt: HoldDoubt | None,
            nominal: tuple[float, float] = (0.8, 1.25)) -> tuple[tuple[float, float], bool]:
    """`tolerance` widened to hold the doubt of the record's rests (not narrowed: the fit's doubt stays); the flag
    says the rests reach beyond `nominal` (the nominal model's own range)."""
    if doubt is None:
        return tolerance, False
    low, high = min(tolerance[0], doubt.tolerance[0]), max(tolerance[1], doubt.tolerance[1])
    return (low, high), low < nominal[0] or high > nominal[1]
