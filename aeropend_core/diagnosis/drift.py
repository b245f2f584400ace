"""Drift of the nominal parameters: fitted per stretch of the record and tested for a trend in time.

A parameter that changes during a recording (the thrust gain falls as the supply sags or the motor warms, the
pivot's damping changes as the bearing warms) is no missing *effect*: the model is right but its numbers move.
:func:`drift_test` refits the thrust gain and the damping on consecutive stretches of ~``STRETCH_SECONDS`` (gravity,
the armature resistance and the effects held at the whole-record values) and :func:`trend_test` fits a straight
line to each parameter against time. The line's slope is judged against the scatter of the stretches around it
(Student t with m - 2 degrees of freedom, so a stretch-to-stretch wobble that is not a trend does not count): a
parameter **drifts** when the trend is significant at ``ALPHA`` (two-sided) and changes it by more than
``MIN_CHANGE`` over the record. The online analysis applies the same :func:`trend_test` to its windows' values
(``aeropend monitor``).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import special

from aeropend_core.diagnosis.output_error import SegmentedData, fit_output_error
from aeropend_core.parallel import map_in_order, workers_for
from aeropend_core.errors import InsufficientDataError
from aeropend_core.model.names import NOMINAL_PARAMETERS

#: Length of the stretches fitted separately [s].
STRETCH_SECONDS = 5.0
#: Significance level of the trend (two-sided).
ALPHA = 1e-3
#: Smallest change over the record, as a fraction of the mean value, reported as drift.
MIN_CHANGE = 0.05
#: Parameters refitted per stretch.
DRIFT_PARAMETERS = ('thrust_gain', 'damping')
#: Likely causes, per parameter.
CAUSES = {
    'thrust_gain': 'supply voltage sag (battery or bench supply under load), motor or driver heating (armature '
                   'resistance rises), propeller damage or a loosening mount',
    'damping': 'the pivot bearing warming up or its lubricant spreading, air flow around the rig changing',
    'gravity_stiffness': 'the rod or motor pod shifting on its mount',
}


def trend_test(times: np.ndarray, values: np.ndarray, name: str = '') -> dict:
    """Straight-line trend of `values` against `times` [s], judged against the scatter around the line.

    Returns
    -------
    dict
        ``parameter``, ``slope`` [unit/s], ``t_statistic``, ``p_value`` (two-sided), ``change`` (fitted change over
        the span, fraction of the mean), ``span`` [s], ``stretches`` (m), ``start``/``end`` (fitted values at the
        first and last time) and ``drifting`` (significant at ``ALPHA`` and larger than ``MIN_CHANGE``).
    """
    times = np.asarray(times, dtype=float)
    values = np.asarray(values, dtype=float)
    keep = np.isfinite(times) & np.isfinite(values)
    times, values = times[keep], values[keep]
    m = times.size
    row = {'parameter': name, 'stretches': int(m), 'slope': float('nan'), 't_statistic': float('nan'),
           'p_value': float('nan'), 'change': float('nan'), 'span': float(np.ptp(times)) if m else 0.0,
           'start': float('nan'), 'end': float('nan'), 'drifting': False}
    if m < 4:
        return row
    centred = times - times.mean()
    sxx = float(np.dot(centred, centred))
    if sxx <= 0:
        return row
    slope = float(np.dot(centred, values - values.mean()) / sxx)
    intercept = float(values.mean())
    residual = values - intercept - slope * centred
    scatter = math.sqrt(float(np.dot(residual, residual)) / (m - 2))
    # a floor on the scatter: 0.1 % of the value (numbers this close are the same fit)
    scatter = max(scatter, 1e-3 * abs(intercept), 1e-12)
    t_statistic = slope / (scatter / math.sqrt(sxx))
    # Student's t survival function as scipy.stats.t.sf computes it (special.stdtr(df, -t)), without importing
    # scipy.stats (about 1 s of a loaded machine's start-up, issue 41)
    p_value = float(2.0 * special.stdtr(m - 2, -abs(t_statistic)))
    start = intercept + slope * (times.min() - times.mean())
    end = intercept + slope * (times.max() - times.mean())
    change = (end - start) / abs(intercept) if intercept else float('nan')
    row.update(slope=slope, t_statistic=float(t_statistic), p_value=p_value, change=float(change), start=float(start),
               end=float(end), drifting=bool(p_value < ALPHA and abs(change) > MIN_CHANGE))
    return row


def drift_test(prep, comparison) -> list[dict]:
    """Fit :data:`DRIFT_PARAMETERS` on consecutive stretches of the record and test each for a trend.

    Parameters
    ----------
    prep : PreparedRecord
    comparison : Comparison
        The whole-record model; its other parameters are held.

    Returns
    -------
    list of dict
        One :func:`trend_test` row per parameter, with ``values`` and ``times`` of the stretches added.
    """
    n = len(prep.time)
    width = int(round(STRETCH_SECONDS / prep.sample_time))
    if n < 4 * width:
        raise InsufficientDataError(f'the record holds fewer than 4 stretches of {STRETCH_SECONDS:g} s')
    bounds = [(start, min(start + width, n)) for start in range(0, n - width // 2, width)]
    if bounds[-1][1] - bounds[-1][0] < width // 2:
        bounds[-2:] = [(bounds[-2][0], bounds[-1][1])]
    valid = getattr(prep, 'valid', None)
    structure = comparison.fit.structure
    parameters = dict(comparison.parameters)
    held = {k: v for k, v in parameters.items() if k not in DRIFT_PARAMETERS}
    times, fitted = [], {name: [] for name in DRIFT_PARAMETERS}
    stretches = [(start, stop, pieces) for start, stop in bounds if (pieces := _clean_pieces(start, stop, valid))]

    def fit_stretch(stretch):
        # the parameters are read, not their sigma; the stretches are independent: side by side on the cores
        data = SegmentedData(prep.voltage, prep.current, prep.angle, stretch[2], prep.sample_time, prep.gate_voltage,
                             valid)
        return fit_output_error(data, structure, parameters, fixed=held, max_iterations=20, covariance=False)
    for (start, stop, _), fit in zip(stretches, map_in_order(fit_stretch, stretches, workers_for(n))):
        times.append(float(prep.time[(start + stop - 1) // 2]))
        for name in DRIFT_PARAMETERS:
            fitted[name].append(fit.parameters[name])
    rows = []
    for name in DRIFT_PARAMETERS:
        row = trend_test(np.array(times), np.array(fitted[name]), name)
        row['unit'] = NOMINAL_PARAMETERS[name][0]
        row['times'] = times
        row['values'] = fitted[name]
        rows.append(row)
    return rows


def _clean_pieces(start: int, stop: int, valid: np.ndarray | None, shortest: int = 40) -> list[tuple[int, int]]:
    """[start, stop) split at samples that are not valid (filled gaps), pieces shorter than `shortest` dropped."""
    if valid is None:
        return [(start, stop)]
    pieces, inside = [], None
    for k in range(start, stop + 1):
        ok = k < stop and bool(valid[k])
        if ok and inside is None:
            inside = k
        elif not ok and inside is not None:
            if k - inside >= shortest:
                pieces.append((inside, k))
            inside = None
    return pieces


def drift_message(rows: list[dict], comparison=None) -> str:
    """The verdict sentence, e.g. "parameter drift: thrust gain -15 % over 120 s (...); likely causes: ..."."""
    parts, causes = [], []
    for row in rows:
        label = row['parameter'].replace('_', ' ')
        parts.append(f'{label} {row["change"] * 100:+.0f} % over {row["span"]:.0f} s ({row["start"]:.4g} -> '
                     f'{row["end"]:.4g} {row.get("unit", "")}, trend t = {row["t_statistic"]:+.1f} over '
                     f'{row["stretches"]} stretches of {STRETCH_SECONDS:g} s)')
        causes.append(f'{label}: {CAUSES.get(row["parameter"], "unknown")}')
    return ('parameter drift: ' + '; '.join(parts) + '. Likely causes: ' + '; '.join(causes)
            + '. A drifting parameter is no missing effect: fit shorter windows (the online identification) or '
              'remove the cause.')


__all__ = ['trend_test', 'drift_test', 'drift_message', 'STRETCH_SECONDS', 'ALPHA', 'MIN_CHANGE']
