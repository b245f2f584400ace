"""The global answer for a nonlinear parameter (a thrust lag's time constant, an angle offset): searched over its
whole range, a second basin reported.

The same search serves an angle offset (its profile runs over :data:`OFFSET_GRID`): the equation-error start values
ignore the offset. (It does not rescue bench/sigma_coverage.py seed 31027, a staircase record with a -73 mrad
offset whose fit collapses to gravity_stiffness 0.81 +- 0.28, truth 104, with the offset itself right: that
collapse is in the inertia scale, not in the offset, and is left open.)

A thrust lag's time constant enters the output-error fit nonlinearly, and the fit's cost has more than one basin:
a short lag with a low gravity stiffness and thrust gain can mimic a long lag with the true ones over a record of
steps (seen: truth 0.15 s, fit 0.030 +- 0.005 s with gravity_stiffness 70 +- 4 instead of 148). A local optimiser
started at one point stops in whichever basin it starts in, and its standard errors describe only that basin.

:func:`search_lag_basins` therefore profiles the time constant cheaply before believing the local fit:

1. an equation-error profile over a log grid of time constants (:data:`LAG_GRID`, 5 ms to 2 s): for each, the
   lagged thrust regressor is built from the thrust input and regressed with sin y and the rate on the angle's
   second derivative (all through the same Savitzky-Golay smoother), one linear least-squares solve each;
2. every local minimum of that profile whose time constant differs from the local fit's by more than
   :data:`DISTINCT_RATIO` starts another output-error fit (at most :data:`EXTRA_STARTS`), from that profile
   point's gravity stiffness, damping and thrust gain;
3. the fit with the lowest cost is the answer; another basin whose cost is within :data:`AMBIGUITY_BIC` of it (in
   the BIC scale with the effective number of independent residuals) is an **ambiguity**: both basins are kept in
   ``fit.extra['ambiguity']`` and every parameter's standard error is widened to the spread of the two basins
   (the standard deviation of an equal mixture: sqrt(sigma^2 + (difference / 2)^2)), never hidden behind the
   winner's local sigma.
"""
from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from aeropend_core.signals.filters import first_order_lag, savgol_filter

#: Time constants [s] of the equation-error profile (log grid over the catalog's useful range).
LAG_GRID = np.geomspace(0.005, 2.0, 36)
#: Two time constants further apart than this ratio belong to different basins.
DISTINCT_RATIO = 1.5
#: At most this many extra output-error fits from the profile's minima.
EXTRA_STARTS = 2
#: A second basin whose cost is within this of the best (n_eff ln(rss2 / rss1), the BIC scale with the same
#: number of parameters) fits nearly as well: the record does not decide between them.
AMBIGUITY_BIC = 10.0


#: The profile's best point also starts a fit when the local fit's gravity stiffness is this factor away from it.
SCALE_RATIO = 1.5
#: Angle offsets [rad] of the equation-error profile (the catalog's bounds, 10 mrad apart).
OFFSET_GRID = np.linspace(-0.5, 0.5, 101)
#: Two offsets further apart than this [rad] belong to different basins.
DISTINCT_OFFSET = 0.02
#: The profiled kernel kinds: grid, and whether basins are told apart on a log scale (time constants).
PROFILED = {'thrust_lag_time': (LAG_GRID, True), 'measured_offset': (OFFSET_GRID, False)}


def lag_profile(prep, values: dict[str, float], grid: np.ndarray = LAG_GRID,
                kind: str = 'thrust_lag_time') -> tuple[np.ndarray, np.ndarray]:
    """Equation-error profile over a nonlinear parameter (a thrust lag's time constant or an angle offset).

    Parameters
    ----------
    prep : PreparedRecord
        The conditioned record (:func:`aeropend_core.diagnosis.compare.prepare`).
    values : dict of str -> float [SI]
        Current parameter values; ``armature_resistance`` [ohm] forms the thrust input e = Va - R Ia.
    grid : ndarray [s or rad]
        Values to try: time constants [s] (``kind='thrust_lag_time'``) or angle offsets [rad]
        (``kind='measured_offset'``: the true angle is the measured one less the offset).
    kind : str [-]
        Which kernel kind the grid is of.

    Returns
    -------
    rss : ndarray, shape (len(grid),)
        Residual sum of squares of the angle's second derivative [rad^2/s^4] at each grid value.
    coefficients : ndarray, shape (len(grid), 3)
        gravity_stiffness [1/s^2], damping [1/s] and thrust_gain [rad/s^2/V^2] fitted at each.
    """
    window = prep.smoothing_window
    stop = prep.split
    y = prep.smoothed_angle[:stop]
    dy = prep.smoothed_rate[:stop]
    ddy = savgol_filter(prep.angle[:stop], window, 3, deriv=2, delta=prep.sample_time)
    e = prep.voltage[:stop] - values.get('armature_resistance', 0.0) * prep.current[:stop]
    thrust = e * np.abs(e)
    keep = slice(window, stop - window)
    rss = np.full(len(grid), np.inf)
    coefficients = np.full((len(grid), 3), np.nan)
    for i, value in enumerate(grid):
        if kind == 'thrust_lag_time':
            decay = math.exp(-prep.sample_time / value)
            lagged = first_order_lag(thrust, decay)
            regressors = np.column_stack([-np.sin(y), -dy, savgol_filter(lagged, window, 3)])[keep]
        else:
            regressors = np.column_stack([-np.sin(y - value), -dy, thrust])[keep]
        solution, *_ = np.linalg.lstsq(regressors, ddy[keep], rcond=None)
        rss[i] = float(np.sum((regressors @ solution - ddy[keep]) ** 2))
        coefficients[i] = solution
    return rss, coefficients


def _local_minima(rss: np.ndarray) -> np.ndarray:
    """Indices of the local minima of a profile, lowest first."""
    finite = np.where(np.isfinite(rss), rss, np.inf)
    padded = np.concatenate(([np.inf], finite, [np.inf]))
    minima = np.flatnonzero((padded[1:-1] <= padded[:-2]) & (padded[1:-1] < padded[2:]))
    return minima[np.argsort(finite[minima])]


def search_lag_basins(prep, fit_from: Callable, values: dict[str, float], parameter: str, local_fit,
                      kind: str = 'thrust_lag_time'):
    """Refit from the equation-error profile's other basins and keep the best; report a near-equal second basin.

    Parameters
    ----------
    prep : PreparedRecord
        The conditioned record.
    fit_from : callable
        ``fit_from(start_values) -> OutputErrorFit``: the output-error fit of the same structure and data.
    values : dict of str -> float [SI]
        The start values of the local fit (other parameters keep them).
    parameter : str [-]
        The profiled parameter's name (the lag's time constant, the measured offset).
    local_fit : OutputErrorFit
        The fit from the default start.
    kind : str [-]
        Its kernel kind, a key of :data:`PROFILED`.

    Returns
    -------
    OutputErrorFit
        The best fit found; with ``extra['ambiguity']`` when another basin fits nearly as well, and
        ``extra['basins']`` listing every basin tried.
    """
    grid, logarithmic = PROFILED[kind]

    def apart(a: float, b: float) -> bool:
        if logarithmic:
            return abs(math.log(max(a, 1e-9) / max(b, 1e-9))) >= math.log(DISTINCT_RATIO)
        return abs(a - b) >= DISTINCT_OFFSET

    rss, coefficients = lag_profile(prep, values, grid, kind)
    starts = []
    tried = [local_fit.parameters[parameter]]
    for rank, index in enumerate(_local_minima(rss)):
        if len(starts) >= EXTRA_STARTS:
            break
        value = float(grid[index])
        gravity, damping, gain = coefficients[index]
        if not (gravity > 0 and gain > 0):
            continue
        # the profile's best point also starts a fit when the local fit agrees on this parameter but not on the
        # scale of the linear ones (a collapse to a tiny gravity stiffness and thrust gain with the right offset)
        scale_apart = rank == 0 and abs(math.log(max(local_fit.parameters['gravity_stiffness'], 1e-9) / gravity)) \
            > math.log(SCALE_RATIO)
        if not (scale_apart or all(apart(value, t) for t in tried)):
            continue
        start = {**values, parameter: value, 'gravity_stiffness': float(gravity),
                 'damping': float(max(damping, 0.1)), 'thrust_gain': float(gain)}
        tried.append(value)
        starts.append(start)
    from aeropend_core.parallel import map_in_order, workers_for  # the starts do not depend on the fits
    fits = [local_fit, *map_in_order(fit_from, starts, workers=workers_for(len(prep.angle)))]
    order = sorted(range(len(fits)), key=lambda i: fits[i].residual_rms)
    best = fits[order[0]]
    basins = []
    for i in order:
        if all(apart(fits[i].parameters[parameter], b.parameters[parameter]) for b in basins):
            basins.append(fits[i])
    best.extra['basins'] = [_basin_summary(f, best, parameter) for f in basins]
    best.extra['local_start'] = {parameter: local_fit.parameters[parameter], 'cost_gap': _cost_gap(local_fit, best)}
    if len(basins) > 1 and _cost_gap(basins[1], best) < AMBIGUITY_BIC:
        second = basins[1]
        unit = 's' if logarithmic else 'rad'
        best.extra['ambiguity'] = {
            'parameter': parameter,
            'basins': [_basin_summary(best, best, parameter), _basin_summary(second, best, parameter)],
            'note': (f'two basins fit nearly as well ({parameter} {best.parameters[parameter]:.3g} {unit} and '
                     f'{second.parameters[parameter]:.3g} {unit}, cost gap {_cost_gap(second, best):.1f} < '
                     f'{AMBIGUITY_BIC:g} on the BIC scale): this record does not decide between them; standard '
                     f'errors widened to cover both. Add zero-thrust rests longer than the motor spin-down and free '
                     f'decays to separate them.')}
        for name, sigma in list(best.standard_errors.items()):
            if name in second.parameters and math.isfinite(sigma):
                half = 0.5 * (best.parameters[name] - second.parameters[name])
                best.standard_errors[name] = math.sqrt(sigma ** 2 + half ** 2)
    return best


def _cost_gap(fit, best) -> float:
    """n_eff ln(rss_fit / rss_best): how much worse `fit` is on the BIC scale (0 for the best)."""
    return float(best.effective_samples * math.log(max(fit.residual_rms, 1e-300) ** 2
                                                   / max(best.residual_rms, 1e-300) ** 2))


def _basin_summary(fit, best, parameter: str) -> dict:
    return {'parameters': dict(fit.parameters), 'standard_errors': dict(fit.standard_errors),
            'residual_rms': fit.residual_rms, 'cost_gap': _cost_gap(fit, best), parameter: fit.parameters[parameter]}


__all__ = ['LAG_GRID', 'OFFSET_GRID', 'PROFILED', 'DISTINCT_RATIO', 'DISTINCT_OFFSET', 'EXTRA_STARTS', 'AMBIGUITY_BIC',
           'lag_profile', 'search_lag_basins']
