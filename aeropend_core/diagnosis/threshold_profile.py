"""The ± of a dead zone's threshold from a profile of the training cost, not from the spacing of the input levels.

A threshold is not a smooth parameter: the model's output changes only where an input sample crosses it, so the
Jacobian's standard error (the curvature at the optimum) does not exist, and the rule "uniform between the two
adjacent training input levels" (``(high - low) / sqrt(12)``) holds only when the input is held at a few levels and
moving the threshold across one of them changes the fit by much more than the noise. On a continuous input (a
chirp, every sample a new level) that interval is ~1e-4 V wide while the fit can barely tell thresholds 0.1-0.7 V
apart (issue 40 item 3: on the second simulator 1 of 17 thresholds was within its 2σ).

So the threshold is profiled: refitted with the threshold held at values stepping outward from the estimate on each
side (every other parameter free, warm-started from the best fit; the same refit at the estimate is the reference
when it ends above the best fit), the training cost turned into a likelihood-ratio
statistic with the effective number of independent residuals the project uses for correlated residuals (as the
BIC in :mod:`aeropend_core.diagnosis.candidates`): ``Δχ² = n_eff ln(rms(t)² / rms²)``. The points where it reaches
the chi-square(1) 95 % quantile (3.84, bisected) bound a ~2σ interval; the threshold's 1σ is the larger of the two
distances to them divided by 1.96, and never smaller than the level-spacing rule. A side that never reaches it before
0 V or the top of the input is as wide as that bound. The other parameters' values at those points say how far the
threshold's doubt carries into them (an angle offset or the thrust gain move with it): their larger shift from the
estimate to either end of the interval, / 1.96, is added in quadrature to their (conditional, threshold held)
standard errors.

Below :mod:`aeropend_core.diagnosis.compare`, which hands in the refit (as for :mod:`map_profile`).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

#: Chi-square(1) quantile bounding the profile interval, and the normal quantile of the same level (its 1σ).
PROFILE_CHI2 = 3.841
PROFILE_Z = 1.960
#: First step [V] away from the estimate, the factor of each next step, and the bisections of a crossing.
FIRST_STEP = 0.04
STEP_FACTOR = 2.0
BISECTIONS = 2
#: Smallest step [V] tried inward: below it the level-spacing rule (or the refit's own resolution) bounds the ±.
SMALLEST_STEP = 0.0025
#: Residual evaluations of each warm-started refit (the full fit's default is 60).
REFIT_ITERATIONS = 30


def profile_statistic(rms: float, best_rms: float, effective: float) -> float:
    """Likelihood-ratio statistic [-] of a fit with training RMS `rms` [rad] against the best one's `best_rms` [rad],
    `effective` independent residuals (Gaussian errors of unknown variance). Infinite for a failed fit."""
    if not (math.isfinite(rms) and rms > 0 and best_rms > 0):
        return math.inf
    return max(float(effective * math.log(rms ** 2 / best_rms ** 2)), 0.0)


def _crossing(refit: Callable, threshold: float, bound: float, direction: float, best_rms: float,
              effective: float, limit: float) -> tuple[float, object | None, float]:
    """Distance [V] from `threshold` to where the statistic reaches `limit` going `direction` (+1/-1), at most to
    `bound`, and a converged fit near the crossing (the nearest inside it, else the nearest beyond it; None if
    neither converged) with its distance [V].

    Steps of :data:`FIRST_STEP`, doubled outward until the limit is passed (halved inward while the first is
    already past it, down to :data:`SMALLEST_STEP`), then bisected; the crossing is interpolated linearly in the
    square root of the statistic (exact for a smooth, quadratic profile, inside the bracket for a jagged one).
    """
    room = abs(bound - threshold)
    if room <= 0:
        return 0.0, None, 0.0

    def statistic(step: float):
        fit = refit(threshold + direction * step)
        return (profile_statistic(fit.residual_rms, best_rms, effective) if fit is not None else math.inf), fit

    step = min(FIRST_STEP, room)
    value, fit = statistic(step)
    inside, inside_value, inside_fit = 0.0, 0.0, None
    if value >= limit:
        while step / STEP_FACTOR >= SMALLEST_STEP:
            smaller, smaller_fit = statistic(step / STEP_FACTOR)
            if smaller < limit:
                inside, inside_value, inside_fit = step / STEP_FACTOR, smaller, smaller_fit
                break
            step, value, fit = step / STEP_FACTOR, smaller, smaller_fit
    else:
        while value < limit:
            inside, inside_value, inside_fit = step, value, fit
            if step >= room:
                return room, fit, room
            step = min(step * STEP_FACTOR, room)
            value, fit = statistic(step)
    outside, outside_value, outside_fit = step, value, fit
    for _ in range(BISECTIONS):
        middle = 0.5 * (inside + outside)
        value, fit = statistic(middle)
        if value >= limit:
            outside, outside_value, outside_fit = middle, value, fit
        else:
            inside, inside_value, inside_fit = middle, value, fit
    # the parameters are read from a fit that converged (a finite statistic), the nearer one inside first
    nearest = ((inside_fit, inside) if inside_fit is not None else
               (outside_fit, outside) if math.isfinite(outside_value) else (None, 0.0))
    if not math.isfinite(outside_value):
        return outside, *nearest
    low, high, target = math.sqrt(inside_value), math.sqrt(outside_value), math.sqrt(limit)
    share = (target - low) / (high - low) if high > low else 1.0
    return inside + min(max(share, 0.0), 1.0) * (outside - inside), *nearest


def threshold_profile(refit: Callable, fit, gate: str, lower: float, upper: float,
                      ranking: Sequence[tuple[float, float]] = ()) -> dict:
    """The profile interval of `fit`'s threshold `gate` [V] and what it means for every parameter's 1σ.

    Parameters
    ----------
    refit : callable
        ``refit(threshold [V]) -> OutputErrorFit or None``: the training fit with the threshold held there.
    fit : OutputErrorFit
        The best fit (its ``residual_rms`` [rad], ``effective_samples`` [-], ``parameters`` [SI]).
    gate : str
        The threshold parameter's name.
    lower, upper : float [V]
        The threshold's range (0 V and the top of the input: beyond, the data cannot bound it).
    ranking : sequence of (threshold [V], training RMS [rad])
        Thresholds simulated once each before the fit (other parameters not refitted: an RMS at or above the
        profile's). One whose statistic stays below the limit is inside the interval however far it lies: the
        refits step outward from the estimate and see only its basin (second-rig seed 42002: 0 V for 0.73 V).

    Returns
    -------
    dict
        ``interval`` (low, high) [V] where the statistic stays below :data:`PROFILE_CHI2`, ``sigma`` [V] (larger
        distance / 1.96), ``spread`` {parameter: its larger shift to an end of the interval / 1.96} [SI], and
        ``refits`` [-].
    """
    threshold = float(fit.parameters[gate])
    effective = max(float(getattr(fit, 'effective_samples', 0.0) or fit.n_residuals), 2.0)
    calls = []

    def counted(value: float):
        calls.append(value)
        try:
            return refit(float(value))
        except (ValueError, FloatingPointError, np.linalg.LinAlgError):
            return None

    # The reference is the same warm-started refit at the estimate itself when it ends higher than the best fit: a
    # refit that stops short of the optimum would otherwise read as a rise of the profile (seed 601 of
    # bench/dead_zone_sigma.py, 33 dB: 0.3 mV for an error of 1.4 mV).
    again = counted(threshold)
    reference = max(fit.residual_rms, again.residual_rms if again is not None and math.isfinite(again.residual_rms)
                    else 0.0)
    sides = [_crossing(counted, threshold, bound, direction, reference, effective, PROFILE_CHI2)
             for bound, direction in ((lower, -1.0), (upper, +1.0))]
    (below, _, _), (above, _, _) = sides
    for value, rms in ranking:
        if profile_statistic(rms, reference, effective) < PROFILE_CHI2:
            below, above = max(below, threshold - value), max(above, value - threshold)
    spread = {}
    for name, value in fit.parameters.items():
        if name == gate:
            continue
        # the shift at the point fitted, scaled linearly back to the crossing
        shifts = [abs(other.parameters[name] - value) * crossing / distance
                  for crossing, other, distance in sides
                  if other is not None and distance > 0 and math.isfinite(other.parameters.get(name, math.nan))]
        if shifts:
            spread[name] = max(shifts) / PROFILE_Z
    return {'interval': (threshold - below, threshold + above), 'sigma': max(below, above) / PROFILE_Z,
            'spread': spread, 'refits': len(calls)}


def once_per_gate_pattern(refit: Callable, gate_signal: np.ndarray, gate: str) -> Callable:
    """`refit` run once per pattern of gated samples: the threshold [V] enters the fit only through the comparisons
    ``gate_signal < threshold`` (the simulation and sensitivity kernels), so two thresholds that gate the same
    samples of `gate_signal` [V] give the same fit from the same start, bit for bit. The later one is the first
    one's fit with `gate` set to it. Between two held input levels every threshold gates the same samples.
    """
    fits = {}

    def cached(threshold: float):
        key = np.packbits(np.asarray(gate_signal) < threshold).tobytes()
        if key not in fits:
            fits[key] = refit(threshold)
            return fits[key]
        fit = fits[key]
        return None if fit is None else replace(fit, parameters={**fit.parameters, gate: float(threshold)})
    return cached


__all__ = ['PROFILE_CHI2', 'once_per_gate_pattern', 'profile_statistic', 'threshold_profile']
