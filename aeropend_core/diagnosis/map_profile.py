"""Profile the reduced model's motor map (time constant T, curvature q) for a record without a usable current.

The motor map (:func:`aeropend_core.signals.reduced.motor_map`) turns the held Va into the thrust voltage e; the
pendulum's parameters are then fitted by output error on e as with the motor observer (R = 0). T and q enter the
thrust only through e, which the compiled kernel takes as an input, so they are profiled: a coarse grid, then a
Nelder-Mead search on the training residual of the nominal model (log T, q). Their 1σ are conditional ones from the
profile's curvature (residual sum of squares around the optimum, scaled by the residuals' effective count), and
are reported as such; the pendulum parameters' standard errors are conditional on the map.

Below :mod:`aeropend_core.diagnosis.compare` (whose ``prepare`` profiles the map of a record without a current):
the fit is passed in. The reduced model's identification and its re-check in the search are
:mod:`aeropend_core.diagnosis.reduced_fit`.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.optimize import minimize

from aeropend_core.diagnosis.output_error import SegmentedData
from aeropend_core.errors import InsufficientDataError
from aeropend_core.model.effects import CATALOG, MEASUREMENT
from aeropend_core.signals.preprocess import step_switches
from aeropend_core.signals.reduced import motor_map

#: Coarse grid of the motor time constant [s] and the map curvature [1/V] before the local search.
TIME_CONSTANT_GRID = (0.05, 0.15, 0.45)
CURVATURE_GRID = (0.0, 0.8)
#: Bounds of the profiled values: T [s], q [1/V].
TIME_CONSTANT_BOUNDS = (0.005, 3.0)
CURVATURE_BOUNDS = (0.0, 10.0)
#: The profile uses at most this much of the training part [s] (a long record's map is the same throughout).
PROFILE_SECONDS = 45.0
#: Effects always free while the map is profiled for the nominal model: an angle offset reshapes the static
#: thrust-to-angle curve as the map's curvature does, so a map profiled without it absorbs an offset (seed 2 of
#: bench/reduced_model.py: T 0.51 s, q 2.4 1/V, and the offset not named); it is ~0 when there is none.
PROFILE_NUISANCE = tuple(name for name, effect in CATALOG.items() if effect.builtin and effect.kind == MEASUREMENT)
#: Nelder-Mead evaluations after the grid, and the resolution it stops at (log T, q [1/V]); the resolution's
#: uniform spread (resolution/sqrt(12)) is added to the profile's 1σ.
SEARCH_EVALUATIONS = 30
SEARCH_RESOLUTION = 0.01


def _subset(data: SegmentedData, seconds: float) -> SegmentedData:
    """The first training segments, about `seconds` [s] of them (all when shorter)."""
    chosen, total = [], 0.0
    for start, stop in data.segments:
        chosen.append((start, stop))
        total += (stop - start) * data.sample_time
        if total >= seconds:
            break
    return dataclasses.replace(data, segments=chosen, voltage_ensemble=None)


def with_map(prep, time_constant: float, curvature: float):
    """`prep` with its thrust voltage from the motor map (T [s], q [1/V]) and no current."""
    switch = step_switches(prep.step_indices, len(prep.gate_voltage), prep.sample_time)
    voltage = motor_map(prep.gate_voltage, time_constant, curvature, prep.sample_time, switch)
    return dataclasses.replace(prep, voltage=voltage, current=np.zeros_like(voltage), reduced=True,
                               voltage_ensemble=None)


def profile_motor_map(prep, fit_model, effects=(), start=None, fixed=None):
    """Profile T and q of the reduced model on `prep`'s training part; return `prep` driven by the best map.

    Parameters
    ----------
    prep : PreparedRecord
        A record prepared without a current (``prep.reduced``); its ``gate_voltage`` is the held Va [V].
    fit_model : callable [-]
        The output-error fit of a model to a prepared record (:func:`aeropend_core.diagnosis.compare.fit_model`),
        passed in: :func:`aeropend_core.diagnosis.compare.prepare` profiles the map, so this module sits below it.
    effects : sequence of str [-]
        Effects in the model the map is profiled with (default: the nominal model), plus
        :data:`PROFILE_NUISANCE` (free, not reported). With a map already profiled
        (``prep.motor_map``) the search starts from it, without the grid.
    start, fixed : dict of str -> float, optional [SI]
        Starting and held parameter values of the fits (as :func:`aeropend_core.diagnosis.compare.fit_model`).

    Returns
    -------
    PreparedRecord
        Thrust voltage from the profiled map; ``motor_map`` holds ``motor_time_constant`` [s],
        ``voltage_map_curvature`` [1/V], their conditional standard errors and the profile's residual [rad].
    """
    def rss(x: np.ndarray) -> float:
        time_constant = float(np.clip(math.exp(x[0]), *TIME_CONSTANT_BOUNDS))
        curvature = float(np.clip(x[1], *CURVATURE_BOUNDS))
        trial = with_map(prep, time_constant, curvature)
        data = _subset(trial.train, PROFILE_SECONDS)
        try:
            fit = fit_model(trial, model, start=warm or start, data=data, fixed=fixed, search_basins=not warm)
        except (InsufficientDataError, ValueError, FloatingPointError, np.linalg.LinAlgError):
            return math.inf
        cache[tuple(np.round(x, 12))] = fit
        return float(fit.residual_rms ** 2 * fit.n_residuals) if math.isfinite(fit.residual_rms) else math.inf

    model = tuple(effects) + tuple(n for n in PROFILE_NUISANCE if n not in effects and n not in (fixed or {}))
    cache: dict = {}
    warm: dict[str, float] = {}
    grid = [np.array([math.log(t), q]) for t in TIME_CONSTANT_GRID for q in CURVATURE_GRID]
    if prep.motor_map:
        grid = [np.array([math.log(prep.motor_map['motor_time_constant']), prep.motor_map['voltage_map_curvature']])]
    scores = [rss(x) for x in grid]
    best = grid[int(np.argmin(scores))]
    # The grid's fits search every basin of an offset or a lag; the local search around the best grid point moves
    # the map a little, so each of its fits starts from that point's fit, in its basin (a basin search per
    # evaluation was three quarters of a reduced diagnosis' time).
    best_fit = cache.get(tuple(np.round(best, 12)))
    warm = dict(best_fit.parameters) if best_fit is not None else {}
    result = minimize(rss, best, method='Nelder-Mead',
                      options={'maxfev': SEARCH_EVALUATIONS, 'xatol': SEARCH_RESOLUTION, 'fatol': 1e-6 * min(scores)})
    x = result.x if result.fun <= min(scores) else best
    x = np.array([np.clip(x[0], *np.log(TIME_CONSTANT_BOUNDS)), np.clip(x[1], *CURVATURE_BOUNDS)])
    value = rss(x)
    fit = cache.get(tuple(np.round(x, 12)))
    errors = _profile_errors(rss, x, value, fit)
    time_constant, curvature = float(math.exp(x[0])), float(x[1])
    mapped = with_map(prep, time_constant, curvature)
    mapped.motor_map = {
        'motor_time_constant': time_constant, 'voltage_map_curvature': curvature,
        'standard_errors': {'motor_time_constant': time_constant * errors[0], 'voltage_map_curvature': errors[1]},
        'residual_rms': float(fit.residual_rms) if fit is not None else float('nan'),
        'at_bound': [name for name, v, (lo, hi) in (('motor_time_constant', time_constant, TIME_CONSTANT_BOUNDS),
                                                      ('voltage_map_curvature', curvature, CURVATURE_BOUNDS))
                     if not lo * 1.01 < v < hi * 0.99 and not (name == 'voltage_map_curvature' and v <= 0.0)],
    }
    return mapped


def _profile_errors(rss, x: np.ndarray, value: float, fit) -> tuple[float, float]:
    """Conditional 1σ of (log T, q) from the curvature of the residual sum of squares along each axis."""
    if fit is None or not math.isfinite(value) or value <= 0:
        return float('nan'), float('nan')
    effective = max(float(getattr(fit, 'effective_samples', fit.n_residuals) or fit.n_residuals), 10.0)
    variance = value / fit.n_residuals * fit.n_residuals / effective    # residual variance, correlated residuals
    out = []
    for axis, step in ((0, 0.05), (1, 0.05)):
        up, down = x.copy(), x.copy()
        up[axis] += step
        down[axis] = max(down[axis] - step, 0.0) if axis == 1 else down[axis] - step
        h = 0.5 * (up[axis] - down[axis])
        curvature = (rss(up) - 2 * value + rss(down)) / h ** 2 if h > 0 else float('nan')
        profile = 2 * variance / curvature if curvature > 0 else float('inf')
        out.append(math.sqrt(profile + SEARCH_RESOLUTION ** 2 / 12.0))
    return out[0], out[1]


__all__ = ['PROFILE_NUISANCE', 'profile_motor_map', 'with_map']
