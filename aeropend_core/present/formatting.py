"""Shared pieces of the diagnosis report: number formatting with units, colours, PNG embedding of matplotlib
figures (object API on an Agg canvas), decimation and smoothing of traces.
"""
from __future__ import annotations

import base64
import html
import io
import math
from collections.abc import Iterable, Sequence

import numpy as np

from aeropend_core.diagnosis.compare import Comparison, excess_error
from aeropend_core.diagnosis.diagnose import (Candidate,
                                    Diagnosis)
from aeropend_core.model.effects import find_parameter
from aeropend_core.model.names import NOMINAL_PARAMETERS


#: Resolution of the embedded PNGs [dots per inch]; with the figure sizes below a page stays well under 2 MB.
DPI = 90


#: Most points drawn per line (lines are decimated by striding; the noise band stays visible).
MAX_POINTS = 3000


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
    'drift': 'Parameter drift',
    'model_does_not_fit': 'The model does not fit this data: a parameter fails a physical check',
}


VERDICT_CLASSES = {'effect_found': 'found', 'nothing_missing': 'ok', 'confounded': 'warn',
                   'unexplained': 'bad', 'drift': 'warn', 'model_does_not_fit': 'bad'}


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


def _png(figure) -> str:
    """Render a matplotlib Figure to a base64 PNG data URI."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(figure)
    buffer = io.BytesIO()
    figure.savefig(buffer, format='png', dpi=DPI)
    return 'data:image/png;base64,' + base64.b64encode(buffer.getvalue()).decode('ascii')


def _figure(width: float, height: float, **kwargs):
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), layout='constrained', **kwargs)


def _img(uri: str, alt: str) -> str:
    return f'<img src="{uri}" alt="{_esc(alt)}">'


def _stride(n: int) -> int:
    return max(1, math.ceil(n / MAX_POINTS))


def _finite_trace(time: np.ndarray, values: np.ndarray, breaks: Iterable[int] = ()) -> tuple[np.ndarray, np.ndarray]:
    """The finite samples of `values` decimated for plotting, with NaN gaps at `breaks` (segment restarts)."""
    index = np.flatnonzero(np.isfinite(values))
    if index.size == 0:
        return np.zeros(0), np.zeros(0)
    index = index[::_stride(index.size)]
    t, v = time[index].astype(float), values[index].astype(float)
    cuts = np.searchsorted(index, sorted(set(breaks)))
    cuts = cuts[(cuts > 0) & (cuts < index.size)]
    if cuts.size:
        t = np.insert(t, cuts, np.nan)
        v = np.insert(v, cuts, np.nan)
    return t, v


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


def _best_candidate(diagnosis: Diagnosis) -> Candidate | None:
    for candidate in diagnosis.candidates:
        if candidate.comparison is not None:
            return candidate
    return None


def _model_name(effects: Sequence[str]) -> str:
    return 'nominal' + ''.join(f' + {e}' for e in effects)
