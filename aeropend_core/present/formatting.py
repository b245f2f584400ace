"""Shared pieces of the diagnosis report: number formatting with units, colours, decimation of traces to a plot's
pixel columns and smoothing (the plots themselves: :mod:`aeropend_core.present.svgplot`).
"""
from __future__ import annotations


import html
import math
from collections.abc import Iterable, Sequence

import numpy as np

from aeropend_core.diagnosis.compare import Comparison, excess_error
from aeropend_core.diagnosis.candidates import Candidate
from aeropend_core.model.effects import find_parameter
from aeropend_core.model.names import NOMINAL_PARAMETERS
from aeropend_core.present.result_types import DiagnosisLike



#: Pixel columns of a full-width plot (about the SVG's plotting width, :mod:`aeropend_core.present.svgplot`): a line
#: keeps its min and max per column (:func:`envelope`).
PIXEL_COLUMNS = 1000


#: Width of the running mean that shows the error's structure under the noise [s].
SMOOTHING_SECONDS = 0.1


MRAD_PER_DEGREE = math.pi / 180 * 1e3


# Colours: measured data grey, the model as given blue, the best candidate green, the model before red.
MEASURED, CURRENT, CANDIDATE, BEFORE = '#555555', '#1f63b4', '#1a9641', '#d7301f'


HELDOUT_SHADE, WORST_SHADE, NOISE_SHADE = '#fff3c4', '#f4a582', '#d9d9d9'


VERDICT_TITLES = {
    'effect_found': 'Missing effect found: {missing}',
    'nothing_missing': 'Nothing significant is missing',
    'confounded': 'Confounded: the data cannot tell which effect is missing',
    'unexplained': 'Unexplained error: no catalog effect explains it',
    'term_discovered': 'A term outside the catalog explains the error',
    'drift': 'Parameter drift',
    'model_does_not_fit': 'The model does not fit this data: a parameter fails a physical check',
}


VERDICT_CLASSES = {'effect_found': 'found', 'nothing_missing': 'ok', 'confounded': 'warn',
                   'unexplained': 'bad', 'term_discovered': 'found', 'drift': 'warn', 'model_does_not_fit': 'bad'}


def _esc(value: object) -> str:
    return html.escape(str(value), quote=True)


def _num(value: float | None, digits: int = 2, scale: float = 1.0, suffix: str = '') -> str:
    """A number for the page, or an em dash when missing or not finite."""
    if value is None or not np.isfinite(value):
        return '&mdash;'
    return f'{value * scale:.{digits}f}{suffix}'


def _sig(value: float | None, digits: int = 4) -> str:
    if value is None or not np.isfinite(value):
        return '&mdash;'
    return f'{value:.{digits}g}'


def _mrad(value: float | None, digits: int = 2) -> str:
    return _num(value, digits, 1e3, '&nbsp;mrad')


def _unit_and_meaning(parameter: str) -> tuple[str, str]:
    """SI unit and meaning of a model parameter (nominal or from the effect catalog, user effects included)."""
    if parameter in NOMINAL_PARAMETERS:
        return NOMINAL_PARAMETERS[parameter]
    found = find_parameter(parameter)
    if found is None:
        return '', ''
    effect, entry = found
    return entry.unit, f'{entry.description} ({effect.name})'


def _excess(comparison: Comparison) -> float:
    return excess_error(comparison.rms_error, comparison.noise_rms)


def envelope(time: np.ndarray, values: np.ndarray, breaks: Iterable[int] = (),
             columns: int = PIXEL_COLUMNS) -> tuple[np.ndarray, np.ndarray]:
    """The finite samples of `values` reduced to what a plot `columns` pixels wide can show.

    Each piece between `breaks` (segment restarts, where a NaN separates the lines) is cut into about
    ``columns * piece / all`` equal bins of samples, and each bin keeps its smallest and its largest sample in time
    order (a min/max envelope: a spike or a noise band looks the same as with every sample drawn). A piece with no
    more than two samples per bin is kept whole.

    Parameters
    ----------
    time : ndarray, shape (n,) [s]
        Sample times.
    values : ndarray, shape (n,) [any unit]
        The trace; NaN samples are skipped (not drawn).
    breaks : iterable of int [-]
        Sample indices where a new line starts (a NaN is put before them).
    columns : int [-]
        Width of the plot in pixel columns (bins over the whole trace).

    Returns
    -------
    tuple of ndarray
        (time [s], values [unit of `values`]), float, at most about ``2 * columns`` points plus one NaN per break.
    """
    index = np.flatnonzero(np.isfinite(values))
    if index.size == 0:
        return np.zeros(0), np.zeros(0)
    cuts = np.searchsorted(index, sorted(set(breaks)))
    cuts = cuts[(cuts > 0) & (cuts < index.size)]
    pieces = np.split(index, cuts)
    kept = []
    for piece in pieces:
        bins = max(1, int(round(columns * piece.size / index.size)))
        width = math.ceil(piece.size / bins)
        if width <= 2:
            kept.append(piece)
        else:
            padded = np.concatenate([piece, np.full((-piece.size) % width, piece[-1])]).reshape(-1, width)
            samples = values[padded]
            low = padded[np.arange(len(padded)), np.argmin(samples, axis=1)]
            high = padded[np.arange(len(padded)), np.argmax(samples, axis=1)]
            kept.append(np.unique(np.concatenate([low, high])))
        kept.append(np.array([-1]))                     # a NaN between pieces
    chosen = np.concatenate(kept[:-1])
    gap = chosen < 0
    t = np.where(gap, np.nan, time[np.maximum(chosen, 0)].astype(float))
    v = np.where(gap, np.nan, values[np.maximum(chosen, 0)].astype(float))
    return t, v


def _finite_trace(time: np.ndarray, values: np.ndarray, breaks: Iterable[int] = ()) -> tuple[np.ndarray, np.ndarray]:
    """The finite samples of `values` decimated for plotting (:func:`envelope`), NaN gaps at `breaks`."""
    return envelope(time, values, breaks)


def _running_mean(values: np.ndarray, width: int) -> np.ndarray:
    """Centred running mean over the finite samples of `values` (NaN stays NaN)."""
    out = np.full(values.shape, np.nan)
    index = np.flatnonzero(np.isfinite(values))
    if index.size == 0:
        return out
    width = max(1, min(width, index.size))
    kernel = np.ones(width) / width
    out[index] = np.convolve(values[index], kernel, mode='same')
    return out


def _best_candidate(diagnosis: DiagnosisLike) -> Candidate | None:
    for candidate in diagnosis.candidates:
        if candidate.comparison is not None:
            return candidate
    return None


def _model_name(effects: Sequence[str]) -> str:
    return 'nominal' + ''.join(f' + {e}' for e in effects)
